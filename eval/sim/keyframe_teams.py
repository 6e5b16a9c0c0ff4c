"""Random CSLAM teams for `InterRobotGraph` with keyframes: the operations a front end would
give a graph, with the true poses they come from.

Each robot moves at its own speed and turn rate, takes a keyframe every 1-4 steps (its own
interval) chained by its odometry (1 cm / 0.1 deg of noise a step), and every step gives the
alignments of consecutive robots and up to two links between keyframes of two robots, each
one of the robot's three latest still within the horizon (0.1 m / 1 deg of noise): robots
whose chains meet across the horizon at different rates, where a bounded graph's keyframes can
part from an unbounded one's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.graph import InterRobotGraph
from tcaff_gtsam.params import constant_alignment_covariance

__all__ = ["KeyframeTeam", "keyframe_team", "play"]

ODOMETRY_NOISE = np.array([0.01, 0.01, np.radians(0.1)])  # per step: m, m, rad
MEASUREMENT_NOISE = np.array([0.1, 0.1, np.radians(1.0)])
#: the covariance every alignment and link is given: the original's constant
R = constant_alignment_covariance()


@dataclass(frozen=True)
class KeyframeTeam:
    """Attributes:
        n_robots, steps, horizon: the team's size, its steps and the horizon (steps) to give
            a bounded graph.
        ops: what to give the graph, in order (`play`): ("keyframe", robot, index, T_o_b,
            odometry_cov or None), ("alignment", step, i, j, (x, y, theta)), ("link", i, m_i,
            j, m_j, (x, y, theta) of T_oi_oj), ("update", step).
    """

    n_robots: int
    steps: int
    horizon: int
    ops: list[tuple]


def _measured(T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return se2_to_params(T) + rng.normal(0.0, MEASUREMENT_NOISE)


def keyframe_team(seed: int) -> KeyframeTeam:
    """A team of 3-5 robots over 30-60 steps with a horizon of 2-6 steps, drawn from `seed`."""
    rng = np.random.default_rng(seed)
    n, steps, horizon = (int(rng.integers(3, 6)), int(rng.integers(30, 61)),
                         int(rng.integers(2, 7)))
    interval = rng.integers(1, 5, n)
    frames = [np.eye(3)] + [se2_from_params([*rng.uniform(-10, 10, 2), rng.uniform(-3, 3)])
                            for _ in range(n - 1)]
    motion = [se2_from_params([rng.uniform(0.2, 0.6), 0.0, rng.uniform(-0.08, 0.08)])
              for _ in range(n)]
    body, odometry = [np.eye(3)] * n, [np.eye(3)] * n
    keyframes: list[list] = [[] for _ in range(n)]  # by index: (step, true pose, odometry pose)
    ops: list[tuple] = []
    for k in range(steps):
        for r in range(n):
            if k:
                body[r] = body[r] @ motion[r]
                odometry[r] = odometry[r] @ motion[r] @ se2_from_params(
                    rng.normal(0.0, ODOMETRY_NOISE))
            if k % interval[r] == 0:
                m = len(keyframes[r])
                keyframes[r].append((k, frames[r] @ body[r], odometry[r]))
                cov = np.diag((ODOMETRY_NOISE * np.sqrt(interval[r])) ** 2) if m else None
                ops.append(("keyframe", r, m, odometry[r], cov))
        for i in range(n - 1):
            ops.append(("alignment", k, i, i + 1,
                        _measured(np.linalg.inv(frames[i]) @ frames[i + 1], rng)))
        for _ in range(int(rng.integers(0, 3))):
            i, j = (int(r) for r in rng.choice(n, 2, replace=False))
            recent = [[m for m in range(len(keyframes[r]))[-3:]
                       if keyframes[r][m][0] >= k - horizon] for r in (i, j)]
            if recent[0] and recent[1]:
                mi, mj = int(rng.choice(recent[0])), int(rng.choice(recent[1]))
                (_, Xi, Oi), (_, Xj, Oj) = keyframes[i][mi], keyframes[j][mj]
                T_oi_oj = Oi @ np.linalg.inv(Xi) @ Xj @ np.linalg.inv(Oj)
                ops.append(("link", i, mi, j, mj, _measured(T_oi_oj, rng)))
        ops.append(("update", k))
    return KeyframeTeam(n, steps, horizon, ops)


def play(graph: InterRobotGraph, op: tuple) -> None:
    """Give `graph` one of `KeyframeTeam.ops`."""
    kind, *args = op
    if kind == "keyframe":
        graph.add_keyframe(*args[:3], odometry_cov=args[3])
    elif kind == "alignment":
        graph.add_alignment(*args, R)
    elif kind == "link":
        graph.add_keyframe_alignment(*args, R)
    else:
        graph.update(*args)
