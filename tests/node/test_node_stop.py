"""How a node stops: SIGTERM and SIGINT alike (ROS 2 launch sends SIGINT, then SIGTERM, then
SIGKILL), within a budget whatever its worker is doing, and with its results whole whenever
the process is killed.

The live tests run two `tcaff node` processes of a team over loopback, r0's worker stuck in
its third filter update (after two steps, whose results are done); they are marked
`realtime`. Their waits are hang guards, not paces the tests expect.
"""

from __future__ import annotations

import ast
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from stuck_node import DONE, ONE_OBJECT, node_stuck_in_its_first_step, start_pair
from tcaff_gtsam.node.replay import RobotReplay, replay
from tcaff_gtsam.node.results import read_alignments

#: hang guard of the waits below (s): a failure, not a pace the tests expect
_HANG = 90.0
#: s a stopped node gets to exit: half the 90 s its stop took before it had a budget (60 s
#: for the worker to go idle, 30 s to finish), which a stop that ignored its budget or a
#: second signal would still take; the stop itself takes about 2 s (`--stop-timeout`)
_STOP_GUARD = 45.0

class StuckTeam:
    """r1, and r0 whose worker sticks in its third update; `stuck()` waits until it has."""

    def __init__(self, folder: Path, *r0_options: str) -> None:
        self.out = folder / "out"
        self.marker = folder / "stuck"
        self.procs, self.logs = start_pair(folder, "stopping", self.marker,
                                           r0_options=r0_options)

    def stuck(self) -> None:
        deadline = time.monotonic() + _HANG
        while not self.marker.exists():
            assert self.procs[0].poll() is None, self.logs[0].read_text()[-3000:]
            assert time.monotonic() < deadline, "r0's worker never got to its third update"
            time.sleep(0.05)

    def stopped(self) -> int:
        """r0's exit status (TimeoutExpired if it does not exit within `_STOP_GUARD`)."""
        return self.procs[0].wait(_STOP_GUARD)

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.fixture
def stuck_team(tmp_path: Path):
    teams: list[StuckTeam] = []

    def make(*r0_options: str) -> StuckTeam:
        teams.append(StuckTeam(tmp_path, *r0_options))
        return teams[-1]

    yield make
    for team in teams:
        team.close()


def assert_results_of_the_finished_steps(out: Path) -> dict:
    """r0's JSON holds its counters: the steps made before the worker stuck, as its CSV
    rows, and the stop noted as cut short. Returns it."""
    outcome = json.loads((out / "r0.json").read_text())
    assert outcome["aligned"] == DONE, outcome
    assert len(read_alignments(out / "r0.csv")["seq"]) == DONE
    assert outcome["maps_sent"] >= DONE and outcome["maps_received"] >= DONE, outcome
    assert outcome["stop_cut_short"] == 1 and "stop_unhandled" in outcome, outcome
    assert not (out / "r0.json.partial").exists()
    return outcome


@pytest.mark.realtime
@pytest.mark.parametrize("first", [signal.SIGTERM, signal.SIGINT], ids=lambda s: s.name)
def test_a_node_whose_worker_is_stuck_writes_its_results_and_exits_when_stopped(
        stuck_team, first: signal.Signals) -> None:
    """SIGTERM (systemd's) and SIGINT (ROS 2 launch's first) alike: r0 stops with its worker
    stuck in a step, writes the results of the steps it made, noting the stop cut short, and
    exits by itself (it used to wait for the worker 90 s, past launch's SIGKILL)."""
    team = stuck_team()
    team.stuck()
    team.procs[0].send_signal(first)
    assert team.stopped() == 0, team.logs[0].read_text()[-3000:]
    assert_results_of_the_finished_steps(team.out)


@pytest.mark.realtime
def test_a_second_signal_cuts_the_stop_short(stuck_team) -> None:
    """With a budget longer than the hang guard, a second signal (launch's SIGTERM after its
    SIGINT) ends the stop's waits at once: the results are written and the node exits."""
    team = stuck_team("--stop-timeout", "3600")
    team.stuck()
    team.procs[0].send_signal(signal.SIGINT)
    time.sleep(0.5)  # inside the stop (or not yet: two signals before it are the same)
    team.procs[0].send_signal(signal.SIGTERM)
    assert team.stopped() == 0, team.logs[0].read_text()[-3000:]
    assert_results_of_the_finished_steps(team.out)


