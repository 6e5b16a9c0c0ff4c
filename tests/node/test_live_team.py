"""A live team: node processes replaying four_robots over Zenoh on 127.0.0.1.

Every node is its own process (`tcaff node`), with its own Zenoh session; the test process opens
sessions of its own to watch the team and to send it bad messages. The nodes replay against the
clock, so these tests are marked `realtime`: `make test` runs them beside the others, which
run at a lower priority.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from tcaff_gtsam.eval.config import MethodsConfig, load_scenario, override
from tcaff_gtsam.eval.methods import run_methods
from tcaff_gtsam.eval.sim.simulate import simulate
from tcaff_gtsam.node.link import Link, alive_key, map_key
from tcaff_gtsam.node.listener import TeamListener
from tcaff_gtsam.node.messages import MAX_BYTES, MapMessage, encode
from tcaff_gtsam.node.results import TEAM_COLUMNS, read_alignments
from tcaff_gtsam.node.run import free_ports, node_argv, save_replays, start_team, wait_team

from tcaff_gtsam import TCAFFParams
from tcaff_gtsam.geometry import se2_to_params, wrap_angle

N = 4
NAMES = [f"r{i}" for i in range(N)]

pytestmark = pytest.mark.realtime


def simulated(duration: float):
    return simulate(override(load_scenario("four_robots"), "test", duration=duration), 0)


def wait_present(session: zenoh.Session, team: str, timeout: float = 60.0) -> None:
    """Until every node's liveliness token is seen."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        replies = session.liveliness().get(alive_key(team, "*"), timeout=1.0)
        if len({str(r.ok.key_expr) for r in replies if r.ok is not None}) == N:
            return
        time.sleep(0.1)
    raise AssertionError("the team did not come up")


def rows_of(output: Path, robot: str) -> dict[str, np.ndarray]:
    return read_alignments(output / f"{robot}.csv")


def counters_of(output: Path, robot: str) -> dict:
    return json.loads((output / f"{robot}.json").read_text())


def bad_payloads(team: str) -> list[tuple[str, bytes]]:
    """(key, payload) of each kind of bad message, one each."""
    good = encode(MapMessage("intruder", 1, 0, 1.0, np.zeros((6, 3)), np.ones(6), np.ones(6),
                             np.zeros(6)))
    other_version = good[:4] + bytes([2]) + good[5:]
    return [
        (map_key(team, "r9"), b"\x00garbage"),                           # malformed
        (map_key(team, "intruder"), other_version),                      # version
        (map_key(team, "intruder"), good),                               # outsider
        (map_key(team, "r9"), b"\x00" * (MAX_BYTES + 1)),                # oversized
    ]


def test_four_nodes_align_as_the_offline_study_and_drop_bad_messages(tmp_path: Path) -> None:
    """Nothing lost: every node's alignments are the offline study's, bit for bit up to the
    float32 wire format, though r1's clock is 1000 s ahead, the nodes run the team
    consistency too (which publishes beside the pairwise alignments, never instead of
    them) and the team is sent one bad message of each kind, which every node drops and
    counts."""
    duration, team = 25.0, "lossless"
    ports = free_ports(N)
    run = simulated(duration)
    replays = save_replays(run, tmp_path / "replay")
    # silence: a map late by a couple of seconds on a loaded machine is not a silent robot
    argvs = [node_argv(replays[k], k, N, team, ports, None, tmp_path, speed=5.0,
                       clock_offset=1000.0 if k == 1 else 0.0, silence=10.0,
                       team_consistency=True)
             for k in range(N)]
    procs = start_team(argvs, tmp_path / "logs")
    link = Link(connect=(f"127.0.0.1:{ports[0]}",))
    try:
        with link.open() as session, TeamListener(team, link, run.T_true) as listener:
            wait_present(session, team)
            for key, payload in bad_payloads(team):
                # blocking: by default a put that finds the link's queue full is dropped, as a
                # 240 kB payload can on a loaded machine
                session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)
            offline = run_methods(run, MethodsConfig(methods=["tcaff"]))
            codes = wait_team(procs, 120)
            time.sleep(0.5)
    finally:
        for proc in procs:
            proc.kill()
    assert codes == [0] * N, [p.read_text() for p in sorted((tmp_path / "logs").iterdir())]
    S = len(run.times)
    estimates = offline.estimates["tcaff"]
    n_accepted, team_errors = 0, []
    for i, robot in enumerate(NAMES):
        counters = counters_of(tmp_path, robot)
        assert counters["maps_sent"] == S, counters
        assert counters["aligned"] == (N - 1) * S, counters
        assert counters.get("silent_steps", 0) == 0, counters
        for reason in ("malformed", "version", "outsider", "oversized"):
            assert counters[f"dropped_{reason}"] == 1, (robot, reason, counters)
        rows = rows_of(tmp_path, robot)
        for j, other in enumerate(NAMES):
            if i == j:
                continue
            mine = rows["neighbour"] == other
            seq = rows["seq"][mine].astype(int)
            assert seq.tolist() == list(range(S)), (robot, other)
            offline_x = estimates[offline.pairs.index((i, j))]
            accepted = rows["accepted"][mine] == 1
            np.testing.assert_array_equal(accepted, np.isfinite(offline_x[:, 0]))
            n_accepted += accepted.sum()
            x = np.column_stack([rows[c][mine] for c in ("x", "y", "theta")])
            np.testing.assert_allclose(x[accepted], offline_x[accepted], atol=1e-4)
        # a team alignment after every step of every pair, near the truth where accepted
        team_rows = read_alignments(tmp_path / f"{robot}.team.csv", TEAM_COLUMNS)
        assert len(team_rows["seq"]) == (N - 1) * S
        kept = team_rows["accepted"] == 1
        seq = team_rows["seq"][kept].astype(int)
        truth = np.array([se2_to_params(run.T_true(i, NAMES.index(o))[s])
                          for o, s in zip(team_rows["neighbour"][kept], seq, strict=True)])
        x = np.column_stack([team_rows[c][kept] for c in ("x", "y", "theta")])
        team_errors.extend(np.linalg.norm(x[:, :2] - truth.reshape(-1, 3)[:, :2], axis=1))
    assert n_accepted > 0
    assert team_errors and np.median(team_errors) < 0.5
    # the listener saw every pair's last step, with its error against the truth
    assert sorted(listener.latest) == [(a, b) for a in NAMES for b in NAMES if a != b]
    assert all(m.seq == S - 1 for m in listener.latest.values())
    shown = [listener.error(m) for m in listener.latest.values() if m.accepted]
    assert shown and all(e[0] < 1.0 for e in shown)
    assert listener.table().row_count == N * (N - 1)


