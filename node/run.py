"""One node process replaying a robot, and a team of them on this machine over loopback."""

from __future__ import annotations

import gc
import logging
import math
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from tcaff_gtsam.params import (
    FrameAlignerParams,
    TCAFFParams,
    _finite,
    _int_at_least,
    _require,
)
from tcaff_gtsam.precompile import compile_kernels

from .link import Link, TlsFiles
from .node import FINISH_TIMEOUT, NodeParams, RobotNode, _joined, _until
from .replay import MAX_TEAM, RobotReplay, replay, robot_names, run_replay
from .results import TEAM_COLUMNS, AlignmentCsv, write_counters

__all__ = ["STOP_TIMEOUT", "free_ports", "live_node", "node_argv", "replay_node", "save_replays",
           "start_team", "wait_team"]

log = logging.getLogger(__name__)

#: s from SIGTERM or SIGINT to a node's results written (`tcaff node --stop-timeout`), its
#: worker and saver finished or left; its session then gets what is left, `_CLOSE_LEAST` s at
#: least. Well within ROS 2 launch's 5 s from SIGINT to SIGTERM (and 5 s more to SIGKILL),
#: on a busy machine too
STOP_TIMEOUT = 2.0
#: s its session gets to close after the results are written, whatever is left of the budget:
#: a healthy close (0.1 s on a loaded machine) withdraws the node from its team cleanly
_CLOSE_LEAST = 0.5


def replay_node(source: RobotReplay, team: str, link: Link, params: NodeParams,
                start: float | None, output: Path, clock_offset: float = 0.0,
                state_dir: Path | None = None,
                progress: Callable[[int, int], None] | None = None,
                stop_timeout: float = STOP_TIMEOUT) -> RobotNode:
    """Run the node of `source`'s robot until its last exchange (or SIGTERM / SIGINT).

    Args:
        start: wall time (epoch s) of the run's first exchange; None: 1 s after every robot
            of the run is up and linked (or `TEAM_WAIT` s have passed).
        stop_timeout: s from SIGTERM or SIGINT to the results written, what the worker
            has not finished by then left (see `_close`); a second signal ends the stop's
            waits at once.
    Writes `<output>/<robot>.csv` (every alignment, as made), with team consistency
    `<output>/<robot>.team.csv` (every team alignment), and `<output>/<robot>.json` (the start,
    then also the node's counters at the end, its share of one core over the replay and the
    latency from a neighbour's map arriving to its alignment going out). Returns the closed
    node.

    Raises:
        ParameterError: stop_timeout not a number > 0.
    """
    _check_stop_timeout("replay_node", stop_timeout)
    robot = source.robots[source.robot]
    params = replace(params, kappa=source.kappa)
    tcaff = None if source.window is None else TCAFFParams(window=source.window)
    aligner = FrameAlignerParams(kappa=source.kappa)
    with _node_files(robot, output, params.team_consistency, stop_timeout
                     ) as (stop, rows, team_rows):
        compile_kernels()  # so that the first exchanges are not late
        node = RobotNode(robot, team, list(source.robots), link, params, aligner, tcaff,
                         rows.write, state_dir, on_team=team_rows and team_rows.write)
        _freeze_heap()
        timing: dict[str, float] = {}
        try:
            if start is None:
                start = _team_start(node, stop)
            write_counters(output / f"{robot}.json", {"start": start})
            cpu, began = time.process_time(), time.time()
            # a full queue behind a stuck worker must not keep the stop waiting
            replay(source, partial(node.publish, cancel=stop.is_set), start, params.speed,
                   clock_offset, stop, progress)
            if not stop.is_set():
                # the neighbours' last maps are still on their way
                stop.wait(min(2.0, 2.0 / params.speed) + 0.2)
            node.wait_idle(60.0, stop.over)
            timing = {"cpu_share": (time.process_time() - cpu) / max(time.time() - began, 1e-9)}
        finally:
            _close(node, output / f"{robot}.json", start, timing, stop)
    return node


