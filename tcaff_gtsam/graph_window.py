"""The sliding window of `InterRobotGraph`: each iSAM2 update (ordered so that what leaves is
always a set of leaves of the Bayes tree), the steps and keyframes that leave with a horizon and
their marginalisation, the joint covariance kept for reading them (and forgotten beyond
`GraphParams.history`), and the roll-back to the graph as it was when gtsam cannot solve an
update."""

from __future__ import annotations

from bisect import bisect_left

import gtsam
import numpy as np

from .errors import DataError, reason
from .graph_inputs import (
    _a_key,
    _Factor,
    _key_list,
    _keyframe_of,
    _step_of,
)

__all__ = ["SlidingWindow"]

#: the squared whitened error past which an update holds rigid factors at odds (a million
#: standard deviations). A least-squares compromise between Gaussian factors is not one: a
#: switch of hypotheses leaves its alignments thousands of standard deviations off for a
#: while; two rigid factors (1e-6 m) 9 km apart are left 1e10 off.
_CONTRADICTION = 1e12


class _Contradiction(RuntimeError):
    """An update's factors at odds (`SlidingWindow._check_agreement`): refused as one gtsam
    cannot solve, without trying another factorisation."""


class SlidingWindow:
    """The part of `InterRobotGraph` that solves, keeps a horizon of steps and rolls back
    (mixed into it; it uses the graph's own attributes)."""

    def _joint(self, step: int, linked: np.ndarray | None = None) -> np.ndarray:
        """Joint marginal covariance of every robot's A at `step`, gtsam's tangent order, NaN
        between robots no factor links (`linked`, from `_linked`: None, the committed factors
        alone): what `alignment` reads from a joint kept for later as unknown."""
        keys = [_a_key(r, step) for r in range(self.n_robots)]
        joint = self._isam.jointMarginalCovariance(keys).fullMatrix()
        if linked is None:
            linked = self._linked()
        apart = linked[:, None] != linked[None, :]
        if apart.any():
            n = joint.shape[0] // self.n_robots
            joint[np.kron(apart, np.ones((n, n), dtype=bool))] = np.nan
        return joint

    def _latest_joint(self, step: int) -> np.ndarray:
        """The joint of the latest step as it is now, kept until the graph changes (with a
        horizon or `past_covariance="causal"`): the update that commits the step computes it
        (and keeps it as the step's causal joint when the next comes); a read computes it
        where none is kept (after an update that failed computing it)."""
        joint = self._joints.get(step)
        if joint is None:
            joint = self._joints[step] = self._joint(step)
        return joint

    @property
    def _keeps_joints(self) -> bool:
        """Whether steps keep the joint they had as the latest (a horizon, or
        `past_covariance="causal"`)."""
        return self.params.horizon is not None or self.params.past_covariance == "causal"

    def _kept_joint(self, step: int) -> np.ndarray | None:
        """The joint `alignment` reads a step's covariance from: the one it left with, the
        latest step's (computed once), an earlier step's as it was the latest unless stale
        (`past_covariance="causal"`); None where the current marginal is read instead."""
        if step in self._left:
            return self._left[step][1]
        if step == self._steps[-1]:
            return self._latest_joint(step) if self._keeps_joints else None
        if self.params.past_covariance == "causal" and step not in self._stale:
            return self._joints.get(step)
        return None

    def _new_solver(self, isam_params: gtsam.ISAM2Params) -> None:
        self._isam = gtsam.ISAM2(isam_params)

    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               remove: list[int], reelim=()) -> gtsam.ISAM2Result:
        """One iSAM2 update. With a horizon, the part of the Bayes tree it eliminates again is
        ordered by the variables' groups (the rank of their step), so that no variable has a
        newer one below it: what leaves is then always a set of leaves, and marginalising it
        touches only their cliques (gtsam's fixed-lag smoother instead eliminates the whole
        path from them to the root, the whole horizon, every time). `reelim`: variables to
        eliminate again whatever the new factors touch: those of the removed factors (the
        prediction leaves them out) and keyframes whose group changed (`_leaving`)."""
        if self.params.horizon is None:
            return self._isam.update(graph, values, remove)
        update = gtsam.ISAM2UpdateParams()
        update.removeFactorIndices = remove
        if reelim:
            update.extraReelimKeys = _key_list(reelim)
        affected, batch = self._isam.predictUpdateInfo(graph, values, update)
        affected = ([*self._isam.getLinearizationPoint().keys(), *values.keys()] if batch
                    else list(affected))
        return self._ordered_update(graph, values, update, affected)

    def _ordered_update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                        update: gtsam.ISAM2UpdateParams, keys) -> gtsam.ISAM2Result:
        """iSAM2's update with `keys`, the variables it eliminates, ordered by their groups."""
        # ccolamd wants the groups numbered from 0 without gaps
        groups = [self._group(key) for key in keys]
        dense = {g: n for n, g in enumerate(sorted(set(groups)))}
        constrained = gtsam.KeyGroupMap()  # the attribute keeps a copy: fill it first
        for key, g in zip(keys, groups, strict=True):
            constrained.insert2(key, dense[g])
        update.constrainedKeys = constrained
        return self._isam.update(graph, values, update)

    def _commit(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                remove: list[int], reelim=()) -> list[int]:
        """New factors, new values, removals and variables to eliminate again (`_solve`); the
        new factors' indices."""
        return list(self._solve(graph, values, remove, reelim).getNewFactorsIndices())

    def _group(self, key: int) -> int:
        """Elimination group of a variable: the rank in self._steps of its step (for a
        keyframe, of the first step added after it)."""
        step = _step_of(key)
        return self._keyframe_rank[key] if step is None else bisect_left(self._steps, step)

    def _has_left(self, key: int) -> bool:
        """Whether a variable has left the graph, forgotten or not (or leaves with this
        update); False for one that never was in it."""
        step = _step_of(key)
        if step is None:
            rank = self._keyframe_rank.get(key)
            if rank is not None:
                return rank < self._n_left
            robot, index = _keyframe_of(key)
            return (index in self._left_keyframes.get(robot, ())
                    or index <= self._forgotten_keyframe.get(robot, -1))
        return (step in self._step_set and self._n_left > 0
                and step <= self._steps[self._n_left - 1])

    @property
    def _n_forgotten(self) -> int:
        """How many of the first steps are forgotten (`GraphParams.history`): steps leave in
        order, and `_left` holds the latest of those that left."""
        return self._n_left - len(self._left)

    def _leaving(self, step: int | None) -> tuple[list[int], set[int]]:
        """With a horizon: the ranks (in self._steps) of the steps the update to `step` lets
        leave, and the keyframes that stay though their step leaves: each robot's latest, kept
        until its successor comes, so that the odometry to it always has its predecessor to act
        on (one keyframe more per robot at most; a chain that restarted instead would leave the
        robots tied to robot 0 through it free). They join the newest step's group and are
        eliminated again. Gauge priors on what leaves are moved to the latest step first (a
        prior marginalised into the graph could never be removed when the robots connect)."""
        horizon = self.params.horizon
        if horizon is None or step is None:
            return [], set()
        first, newest = self._n_left, len(self._steps) - 1
        kept = set()
        while self._n_left < len(self._steps) and self._steps[self._n_left] <= step - horizon:
            at = self._keyframes_at.get(self._n_left, [])
            for key in list(at):
                robot, index = _keyframe_of(key)
                if self._last_keyframe[robot] == index:
                    at.remove(key)
                    self._keyframes_at[newest].append(key)
                    self._keyframe_rank[key] = newest
                    kept.add(key)
            self._n_left += 1
        self._to_remove.extend(index for chain, index in self._free.items()
                               if index not in self._to_remove
                               and self._has_left(self._active[index].keys[0]))
        return list(range(first, self._n_left)), kept

    def _leaving_joints(self, ranks: list[int], linked: np.ndarray) -> dict[int, np.ndarray]:
        """The joint each step at `ranks` leaves with, by step: the one kept by the update that
        added the next step (a step leaves only after one), unless a removal since made it
        stale, then the joint as it is now (its robots `linked` as the update leaves them).
        Computed before anything leaves, so that a system gtsam cannot solve for it rolls the
        update back."""
        joints = {}
        for rank in ranks:
            k = self._steps[rank]
            joint = self._joints.get(k)
            joints[k] = self._joint(k, linked) if joint is None or k in self._stale else joint
        return joints

    def _marginalise(self, ranks: list[int], joints: dict[int, np.ndarray],
                     marginals: dict) -> None:
        """Marginalise the variables of the steps at `ranks` and the keyframes added with them
        (leaves of the Bayes tree, see `_solve`), keeping their estimates and `joints` (by
        step, `_leaving_joints`) for reading until `_forget` forgets them. The factors of
        those steps that the cycle check holds out can never come back: dropped.
        `marginals`: the marginal factors of what left before, by index (a refused
        marginalisation drops them from gtsam's graph)."""
        if ranks and self._suspended:
            gone = {self._steps[rank] for rank in ranks}
            for held_out in self._suspended.values():
                held_out.factors = [f for f in held_out.factors if f.step not in gone]
        keys = []
        for rank in ranks:
            k = self._steps[rank]
            step_keys = [_a_key(r, k) for r in range(self.n_robots)]
            estimate = self._isam.calculateEstimate(step_keys)
            get = estimate.atPose2 if self._planar else estimate.atPose3
            A = np.array([get(key).matrix() for key in step_keys])
            self._joints.pop(k, None)
            self._stale.discard(k)
            self._left[k] = (A, joints[k])
            keys += step_keys
            for key in self._keyframes_at.pop(rank, []):
                robot, index = _keyframe_of(key)
                if self._isam.valueExists(key):
                    self._left_keyframes[robot][index] = self._value(key)
                    keys.append(key)
                if self.params.history is not None:
                    self._left_with.setdefault(k, []).append((robot, index))
                del self._keyframes[robot][index], self._keyframe_rank[key]
        self._forget()
        if not keys:
            return
        try:
            marginal, deleted = self._isam.marginalizeLeavesWithIndices(_key_list(keys))
        except (ValueError, RuntimeError):
            # gtsam refuses ("not unused"): a keyframe linked to one of another robot that
            # stays can share a clique with it above a clique that leaves whole (its ordering
            # groups keyframes by the step added after them, not by what they are linked to);
            # or the partial elimination of such a clique fails. Either way it throws before
            # it changes the solver, and marginalising in a new one is right whatever the cause
            self._marginalise_rebuilt(keys, marginals)
            return
        active = self._active
        for index in deleted:
            active.pop(index, None)
        self._marginal.difference_update(deleted)
        self._marginal.update(marginal)
        if self._free:
            self._free = {chain: i for chain, i in self._free.items() if i in active}

    def _converge(self) -> bool:
        """After a big correction (`_settle` iterated) or while a variable of a marginal
        factor is `settle_threshold` from its linearisation point, a new solver from the
        current estimate, iterated until no variable is `relinearize_threshold` from its
        linearisation point; returns whether that was done. gtsam never relinearises the
        variables of its marginal factors: a group of keyframe chains that joins robot 0
        after its first keyframes left moves by metres and radians, while the factors on its
        fixed variables stay linearised where they were. And iSAM2's partial check does not
        descend below a clique that converged, where the horizon's ordering puts the oldest
        variables. In the new solver the marginal factors hold their linearisation point,
        moved with their variables where they hold relative information only (`_moved`).
        Where gtsam fails on the way the graph keeps its solver as it was."""
        if self._settled_from is None and self._fixed_far() < self.params.settle_threshold:
            return False
        isam = self._isam
        before = (isam, self._active, self._marginal, self._free)
        threshold = self.params.relinearize_threshold
        try:
            theta, estimate = isam.getLinearizationPoint(), isam.calculateEstimate()
            factors = isam.getFactorsUnsafe()
            moved = [self._moved(factors.at(i), theta, estimate) for i in self._marginal]
            self._rebuild(dict(self._active), moved, estimate, set())
            for _ in range(self.params.max_iterations):
                if np.abs(self._isam.getDelta().vector()).max() < threshold:
                    break
                self._relinearise_all()
        except (DataError, RuntimeError, ValueError, IndexError):  # gtsam's, all of them
            self._isam, self._active, self._marginal, self._free = before
            return False
        return True

    def _fixed_far(self) -> float:
        """How far (m or rad) the variable of a marginal factor furthest from its
        linearisation point is from it (0 without a horizon): gtsam never relinearises them."""
        if self.params.horizon is None:
            return 0.0
        delta = self._isam.getDelta()
        fixed = [key for key in self._isam.getFixedVariables() if delta.exists(key)]
        return float(np.abs(delta.vector(fixed)).max()) if fixed else 0.0

    def _moved(self, marginal, theta: gtsam.Values, estimate: gtsam.Values):
        """A marginal factor (linear about `theta`) as a linear factor holding its
        linearisation point, that point moved rigidly onto `estimate` where the factor holds
        relative information only (no more information on a rigid motion of its variables
        than a gauge prior gives: a group of chains free of robot 0's anchor when it was
        made). Between-factors see relative poses only, so the moved factor is the same linear
        factor, where the old point reads a rigid move of the group as a violation of it,
        badly so for large rotations."""
        linear = marginal.linearize(theta)
        keys = list(linear.keys())
        pose = gtsam.Values.atPose2 if self._planar else gtsam.Values.atPose3
        before = [pose(theta, key) for key in keys]
        # a rigid motion G of the group moves each variable's tangent by Ad(X^-1) G's
        V = np.vstack([X.inverse().AdjointMap() for X in before])
        on_motion = V.T @ linear.information() @ V
        if np.linalg.eigvalsh(on_motion).max() <= 1.0 / min(self.params.free_sigmas) ** 2:
            G = self._rigid_motion(before, [pose(estimate, key) for key in keys])
            before = [G.compose(X) for X in before]
        point = gtsam.Values()
        for key, X in zip(keys, before, strict=True):
            point.insert(key, X)
        return gtsam.LinearContainerFactor(linear, point)

    def _rigid_motion(self, before: list, after: list):
        """G with G before[i] ~ after[i] (gtsam poses): least squares in the plane, the first
        pair's in 3D."""
        if not self._planar:
            return after[0].compose(before[0].inverse())
        turns = [a.theta() - b.theta() for a, b in zip(after, before, strict=True)]
        theta = float(np.arctan2(np.mean(np.sin(turns)), np.mean(np.cos(turns))))
        c, s = np.cos(theta), np.sin(theta)
        R = np.array([[c, -s], [s, c]])
        t = np.mean([a.translation() - R @ b.translation()
                     for a, b in zip(after, before, strict=True)], axis=0)
        return gtsam.Pose2(float(t[0]), float(t[1]), theta)

    def _relinearise_all(self) -> None:
        """One iSAM2 iteration, in the horizon's order, relinearising every variable that is
        `relinearize_threshold` from its linearisation point (its delta solved in full first,
        whatever `relinearize_skip`)."""
        update = gtsam.ISAM2UpdateParams()
        update.forceFullSolve = update.force_relinearize = True
        self._ordered_update(gtsam.NonlinearFactorGraph(), gtsam.Values(), update,
                             list(self._isam.getLinearizationPoint().keys()))

    def _marginalise_rebuilt(self, keys: list[int], marginals: dict) -> None:
        """Marginalise `keys` where gtsam's marginalisation of leaves refused them, in a new
        solver: the factors on them (`self._active`'s and the earlier `marginals`, by index)
        are linearised at the linearisation point and the keys eliminated from them; the other
        factors and what that elimination leaves on the variables that stay (linear factors
        that hold that point) make the new solver. Its estimate starts from the same point."""
        theta = self._isam.getLinearizationPoint()  # the failed call leaves it whole
        leaving = set(keys)
        earlier = self._pointed(marginals, theta)
        on_leaving = gtsam.NonlinearFactorGraph()
        for factor in [*(f.factor for f in self._active.values()), *earlier]:
            if not leaving.isdisjoint(factor.keys()):
                on_leaving.add(factor)
        _, remaining = on_leaving.linearize(theta).eliminatePartialMultifrontal(
            gtsam.Ordering(list(keys)))
        new = gtsam.LinearContainerFactor.ConvertLinearGraph(remaining, theta)
        self._rebuild({i: f for i, f in self._active.items() if leaving.isdisjoint(f.keys)},
                      [*(m for m in earlier if leaving.isdisjoint(m.keys())),
                       *(new.at(n) for n in range(new.size()))], theta, leaving)

    def _rebuild(self, active: dict[int, _Factor], marginals: list, point: gtsam.Values,
                 without: set[int], qr_only: bool = False) -> dict[int, int]:
        """A new solver holding the factors `active` (by index) and the marginal factors
        `marginals`, from the values of `point` but those of the variables `without`;
        `_active`, `_marginal` and `_free` index its factors from then on. Returns each
        factor's new index by its index in `active`.

        It factorises as the solver before it did, and where that fails by QR (a system
        Cholesky finds indeterminate: near-singular covariances), more slowly, from then on;
        a DataError where neither solves it. `qr_only`: by QR alone, and gtsam's RuntimeError
        where that fails. Either way the graph keeps the solver before it when it fails."""
        values = gtsam.Values(point)
        for key in without:
            if values.exists(key):
                values.erase(key)
        graph = gtsam.NonlinearFactorGraph()
        for f in active.values():
            graph.add(f.factor)
        for factor in marginals:
            graph.add(factor)
        old, params = self._isam, self._isam.params()
        factorization = params.getFactorization()
        attempts = ("QR",) if qr_only else tuple(dict.fromkeys((factorization, "QR")))
        try:
            for attempt in attempts:
                params.setFactorization(attempt)
                try:
                    self._new_solver(params)  # gtsam's solver keeps a copy of its parameters
                    indices = self._commit(graph, values, [])
                    break
                except RuntimeError as exc:
                    if attempt != attempts[-1]:
                        continue
                    self._isam = old
                    if qr_only:
                        raise
                    raise DataError(f"InterRobotGraph: gtsam could not solve the graph again "
                                    f"in a new solver ({reason(exc)}); the graph cannot be "
                                    f"used further") from None
        finally:  # `params` is the old solver's own (gtsam gives it by reference)
            params.setFactorization(factorization)
        remap = dict(zip(active, indices[:len(active)], strict=True))
        self._active = {remap[i]: f for i, f in active.items()}
        self._marginal = set(indices[len(active):])
        self._free = {chain: remap[i] for chain, i in self._free.items() if i in remap}
        return remap

    @staticmethod
    def _pointed(marginals: dict, point: gtsam.Values) -> list:
        """The marginal factors of what left (by index) as linear factors that hold the
        linearisation point `point` of their variables, for a new solver: gtsam's own hold
        none, their variables being fixed in the solver that made them, and a new solver would
        relinearise those variables under them."""
        return [gtsam.LinearContainerFactor(m.linearize(point), point)
                for m in marginals.values()]

    def _forget(self) -> None:
        """Forget the steps that left beyond the latest `GraphParams.history` of them, and the
        keyframes that left with them (steps leave in order, so `_left` is oldest first)."""
        history = self.params.history
        if history is None:
            return
        while len(self._left) > history:
            k = next(iter(self._left))
            del self._left[k]
            for robot, index in self._left_with.pop(k, ()):
                self._left_keyframes[robot].pop(index, None)
                self._forgotten_keyframe[robot] = index

    def _forget_keyframes(self, keys: set[int]) -> None:
        """Unregister keyframes whose values were dropped with a failed update."""
        for key in keys:
            if _step_of(key) is None:
                robot, index = _keyframe_of(key)
                frames = self._keyframes[robot]
                del frames[index]
                self._keyframes_at[self._keyframe_rank.pop(key)].remove(key)
                # a robot's latest keyframe stays in the graph (`_leaving`)
                before = max(frames, default=None)
                if before is None:
                    del self._last_keyframe[robot]
                else:
                    self._last_keyframe[robot] = before

    def _rebuild_before(self, gone: list[tuple[int, _Factor]], marginals: dict,
                        point: gtsam.Values, qr_only: bool = False) -> dict[int, int]:
        """`_rebuild` of the graph before an update at `point`: its factors, those the update
        removes (`gone`) with them, and the marginal factors of what left (`marginals`)."""
        return self._rebuild({**self._active, **dict(gone)}, self._pointed(marginals, point),
                             point, set(), qr_only)

    def _restart_point(self, pending: set[int]) -> gtsam.Values:
        """The point a failed update solves the graph before it again from: where `_settle`
        started, else the solver's linearisation point, without the new variables `pending`
        (gtsam's solver is unusable after an exception, but its point can be read)."""
        point = gtsam.Values(self._isam.getLinearizationPoint() if self._settled_from is None
                             else self._settled_from)
        for key in pending:
            if point.exists(key):
                point.erase(key)
        return point

    def _roll_back(self, gone: list[tuple[int, _Factor]], marginals: dict, step: int | None,
                   leaving: list[int], pending: set[int], point: gtsam.Values | None) -> None:
        """After a failed update: the steps and keyframes as they were, then a new solver
        holding the factors of the graph before it at `point` (`_restart_point` when None)."""
        self._n_left -= len(leaving)
        if step is not None:
            self._steps.pop()
            self._step_set.discard(step)
        if point is None:
            point = self._restart_point(pending)
        remap = self._rebuild_before(gone, marginals, point)
        for index, f in gone:
            self._count(f, remap[index], +1)

    def _refactorised(self, gone: list[tuple[int, _Factor]], marginals: dict,
                      point: gtsam.Values) -> list[tuple[int, _Factor]]:
        """After Cholesky failed on an update: a new solver that factorises by QR from then on,
        holding the graph before the update at `point`, and the update's removals indexed in
        it. Returns `gone`, the factors the update removes, by their new indices."""
        remap = self._rebuild_before(gone, marginals, point, qr_only=True)
        gone = [(remap[index], self._active.pop(remap[index])) for index, _ in gone]
        self._to_remove = [index for index, _ in gone]
        return gone

    def _check_agreement(self) -> None:
        """`_Contradiction` where a factor the update brings is left more than a million
        standard deviations from its measurement by the solution (`_CONTRADICTION`, its
        squared whitened error; robust factors twice their loss): rigid factors at odds.
        Cholesky usually fails on them, but not always, and QR's least squares averages them
        into a solution far from every one of them (anywhere up to 1e29 m away)."""
        estimate = gtsam.Values()
        get = (self._isam.calculateEstimatePose2 if self._planar
               else self._isam.calculateEstimatePose3)
        for key in {key for f in self._queued for key in f.keys}:
            estimate.insert(key, get(key))
        worst = max((2.0 * f.factor.error(estimate) for f in self._queued), default=0.0)
        if not worst <= _CONTRADICTION:
            raise _Contradiction(f"the update's factors contradict each other: one is left "
                                 f"with a squared whitened error of {worst:.3g}, past "
                                 f"{_CONTRADICTION:.0e}")

    def _settle(self, keys: set[int]) -> None:
        """Extra iterations while a variable the update touched is still far from its
        linearisation point (after a first alignment or a removed hypothesis); ordinary steps
        leave the usual relinearisation to the next update."""
        keys = list(keys)
        for _ in range(self.params.max_iterations):
            delta = self._isam.getDelta()
            present = [key for key in keys if delta.exists(key)]
            if not present or np.abs(delta.vector(present)).max() < self.params.settle_threshold:
                return
            if self._settled_from is None:  # a roll-back restarts from here, not from the
                # point a failed iteration moved (rare: big corrections only)
                self._settled_from = gtsam.Values(self._isam.getLinearizationPoint())
            self._solve(gtsam.NonlinearFactorGraph(), gtsam.Values(), [])
