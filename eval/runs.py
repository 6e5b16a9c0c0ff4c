"""Runs: what any data source hands the compared methods.

A run is the robots' object maps at the 1 Hz exchanges, on one clock, with the truth to score
against when the source has it. The simulator (`sim.simulate.SimRun`) and every recorded data set
(`RecordedRun`, built by the loaders in `datasets/`) satisfy the `AlignmentRun` protocol; the
method runners, the scoring and the study read nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se3_to_se2
from tcaff_gtsam.object_map import ObjectMap

__all__ = ["AlignmentRun", "RecordedRun", "RunSettings", "directed_pairs", "planar_poses"]


@dataclass(frozen=True)
class RunSettings:
    """What the methods take from a run's configuration.

    Attributes:
        kappa: s, objects of a map seen longer ago are not aligned.
        window: the TCAFF window W of this run, for every TCAFF preset (None: the preset's).
        graph_drift: iSAM2 between-step drift (m, deg) per step (None: TCAFF's Q).
    """

    kappa: float
    window: int | None = None
    graph_drift: tuple[float, float] | None = None


class AlignmentRun(Protocol):
    """The robots' maps at the 1 Hz exchanges, and the truth to score against.

    Attributes:
        settings: `RunSettings`.
        times: (S,) s of the exchanges, on the maps' clock.
        maps: maps[r][s], robot r's map at exchange s, in its odometry frame.
        pairs: the directed pairs (i, j) to align; None: every ordered pair of robots.
    """

    settings: RunSettings
    times: np.ndarray
    maps: list[list[ObjectMap]]
    pairs: list[tuple[int, int]] | None

    @property
    def n_robots(self) -> int: ...

    def T_true(self, i: int, j: int) -> np.ndarray:
        """(S, 3, 3) the true T_oi_oj at each exchange (NaN where unknown)."""
        ...

    def overlap(self, i: int, j: int) -> np.ndarray | None:
        """(S,) bool: the two maps share enough objects for an alignment to be found; None when
        the source cannot tell (availability is then counted over every step)."""
        ...


def directed_pairs(run: AlignmentRun) -> list[tuple[int, int]]:
    """The run's directed pairs (i, j) to align: its own list, or every ordered pair of its
    robots."""
    n = run.n_robots
    return run.pairs or [(i, j) for i in range(n) for j in range(n) if i != j]


def planar_poses(T: np.ndarray) -> np.ndarray:
    """(..., 3) x [m], y [m], yaw [rad] of (..., 4, 4) or (..., 3, 3) poses; NaN poses give NaN
    rows (where the checked conversions of `geometry` would refuse them)."""
    T = np.asarray(T, dtype=float)
    yaw = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    last = T.shape[-1] - 1
    return np.stack([T[..., 0, last], T[..., 1, last], yaw], axis=-1)


@dataclass(frozen=True, eq=False)
class RecordedRun:
    """A recorded data set's run (an `AlignmentRun`): maps at exchanges every robot shares.

    Attributes:
        name: the data set or test, for file names and tables.
        settings: `RunSettings`.
        times: (S,) s, the exchanges on the data set's clock.
        maps: maps[r][s], robot r's map at exchange s, in its odometry frame.
        T_world_odom: (n, S, 4, 4) each robot's odometry frame in the shared world frame at
            each exchange (NaN where there is no truth). Planar runs use z = 0.
        T_odom_body: (n, S, 4, 4) each robot's body in its odometry frame.
        shared: (n, n, S) bool, maps i and j share enough objects at step s (None: unknown).
        robot_names: one name per robot.
        pairs: the directed pairs (i, j) to align, robot indices (None: every pair).
    """

    name: str
    settings: RunSettings
    times: np.ndarray
    maps: list[list[ObjectMap]]
    T_world_odom: np.ndarray
    T_odom_body: np.ndarray
    shared: np.ndarray | None = None
    robot_names: tuple[str, ...] = ()
    pairs: list[tuple[int, int]] | None = None

    def __post_init__(self) -> None:
        n, S = len(self.maps), len(self.times)
        if n < 2:
            raise DataError(f"RecordedRun {self.name}: needs two robots or more, got {n}")
        if any(len(m) != S for m in self.maps):
            raise DataError(f"RecordedRun {self.name}: every robot needs one map per exchange "
                            f"({S}), got {[len(m) for m in self.maps]}")
        for field, value in (("T_world_odom", self.T_world_odom),
                             ("T_odom_body", self.T_odom_body)):
            if np.shape(value) != (n, S, 4, 4):
                raise DataError(f"RecordedRun.{field}: expected shape {(n, S, 4, 4)}, got "
                                f"{np.shape(value)}")
        if self.shared is not None and np.shape(self.shared) != (n, n, S):
            raise DataError(f"RecordedRun.shared: expected shape {(n, n, S)}, got "
                            f"{np.shape(self.shared)}")
        if not self.robot_names:
            object.__setattr__(self, "robot_names", tuple(str(r) for r in range(n)))
        if self.pairs is not None and (not self.pairs or any(
                not (0 <= i < n and 0 <= j < n and i != j) for i, j in self.pairs)):
            raise DataError(f"RecordedRun.pairs: need directed pairs of two different robots "
                            f"among {n}, got {self.pairs}")

    @property
    def n_robots(self) -> int:
        return len(self.maps)

    @property
    def has_truth(self) -> bool:
        return bool(np.all(np.isfinite(self.T_world_odom)))

    def T_true(self, i: int, j: int) -> np.ndarray:
        """(S, 3, 3) the true planar T_oi_oj (NaN without truth)."""
        if not np.all(np.isfinite(self.T_world_odom[[i, j]])):
            return np.full((len(self.times), 3, 3), np.nan)
        return se3_to_se2(invert(self.T_world_odom[i]) @ self.T_world_odom[j])

    def overlap(self, i: int, j: int) -> np.ndarray | None:
        return None if self.shared is None else self.shared[i, j]