def live_node(robot: str, team: str, members: list[str], link: Link, params: NodeParams,
              output: Path, state_dir: Path | None = None, duration: float | None = None,
              stop_timeout: float = STOP_TIMEOUT) -> RobotNode:
    """Run a node that takes its robot's maps from the ROS 2 topic /<robot>/tcaff/objects
    (`params.ros2_objects`) until SIGTERM / SIGINT or `duration` s; writes what `replay_node`
    writes (without the share of a core), stops as it does. Returns the closed node."""
    _check_stop_timeout("live_node", stop_timeout)
    with _node_files(robot, output, params.team_consistency, stop_timeout
                     ) as (stop, rows, team_rows):
        compile_kernels()
        node = RobotNode(robot, team, members, link, params, on_alignment=rows.write,
                         state_dir=state_dir, on_team=team_rows and team_rows.write)
        _freeze_heap()
        start = time.time()
        try:
            write_counters(output / f"{robot}.json", {"start": start})
            stop.wait(duration)
            node.wait_idle(60.0, stop.over)
        finally:
            _close(node, output / f"{robot}.json", start, {}, stop)
    return node


class _StopEvent:
    """A node process's stop event, which a signal handler may set at any moment.

    A `threading.Event` cannot be: the handler runs on the main thread between two of its
    bytecodes, and when those are inside the same event's `wait`, which holds the event's lock,
    `set` waits for that lock forever (the process then ignores every further SIGTERM). Here
    `set` takes no lock: it writes a byte to a pipe, and `wait` waits for the pipe to be
    readable; the byte is never read, so every later `wait` returns at once. The methods are
    the `threading.Event` ones that `replay` and `_team_start` use, and the stop's budget of
    `budget` s: `over` and `left`, counted from the first `set`, and spent at once by a second
    (the second signal of a supervisor losing patience).

    Attributes:
        at: `time.monotonic()` of the first `set` (None: not set).
        times: how many times it was set.
    """

    def __init__(self, budget: float) -> None:
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)  # a signal handler never blocks
        self._budget = budget
        self.at: float | None = None
        self.times = 0

    def set(self) -> None:
        self.times += 1
        if self.at is None:
            self.at = time.monotonic()
            os.write(self._write, b"\0")

    def is_set(self) -> bool:
        return self.at is not None

    def left(self) -> float:
        """s left of the budget (inf before the first `set`; 0 after a second)."""
        if self.at is None:
            return math.inf
        return 0.0 if self.times > 1 else max(self.at + self._budget - time.monotonic(), 0.0)

    def over(self) -> bool:
        """Whether the budget has passed since the first `set`, or it was set again."""
        return self.left() <= 0.0

    def wait(self, timeout: float | None = None) -> bool:
        """True once set; waits up to `timeout` s (None: until set) for that."""
        if not self.is_set():
            select.select([self._read], [], [], None if timeout is None else max(timeout, 0.0))
        return self.is_set()

    def close(self) -> None:
        os.close(self._read)
        os.close(self._write)


@contextmanager
def _node_files(robot: str, output: Path, team_consistency: bool, stop_timeout: float
                ) -> Iterator[tuple[_StopEvent, AlignmentCsv, AlignmentCsv | None]]:
    """A node process's stop event (its budget `stop_timeout` s), set by SIGTERM / SIGINT
    while inside (the previous handlers are restored after), and the CSV writers of its
    alignments (and team alignments), closed after."""
    output.mkdir(parents=True, exist_ok=True)
    with ExitStack() as opened:  # what opened is closed, also when the next fails to open
        rows = AlignmentCsv(output / f"{robot}.csv")
        opened.callback(rows.close)
        team_rows = None
        if team_consistency:
            team_rows = AlignmentCsv(output / f"{robot}.team.csv", TEAM_COLUMNS)
            opened.callback(team_rows.close)
        stop = _StopEvent(stop_timeout)
        opened.callback(stop.close)
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                opened.callback(signal.signal, sig, signal.signal(sig, lambda *_: stop.set()))
        yield stop, rows, team_rows


