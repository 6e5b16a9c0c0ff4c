"""The comparison study: schedules scenarios x seeds as jobs, in parallel processes.

Each job (`jobs.simulated_job`: one scenario, one seed) simulates the run, runs every
method over every directed pair and scores them. A finished job is written to
`<output>/<timestamp>/runs/` at once, with the trajectories of the table's methods in TUM files
under `trajectories/` (see `trajectories`), so an interrupted or partly failed study keeps
everything it finished. At the end the study writes
metrics.json, metrics.csv and the figures, and points `<output>/latest` at the folder.
"""

from __future__ import annotations

import logging
import os
import queue
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from multiprocessing.context import SpawnContext, SpawnProcess
from pathlib import Path

from tcaff_gtsam.errors import DataError

from .config import MethodsConfig, ScenarioConfig, StudyConfig, dump_study
from .jobs import simulated_job
from .registry import estimate_names, shown_streams
from .results import JobResult, summarize, summarize_mot, thresholds_of, write_tables
from .trajectories import write_tum

__all__ = ["Progress", "StudyOutcome", "run_study"]

log = logging.getLogger(__name__)

@dataclass
class StudyOutcome:
    """What a study produced, including when it stopped early."""

    folder: Path
    jobs: list[JobResult]
    failed: list[dict]
    interrupted: bool
    summary: dict[str, dict[str, dict]]
    mot_summary: dict[str, dict[str, dict]] = field(default_factory=dict)


def _job_in_worker(scenario: ScenarioConfig, methods: MethodsConfig, seed: int, key: int,
                   updates) -> JobResult:
    return simulated_job(scenario, methods, seed, lambda share: updates.put((key, share)))


_ANNOUNCE_WAIT = 3.0  # seconds a stopped study waits for workers still starting


def _announce(updates) -> None:
    """Each worker process ignores Ctrl-C (the study's process handles it and ends the workers)
    and says who it is, so a stopped study can end its workers."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # already so when started by the study
    updates.put(("pid", os.getpid()))


@contextmanager
def _sigint(deferred: bool) -> Iterator[None]:
    """Ctrl-C in this process during the block: ignored (`deferred` False), or held back and
    raised once the block is done (True). Only the main thread can do either.

    Ignored, for the moment this process starts a process (a few ms): an ignored SIGINT stays
    ignored in the new process, which then never raises KeyboardInterrupt, not even while it
    starts (imports the stack, before `_announce`). Deferred, while the manager starts: cut
    short, its process, left without a reader, prints a traceback."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, (lambda signum, frame: caught.append(signum)) if deferred
                      else signal.SIG_IGN)
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class _QuietSpawnProcess(SpawnProcess):
    """A spawned process that ignores Ctrl-C from its very start (see `_sigint`)."""

    @staticmethod
    def _Popen(process_obj):
        with _sigint(deferred=False):
            return SpawnProcess._Popen(process_obj)


class _QuietSpawnContext(SpawnContext):
    """The spawn context, its processes (the pool's workers, the manager) ignoring Ctrl-C: the
    study's process handles it and ends them."""

    Process = _QuietSpawnProcess


def _new_folder(root: Path) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    root.mkdir(parents=True, exist_ok=True)
    for n in range(1, 1000):
        folder = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir()  # atomic: two studies started in the same second get two folders
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{root}: no free results folder for {stamp}")


def _link_latest(root: Path, folder: Path) -> None:
    latest = root / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(folder.name, target_is_directory=True)
    except OSError as exc:  # some file systems have no symbolic links; results are still there
        log.warning("could not link %s: %s", latest, exc)


class Progress:
    """What the study reports while it runs; the CLI draws it as progress bars."""

    def start(self, key: int, label: str) -> None: ...
    def advance(self, key: int, share: float) -> None: ...
    def finish(self, key: int, ok: bool) -> None: ...