def test_a_stuck_worker_leaves_finish_at_its_timeout_with_what_it_holds() -> None:
    """`finish` gives up on a worker stuck in a step and says so, counting what it left
    unhandled; a replay's publish behind the full queue gives up when told to, the map not
    aligned and counted."""
    node, stepping, release = node_stuck_in_its_first_step(2)
    try:
        node.publish(0.0, ONE_OBJECT)
        assert stepping.wait(_HANG)
        node.publish(1.0, ONE_OBJECT)
        node.publish(2.0, ONE_OBJECT)  # the queue's two places
        node.publish(3.0, ONE_OBJECT, cancel=lambda: True)
        assert node.counters["dropped_overflow"] == 1
        answers: list[bool] = []
        finishing = threading.Thread(target=lambda: answers.append(node.finish(0.2)),
                                     daemon=True)
        finishing.start()
        finishing.join(_HANG)  # catches a hang only
        assert answers == [False]
        assert node.queued() == 2

        def waited() -> bool:
            raise AssertionError("finish waited for the worker again")

        assert node.finish(_HANG, waited) is False  # the first answer, without a wait
    finally:
        release.set()
        node.close()
    assert node.counters["maps_sent"] == 4


def test_a_replay_behind_its_schedule_ends_when_stopped() -> None:
    """A replay behind its schedule (a publish that waited on the full queue of a stuck
    worker, at a speed of many exchanges a second) publishes nothing once stopped: it used to
    ask the stop only while waiting for an exchange's time, and so published every exchange
    left, each after a wait on the full queue (a stop of 24 s with 470 left)."""
    times = np.arange(50.0)
    source = RobotReplay(("r0", "r1"), 0, times, [ONE_OBJECT] * len(times), kappa=20.0)
    stop = threading.Event()
    published: list[int] = []

    def publish(t: float, object_map, k: int) -> None:
        published.append(k)
        stop.set()  # the signal comes while the first map waits for a place

    # every exchange due at once, a moment from now: behind the schedule after the first
    done = replay(source, publish, time.time() + 0.01, 1e12, stop=stop)
    assert published == [0] and done == 1


#: in a process of its own: the results are written again and again, and the writer is
#: killed (SIGKILL, in a forked child) at the k-th event (call, line, return) of the write,
#: for every k; prints whether every file left behind was the old or the new results whole
KILLED_WHILE_WRITING = """
import json, os, signal, sys
from pathlib import Path
from tcaff_gtsam.node.results import write_counters

path = Path(sys.argv[1]) / "r0.json"
old, new = {"start": 1.0}, {"start": 1.0, "maps_sent": 7, "aligned": 5}
whole = []
for k in range(100000):
    path.write_text(json.dumps(old))
    pid = os.fork()
    if pid == 0:
        events = [0]

        def tracer(frame, event, arg):
            events[0] += 1
            if events[0] == k + 1:
                os.kill(os.getpid(), signal.SIGKILL)
            return tracer

        sys.settrace(tracer)
        write_counters(path, new)
        sys.settrace(None)
        os._exit(0)
    _, status = os.waitpid(pid, 0)
    try:
        whole.append(json.loads(path.read_text()) in (old, new))
    except ValueError:
        whole.append(False)
    if os.WIFEXITED(status):  # every event of the write has had its kill
        break
print(whole)
"""


def test_results_are_whole_wherever_the_writer_is_killed(tmp_path: Path) -> None:
    """A node's JSON is written aside and renamed: a SIGKILL at any moment of the write
    leaves the old results or the new, never an empty or cut file (it was written in
    place)."""
    done = subprocess.run([sys.executable, "-c", KILLED_WHILE_WRITING, str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    whole = ast.literal_eval(done.stdout)
    assert len(whole) > 5 and all(whole), whole
