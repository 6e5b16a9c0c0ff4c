"""What every runner of a run shares: the pairs and the truth, and the stages computed once per
pair and step for every runner that wants them (MNO-CLIPPER candidates, the default TCAFF)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from tcaff_gtsam.frame_aligner import AlignmentMeasurement, FrameAligner
from tcaff_gtsam.geometry import se2_to_params
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import FrameAlignerParams, TCAFFParams
from tcaff_gtsam.tcaff import TCAFF, AlignmentEstimate

from ..config import MethodsConfig
from ..runs import AlignmentRun

__all__ = ["RunSetup", "SharedStages", "warm_up"]


@dataclass(frozen=True, eq=False)
class RunSetup:
    """A run as the runners see it.

    Attributes:
        run: the run.
        pairs: the directed pairs (i, j), i the ego robot, in a fixed order (P of them).
        T_true: (P, S, 3, 3) the true T_oi_oj (NaN where unknown).
        truth: (P, S, 3) its (x, y, theta).
        known: (P, S) bool, where the truth is known.
    """

    run: AlignmentRun
    pairs: list[tuple[int, int]]
    T_true: np.ndarray
    truth: np.ndarray
    known: np.ndarray

    @classmethod
    def of(cls, run: AlignmentRun) -> RunSetup:
        n, n_steps = run.n_robots, len(run.times)
        pairs = run.pairs or [(i, j) for i in range(n) for j in range(n) if i != j]
        T_true = np.array([run.T_true(i, j) for i, j in pairs]).reshape(len(pairs), n_steps, 3, 3)
        known = np.all(np.isfinite(T_true), axis=(2, 3))
        truth = np.full((len(pairs), n_steps, 3), np.nan)
        if known.any():
            truth[known] = se2_to_params(T_true[known])
        return cls(run, pairs, T_true, truth, known)

    @property
    def n_steps(self) -> int:
        return len(self.run.times)

    def empty(self) -> np.ndarray:
        """(P, S, 3) NaN: an estimate array with no estimate yet."""
        return np.full((len(self.pairs), self.n_steps, 3), np.nan)

    def maps(self, p: int, s: int) -> tuple[ObjectMap, ObjectMap]:
        """The ego's and the other robot's map of pair p at exchange s."""
        i, j = self.pairs[p]
        return self.run.maps[i][s], self.run.maps[j][s]


class SharedStages:
    """Stages several runners need, each computed at most once per pair and step, on demand.

    `candidates(p)`: every MNO-CLIPPER solution of pair p at this step, without the residual
    check (the reference preset sees them all). `tcaff(p)`: the default-preset TCAFF filter of
    pair p fed the candidates that pass `max_rmse`, with their covariances. A filter is advanced
    only through `tcaff(p)`, so every runner that uses it must ask for every pair at every step.
    `seconds` holds each stage's time.
    """

    def __init__(self, setup: RunSetup, methods: MethodsConfig) -> None:
        settings = setup.run.settings
        aligner = methods.aligner_params(settings.kappa)
        self.setup = setup
        self.max_rmse = aligner.max_rmse
        self.aligner = FrameAligner(replace(aligner, max_rmse=None))
        self.tcaff_params = methods.tcaff_params(False, settings.window)
        self.seconds = {"candidates": 0.0, "tcaff": 0.0}
        self._filters: list[TCAFF] | None = None
        self._steps: list[list[int]] = [[] for _ in setup.pairs]
        self._z: list[list[np.ndarray]] = [[] for _ in setup.pairs]
        self.s, self.t = -1, 0.0
        self._candidates: dict[int, list[AlignmentMeasurement]] = {}
        self._tcaff: dict[int, tuple[AlignmentEstimate | None, np.ndarray, np.ndarray]] = {}

    def begin(self, s: int, t: float) -> None:
        """Start exchange s at time t (s)."""
        self.s, self.t = s, t
        self._candidates.clear()
        self._tcaff.clear()

    def seconds_total(self) -> float:
        return self.seconds["candidates"] + self.seconds["tcaff"]

    def candidates(self, p: int) -> list[AlignmentMeasurement]:
        if p not in self._candidates:
            start = time.perf_counter()
            self._candidates[p] = self.aligner.measurements(*self.setup.maps(p, self.s), self.t)
            self.seconds["candidates"] += time.perf_counter() - start
        return self._candidates[p]

    def tcaff(self, p: int) -> tuple[AlignmentEstimate | None, np.ndarray, np.ndarray]:
        """(estimate or None, zs (k, 3), Rs (k, 3, 3)) of pair p's default TCAFF at this step."""
        if p not in self._tcaff:
            found = self.candidates(p)
            start = time.perf_counter()
            kept = [m for m in found if self.max_rmse is None or m.rmse <= self.max_rmse]
            if self._filters is None:
                self._filters = [TCAFF(self.tcaff_params) for _ in self.setup.pairs]
            zs = np.array([m.z for m in kept]).reshape(-1, 3)
            Rs = np.array([m.R for m in kept]).reshape(-1, 3, 3)
            self._tcaff[p] = (self._filters[p].update(zs, Rs), zs, Rs)
            self._steps[p] += [self.s] * len(zs)
            self._z[p] += list(zs)
            self.seconds["tcaff"] += time.perf_counter() - start
        return self._tcaff[p]

    def candidate_history(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per pair, (steps (M,), z (M, 3)): every candidate the default TCAFF saw."""
        return [(np.array(steps, dtype=np.int64), np.array(z).reshape(-1, 3))
                for steps, z in zip(self._steps, self._z, strict=True)]


_warm = False


def warm_up() -> None:
    """Compile the aligner's and the filters' numba kernels once per process, on a small map
    and its rotated copy, so that no method's timing includes compilation."""
    global _warm
    if _warm:
        return
    rng = np.random.default_rng(0)
    n = 12
    xy = rng.uniform(-5.0, 5.0, (n, 2))
    c, s = np.cos(0.3), np.sin(0.3)
    moved = xy @ np.array([[c, s], [-s, c]]) + [1.0, -0.5]
    sizes, seen = np.full(n, 0.5), np.zeros(n)

    def object_map(points: np.ndarray) -> ObjectMap:
        return ObjectMap(np.c_[points, np.zeros(n)], sizes, sizes, seen)

    found = FrameAligner(FrameAlignerParams()).measurements(object_map(xy), object_map(moved),
                                                            0.0)
    zs = np.array([m.z for m in found]).reshape(-1, 3)
    Rs = np.array([m.R for m in found]).reshape(-1, 3, 3)
    for params in (TCAFFParams(), TCAFFParams.reference()):
        tcaff = TCAFF(params)
        for _ in range(params.window + 2):
            tcaff.update(zs, Rs)
        tcaff.update(np.zeros((0, 3)), np.zeros((0, 3, 3)))
    _warm = True
