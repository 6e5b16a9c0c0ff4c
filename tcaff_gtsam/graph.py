"""InterRobotGraph: accepted frame alignments as between-factors in a GTSAM iSAM2 graph.

Two kinds of variables, each robot r having its own chain of both:

- A_r(k), the pose of robot r's odometry frame in the common frame at alignment step k. Chains
  are linked by identity between-factors with the drift covariance Q / 2 per step (so a pair
  drifts by Q, as TCAFF assumes); robot 0's first A is anchored by a prior. A robot not (yet, or
  no longer) connected to robot 0 by alignments gets a weak prior that only fixes its gauge. An
  alignment T_oi_oj at step k is the factor A_i(k)^-1 A_j(k) = T_oi_oj (its covariance
  inflated where the step's alignments close a cycle: `GraphParams.shared_maps`), and
  `alignment(i, j, k)` reads T_oi_oj(k) = A_i(k)^-1 A_j(k) with its marginal covariance. The
  graph makes these cycle consistent: T_ij T_jk = T_ik holds exactly.
- X_r(m), keyframe poses in the common frame, for CSLAM use: odometry between-factors along each
  robot's chain, inter-robot factors between keyframes from accepted alignments, and any other
  between-factor a user has (loop closures).

With `GraphParams.horizon`, only the variables of the latest `horizon` steps stay in the graph
(a keyframe belongs to the first step added after it): the oldest step leaves at each
update, marginalised as a set of leaves of iSAM2's Bayes tree (see `_solve` for why it is one),
and keeps, for reading, the estimates (and for alignment steps the joint covariance) it had.

The graph's rooms: this module holds the variables, the alignment factors, each update and the
gauge; `graph_inputs` the variables' keys and the checks of what is given; `graph_window` the
iSAM2 update, the horizon and its marginalisation, and the roll-back; `graph_tcaff` TCAFF's
hypotheses as factors; `graph_keyframes` the keyframes; `graph_output` what is read out.
`InterRobotGraph` is the one public door to all of them.

Covariances of poses follow gtsam: right perturbations T Exp(xi) with xi = (vx, vy, omega) for
Pose2 and (wx, wy, wz, vx, vy, vz), rotation first, for Pose3. Alignment covariances given to or
returned by this module are over the parameters (x, y, theta) or (x, y, z, yaw) instead, and
are converted at the boundary.
"""

from __future__ import annotations

import logging
import math
from bisect import bisect_right
from collections import Counter, defaultdict

import gtsam
import numpy as np

from .errors import ConfigError, DataError, reason
from .geometry import (
    _se2_from_params,
    _se2_to_params,
    _se3_from_xyz_yaw,
    _se3_to_se2,
)
from .graph_inputs import (
    _KIND_SHIFT,
    _ROBOT_SHIFT,
    _a_key,
    _blocks,
    _chain,
    _check_cov,
    _check_finite,
    _check_index,
    _check_translation,
    _components,
    _Factor,
    _keyframe_of,
    _step_of,
    _x_key,
    alignment_key,
    keyframe_key,
)
from .graph_keyframes import KeyframeFactors
from .graph_output import GraphReadout
from .graph_tcaff import HypothesisFactors, _Abandoned, _copied_switches, _Suspended
from .graph_window import SlidingWindow, _Contradiction
from .inputs import real_array, shown
from .params import GraphParams, _given_or_default, _int_at_least
from .tcaff import AlignmentEstimate

__all__ = ["InterRobotGraph", "alignment_key", "keyframe_key"]

log = logging.getLogger(__name__)