def run_study(study: StudyConfig, progress: Progress | None = None,
              on_job_done: Callable[[JobResult], None] | None = None,
              figures: bool = True) -> StudyOutcome:
    """Run a resolved study (see `config.resolve_study`) and write its results.

    Jobs run in `study.workers` processes (in this process when 1). Ctrl-C stops the study: the
    jobs already finished are summarised and written, and `interrupted` is set.

    Args:
        on_job_done: called in this process with each finished job, after it is saved.
        figures: draw the PNG figures.
    """
    from . import plots

    progress = progress or Progress()
    root = Path(study.output)
    try:
        folder = _new_folder(root)
    except OSError as exc:
        raise DataError(f"output {str(root)!r}: cannot make a results folder in it "
                        f"({exc.strerror or exc})") from None
    (folder / "config.yaml").write_text(dump_study(study))
    methods: MethodsConfig = study.methods  # type: ignore[assignment]
    todo = [(s, seed) for s in study.scenarios for seed in study.seeds]
    jobs: list[JobResult] = []
    failed: list[dict] = []
    shown = shown_streams(methods)  # the table's; `tcaff export` writes the whole sweep
    interrupted = False

    def done(key: int, job: JobResult) -> None:
        job.save(folder / "runs")
        write_tum(folder, job, streams=shown)
        jobs.append(job)
        progress.finish(key, True)
        if on_job_done is not None:
            on_job_done(job)

    def fail(key: int, scenario: ScenarioConfig, seed: int, exc: BaseException) -> None:
        log.error("%s seed %d failed: %s", scenario.name, seed, exc)
        failed.append({"scenario": scenario.name, "seed": seed, "error": str(exc),
                       "traceback": "".join(traceback.format_exception(exc))})
        progress.finish(key, False)

    for key, (scenario, seed) in enumerate(todo):
        progress.start(key, f"{scenario.name} seed {seed}")
    try:
        if study.workers == 1 or len(todo) == 1:
            for key, (scenario, seed) in enumerate(todo):
                try:
                    job = simulated_job(scenario, methods, seed,
                                  lambda share, key=key: progress.advance(key, share))
                except Exception as exc:
                    fail(key, scenario, seed, exc)
                    continue
                done(key, job)
        else:
            _run_parallel(todo, methods, min(study.workers, len(todo)), progress, done, fail)
    except KeyboardInterrupt:
        interrupted = True  # the caller reports it; the finished jobs are written below
        log.info("interrupted: writing the %d finished jobs", len(jobs))
    order = {(s.name, seed): k for k, (s, seed) in enumerate(todo)}
    jobs.sort(key=lambda j: order[(j.name, j.seed)])
    names = estimate_names(methods)
    outcome = StudyOutcome(folder, jobs, failed, interrupted,
                           summarize(jobs, names, thresholds_of(methods)), summarize_mot(jobs))
    write_tables(folder, {"study": study.name, "interrupted": interrupted, "failed": failed},
                 jobs, outcome.summary, outcome.mot_summary)
    if figures and jobs:
        plots.draw_all(folder / "figures", jobs, outcome.summary, methods, outcome.mot_summary)
    if jobs:
        _link_latest(root, folder)
    return outcome


def _run_parallel(todo, methods: MethodsConfig, workers: int, progress: Progress,
                  done, fail) -> None:
    context = _QuietSpawnContext()  # spawn: fork would copy numba and gtsam state
    with _sigint(deferred=True):
        manager = context.Manager()  # started
    with manager:
        updates = manager.Queue()
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_announce, initargs=(updates,))
        workers_seen: set[int] = set()
        futures: dict[Future, int] = {}
        handled: set[Future] = set()

        def collect(future: Future) -> None:
            handled.add(future)
            key = futures[future]
            scenario, seed = todo[key]
            try:
                job = future.result()
            except Exception as exc:
                fail(key, scenario, seed, exc)
                return
            done(key, job)

        try:
            for key, (scenario, seed) in enumerate(todo):  # starts the workers
                futures[pool.submit(_job_in_worker, scenario, methods, seed, key, updates)] = key
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
