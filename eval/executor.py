"""Where jobs run: in this process, in a pool of local processes, or on a Dask cluster.

A job is a `JobSpec` (a scenario, a method set and a seed: a few kB of configuration, never
arrays); whichever executor runs it, the worker calls `jobs.simulated_job` and hands the
`JobResult` back to this process, which calls `done` (or `fail`) with it as soon as it arrives,
so the caller can write each finished job at once.

On Dask (`distributed`), a job whose worker dies is run again on another worker by the
scheduler (up to its `distributed.scheduler.allowed-failures`, 3 by default, then it fails with
`KilledWorker`); a job that raises is handed to `fail` with its traceback and the others go on.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import time
import uuid
from collections.abc import Callable, Collection, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tcaff_gtsam.errors import ConfigError

from .config import MethodsConfig, ScenarioConfig
from .jobs import simulated_job
from .quiet_spawn import QuietSpawnContext, sigint
from .registry import describe, estimate_names
from .results import JobResult

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["Executor", "JobSpec", "Progress", "dask_client", "job_runner"]

log = logging.getLogger(__name__)

#: done(key, job) and fail(key, error), called in this process's main thread
Done = Callable[[int, JobResult], None]
Fail = Callable[[int, BaseException], None]


class Progress:
    """What running jobs report; the CLI draws it as progress bars."""

    def start(self, key: int, label: str) -> None: ...
    def advance(self, key: int, share: float) -> None: ...
    def finish(self, key: int, ok: bool) -> None: ...

    def lost(self, worker: str, keys: list[int]) -> None:
        """A Dask worker left the cluster holding the jobs `keys` (running or waiting there;
        maybe none); the scheduler runs them again on other workers."""


@dataclass(frozen=True)
class JobSpec:
    """One simulated job, as sent to a worker: a scenario, a method set and a seed."""

    scenario: ScenarioConfig
    methods: MethodsConfig
    seed: int

    @property
    def label(self) -> str:
        return f"{self.scenario.name} seed {self.seed}"


@dataclass(frozen=True)
class Executor:
    """Where jobs run.

    Attributes:
        workers: local processes (1: in this process). Unused on Dask.
        scheduler: the address of a running Dask scheduler (`tcp://host:8786`), whose workers
            run the jobs.
        local_cluster: start a Dask cluster of this many worker processes on this machine
            (127.0.0.1) for the jobs, and stop it afterwards.
    """

    workers: int = 1
    scheduler: str | None = None
    local_cluster: int | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise ConfigError(f"workers {self.workers!r}: must be an int >= 1")
        if self.local_cluster is not None and not (
                isinstance(self.local_cluster, int) and self.local_cluster >= 1):
            raise ConfigError(f"local_cluster {self.local_cluster!r}: must be an int >= 1 "
                              f"(worker processes)")
        if self.scheduler is not None and self.local_cluster is not None:
            raise ConfigError(f"scheduler {self.scheduler!r} and local_cluster "
                              f"{self.local_cluster!r}: give one or the other")
        if self.scheduler is not None and not (isinstance(self.scheduler, str)
                                               and self.scheduler.strip()):
            raise ConfigError(f"scheduler {self.scheduler!r}: expected an address like "
                              f"tcp://host:8786")

    @property
    def on_dask(self) -> bool:
        return self.scheduler is not None or self.local_cluster is not None

    def describe(self) -> str:
        """Where the jobs run, for a person."""
        if self.scheduler is not None:
            return f"Dask scheduler {self.scheduler}"
        if self.local_cluster is not None:
            return f"a local Dask cluster of {self.local_cluster} worker(s)"
        return f"{self.workers} local process(es)"


def expected_seconds(spec: JobSpec) -> float:
    """A rough guess of a job's seconds on one core, from its size: the directed pairs aligned
    each second by every method, the frames simulated (ray-cast and mapped when the scenario
    has a camera) and the frames of people tracked per robot with every causal method's
    alignments. Only the order the jobs start in depends on it, never a result."""
    s = spec.scenario
    n = s.n_robots
    seconds = 6e-3 * s.duration * n * (n - 1)
    frames = s.duration * s.mapping.frame_rate * n
    seconds += frames * (3e-4 if s.camera is None else 3.5e-7 * s.camera.width * s.camera.height)
    if s.pedestrians is not None:
        tracked = 1 + sum(describe(name).causal for name in estimate_names(spec.methods))
        seconds += 5e-4 * s.duration * s.pedestrians.rate * n * tracked
    return seconds


#: run(specs, progress, done, fail): every job of `specs`, keys being indices into it
Run = Callable[[Sequence[JobSpec], Progress, Done, Fail], None]


#: a local Dask scheduler's HTTP server (no dashboard, but metrics) on a free port of 127.0.0.1:
#: its default is 8787, which another cluster's may hold (distributed then warns and takes another)
FREE_HTTP_PORT = {"dashboard_address": "127.0.0.1:0"}

#: the topic the Dask scheduler logs its cluster events to (workers added and removed, ...)
SCHEDULER_EVENTS = "all"


@contextmanager
def job_runner(executor: Executor) -> Iterator[Run]:
    """The executor, ready for the block: a function that runs jobs on it.

    The function calls `done` or `fail` with each job as it ends, in this process. Ctrl-C
    (KeyboardInterrupt) stops the jobs not yet finished and is raised again; the jobs finished
    by then have been handed to `done`. On Dask the client is connected (or the local cluster
    started) on entry and closed on exit.

    Raises:
        ConfigError: on entry, when the Dask scheduler cannot be reached or its workers lack
            this package.
    """
    if executor.on_dask:
        with dask_client(executor) as client:
            yield lambda specs, progress, done, fail: _run_dask(client, specs, progress, done,
                                                                fail)
    else:
        yield lambda specs, progress, done, fail: _run_local(executor.workers, specs,
                                                             progress, done, fail)


def _run_local(workers: int, specs: Sequence[JobSpec], progress: Progress, done: Done,
               fail: Fail) -> None:
    """In this process (one worker or one job), else in a pool of processes."""
    if workers > 1 and len(specs) > 1:
        _run_pool(specs, min(workers, len(specs)), progress, done, fail)
        return
    for key, spec in enumerate(specs):
        try:
            job = simulated_job(spec.scenario, spec.methods, spec.seed,
                                lambda share, key=key: progress.advance(key, share))
        except Exception as exc:
            fail(key, exc)
            continue
        done(key, job)


# -- local processes -----------------------------------------------------------------------------


def _job_in_worker(spec: JobSpec, key: int, updates) -> JobResult:
    return simulated_job(spec.scenario, spec.methods, spec.seed,
                         lambda share: updates.put((key, share)))


_ANNOUNCE_WAIT = 3.0  # seconds a stopped study waits for workers still starting


def _announce(updates, threads: int) -> None:
    """Each worker process ignores Ctrl-C (the study's process handles it and ends the workers)
    and says who it is, so a stopped study can end its workers. It renders on `threads`
    threads, its share of the cores (`sim.threads.cast_threads`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # already so when started by the study
    try:
        updates.put(("pid", os.getpid()))
    except (OSError, EOFError):
        # The study was stopped while this worker started, gave up waiting for it and closed
        # its queue: end before taking a job, and without the pool's traceback of a failed
        # initializer under the study's one-line message.
        os._exit(0)
    from .sim.threads import cast_threads

    cast_threads(threads)


def _run_pool(specs: Sequence[JobSpec], workers: int, progress: Progress, done: Done,
              fail: Fail) -> None:
    context = QuietSpawnContext()  # spawn: fork would copy numba and gtsam state
    with sigint(deferred=True):
        manager = context.Manager()  # started
    with manager:
        updates = manager.Queue()
        # each worker's share of the cores: threads beyond it only wait for a core
        share = max(1, (os.cpu_count() or 1) // workers)
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_announce, initargs=(updates, share))
        workers_seen: set[int] = set()
        futures: dict[Future, int] = {}
        handled: set[Future] = set()

        def collect(future: Future) -> None:
            handled.add(future)
            key = futures[future]
            try:
                job = future.result()
            except Exception as exc:
                fail(key, exc)
                return
            done(key, job)

        try:
            # the longest jobs first: a long job started last would run on while the other
            # workers idle (the keys, and so the results' order, stay those of `specs`)
            for key in sorted(range(len(specs)), key=lambda k: -expected_seconds(specs[k])):
                futures[pool.submit(_job_in_worker, specs[key], key, updates)] = key
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                _drain(updates, progress, workers_seen)
                for future in finished:
                    collect(future)
        except BaseException:
            _drain(updates, None, workers_seen)
            # workers still starting ignore Ctrl-C and announce themselves once started: wait a
            # moment for them, or one could take a queued job and run it to the end
            deadline = time.monotonic() + _ANNOUNCE_WAIT
            while len(workers_seen) < workers and time.monotonic() < deadline:
                time.sleep(0.05)
                _drain(updates, None, workers_seen)
            pool.shutdown(wait=False, cancel_futures=True)
            for pid in workers_seen:  # a running job would otherwise finish first
                try:
                    os.kill(pid, signal.SIGTERM)
                except ProcessLookupError:
                    continue
            # jobs that finished meanwhile are kept like the others
            for future in futures:
                if future not in handled and future.done() and not future.cancelled():
                    try:
                        collect(future)
                    except BaseException:
                        continue
            raise
        pool.shutdown()


def _drain(updates, progress: Progress | None, workers_seen: set[int]) -> None:
    """Pass the workers' progress reports on and note the workers' process ids."""
    while True:
        try:
            key, value = updates.get_nowait()
        except (queue.Empty, OSError, EOFError):  # the manager may be gone on Ctrl-C
            return
        if key == "pid":
            workers_seen.add(value)
        elif progress is not None:
            progress.advance(key, value)


# -- Dask --------------------------------------------------------------------------------------

_PROGRESS_STEP = 0.05  # share of a job between two progress events a Dask worker sends
_CONNECT_TIMEOUT = 5.0  # s to reach a scheduler


def _job_on_dask(spec: JobSpec, key: int, topic: str) -> JobResult:
    """Run one job on a Dask worker, sending its progress to the scheduler's `topic` events
    now and then (each event is a message to the scheduler)."""
    from distributed import get_worker

    worker = get_worker()
    sent = [-1.0]

    def report(share: float) -> None:
        if share - sent[0] >= _PROGRESS_STEP:
            sent[0] = share
            worker.log_event(topic, [key, float(share)])

    return simulated_job(spec.scenario, spec.methods, spec.seed, report)


def _worker_stack() -> str:
    """Runs on each worker: this package's version there."""
    from importlib.metadata import version

    import tcaff_gtsam.eval.jobs  # noqa: F401  (the stack a job needs imports on the worker)

    return version("tcaff-gtsam")


@contextmanager
def dask_client(executor: Executor) -> Iterator[Client]:
    """A client of the executor's scheduler, or of a local cluster started for the block.

    Raises:
        ConfigError: distributed is not installed, or no scheduler answers at the address, or
            a worker lacks this package (or has another version of it).
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ConfigError("running on Dask needs the distributed package: pip install "
                          "'tcaff-gtsam[cluster]'") from None
    cluster = None
    try:
        if executor.local_cluster is not None:
            # worker processes started with Ctrl-C ignored: this process handles it and stops
            # the cluster (a Ctrl-C while the cluster starts is dropped)
            with sigint(deferred=False):
                cluster = LocalCluster(n_workers=executor.local_cluster, threads_per_worker=1,
                                       processes=True, host="127.0.0.1", scheduler_port=0,
                                       dashboard_address=None, silence_logs=logging.ERROR,
                                       scheduler_kwargs=FREE_HTTP_PORT)
            client = Client(cluster)
        else:
            try:
                client = Client(executor.scheduler, timeout=_CONNECT_TIMEOUT)
            except (OSError, ValueError, TypeError) as exc:
                raise ConfigError(f"scheduler {executor.scheduler!r}: no Dask scheduler "
                                  f"answers there ({type(exc).__name__}: {exc})") from None
        with client:
            _check_workers(client)
            yield client
    finally:
        if cluster is not None:
            cluster.close()


def _check_workers(client: Client) -> None:
    """Every worker connected now runs this package at this version (a worker that cannot
    import it would fail every job it takes)."""
    from importlib.metadata import version

    mine = version("tcaff-gtsam")
    try:
        theirs = client.run(_worker_stack, on_error="return")
    except OSError:  # the workers vanished meanwhile; jobs wait for new ones
        return
    bad = {worker: answer for worker, answer in theirs.items() if answer != mine}
    if bad:
        worker, answer = next(iter(bad.items()))
        what = (f"has tcaff-gtsam {answer}" if isinstance(answer, str)
                else f"cannot import tcaff_gtsam ({type(answer).__name__}: {answer})")
        raise ConfigError(f"scheduler {client.scheduler.address}: worker {worker} {what}; every "
                          f"worker needs tcaff-gtsam {mine} (see "
                          f"docs/sweeps.md#running-on-a-real-cluster)")


def _run_dask(client: Client, specs: Sequence[JobSpec], progress: Progress, done: Done,
              fail: Fail) -> None:
    from distributed import as_completed

    if not specs:
        return
    topic = f"tcaff-progress-{uuid.uuid4().hex}"
    updates: queue.SimpleQueue = queue.SimpleQueue()
    removals: queue.SimpleQueue = queue.SimpleQueue()
    client.subscribe_topic(topic, lambda event: updates.put(event[1]))
    # the scheduler's own events: a worker removed, with the tasks it was processing then
    client.subscribe_topic(SCHEDULER_EVENTS, lambda event: removals.put(event[1]))
    futures = {client.submit(_job_on_dask, spec, key, topic,
                             key=f"{spec.label.replace(' ', '-')}-{uuid.uuid4().hex[:8]}"): key
               for key, spec in enumerate(specs)}
    jobs = {future.key: key for future, key in futures.items()}
    remaining = as_completed(futures)
    try:
        while not remaining.is_empty():
            finished = remaining.next_batch(block=False)
            _drain_events(updates, progress)
            _report_lost_workers(removals, jobs, futures.values(), progress)
            if not finished:
                time.sleep(0.05)
            for future in finished:
                key = futures.pop(future)
                try:
                    job = future.result()
                except Exception as exc:
                    fail(key, exc)
                    continue
                finally:
                    future.release()  # its result leaves the cluster's memory
                done(key, job)
    except BaseException:
        client.cancel(list(futures))
        raise
    finally:
        client.unsubscribe_topic(topic)
        client.unsubscribe_topic(SCHEDULER_EVENTS)


def _report_lost_workers(removals: queue.SimpleQueue, jobs: dict[str, int],
                         pending: Collection[int], progress: Progress) -> None:
    """Report the workers the scheduler removed, on purpose or not, with those of their jobs
    (Dask key -> job key in `jobs`) still `pending` (not yet handed to done or fail), which the
    scheduler runs again elsewhere. A worker retired on purpose holding none of them is not a
    loss."""
    waiting: set[int] | None = None  # `pending` as a set, made when a worker was removed
    while True:
        try:
            event = removals.get_nowait()
        except queue.Empty:
            return
        if not (isinstance(event, dict) and event.get("action") == "remove-worker"):
            continue
        waiting = set(pending) if waiting is None else waiting
        held = sorted(jobs[k] for k in event.get("processing-tasks", ()) if k in jobs
                      and jobs[k] in waiting)
        if held or not event.get("expected", False):
            progress.lost(str(event.get("worker")), held)


def _drain_events(updates: queue.SimpleQueue, progress: Progress) -> None:
    while True:
        try:
            key, share = updates.get_nowait()
        except queue.Empty:
            return
        progress.advance(int(key), float(share))