def _freeze_heap() -> None:
    """In a node process (the runner on its main thread), leave every object alive now out of
    the later garbage collections (`gc.freeze`): the libraries' (numba's kernels, gtsam,
    rclpy; some 130 000 objects) and the node's, all kept until the process ends.

    The interpreter's teardown collects the garbage several times over, and that was most of
    a node's exit after SIGTERM: 0.45 s of CPU, 0.07 s with the heap frozen, which a loaded
    machine stretches (beside ten busy processes on two cores: 8 to 13 s, frozen 0.7 to
    1.2 s). A runner on another thread is a guest of its process and leaves its heap alone.
    """
    if threading.current_thread() is threading.main_thread():
        gc.freeze()


def _check_stop_timeout(owner: str, stop_timeout: float) -> None:
    _require(_finite(stop_timeout) and stop_timeout > 0, owner, "stop_timeout", stop_timeout,
             "must be a number > 0 (s)")


def _close(node: RobotNode, path: Path, start: float | None, timing: dict[str, float],
           stop: _StopEvent) -> None:
    """Stop `node` within the stop's budget from its signal (a second ends every wait at
    once): its worker finishes what it has received and its filters are saved
    (`RobotNode.finish`), then its outcome goes to `path` (`_write_outcome`), then its session
    closes (`_close_session`). A stop cut short (a worker stuck in a step) writes what is
    known, with "stop_cut_short" 1 and "stop_unhandled", the messages left unhandled. The
    outcome is written whatever the finishing raises, and before the session's close, which
    may take long (Zenoh gives up on a frozen peer after some 10 s); a failure of the close is
    raised after."""
    finished = False
    try:
        finished = node.finish(min(stop.left(), FINISH_TIMEOUT), stop.over)
    finally:
        ending = {} if finished else {"stop_cut_short": 1, "stop_unhandled": node.queued()}
        if stop.at is not None:
            ending["stop_s"] = time.monotonic() - stop.at
        _write_outcome(path, node, start, timing | ending)
    least = time.monotonic() + _CLOSE_LEAST
    _close_session(node, lambda: stop.times > 1 or (stop.over() and time.monotonic() > least))


def _close_session(node: RobotNode, cancel: Callable[[], bool]) -> None:
    """Close `node` (its session; its worker has finished or been left) on a thread, waiting
    until it is closed or `cancel()` is true; a session left closing is logged, and the
    process's exit ends it. A failure of the close is raised here."""
    failed: list[BaseException] = []

    def close() -> None:
        try:
            node.close()
        except BaseException as exc:  # raised on the caller's thread
            failed.append(exc)

    closing = threading.Thread(target=close, name=f"tcaff-close-{node.robot}", daemon=True)
    closing.start()
    if not _until(lambda s: _joined(closing, s), math.inf, cancel):
        log.warning("%s: its session is still closing; the node stops without waiting for "
                    "it (its results are written)", node.robot)
    if failed:
        raise failed[0]


def _write_outcome(path: Path, node: RobotNode, start: float | None,
                   timing: dict[str, float]) -> None:
    """A closed node's JSON: its start, counters, `timing` and its latency figures."""
    latency = np.array(node.latencies)
    if latency.size:
        timing = timing | {"latency_median_ms": 1e3 * float(np.median(latency)),
                           "latency_p95_ms": 1e3 * float(np.percentile(latency, 95)),
                           "latency_max_ms": 1e3 * float(latency.max())}
    write_counters(path, {"start": start, **node.counters, **timing})


#: s a node waits for its team before it starts its run anyway
TEAM_WAIT = 120.0


def _team_start(node: RobotNode, stop: _StopEvent) -> float:
    """1 s after every member is present; `TEAM_WAIT` s at most (or the stop)."""
    deadline = time.monotonic() + TEAM_WAIT
    while (missing := node.members - node.present()) and time.monotonic() < deadline:
        if stop.wait(0.1):
            log.info("%s: stopped while waiting for %s", node.robot,
                     ", ".join(sorted(missing)))
            break
    else:
        if missing:
            log.warning("%s: starting without %s", node.robot, ", ".join(sorted(missing)))
    return time.time() + 1.0


