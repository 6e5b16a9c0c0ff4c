"""A node stuck at will, for the tests of a node's stop and `scripts/bench_stop.py`: a
`tcaff node` whose worker never returns from a filter update, the replays a two-robot team
plays, and a transport that links a node to nobody."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
from tcaff_gtsam.node import NodeParams, RobotNode
from tcaff_gtsam.node.replay import RobotReplay
from tcaff_gtsam.node.run import free_ports, node_argv

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.geometry import se2_from_params

#: a `tcaff node` whose worker's filter updates past the first `after` never return;
#: argv: marker file (written when the worker gets stuck), after, then tcaff's arguments
STUCK_NODE = """
import sys, threading
from pathlib import Path
from tcaff_gtsam.pairwise import PairwiseAligner

marker, after = Path(sys.argv[1]), int(sys.argv[2])
update, calls = PairwiseAligner.update, [0]

def update_then_stick(self, *args, **kwargs):
    if threading.current_thread().name.startswith("tcaff-node-"):  # not the kernels' warm-up
        calls[0] += 1
    if calls[0] > after:
        marker.write_text("stuck")
        threading.Event().wait()
    return update(self, *args, **kwargs)

PairwiseAligner.update = update_then_stick
from tcaff_gtsam.eval.cli import main
sys.argv = ["tcaff", *sys.argv[3:]]
main()
"""

#: filter updates a stuck node's worker makes before it sticks (its results: these steps)
DONE = 2


def stuck_argv(argv: list[str], marker: Path, after: int = DONE) -> list[str]:
    """`argv`, a `tcaff node` command line of `node_argv`, run as `STUCK_NODE`: its filter
    updates past the first `after` never return, `marker` written when the worker sticks."""
    return [sys.executable, "-c", STUCK_NODE, str(marker), str(after), *argv[3:]]


def start_pair(folder: Path, team: str, marker: Path, after: int = DONE,
               r0_options: tuple[str, ...] = (), **argv_options
               ) -> tuple[list[subprocess.Popen], list[Path]]:
    """r0, stuck past `after` filter updates (`stuck_argv`, with `r0_options` on its command
    line), and r1 of a team playing `replays(folder)` into `folder`/out, each process's output
    in `folder`/node<k>.log; `argv_options`: `node_argv`'s (domain_id, ros2). Returns the two
    processes and their logs."""
    paths = replays(folder)
    ports = free_ports(2)
    argvs = [node_argv(paths[k], k, 2, team, ports, None, folder / "out", **argv_options)
             for k in range(2)]
    argvs[0] = stuck_argv([*argvs[0], *r0_options], marker, after)
    logs = [folder / f"node{k}.log" for k in range(2)]
    procs = []
    for argv, log in zip(argvs, logs, strict=True):
        with open(log, "wb") as file:
            procs.append(subprocess.Popen(argv, stdout=file, stderr=subprocess.STDOUT))
    return procs, logs


def replays(folder: Path, exchanges: int = 120) -> list[Path]:
    """Replays of r0 and r1 at 1 Hz: 30 objects both see, r1's frame moved by (3 m, -2 m,
    0.4 rad)."""
    rng = np.random.default_rng(5)
    n = 30
    xy = rng.uniform(-10, 10, (n, 2))
    sizes = rng.uniform(0.3, 1.5, n)
    T = se2_from_params([3.0, -2.0, 0.4])
    in_r1 = (np.linalg.inv(T) @ np.c_[xy, np.ones(n)].T).T[:, :2]
    times = np.arange(float(exchanges))
    paths = []
    for k, points in enumerate((xy, in_r1)):
        maps = [ObjectMap(np.c_[points, np.zeros(n)], sizes, sizes, np.full(n, t))
                for t in times]
        paths.append(folder / f"r{k}.npz")
        RobotReplay(("r0", "r1"), k, times, maps, kappa=20.0).save(paths[-1])
    return paths


class Alone:
    """A transport that sends nothing and hears nothing: the node by itself, in memory."""

    def configure(self, robot, params):
        return params

    def open(self, node) -> None:
        pass

    def put_map(self, message, recent) -> None:
        pass

    def put_alignment(self, message) -> None:
        pass

    def put_team(self, message) -> None:
        pass

    def present(self, timeout):
        return set()

    def close(self) -> None:
        pass


#: a map of one object, for a node whose steps do not matter
ONE_OBJECT = ObjectMap(np.zeros((1, 3)), np.ones(1), np.ones(1), np.zeros(1))


def node_stuck_in_its_first_step(queue: int) -> tuple[RobotNode, threading.Event,
                                                      threading.Event]:
    """A node linked to nobody (`Alone`) with `queue` places, whose worker sticks in the
    first map it steps until `release` is set; `stepping` is set once it is stuck. Returns
    (node, stepping, release); close the node after setting `release`."""
    node = RobotNode("r0", "team", ["r0", "r1"], Alone(), NodeParams(queue=queue))
    stepping, release = threading.Event(), threading.Event()
    step = node._ego_step

    def stuck(*args) -> None:
        stepping.set()
        release.wait()
        step(*args)

    node._ego_step = stuck
    return node, stepping, release
