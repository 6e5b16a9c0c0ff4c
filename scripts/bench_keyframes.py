"""Keyframes of a bounded graph against a graph without a horizon iterated to convergence.

Random CSLAM teams (`eval.sim.keyframe_teams`: 3-5 robots, 30-60 steps, a horizon of 2-6
steps, keyframes every 1-4 steps, links between keyframes of robots across the horizon) are
played into an `InterRobotGraph` with `GraphParams(horizon=H)` and into one without a horizon
that is iterated after every update until no variable moves by 1e-7 (what both try to reach).
Per run, the worst difference (metres or radians, whichever is larger) against that converged
graph of:

  alignment   T_oi_oj of consecutive robots at the last step;
  inside      keyframes still in the bounded graph at the end;
  left        keyframes that left, with the pose they left with, against the converged graph
              at that update;

counting only robots whose keyframes a chain of links ties to robot 0's (the others sit in an
arbitrary gauge). The table gives the runs above each threshold, the worst, and the runs whose
updates raised; then the bounded graph's mean time per update.

    python scripts/bench_keyframes.py [--runs 200] [--first-seed 0] [--workers 2]
"""

from __future__ import annotations

import argparse
import time
from multiprocessing import Pool

import numpy as np
from tcaff_gtsam.eval.sim.keyframe_teams import keyframe_team, play

from tcaff_gtsam import GraphParams, InterRobotGraph, TcaffError
from tcaff_gtsam.errors import reason
from tcaff_gtsam.geometry import se2_error
from tcaff_gtsam.graph_inputs import _components

THRESHOLDS = (1e-3, 1e-2, 0.1, 1.0)


class Converged(InterRobotGraph):
    """The graph without a horizon, every variable relinearised past 1e-6 and iterated after
    each update until none moves by 1e-7 (it reaches into the solver: a reference only)."""

    def __init__(self, n_robots: int) -> None:
        super().__init__(n_robots, GraphParams(relinearize_threshold=1e-6))

    def _new_solver(self, isam_params) -> None:
        isam_params.enablePartialRelinearizationCheck = False
        super()._new_solver(isam_params)

    def update(self, step: int | None = None) -> None:
        super().update(step)
        for _ in range(30):
            delta = self._isam.getDelta()
            if delta.size() == 0 or np.abs(delta.vector()).max() < 1e-7:
                return
            self._isam.update()


def difference(A: np.ndarray, B: np.ndarray) -> float:
    return float(max(se2_error(A, B)))


def poses(graph: InterRobotGraph, robot: int) -> dict[int, np.ndarray]:
    """A robot's keyframes in the common frame, by index (`trajectory`)."""
    indices, T = graph.trajectory(robot)
    return dict(zip(indices.tolist(), T, strict=True))


def tied_to_robot_0(n: int, links: list[tuple[int, int]]) -> set[int]:
    """The robots whose keyframe chains `links` connect to robot 0's."""
    root = _components(range(n), links)
    return {r for r in range(n) if root(r) == root(0)}


def one(seed: int) -> dict:
    """The worst differences of one team's bounded graph from the converged one."""
    team = keyframe_team(seed)
    n = team.n_robots
    bounded = InterRobotGraph(n, GraphParams(horizon=team.horizon))
    converged = Converged(n)
    links: list[tuple[int, int]] = []
    worst = {"alignment": 0.0, "inside": 0.0, "left": 0.0}
    seconds = 0.0
    try:
        for op in team.ops:
            if op[0] != "update":
                if op[0] == "link":
                    links.append((op[1], op[3]))
                play(bounded, op)
                play(converged, op)
                continue
            tied = tied_to_robot_0(n, links)
            # the keyframes that left and the poses they left with: the graph's own record
            left = {r: set(bounded._left_keyframes[r]) for r in tied}
            start = time.perf_counter()
            play(bounded, op)
            seconds += time.perf_counter() - start
            play(converged, op)
            for r in tied:
                now_left = bounded._left_keyframes[r]
                if fresh := now_left.keys() - left[r]:
                    reference = poses(converged, r)
                    worst["left"] = max(worst["left"], *(difference(reference[m], now_left[m])
                                                         for m in fresh))
        for r in tied_to_robot_0(n, links):
            reference = poses(converged, r)
            for m, T in poses(bounded, r).items():
                if m in bounded._keyframes[r]:
                    worst["inside"] = max(worst["inside"], difference(reference[m], T))
        last = team.steps - 1
        worst["alignment"] = max(difference(converged.alignment(i, i + 1, last)[0],
                                            bounded.alignment(i, i + 1, last)[0])
                                 for i in range(n - 1))
    except TcaffError as exc:
        return {"seed": seed, "error": reason(exc)}
    return {"seed": seed, **worst, "ms_per_update": 1e3 * seconds / team.steps}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.runs)
    with Pool(args.workers) as pool:
        rows = pool.map(one, seeds, chunksize=4)
    done = [row for row in rows if "error" not in row]
    raised = [row for row in rows if "error" in row]
    print(f"{len(rows)} teams (seeds {seeds.start}-{seeds.stop - 1}), {len(raised)} raised")
    for row in raised[:5]:
        print(f"  seed {row['seed']}: {row['error']}")
    print(f"{'worst difference':18}" + "".join(f"{'> ' + format(t, 'g'):>9}" for t in THRESHOLDS)
          + f"{'worst':>10}")
    for name in ("alignment", "inside", "left"):
        values = np.array([row[name] for row in done])
        print(f"{name:18}" + "".join(f"{int(np.sum(values > t)):>9}" for t in THRESHOLDS)
              + f"{values.max():>10.3g}")
    ms = np.array([row["ms_per_update"] for row in done])
    print(f"bounded graph: {ms.mean():.2f} ms an update (mean over teams; median team "
          f"{np.median(ms):.2f})")


if __name__ == "__main__":
    main()