def free_ports(n: int) -> list[int]:
    """n TCP ports on 127.0.0.1 free at this moment.

    Raises:
        ConfigError: n not an int in [0, MAX_TEAM] (a socket each is held open at once).
    """
    _require(_int_at_least(n, 0) and n <= MAX_TEAM, "free_ports", "n", n,
             f"must be an int in [0, {MAX_TEAM}] (MAX_TEAM)")
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def node_argv(replay_file: Path, robot: int, n: int, team: str, ports: list[int],
              start: float | None, output: Path, speed: float = 1.0, drop_share: float = 0.0,
              clock_offset: float = 0.0, state: Path | None = None,
              tls: TlsFiles | None = None, silence: float | None = None,
              team_consistency: bool = False, domain_id: int | None = None,
              on_arrival: bool = False, ros2: str = "zenoh") -> list[str]:
    """The command line of robot `robot` of a team of n on loopback, replaying its
    `RobotReplay` file: it listens on ports[robot] and dials every robot before it, so every
    pair is linked once. `domain_id`: speak ROS 2 in that domain (--ros2 `ros2`: "zenoh", the
    Zenoh team with ROS 2 topics, or "dds", a team over rclpy, for which `ports` and `tls`
    are not used); `on_arrival`: align maps as they arrive (--on-arrival), not exchange by
    exchange."""
    dds = domain_id is not None and ros2 == "dds"
    argv = [sys.executable, "-m", "tcaff_gtsam.eval.cli", "node", "--robot", f"r{robot}",
            "--team", team, "--replay", str(replay_file), "--speed", str(speed),
            "--output", str(output)]
    if not dds:
        argv += ["--listen", f"127.0.0.1:{ports[robot]}"]
        for other in range(robot):
            argv += ["--connect", f"127.0.0.1:{ports[other]}"]
    if start is not None:
        argv += ["--start-at", repr(start)]
    if drop_share:
        argv += ["--drop-share", str(drop_share), "--drop-seed", str(robot)]
    if clock_offset:
        argv += ["--clock-offset", str(clock_offset)]
    if state is not None:
        argv += ["--state", str(state)]
    if silence is not None:
        argv += ["--silence", str(silence)]
    if team_consistency:
        argv.append("--team-consistency")
    if on_arrival:
        argv.append("--on-arrival")
    if domain_id is not None:
        argv += ["--ros2", ros2, "--domain-id", str(domain_id)]
    if tls is not None and not dds:
        argv += ["--tls-ca", str(tls.ca), "--tls-cert", str(tls.certificate),
                 "--tls-key", str(tls.key)]
    return argv


def save_replays(run, folder: Path) -> list[Path]:
    """Each robot's `RobotReplay` of an `AlignmentRun` in `<folder>/r<k>.npz`: a run made once
    (simulated or loaded) that every node process reads instead of making it again."""
    folder.mkdir(parents=True, exist_ok=True)
    names = robot_names(run.n_robots)
    paths = []
    for k in range(run.n_robots):
        paths.append(folder / f"{names[k]}.npz")
        run_replay(run, k, names).save(paths[-1])
    return paths


def start_team(argvs: list[list[str]], log_dir: Path) -> list[subprocess.Popen]:
    """Start each node command, its output in `<log_dir>/node<k>.log` (what `tcaff team`
    quotes a failed node's error from)."""
    log_dir.mkdir(parents=True, exist_ok=True)
    procs = []
    for k, argv in enumerate(argvs):
        with open(log_dir / f"node{k}.log", "wb") as out:
            procs.append(subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT))
    return procs


def wait_team(procs: list[subprocess.Popen], timeout: float) -> list[int | None]:
    """Exit codes of every node (None: still running at `timeout` s, then terminated)."""
    deadline = time.monotonic() + timeout
    codes: list[int | None] = []
    for proc in procs:
        try:
            codes.append(proc.wait(max(deadline - time.monotonic(), 0.1)))
        except subprocess.TimeoutExpired:
            proc.terminate()
            proc.wait(10)
            codes.append(None)
    return codes
