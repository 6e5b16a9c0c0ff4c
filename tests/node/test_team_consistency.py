"""Team consistency inside the node: a pairwise alignment that fails the team's cycles is left
out, and a pair with no shared objects gets an alignment chained through a third robot.

The chain runs three replaying nodes (`replay_node`, what `tcaff node --replay` runs), each
with its own Zenoh session on 127.0.0.1, side by side in the test process; the rejection runs
one RobotNode and a second Zenoh session that speaks for its neighbours.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from tcaff_gtsam.eval.config import load_scenario, override
from tcaff_gtsam.eval.runs import RecordedRun
from tcaff_gtsam.eval.sim.simulate import simulate
from tcaff_gtsam.node import AlignmentMessage, Link, MapMessage, NodeParams, RobotNode, encode
from tcaff_gtsam.node.link import alignment_key, map_key
from tcaff_gtsam.node.replay import robot_names, run_replay
from tcaff_gtsam.node.results import TEAM_COLUMNS, read_alignments
from tcaff_gtsam.node.run import free_ports, replay_node

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, wrap_angle


def _se3(T: np.ndarray) -> np.ndarray:
    """(..., 4, 4) of planar (..., 3, 3) transforms."""
    out = np.tile(np.eye(4), (*T.shape[:-2], 1, 1))
    out[..., :2, :2], out[..., :2, 3] = T[..., :2, :2], T[..., :2, 2]
    return out


def bridged_team(duration: float) -> RecordedRun:
    """Three robots of two simulated rooms: r0 is a robot of four_robots (seed 0), r2 the same
    robot of another room (seed 1), and r1 maps both rooms: its map is its robot's in room
    one plus another robot's of room two, placed 20 m away in its frame. r0 and r2 share no
    object, r1 shares objects with each."""
    one, two = (simulate(override(load_scenario("four_robots"), "test", duration=duration), s)
                for s in (0, 1))
    ends, bridge = 3, 0  # robots of the rooms: r0 and r2, and r1's two halves
    T_r1_two = se2_from_params(np.array([20.0, 3.0, 0.7]))  # room two's part in r1's frame
    maps = []
    for a, b in zip(one.maps[bridge], two.maps[bridge], strict=True):
        xy = b.centroids[:, :2] @ T_r1_two[:2, :2].T + T_r1_two[:2, 2]
        maps.append(ObjectMap(np.vstack([a.centroids, np.c_[xy, b.centroids[:, 2]]]),
                              np.r_[a.widths, b.widths], np.r_[a.heights, b.heights],
                              np.r_[a.last_seen, b.last_seen]))
    T_w_r2 = (one.T_w_o(bridge) @ T_r1_two @ np.linalg.inv(two.T_w_o(bridge))
              @ two.T_w_o(ends))
    S = len(one.times)
    return RecordedRun("bridged", one.settings, one.times, [one.maps[ends], maps, two.maps[ends]],
                       _se3(np.array([one.T_w_o(ends), one.T_w_o(bridge), T_w_r2])),
                       np.tile(np.eye(4), (3, S, 1, 1)))


def test_three_nodes_chain_the_pair_that_shares_no_objects(tmp_path: Path) -> None:
    """r0 and r2 never align on their own; with team consistency each publishes the other's
    alignment chained through r1, within 0.5 m and 2 deg of the truth."""
    run, team, n = bridged_team(26.0), "chain", 3
    ports, names = free_ports(n), robot_names(n)
    # the settings `tcaff node --replay R --speed 8 --silence 10 --team-consistency` runs
    # with; in threads of this process, which has the imports and kernels a node process
    # would spend seconds of CPU on loading
    params = NodeParams(silence=10.0, lockstep=True, speed=8.0, team_consistency=True)

    def node(k: int) -> RobotNode:
        link = Link(listen=(f"127.0.0.1:{ports[k]}",),
                    connect=tuple(f"127.0.0.1:{p}" for p in ports[:k]))
        return replay_node(run_replay(run, k, names), team, link, params, None, tmp_path)

    with ThreadPoolExecutor(n) as pool:
        nodes = [done.result(timeout=120) for done in [pool.submit(node, k) for k in range(n)]]
    for robot in nodes:  # no step of any node failed
        assert not robot.counters["errors"], robot.counters
    for i, j in ((0, 2), (2, 0)):
        own = read_alignments(tmp_path / f"r{i}.csv")
        assert not own["accepted"][own["neighbour"] == f"r{j}"].any()
        rows = read_alignments(tmp_path / f"r{i}.team.csv", TEAM_COLUMNS)
        chained = (rows["neighbour"] == f"r{j}") & (rows["accepted"] == 1)
        assert chained.sum() >= 3, (i, j)
        assert set(rows["via"][chained]) == {"r1"}
        truth = se2_to_params(run.T_true(i, j)[rows["seq"][chained].astype(int)])
        x = np.column_stack([rows[c][chained] for c in ("x", "y", "theta")])
        assert np.linalg.norm(x[:, :2] - truth[:, :2], axis=1).max() < 0.5
        assert np.degrees(np.abs(wrap_angle(x[:, 2] - truth[:, 2]))).max() < 2.0
        # pairs that align on their own keep their own alignment
        direct = (rows["neighbour"] == "r1") & (rows["accepted"] == 1)
        assert direct.any() and set(rows["via"][direct]) == {""}


# T_r0_rk of the robots r1, r2, r3 as (x, y, theta)
TRUE = {"r1": np.array([2.0, -1.0, 0.4]), "r2": np.array([-3.0, 4.0, -1.1]),
        "r3": np.array([6.0, 2.0, 2.5])}


def test_a_pairwise_alignment_that_fails_the_teams_cycles_is_left_out(tmp_path: Path) -> None:
    """r0's map of r2 is in truth r1's map, so r0 aligns r2 where r1 is; r1, r2 and r3
    publish alignments among themselves that agree with the truth. The cycles r0-r1-r2 and
    r0-r2-r3 fail and only r0-r2 lies in both: the node publishes r0 -> r2 chained through
    another robot at the true place, and keeps its own r0 -> r1 and r0 -> r3."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(-10, 10, (30, 2))
    sizes = rng.uniform(0.3, 1.5, 30)

    def seen_by(robot: str) -> np.ndarray:
        T = np.linalg.inv(se2_from_params(TRUE[robot]))
        return np.c_[xy @ T[:2, :2].T + T[:2, 2], np.zeros(30)]

    port = free_ports(1)[0]
    got: list = []
    node = RobotNode("r0", "cycles", ["r0", "r1", "r2", "r3"],
                     Link(listen=(f"127.0.0.1:{port}",)),
                     NodeParams(silence=1000.0, team_consistency=True), on_team=got.append)
    team = Link(connect=(f"127.0.0.1:{port}",)).open()
    try:
        published = [team.declare_publisher(map_key("cycles", r)) for r in ("r1", "r2", "r3")]
        time.sleep(1.0)  # the sessions link up
        maps = {"r1": seen_by("r1"), "r2": seen_by("r1"), "r3": seen_by("r3")}
        P = np.diag([1e-3, 1e-3, 1e-5])
        for k in range(12):
            t = 10.0 + k
            for a, b in (("r1", "r2"), ("r1", "r3"), ("r2", "r3")):
                T = np.linalg.inv(se2_from_params(TRUE[a])) @ se2_from_params(TRUE[b])
                team.put(alignment_key("cycles", a, b), encode(AlignmentMessage(
                    a, 1, k, t, b, k, t, k + 1, 0, True, se2_to_params(T), P)))
            node.publish(t, ObjectMap(np.c_[xy, np.zeros(30)], sizes, sizes, np.full(30, t)))
            for pub, robot in zip(published, ("r1", "r2", "r3"), strict=True):
                pub.put(encode(MapMessage(robot, 1, k, t, maps[robot], sizes, sizes,
                                          np.zeros(30))))
            deadline = time.monotonic() + 10
            while node.counters["aligned"] < 3 * (k + 1) and time.monotonic() < deadline:
                time.sleep(0.01)
            node.wait_idle()
    finally:
        team.close()
        node.close()
    c = node.counters
    assert c["alignments_heard"] == 36 and c["aligned"] == 36, c
    own = node.latest
    assert own["r2"].accepted  # the node's own filter took r1's map for r2's
    np.testing.assert_allclose(own["r2"].x, TRUE["r1"], atol=0.05)
    assert c["team_rejected"] > 0
    team_r2 = node.team_latest["r2"]
    assert team_r2.accepted and team_r2.via in (("r1",), ("r3",))
    np.testing.assert_allclose(team_r2.x, TRUE["r2"], atol=0.1)
    for robot in ("r1", "r3"):
        m = node.team_latest[robot]
        assert m.accepted and m.via == ()
        np.testing.assert_allclose(m.x, TRUE[robot], atol=0.05)
    assert got[-1] is node.team_latest[got[-1].neighbour]