class InterRobotGraph(HypothesisFactors, KeyframeFactors, SlidingWindow, GraphReadout):
    """iSAM2 smoothing of the frame alignments of `n_robots` robots (and their keyframes).

    Per step: add that step's alignments (`add_alignment` or `add_tcaff_estimate`), then call
    `update(step)`; read `alignment(i, j, step)` right after for the causal estimate, or later
    for the smoothed one. Factors wait in a queue until the next `update`.

    Up to 2^16 robots (what the variables' keys tell apart). Every step keeps the joint
    covariance of all robots' alignments it had as the latest: a past step's covariance
    (`GraphParams.past_covariance`), and with a horizon, any pair's covariance after the step
    has left, for the latest `GraphParams.history` steps that left (all of them by default;
    what that costs is under `history`).
    """

    def __init__(self, n_robots: int, params: GraphParams | None = None) -> None:
        max_robots = 1 << (_KIND_SHIFT - _ROBOT_SHIFT)  # what the variables' keys tell apart
        if not (_int_at_least(n_robots, 1) and n_robots <= max_robots):
            raise DataError(f"InterRobotGraph: n_robots must be an int in [1, {max_robots}], "
                            f"got {shown(n_robots)}")
        self.n_robots = n_robots
        self.params = _given_or_default(GraphParams, params, "InterRobotGraph")
        prm = self.params
        if n_robots == 1 and prm.horizon is not None:
            # its steps' variables only chain to each other, and the horizon's ordering of
            # them fails from the third step; one robot has no alignment to estimate anyway
            raise ConfigError(f"InterRobotGraph: a horizon (GraphParams.horizon = "
                              f"{prm.horizon}) needs at least two robots, got n_robots = 1")
        self._planar = prm.dim == 2
        isam_params = gtsam.ISAM2Params()
        isam_params.setRelinearizeThreshold(prm.relinearize_threshold)
        isam_params.relinearizeSkip = prm.relinearize_skip
        # check relinearisation from the root down only as far as needed, not every variable
        isam_params.enablePartialRelinearizationCheck = True
        # reuse the slots of removed factors: a long run's factor list stays bounded
        isam_params.findUnusedFactorSlots = True
        self._new_solver(isam_params)
        # with a horizon: steps that left the graph, their A_r (n_robots, side, side) and the
        # joint covariance of (A_0 .. A_n-1) in gtsam's tangent order as it was while the step
        # was the latest (cheap to compute then, near the root of the Bayes tree; smoothing
        # only shrinks it later)
        self._left: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # with `history`: the keyframes (robot, index) that left with each step in self._left,
        # and each robot's latest keyframe forgotten
        self._left_with: dict[int, list[tuple[int, int]]] = {}
        self._forgotten_keyframe: dict[int, int] = {}
        self._joints: dict[int, np.ndarray] = {}  # that covariance while the step was latest
        # committed factors removed and not put back, by id: (factor, its step, the update's
        # step), and the kept steps whose joint counted one of them (from its step on)
        self._removed: dict[int, tuple[_Factor, int, int]] = {}
        self._stale: set[int] = set()
        self._n_left = 0  # self._steps[:self._n_left] have left
        self._marginal: set[int] = set()  # indices of the marginal factors of what left
        self._settled_from: gtsam.Values | None = None
        self._steps: list[int] = []
        self._step_set: set[int] = set()
        # keyframes in the graph (or queued): odometry pose T_o_b per robot and index, and the
        # rank in self._steps of the first step added after each (it leaves with that step)
        self._keyframes: dict[int, dict[int, np.ndarray]] = defaultdict(dict)
        self._keyframe_rank: dict[int, int] = {}
        self._keyframes_at: dict[int, list[int]] = defaultdict(list)  # rank -> keys
        self._last_keyframe: dict[int, int] = {}  # robot -> its latest keyframe index
        # keyframes that left: their pose in the common frame when they left, per robot
        self._left_keyframes: dict[int, dict[int, np.ndarray]] = defaultdict(dict)
        self._queued: list[_Factor] = []
        self._pending_values = gtsam.Values()
        self._to_remove: list[int] = []
        self._active: dict[int, _Factor] = {}  # by iSAM2 factor index
        self._links: Counter[tuple] = Counter()  # committed factors per linked chain pair
        self._free: dict[tuple, int] = {}  # chain -> index of its gauge prior
        self._a_chains = frozenset(("A", r) for r in range(n_robots))
        self._gauge_kept: tuple | None = None  # what `_fix_gauge` last found nothing to do in
        self._drift_noise: dict[int, gtsam.noiseModel.Base] = {}  # chain noise per step span
        self._hypothesis: dict[tuple[int, int], int] = {}
        # pair -> an abandoned hypothesis whose factors wait for removal
        self._abandoned: dict[tuple[int, int], _Abandoned] = {}
        # this step's TCAFF estimates, and pairs whose hypothesis the cycle check holds out
        self._given: dict[tuple[int, int], AlignmentEstimate] = {}
        self._given_step: int | None = None  # the step of `_given`'s estimates
        self._suspended: dict[tuple[int, int], _Suspended] = {}
        # the three as the last update that succeeded left them: what a failed one restores
        self._switches = _copied_switches(self._hypothesis, self._abandoned, self._suspended)

    # -- pose helpers --------------------------------------------------------------------------

    @property
    def _n_param(self) -> int:
        return 3 if self._planar else 4

    @property
    def _side(self) -> int:
        """Rows of a homogeneous matrix: 3 for SE(2), 4 for SE(3)."""
        return 3 if self._planar else 4

    def _pose(self, T: np.ndarray):
        if self._planar:
            return gtsam.Pose2(T[0, 2], T[1, 2], math.atan2(T[1, 0], T[0, 0]))
        return gtsam.Pose3(T)

    def _queue_between(self, a: int, b: int, T: np.ndarray, noise, tag: tuple | None = None,
                       step: int | None = None, link: tuple | None = None) -> None:
        """Queue the factor a^-1 b = T (a (side, side) matrix)."""
        cls = gtsam.BetweenFactorPose2 if self._planar else gtsam.BetweenFactorPose3
        self._queued.append(_Factor(cls(a, b, self._pose(T), noise), (a, b), tag, step, link))

    def _queue_prior(self, key: int, T: np.ndarray, sigmas: tuple[float, float],
                     tag: tuple | None = None) -> None:
        """Queue a prior on `key` at T with sigmas (translation [m], rotation [rad])."""
        t, r = sigmas
        s = np.array([t, t, r]) if self._planar else np.array([r, r, r, t, t, t])
        noise = gtsam.noiseModel.Diagonal.Sigmas(s)
        cls = gtsam.PriorFactorPose2 if self._planar else gtsam.PriorFactorPose3
        self._queued.append(_Factor(cls(key, self._pose(T), noise), (key,), tag))

    def _matrix(self, T_params) -> np.ndarray:
        """Homogeneous matrix of an alignment given as a matrix or as parameters."""
        p = real_array("InterRobotGraph", "T", T_params)
        if p.shape == (self._n_param,):
            p = _check_finite("T (parameters)", p, p.shape)
            _check_translation("T (parameters)", p[:-1])
            return _se2_from_params(p) if self._planar else _se3_from_xyz_yaw(*p)
        T = self._rigid("T", p)
        _check_translation("T", T[:-1, -1])
        return T if self._planar else _se3_from_xyz_yaw(*self._params(T))  # gravity-aligned

    def _params(self, T: np.ndarray) -> np.ndarray:
        """(x, y, theta) of an SE(2) matrix or (x, y, z, yaw) of an SE(3) one."""
        if self._planar:
            return _se2_to_params(T)
        return np.array([*T[:3, 3], _se2_to_params(_se3_to_se2(T))[2]])

    def _params_to_tangent(self, T: np.ndarray) -> np.ndarray:
        """G with xi = G d(params) at pose T; (3, 3) or (6, 4)."""
        R = T[:-1, :-1]
        if self._planar:
            G = np.zeros((3, 3))
            G[:2, :2] = R.T
            G[2, 2] = 1.0
            return G
        G = np.zeros((6, 4))
        G[2, 3] = 1.0
        G[3:, :3] = R.T
        return G

    def _tangent_cov(self, T: np.ndarray, cov_params: np.ndarray) -> np.ndarray:
        G = self._params_to_tangent(T)
        cov = G @ cov_params @ G.T
        if not self._planar:
            cov[0, 0] += self.params.gravity_sigma**2
            cov[1, 1] += self.params.gravity_sigma**2
        return 0.5 * (cov + cov.T)

    def _params_cov(self, T: np.ndarray, cov_tangent: np.ndarray) -> np.ndarray:
        if self._planar:
            J = np.eye(3)
            J[:2, :2] = T[:2, :2]
        else:
            J = np.zeros((4, 6))
            J[:3, 3:] = T[:3, :3]
            J[3, :3] = T[:3, :3][2]  # d yaw = (R omega)_z for a right perturbation
        return J @ cov_tangent @ J.T

    def _noise(self, cov_tangent: np.ndarray, robust: bool):
        gaussian = gtsam.noiseModel.Gaussian.Covariance(cov_tangent)
        kind = self.params.robust if robust else "none"
        if kind == "none":
            return gaussian
        m = gtsam.noiseModel.mEstimator
        estimator = (m.Huber if kind == "huber" else m.Cauchy).Create(self.params.robust_k)
        return gtsam.noiseModel.Robust.Create(estimator, gaussian)

    def _value(self, key: int) -> np.ndarray:
        """Current estimate of one variable (its initial value while it is still queued)."""
        step = _step_of(key)
        if step in self._left:
            return self._left[step][0][_chain(key)[1]].copy()
        if step is None and key not in self._keyframe_rank:  # a keyframe that left
            robot, index = _keyframe_of(key)
            return self._left_keyframes[robot][index].copy()
        if self._pending_values.exists(key):
            values = self._pending_values
            pose = values.atPose2(key) if self._planar else values.atPose3(key)
        elif self._planar:
            pose = self._isam.calculateEstimatePose2(key)
        else:
            pose = self._isam.calculateEstimatePose3(key)
        return pose.matrix()

    def _exists(self, key: int) -> bool:
        return self._pending_values.exists(key) or self._isam.valueExists(key)

    def _insert(self, key: int, T: np.ndarray) -> None:
        self._pending_values.insert(key, self._pose(T))

    def _rigid(self, name: str, T) -> np.ndarray:
        """A homogeneous rigid transform of this graph's dimension, else DataError."""
        size = self._side
        T = _check_finite(name, T, (size, size))
        R = T[: size - 1, : size - 1]
        if (np.abs(R.T @ R - np.eye(size - 1)).max() > 1e-6 or np.linalg.det(R) < 0
                or np.abs(T[-1] - np.eye(size)[-1]).max() > 1e-9):
            raise DataError(f"{name} is not a rigid transform: {T.tolist()}")
        return T

    def _check_robot(self, name: str, robot) -> None:
        if not (_int_at_least(robot, 0) and robot < self.n_robots):
            raise DataError(f"{name} = {robot!r} is not a robot of this graph (0 to "
                            f"{self.n_robots - 1})")

    # -- alignment chains ----------------------------------------------------------------------

    @property
    def steps(self) -> list[int]:
        """The committed alignment steps, increasing."""
        return list(self._steps)

    def add_alignment(self, step: int, i: int, j: int, T_oi_oj, cov,
                      hypothesis: int | None = None, robust: bool = True) -> None:
        """Queue the factor A_i(step)^-1 A_j(step) = T_oi_oj.

        Args:
            step: a committed step or the step of the next `update`.
            i, j: robots (ego, other), i != j.
            T_oi_oj: (3, 3) SE(2) / (4, 4) SE(3) matrix, or parameters (x, y, theta) /
                (x, y, z, yaw); 3D alignments are projected onto the gravity-aligned ones.
            cov: covariance of those parameters, (3, 3) or (4, 4); inflated at the update when
                the step's alignments close a cycle (`GraphParams.shared_maps`).
            hypothesis: tag; `remove_hypothesis(i, j, hypothesis)` removes these factors.
            robust: use the M-estimator of `params.robust` (else Gaussian).
        Raises:
            DataError: unknown robot, i == j, a step before the last committed one that has
                no variables, non-finite values, cov not positive definite.
        """
        self._check_robot("i", i)
        self._check_robot("j", j)
        if i == j:
            raise DataError(f"add_alignment: i and j are both {i}")
        step = _check_index("add_alignment: step", step, _ROBOT_SHIFT)
        if self._steps and step <= self._steps[-1] and step not in self._step_set:
            raise DataError(f"add_alignment: step {step} was never committed (steps so far "
                            f"end at {self._steps[-1]})")
        if self._has_left(_a_key(0, step)):
            raise DataError(f"add_alignment: step {step} has left the graph (horizon "
                            f"{self.params.horizon} steps, latest {self._steps[-1]})")
        T = self._matrix(T_oi_oj)
        C = _check_cov("add_alignment: cov", cov, self._n_param)
        noise = self._noise(self._tangent_cov(T, C), robust)
        i, j = int(i), int(j)
        self._queue_between(_a_key(i, step), _a_key(j, step), T, noise,
                            ("alignment", i, j, hypothesis), step, (("A", i), ("A", j)))

    def update(self, step: int | None = None) -> None:
        """Commit the queued factors, creating A_r(step) for every robot if `step` is given.

        With `GraphParams.horizon` = H, the update to `step` then marginalises every variable
        of the steps at or before step - H, the keyframes committed with them included; their
        last estimates stay readable.

        Raises:
            DataError: `step` is not after the last committed step, a queued alignment refers
                to a step that neither exists nor is `step`, or gtsam could not solve the graph
                with the queued factors, by Cholesky nor by QR, or its solution leaves one of
                them a million standard deviations off (rigid factors at odds). The queued
                factors are then dropped, and the graph holds the factors, hypotheses,
                pending switches and held-out hypotheses it held before; its estimate is
                solved again from them, from their linearisation point, and can move where
                the graph holds contradicting alignments.
        """
        if step is not None:
            step = _check_index("update: step", step, _ROBOT_SHIFT)
            if self._steps and step <= self._steps[-1]:
                raise DataError(f"update: step {step} is not after the last committed step "
                                f"{self._steps[-1]}")
        newest = step if step is not None else (self._steps[-1] if self._steps else -1)
        skipped = [q for q in self._queued
                   if q.step is not None and q.step not in self._step_set and q.step < newest
                   and q.step != step]
        if skipped:
            self._queued = [q for q in self._queued if all(q is not b for b in skipped)]
            raise DataError(f"update: {len(skipped)} queued alignments refer to step "
                            f"{skipped[0].step}, which was skipped; they were dropped")
        if step is not None:
            self._add_step(step)
        # alignments for later steps wait in the queue until their step is committed
        now, later = [], []
        for q in self._queued:
            (later if q.step is not None and q.step > newest else now).append(q)
        now, restored = self._cycle_checked(
            self._shared_maps_weighed(now) if self.params.shared_maps else now)
        self._queued = now + restored
        leaving, kept = self._leaving(step)
        self._fix_gauge()
        if not self._queued and not self._to_remove:
            self._queued = later
            self._switches = _copied_switches(self._hypothesis, self._abandoned,
                                              self._suspended)
            return
        graph = gtsam.NonlinearFactorGraph()
        touched = set()
        for q in self._queued:
            graph.add(q.factor)
            touched.update(q.keys)
        gone = [(index, self._active.pop(index)) for index in self._to_remove]
        removed_keys = set()
        for index, f in gone:
            removed_keys.update(f.keys)
            self._count(f, index, -1)
        touched |= removed_keys
        factors = self._isam.getFactorsUnsafe()
        self._settled_from = None
        # the marginal factors of what left (a roll-back needs them)
        marginals = {i: factors.at(i) for i in self._marginal}
        stale = (dict(self._removed), set(self._stale)) if gone or restored else None
        pending = set(self._pending_values.keys())
        factorization = self._isam.params().getFactorization()
        before = None  # the point the graph before the update is solved from again

        def apply() -> tuple[list[int], dict[int, np.ndarray]]:
            indices = self._commit(graph, self._pending_values, self._to_remove,
                                   removed_keys | kept)
            self._settle(touched)
            self._check_agreement()  # before any covariance is kept from a refused solution
            self._mark_stale(gone, restored, newest)
            # which robots the committed factors and this update's link: one search for every
            # joint computed here, none when there is none to compute
            keeps = self._keeps_joints and bool(self._steps)
            linked = self._linked(self._queued) if leaving or keeps else None
            joints = self._leaving_joints(leaving, linked)
            if keeps:
                # the latest step's joint, which it keeps when the next step comes: computed
                # here, so that a graph whose marginals gtsam cannot compute rolls back
                self._joints[self._steps[-1]] = self._joint(self._steps[-1], linked)
            return indices, joints

        try:
            try:
                indices, joints = apply()
            except _Contradiction:
                raise
            except RuntimeError:
                if factorization != "CHOLESKY":
                    raise
                # Cholesky works on the square of the system and finds a consistent one
                # indeterminate where its information spans some eight orders of magnitude
                # (odometry sure to 1e-4 under a gauge prior of 1, variances of 1e6 for
                # "unknown"); QR does not
                before = self._restart_point(pending)
                gone = self._refactorised(gone, marginals, before)
                self._settled_from = None
                if stale is not None:
                    self._removed, self._stale = dict(stale[0]), set(stale[1])
                indices, joints = apply()
        except RuntimeError as exc:  # gtsam could not solve it: back to the graph before
            # the roll-back factorises as the graph did before (the failed solver's own)
            self._isam.params().setFactorization(factorization)
            if stale is not None:
                self._removed, self._stale = stale
            hypothesis, abandoned, suspended = self._switches
            # copied again: the snapshot must serve a failure of the next update too
            self._hypothesis, self._abandoned, _ = _copied_switches(hypothesis, abandoned, {})
            self._suspended = {pair: held_out for pair, (held_out, _) in suspended.items()}
            for held_out, n in suspended.values():
                del held_out.factors[n:]
            self._forget_keyframes(pending)
            dropped, self._queued = self._queued, later
            self._pending_values, self._to_remove = gtsam.Values(), []
            tags = [q.tag for q in dropped if q.tag and q.tag[0] != "free"]
            self._roll_back(gone, marginals, step, leaving, pending, before)  # last: it can raise
            raise DataError(f"update: gtsam could not solve the graph with the {len(dropped)} "
                            f"factors queued for this update ({reason(exc)}); they were dropped "
                            f"and the graph is as it was before (tagged among them: "
                            f"{tags[:5]})") from None
        for q, index in zip(self._queued, indices, strict=True):
            self._active[index] = q
            self._count(q, index, +1)
        self._queued, self._pending_values, self._to_remove = later, gtsam.Values(), []
        # a new solver (by QR, or converged), with marginal factors of its own
        if self._converge() or before is not None:
            factors = self._isam.getFactorsUnsafe()
            marginals = {i: factors.at(i) for i in self._marginal}
        self._marginalise(leaving, joints, marginals)
        self._switches = _copied_switches(self._hypothesis, self._abandoned, self._suspended)

    def _mark_stale(self, gone: list[tuple[int, _Factor]], restored: list[_Factor],
                        newest: int) -> None:
        """Mark the kept joints that counted a factor this update removed for good, from the
        factor's step up to the step before this update's (information runs forward along
        the chains); a held-out factor put back unmarks them (`past_covariance`)."""
        changed = bool(restored)
        for f in restored:
            self._removed.pop(id(f), None)
        for _, f in gone:
            if f.step is not None and f.step < newest:
                self._removed[id(f)] = (f, f.step, newest)
                changed = True
        if not changed:
            return
        first = self._steps[self._n_left] if self._n_left < len(self._steps) else newest
        self._removed = {key: v for key, v in self._removed.items() if v[2] > first}
        merged: list[list[int]] = []  # the spans [step, update) as disjoint ones
        for start, end in sorted((s, u) for _, s, u in self._removed.values()):
            if merged and start <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], end)
            else:
                merged.append([start, end])
        starts = [start for start, _ in merged]
        self._stale = {k for k in self._joints
                       if (n := bisect_right(starts, k) - 1) >= 0 and k < merged[n][1]}

    def _shared_maps_weighed(self, queued: list[_Factor]) -> list[_Factor]:
        """`queued` with the alignment factors of each step that close cycles inflated
        (`GraphParams.shared_maps`): in each block of the step's robot pairs (a biconnected
        component: pairs joined by cycles) of E pairs among V robots, each factor's
        covariance times E / (V - 1); a pair on no cycle is a block of its own and stays as
        it is. Factors of one pair (both directions, rival hypotheses) count as one pair."""
        by_step: dict[int, list[int]] = defaultdict(list)
        for n, q in enumerate(queued):
            if q.tag is not None and q.tag[0] == "alignment":
                by_step[q.step].append(n)
        out = list(queued)
        for members in by_step.values():
            pair_of = [tuple(sorted(queued[n].link)) for n in members]
            pairs = list(dict.fromkeys(pair_of))
            if len(pairs) < 3:  # a cycle of different robots needs three pairs
                continue
            block = dict(zip(pairs, _blocks(pairs), strict=True))
            edges, robots = Counter(block.values()), defaultdict(set)
            for pair, b in block.items():
                robots[b].update(pair)
            for n, pair in zip(members, pair_of, strict=True):
                b = block[pair]
                inflation = edges[b] / (len(robots[b]) - 1)
                if inflation > 1.0:
                    out[n] = self._inflated(queued[n], inflation)
        return out

    def _inflated(self, q: _Factor, inflation: float) -> _Factor:
        """The between-factor q with its covariance times `inflation`, robust as it was."""
        noise = q.factor.noiseModel()
        robust = isinstance(noise, gtsam.noiseModel.Robust)
        cov = (noise.noise() if robust else noise).covariance() * inflation
        factor = type(q.factor)(*q.keys, q.factor.measured(), self._noise(cov, robust))
        return q._replace(factor=factor)

    def _count(self, f: _Factor, index: int, sign: int) -> None:
        if f.link:
            self._links[f.link] += sign
            if self._links[f.link] == 0:
                del self._links[f.link]
        if f.tag and f.tag[0] == "free":
            if sign > 0:
                self._free[f.tag[1]] = index
            else:
                self._free.pop(f.tag[1], None)

    def _fix_gauge(self) -> None:
        """Keep every group of chains that is not connected to robot 0's anchored chains fixed
        by exactly one weak prior, and no prior on the others (priors there would bias the
        alignments). Runs before each iSAM2 update, so priors come and go with the factors
        (a first alignment, a removed hypothesis) in the same update."""
        chains = self._a_chains if self._steps else frozenset()
        # a robot's latest keyframe never leaves (`_leaving`)
        chains = chains | {("X", robot) for robot in self._last_keyframe}
        removing = self._to_remove
        dropped = Counter(self._active[i].link for i in removing if self._active[i].link)
        # pairs of chains with committed factors between them
        linked = {link for link, n in self._links.items() if n > dropped[link]}
        linked.update(q.link for q in self._queued if q.link)
        free = {c: i for c, i in self._free.items() if i not in removing}
        # all the decision depends on: as it was when nothing was to be done (every step of a
        # connected team), nothing is to be done
        state = (chains, frozenset(linked), frozenset(free))
        if state == self._gauge_kept:
            return
        root = _components(chains, linked)
        anchored = {root(c) for c in (("A", 0), ("X", 0)) if c in chains}
        groups: dict[tuple, list] = defaultdict(list)
        for c in sorted(chains):
            groups[root(c)].append(c)
        actions = (len(removing), len(self._queued))
        for group_root, members in groups.items():
            have = [c for c in members if c in free]
            keep = [] if group_root in anchored else have[:1]
            removing.extend(free[c] for c in have if c not in keep)
            if group_root not in anchored and not keep:
                kind, robot = members[0]
                key = (_a_key(robot, self._steps[-1]) if kind == "A"
                       else _x_key(robot, self._last_keyframe[robot]))
                self._queue_prior(key, self._value(key), self.params.free_sigmas,
                                  ("free", members[0]))
        self._gauge_kept = state if actions == (len(removing), len(self._queued)) else None

    def _add_step(self, step: int) -> None:
        """Queue A_r(step) for every robot: for the first step at the identity, robot 0's
        anchored; after it at A_r of the previous step, linked to it by the drift factor."""
        prm = self.params
        identity = np.eye(self._side)
        if not self._steps:
            for r in range(self.n_robots):
                self._insert(_a_key(r, step), identity)
            self._queue_prior(_a_key(0, step), identity, (prm.anchor_sigma,) * 2)
        else:
            previous = self._steps[-1]
            span = step - previous
            noise = self._drift_noise.get(span)
            if noise is None:
                drift = self._tangent_cov(identity, prm.Q * span / 2.0)
                noise = self._drift_noise[span] = self._noise(drift, False)
            for r in range(self.n_robots):
                before, key = _a_key(r, previous), _a_key(r, step)
                self._insert(key, self._value(before))
                self._queue_between(before, key, identity, noise)
        self._steps.append(step)
        self._step_set.add(step)
