"""What every runner of a run shares: the pairs and the truth, and the stages computed once per
pair and step for every runner that wants them (MNO-CLIPPER candidates, the default TCAFF)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from tcaff_gtsam.frame_aligner import AlignmentMeasurement, FrameAligner, MapMemory
from tcaff_gtsam.geometry import se2_to_params
from tcaff_gtsam.identities import ObjectIdentities, recent_ids
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.pairwise import (
    HeldDrift,
    admitted,
    counted,
    evidence_of,
    explained,
    fed_by,
    feeding,
    gives_ids,
    guided_search,
    unchecked,
)
from tcaff_gtsam.precompile import compile_kernels
from tcaff_gtsam.tcaff import TCAFF, AlignmentEstimate
from tcaff_gtsam.twins import Twins

from ..config import MethodsConfig
from ..runs import AlignmentRun, directed_pairs

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
        n_steps = len(run.times)
        pairs = directed_pairs(run)
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

    def empty_covariance(self) -> np.ndarray:
        """(P, S, 3, 3) NaN: the covariances of an estimate array with no estimate yet."""
        return np.full((len(self.pairs), self.n_steps, 3, 3), np.nan)

    def maps(self, p: int, s: int) -> tuple[ObjectMap, ObjectMap]:
        """The ego's and the other robot's map of pair p at exchange s."""
        i, j = self.pairs[p]
        return self.run.maps[i][s], self.run.maps[j][s]


class SharedStages:
    """Stages several runners need, each computed at most once per pair and step, on demand.

    `candidates(p)`: every MNO-CLIPPER solution of pair p at this step, without the checks
    beyond it (`pairwise.unchecked`: the reference preset sees them all). `tcaff(p)`: the
    default-preset TCAFF filter of pair p fed the candidates that pass the method set's checks
    and that it may take (`pairwise.admitted`), with their covariances and object evidence.
    When the set's aligner checks more than the residual, its candidates are searched anew
    (with each robot's earlier maps); otherwise they are `candidates(p)` filtered by residual.
    A filter is advanced only through `tcaff(p)`, so every runner that uses it must ask for
    every pair at every step. `seconds` holds each stage's time.
    """

    def __init__(self, setup: RunSetup, methods: MethodsConfig) -> None:
        settings = setup.run.settings
        self.setup = setup
        tcaff_params = methods.tcaff_params(False, settings.window)
        self.checked = feeding(methods.aligner_params(settings.kappa), tcaff_params)
        self.tcaff_params = fed_by(tcaff_params, self.checked)
        self._held_drift = [HeldDrift(self.checked, self.tcaff_params) for _ in setup.pairs]
        self._twins = [Twins(self.checked, self.tcaff_params.window) for _ in setup.pairs]
        self.aligner = FrameAligner(unchecked(self.checked))
        # checks beyond the residual need a search of their own; the residual alone filters
        # the unchecked candidates
        checks_more = replace(self.checked, max_rmse=None) != self.aligner.params
        self.checked_aligner = FrameAligner(self.checked)
        self._verifier = self.checked_aligner if checks_more else None
        self.seconds = {"candidates": 0.0, "tcaff": 0.0}
        self._filters: list[TCAFF] | None = None
        self._steps: list[list[int]] = [[] for _ in setup.pairs]
        self._z: list[list[np.ndarray]] = [[] for _ in setup.pairs]
        self.s, self.t = -1, 0.0
        self._candidates: dict[int, list[AlignmentMeasurement]] = {}
        self._tcaff: dict[int, tuple[AlignmentEstimate | None, np.ndarray, np.ndarray]] = {}
        self._filtered: dict[int, AlignmentEstimate | None] = {}
        n = setup.run.n_robots
        self._memory = [MapMemory.of(self.checked) for _ in range(n)]
        self._identities = [ObjectIdentities() for _ in range(n)]
        self._ids: dict[int, np.ndarray] = {}
        self._since_full = [0] * len(setup.pairs)  # per pair, steps in a row guided

    def begin(self, s: int, t: float) -> None:
        """Start exchange s at time t (s)."""
        if self.s >= 0:
            for robot, memory in enumerate(self._memory):
                memory.add(self.t, self.setup.run.maps[robot][self.s])
        self.s, self.t = s, t
        self._candidates.clear()
        self._tcaff.clear()
        self._filtered.clear()
        self._ids.clear()

    def seconds_total(self) -> float:
        return self.seconds["candidates"] + self.seconds["tcaff"]

    def candidates(self, p: int) -> list[AlignmentMeasurement]:
        if p not in self._candidates:
            start = time.perf_counter()
            self._candidates[p] = self.aligner.measurements(*self.setup.maps(p, self.s), self.t)
            self.seconds["candidates"] += time.perf_counter() - start
        return self._candidates[p]

    def _checked(self, p: int) -> list[AlignmentMeasurement]:
        """Pair p's candidates under the method set's checks."""
        if self._verifier is None:
            max_rmse = self.checked.max_rmse
            return [m for m in self.candidates(p) if max_rmse is None or m.rmse <= max_rmse]
        i, j = self.setup.pairs[p]
        tcaff = None if self._filters is None else self._filters[p]
        guided = tcaff is not None and guided_search(self.checked, tcaff, self._since_full[p])
        self._since_full[p] = self._since_full[p] + 1 if guided else 0
        start = time.perf_counter()
        found = self._verifier.measurements(*self.setup.maps(p, self.s), self.t,
                                            self._memory[i].snapshots(),
                                            self._memory[j].snapshots(),
                                            None if tcaff is None or tcaff.held is None
                                            else tcaff.held.x, guided)
        self.seconds["candidates"] += time.perf_counter() - start
        return found

    def tcaff(self, p: int) -> tuple[AlignmentEstimate | None, np.ndarray, np.ndarray]:
        """(estimate or None, zs (k, 3), Rs (k, 3, 3)) of pair p's default TCAFF at this step,
        as `PairwiseAligner` reports it (its covariance covering the twins, `twins.Twins`)."""
        if p not in self._tcaff:
            found = self._checked(p)
            start = time.perf_counter()
            if self._filters is None:
                self._filters = [TCAFF(self.tcaff_params) for _ in self.setup.pairs]
            kept = admitted(found, self._filters[p].confirmable, self.checked)
            zs = np.array([m.z for m in kept]).reshape(-1, 3)
            Rs = np.array([m.R for m in kept]).reshape(-1, 3, 3)
            objects = explained(kept)
            only = counted(self.tcaff_params,
                           gives_ids(self.checked_aligner, self.tcaff_params,
                                     *self.setup.maps(p, self.s), self.t), objects)
            ids = None if only is None else tuple(self.object_ids(r)
                                                  for r in self.setup.pairs[p])
            filt = self._filters[p]
            growth = self._held_drift[p].growth(filt.held, *self.setup.maps(p, self.s), self.t)
            self._filtered[p] = filt.update(zs, Rs, evidence_of(kept, ids, only), objects,
                                            growth)
            self._tcaff[p] = (self._twins[p].update(self._filtered[p], kept,
                                                    *self.setup.maps(p, self.s), self.t), zs, Rs)
            self._steps[p] += [self.s] * len(zs)
            self._z[p] += list(zs)
            self.seconds["tcaff"] += time.perf_counter() - start
        return self._tcaff[p]

    def filtered(self, p: int) -> AlignmentEstimate | None:
        """Pair p's estimate at this step as its filter gave it (`TCAFF.update`'s, before the
        twins): what `InterRobotGraph.add_tcaff_estimate` takes with the step's candidates."""
        self.tcaff(p)
        return self._filtered[p]

    def object_ids(self, robot: int) -> np.ndarray:
        """(n,) persistent ids of the robot's map objects at this step (-1 for objects not
        seen within kappa, which no candidate associates)."""
        if robot not in self._ids:
            self._ids[robot] = recent_ids(self._identities[robot],
                                          self.setup.run.maps[robot][self.s], self.t,
                                          self.checked.kappa)
        return self._ids[robot]

    def candidate_history(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per pair, (steps (M,), z (M, 3)): every candidate the default TCAFF saw."""
        return [(np.array(steps, dtype=np.int64), np.array(z).reshape(-1, 3))
                for steps, z in zip(self._steps, self._z, strict=True)]


_warm = False


def warm_up() -> None:
    """Compile (or load) the aligner's and the filters' numba kernels once per process, so
    that no method's timing includes compilation."""
    global _warm
    if not _warm:
        compile_kernels()
        _warm = True