@pytest.mark.slow
def test_a_lossy_team_keeps_its_bounds_and_a_killed_node_rejoins(tmp_path: Path) -> None:
    """30 % of maps lost on arrival at every node, and r3 killed mid-run and started again
    from its saved filters: the others keep running, r3 rejoins within W + 2 exchanges, the
    accepted alignments stay within 0.5 m and 2 deg (median) of the truth, and the team
    accepts at least 35 % of the pair-steps the lossless offline study does (a minute of
    run, and a restart that takes seconds: slow)."""
    duration, team, speed = 60.0, "lossy", 4.0
    ports = free_ports(N)
    state = tmp_path / "state"
    run = simulated(duration)
    replays = save_replays(run, tmp_path / "replay")
    # silence: as in the test above, a map late on a loaded machine is not a silent robot (3 s
    # of run at 4x are 0.75 s of wall time: beside the suite, the team then accepted 59 of the
    # 208 pair-steps it accepts alone)
    argvs = [node_argv(replays[k], k, N, team, ports, None, tmp_path, speed=speed,
                       drop_share=0.3, state=state, silence=10.0) for k in range(N)]
    procs = start_team(argvs, tmp_path / "logs")
    try:
        # while the nodes start: how much the offline study accepts with nothing lost
        offline = run_methods(run, MethodsConfig(methods=["tcaff"]))
        lossless, offline_pairs = offline.estimates["tcaff"], offline.pairs
        # kill r3 once it has aligned 15 exchanges
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            csv = tmp_path / "r3.csv"
            if csv.exists() and len(csv.read_text().splitlines()) > 3 * 15:
                break
            time.sleep(0.05)
        procs[3].send_signal(signal.SIGKILL)
        procs[3].wait()
        killed_at = int(rows_of(tmp_path, "r3")["seq"].max())
        start = counters_of(tmp_path, "r3")["start"]
        argv = node_argv(replays[3], 3, N, team, ports, start, tmp_path, speed=speed,
                         drop_share=0.3, state=state, silence=10.0)
        with open(tmp_path / "logs" / "node3-restart.log", "wb") as log:
            restarted = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
        codes = wait_team([*procs[:3], restarted], 150)
    finally:
        for proc in procs:
            proc.kill()
    assert codes == [0] * N
    S, W = len(run.times), TCAFFParams().window
    for robot in NAMES[:3]:
        counters = counters_of(tmp_path, robot)
        assert counters["maps_sent"] == S  # the others never stopped
        assert 0.2 < counters["lost"] / counters["maps_received"] < 0.4
    r3 = rows_of(tmp_path, "r3")
    after = r3["seq"] > killed_at
    back = int(r3["seq"][after].min())  # r3's first exchange after its restart
    assert back > killed_at + 1
    errors, accepted_steps = [], 0
    for i, robot in enumerate(NAMES):
        rows = rows_of(tmp_path, robot)
        for j, other in enumerate(NAMES):
            mine = (rows["neighbour"] == other) & (rows["accepted"] == 1)
            if i == j or not mine.any():
                continue
            seq = rows["seq"][mine].astype(int)
            truth = se2_to_params(run.T_true(i, j)[seq])
            x = np.column_stack([rows[c][mine] for c in ("x", "y", "theta")])
            errors.append(np.column_stack([np.linalg.norm(x[:, :2] - truth[:, :2], axis=1),
                                           np.abs(wrap_angle(x[:, 2] - truth[:, 2]))]))
            if 3 not in (i, j):
                accepted_steps += len(seq)
            if 3 in (i, j) and (seq < killed_at).any():
                # held before the kill: accepted again within W + 2 exchanges of the restart
                assert seq[seq >= back].min() <= back + W + 2, (robot, other)
    errors = np.concatenate(errors)
    assert np.median(errors[:, 0]) < 0.5 and np.degrees(np.median(errors[:, 1])) < 2.0
    # availability of the pairs r3 is not in: at least 35 % of the pair-steps the lossless
    # offline study accepts (a filter accepts after W steps of evidence, and a pair that
    # loses 30 % of its maps takes its steps that much more slowly: in a one-minute run the
    # share accepted falls by more than the share lost). The maps lost are the same every run
    # (fixed by sender and exchange): 131 of 208 here, quiet or beside two busy processes;
    # lost in the order maps came in, with a 3 s silence, they gave 59-85.
    others = [p for p, pair in enumerate(offline_pairs) if 3 not in pair]
    assert accepted_steps >= 0.35 * np.isfinite(lossless[others, :, 0]).sum()
