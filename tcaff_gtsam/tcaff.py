"""TCAFF: the temporally consistent alignment of frames filter (paper, "Multiple Hypothesis
Formulation" and "Frame Alignment Filter").

Each step brings a set of candidate measurements z (from MNO-CLIPPER), at most one of them
correct. Hypotheses are sequences of choices (one measurement or none per step) filtered by a
Kalman filter with identity motion; a sequence costs the sum over steps of

    1/2 (|z - x|^2_S + log |S|),  S = P + Q + R,     for a measurement,
    -log p_NM - d/2 log 2 pi                          for no measurement

(the paper's final equation). Every measurement seeds an exploring tree (while a main tree
exists, only those it gates out); when, W steps later, the best path of some exploring tree
costs less than tau, that tree becomes the main tree and its best leaf is the estimate. Before
that, the filter has no estimate.

Beyond the paper, acceptance and switching count distinct evidence: a path's measurements that
re-match only objects its earlier measurements used are one piece of evidence, not several
(`TCAFFParams.min_distinct`, `switch_stale`; the object ids come with `update`, and
`PairwiseAligner` gives them only among look-alike objects), and a rival seen clearly more
often than the main hypothesis replaces it (`switch_support`).
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from .errors import TcaffError
from .geometry import _chi2_quantile, _se2_from_params
from .hypothesis_tree import (
    BEFORE_ROOT,
    CostModel,
    Leaves,
    best_per_tree,
    branch,
    extend,
    kalman_children,
    lowest,
    mahalanobis_to,
    measurement_costs,
    seed,
)
from .params import TCAFFParams, _given_or_default
from .tcaff_evidence import EvidenceRules
from .tcaff_inputs import (
    validated_evidence,
    validated_held_Q,
    validated_measurements,
    validated_objects,
)

# write_snapshot is the module's for its callers (a node writes snapshots on another thread)
from .tcaff_state import JITTER_CAP, FilterState, write_snapshot  # noqa: F401

__all__ = ["TCAFF", "AlignmentEstimate"]

#: the largest entry a reported covariance is scaled to (half the largest float)
_LARGEST_ENTRY = float(np.finfo(float).max) / 2.0

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class AlignmentEstimate:
    """The filter's estimate at one step.

    Attributes:
        x: (d,) state; for frame alignment (x [m], y [m], theta [rad]) of T_oi_oj.
        P: (d, d) its covariance.
        cost: path cost of the best hypothesis over the window (nats).
        hypothesis: id of the main tree that produced it; it changes when the filter accepts a
            new main tree (after a drop or a switch), not when it recalls a dropped one
            (unless another id was reported since: a reported id is never reused).
        step: number of updates so far (1 for the first).
        n_measurements: measurements on the best path within the window.
        measurement: index of this step's measurement on the best path, -1 if none.
    """

    x: np.ndarray
    P: np.ndarray
    cost: float
    hypothesis: int
    step: int
    n_measurements: int
    measurement: int

    @property
    def T(self) -> np.ndarray:
        """(3, 3) SE(2) matrix of a 3-dimensional (x, y, theta) state."""
        if self.x.shape != (3,):
            raise TcaffError(f"AlignmentEstimate.T needs an (x, y, theta) state, got shape "
                             f"{self.x.shape}")
        return _se2_from_params(self.x)


class TCAFF(EvidenceRules, FilterState):
    """The multiple-hypothesis filter for one directed robot pair (or any identity-motion state
    whose measurements may be wrong and are told apart by temporal consistency).

    Call `update` once per step with that step's measurements, in order.
    """

    def __init__(self, params: TCAFFParams | None = None) -> None:
        """A filter with `params` (None: the defaults), at step 0.

        Raises:
            ConfigError: params is neither a TCAFFParams nor None.
        """
        self.params = _given_or_default(TCAFFParams, params, "TCAFF")
        #: steps that gave more than `max_measurements` measurements, since construction
        self.capped_steps = 0
        prm = self.params
        d = prm.dim
        angular = np.zeros(d, dtype=bool)
        angular[list(prm.angle_indices)] = True
        nm_cost = -np.log(prm.p_no_measurement)
        if prm.cost_model == "paper":
            nm_cost -= 0.5 * d * np.log(2.0 * np.pi)
        self._model = CostModel(
            Q=prm.Q, angular=angular, reference=prm.cost_model == "reference",
            use_box=prm.gate == "box", gate_chi2=_chi2_quantile(prm.gate_probability, d),
            gate_box=np.array(prm.gate_box), no_measurement_cost=float(nm_cost))
        # a step without any measurement says nothing about which alignment is right
        self._empty_step_model = (replace(self._model, no_measurement_cost=0.0)
                                  if prm.neutral_empty_steps else self._model)
        # the same two (indexed by whether the step is empty), for a main tree held while the
        # drift is as assumed (`held_Q`)
        self._drift_models = tuple(replace(model, held_Q=prm.held_Q, held_after=prm.window)
                                   for model in (self._model, self._empty_step_model))
        self._columns = prm.window + 2
        self.reset()

    # -- public --------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget everything: no main tree, no exploring trees, step 0."""
        d = self.params.dim
        self.step = 0
        self.hypothesis = 0
        self._highest_reported = 0  # the highest hypothesis id ever reported (0: none)
        self._main: Leaves | None = None
        self._explore = Leaves.empty(d, self._columns)
        self._next_tree = 0
        self._switch_streak = 0
        self._rival: Leaves | None = None  # best rival leaf of the current streak
        self._empty_windows = 0
        self._bank: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.params.window + 1)
        # per step of the main tree's columns: each measurement's object-id pairs, or None
        self._evidence: deque[list[list[tuple[int, int]] | None]] = deque(maxlen=self._columns)
        # per step of the columns: its number of measurements (bounds the paths' choices)
        self._sizes: deque[int] = deque(maxlen=self._columns)
        self._fresh = 0  # last step at which the main's best path brought distinct evidence
        # per step of the columns: the objects each measurement explains, or None
        self._objects: deque[np.ndarray | None] = deque(maxlen=self._columns)
        # the last dropped main tree's best leaf, and the steps since it was dropped
        self._dormant: Leaves | None = None
        self._dormant_age = 0
        # most measurements the main tree's best path has held in its window, and the dormant
        # hypothesis's when it was dropped: the history a recall weighs against a main tree
        # accepted in the gap
        self._peak = 0
        self._dormant_peak = 0
        self._reclaiming = False  # the dormant hypothesis is being confirmed against the main
        # measurements the main's best path has taken since it came out of a silence of W
        # steps or more, until there are `early_measurements` of them (0: not in such a return)
        self._returning = 0
        # (step, hypothesis) of a switch away from a main tree in a gap of its measurements
        # (or from one that so replaced it and was not measured since), or of the window's
        # acceptance of an unmeasured hypothesis over a dormant one it contradicts, until the
        # hypothesis switched to is measured at a later step (`_contested`)
        self._silent_switch: tuple[int, int] | None = None
        # (step accepted, hypothesis) of a main tree accepted early whose path does not hold
        # what its complete window will be judged by (`_settle_provisional`)
        self._provisional: tuple[int, int] | None = None
        # (step, d' (R_a + R_b)^-1 d / d_dim, hypothesis) of consecutive measurements of the
        # main hypothesis over the last `jitter_span` steps, and (step, hypothesis, z, R) of the
        # latest measurement the main hypothesis took (`jitter_reference`)
        self._jitter: deque[tuple[int, float, int]] = deque()
        self._last_taken: tuple[int, int, np.ndarray, np.ndarray] | None = None
        # whether the jitter was within `jitter_reference` at the main hypothesis's latest
        # measurement (`hold_for`)
        self._drift_as_assumed = False
        self._estimate: AlignmentEstimate | None = None
        self._held: AlignmentEstimate | None = None

    @property
    def estimate(self) -> AlignmentEstimate | None:
        """The estimate of the latest step, or None."""
        return self._estimate

    @property
    def provisional(self) -> bool:
        """Whether the main hypothesis was accepted early on evidence its complete window
        would not yet hold (`_settle_provisional`): held, not reported."""
        return self._provisional is not None

    @property
    def confirmable(self) -> AlignmentEstimate | None:
        """The estimate that a measurement which may only confirm (an ambiguous or tracked
        candidate, `pairwise.admitted`) may confirm: `held`, but None while the hypothesis is
        provisional, which only a plain candidate settles."""
        return None if self._provisional is not None else self._held

    @property
    def held(self) -> AlignmentEstimate | None:
        """The main tree's estimate of the latest step, also while it is not reported
        (`withhold_contested`, `report_after`, `provisional`): what a search may be guided
        by once it is not provisional (`pairwise.guided_search`). None while there is no main
        tree."""
        return self._held

    @property
    def rivalled(self) -> bool:
        """Whether an exploring hypothesis that disagrees with the main tree's best leaf is
        open (one seeded within the last W steps): a search for measurements only near the
        held estimate would starve it. False while there is no main tree."""
        if self._main is None or len(self._explore) == 0:
            return False
        return not bool(self._consistent(self._explore, self._main_best()).all())

    def update(self, zs, Rs, evidence=None, objects=None, held_Q=None
               ) -> AlignmentEstimate | None:
        """One step.

        Args:
            zs: (k, d) measurements (k may be 0; an empty list is fine), angles in radians.
            Rs: (k, d, d) their covariances, symmetric positive definite.
            evidence: None, or k entries, one per measurement: None or an (m, 2) int array of
                the (ego object id, other object id) pairs the measurement associates, ids
                that persist across steps (`ObjectIdentities`). Used by `min_distinct`,
                `switch_stale`, `withhold_contested` and `switch_support`; without it every
                measurement is distinct evidence (`PairwiseAligner` gives ids only at steps
                whose maps are of look-alikes, `TCAFFParams.lookalike_share`).
            objects: None, or (k,) ints >= 0: how many objects each measurement explains
                (`AlignmentMeasurement.inliers`). Each is worth `object_nats` per object
                beyond `object_base` to a sequential acceptance (`TCAFFParams.sequential`);
                None counts every measurement as `object_base` objects.
            held_Q: None, or (d, d): this step's growth of a held leaf's covariance in place of
                `params.held_Q` (which must not be None), for a caller that knows where the
                alignment's drift turns it (`PairwiseAligner`: `pairwise.HeldDrift`).
        Returns:
            The estimate from the main tree's best leaf, or None while there is no main tree
            or it is not reported (`withhold_contested`, `report_after`; `held` has it).
        Raises:
            DataError: wrong shapes, non-finite values, R or held_Q not symmetric positive
                definite, evidence or objects of the wrong length, shape or kind, held_Q for
                a filter whose `params.held_Q` is None.
        """
        zs, Rs = validated_measurements(zs, Rs, self.params)
        held_Q = validated_held_Q(held_Q, self.params)
        evidence = validated_evidence(evidence, zs.shape[0])
        objects = validated_objects(objects, zs.shape[0])
        prm = self.params
        if zs.shape[0] > prm.max_measurements:
            zs, Rs, evidence, objects = self._capped(zs, Rs, evidence, objects)
        self.step += 1
        self._evidence.append(evidence if prm.counts_evidence else None)
        self._sizes.append(zs.shape[0])
        self._objects.append(objects)
        if prm.promotion == "reseed":  # only the released code's promotion replays steps
            self._bank.append((zs, Rs))
        if self._main is not None and self._main_is_stale():
            log.debug("step %d: main tree %d dropped", self.step, self.hypothesis)
            if prm.recall_for is not None and self._provisional is None:
                # the best leaf before this step's prediction, as the dormant state of this step
                best = self._main_best()
                self._keep_dormant(Leaves(best.x, best.P + prm.Q, best.choice, best.edge,
                                          best.since, best.tree))
            self._drop_main()
        elif self._dormant is not None:
            self._age_dormant()
        empty = zs.shape[0] == 0
        model = self._empty_step_model if empty else self._model
        if self._main is not None:
            silent = bool(self._main.since[np.argmin(self._main.cost)] >= prm.window)
            drifting = prm.held_Q is not None and (prm.jitter_reference is None
                                                   or self._drift_as_assumed)
            main_model = model
            if drifting:
                main_model = self._drift_models[empty]
                if held_Q is not None:
                    main_model = replace(main_model, held_Q=held_Q)
            self._main = extend(self._main, zs, Rs, main_model, prm.max_children,
                                lambda cost, choice, _: self._main_keep(cost, choice))
            if self._main.since[np.argmin(self._main.cost)] == 0:
                returning = 1 if silent else self._returning + (self._returning > 0)
                self._returning = returning if returning < prm.early_measurements else 0
        complete = self._advance_exploring(zs, Rs, model)
        self._reclaiming = False
        if self._main is not None:
            if self._dormant is not None:
                self._recall()
            if prm.switch_after is not None:
                self._consider_switch(complete)
        else:
            self._accept_best(complete)
            if self._main is None and self._dormant is not None:
                self._recall()
            elif self._dormant is not None:
                # a tree the window has just accepted is contested as any main tree is; the
                # dormant hypothesis may take its place from its next measurement (`_recall`)
                self._contest()
                best = self._main_best()
                if best.since[0] > 0 and not self._consistent(best, self._dormant)[0]:
                    # accepted on its window alone, unmeasured now: nothing has contradicted
                    # the dormant hypothesis since it fell silent
                    self._silent_switch = (self.step, self.hypothesis)
            if self._main is None and prm.sequential:
                self._accept_early()
        if self._provisional is not None:
            self._settle_provisional()
        # a hypothesis accepted in the gap that contradicts the dormant one leaves it
        # recallable: it has history, the newcomer only its window (and so does one still
        # provisional, which may yet be dropped)
        if (self._main is not None and self._dormant is not None and self._provisional is None
                and self._consistent(self._main_best(), self._dormant)[0]):
            # the main tree now is the dormant hypothesis (a switch to it): nothing to reclaim
            self._dormant, self._reclaiming = None, False
        self._estimate = self._main_estimate()
        if self._estimate is not None:
            self._peak = max(self._peak, self._estimate.n_measurements)
        switch = self._silent_switch
        if switch is not None and (self._estimate is None or switch[1] != self.hypothesis or (
                self.step > switch[0] and self._estimate.measurement >= 0)):
            self._silent_switch = None
        if prm.switch_stale and self._estimate is not None and self._estimate.measurement >= 0:
            best = int(np.argmin(self._main.cost))
            if self._distinct(self._main.choice[best])[1]:
                self._fresh = self.step
        if self._estimate is not None:
            has_measurement = self._estimate.n_measurements > 0
            self._empty_windows = 0 if has_measurement else self._empty_windows + 1
        if prm.jitter_reference is not None:
            self._record_jitter(zs, Rs)
            if self._estimate is not None and self._estimate.measurement >= 0:
                own = self._jitter_scale(self.hypothesis)
                self._drift_as_assumed = own is not None and own <= 1.0
        self._held = self._jittered(self._estimate)
        self._estimate = self._reported(self._held)
        if self._estimate is not None:
            self._highest_reported = max(self._highest_reported, self._estimate.hypothesis)
        return self._estimate

    def _capped(self, zs: np.ndarray, Rs: np.ndarray, evidence: list | None,
                objects: np.ndarray | None) -> tuple:
        """The first `max_measurements` of a step's measurements, logged: a warning the first
        time, then at debug level."""
        keep = self.params.max_measurements
        self.capped_steps += 1
        log.log(logging.WARNING if self.capped_steps == 1 else logging.DEBUG,
                "TCAFF step %d: %d measurements given; took the first max_measurements=%d%s",
                self.step + 1, zs.shape[0], keep,
                " (repeats are logged at debug level; TCAFF.capped_steps counts them)"
                if self.capped_steps == 1 else "")
        return (zs[:keep], Rs[:keep], None if evidence is None else evidence[:keep],
                None if objects is None else objects[:keep])

    # -- exploring trees -----------------------------------------------------------------------

    def _advance_exploring(self, zs: np.ndarray, Rs: np.ndarray, model: CostModel) -> Leaves:
        """Extend the exploring trees by one step and seed one per measurement; return (and
        remove) the trees whose root is now W steps old.

        While there is a main tree and switching is on, only measurements its best leaf gates
        out seed trees: the others start hypotheses consistent with it, which can never be
        grounds for a switch.
        """
        prm = self.params
        explore = extend(self._explore, zs, Rs, model, prm.explore_max_children,
                         lambda cost, _, tree: best_per_tree(cost, tree, prm.explore_max_leaves))
        done = explore.choice[:, 1] != BEFORE_ROOT  # root at step n - W
        index = np.arange(zs.shape[0])
        if self._main is not None and prm.switch_after is not None:
            best = self._main_best()
            index = index[~np.isfinite(measurement_costs(best, zs, Rs, self._model)[0])]
        ids = self._next_tree + np.arange(index.size)
        self._next_tree += index.size
        seeds = seed(zs[index], prm.P0, ids, index, self._columns)
        self._explore = Leaves.concat([explore.take(~done), seeds])
        return explore.take(done)

    def _accept_best(self, complete: Leaves) -> None:
        """With no main tree: accept the best complete exploring tree if its score (its path
        cost less its object support, `_object_support`) beats tau."""
        score = complete.cost - self._object_support(complete.choice)
        below = np.flatnonzero(score < self.params.tau)
        for best in below[np.argsort(score[below], kind="stable")]:
            if self._distinct_enough(complete, best):
                self._accept(complete, int(best))
                return

    def _accept_early(self) -> None:
        """With no main tree: accept the open exploring hypothesis whose acceptance is
        certain (`TCAFFParams.sequential`): its score (path cost less object support) plus
        the cost of a missed measurement at each of its remaining W - a steps is below tau,
        its path holds `early_measurements` measurements and `min_distinct` distinct pieces of
        evidence, every open hypothesis inconsistent with it scores `switch_margin` worse,
        and it agrees with the dormant hypothesis if there is one. The lowest bound is tried
        first. Where the path holds fewer than `min_distinct` besides its seed, which leaves
        the window when the tree is W steps old, the acceptance is provisional
        (`_settle_provisional`)."""
        prm = self.params
        explore = self._explore
        if len(explore) == 0:
            return
        age = self._steps_since_root(explore.choice) - 1
        score = explore.cost - self._object_support(explore.choice)
        bound = score + (prm.window - age) * self._model.no_measurement_cost
        ready = (bound < prm.tau) & (self._taken(explore.choice) >= prm.early_measurements)
        if self._dormant is not None:
            # contradicting a hypothesis that was accepted before the gap takes the window
            ready &= self._consistent(explore, self._dormant)
        for best in np.flatnonzero(ready)[np.argsort(bound[ready], kind="stable")]:
            rivals = ~self._consistent(explore, explore.take([best]))
            if np.any(score[rivals] < score[best] + prm.switch_margin):
                continue
            if not self._distinct_enough(explore, best):
                continue
            log.debug("step %d: tree %d accepted early, %d steps old (bound %.2f)",
                      self.step, explore.tree[best], age[best], bound[best])
            tree = explore.tree[best]
            judged = self._distinct_enough(explore, best, without_root=True)
            self._accept(explore, int(best))
            if not judged:
                self._provisional = (self.step, self.hypothesis)
            self._explore = explore.take(explore.tree != tree)
            return

    def _settle_provisional(self) -> None:
        """A main tree accepted early on evidence its complete window would not hold (a seed
        and one distinct measurement besides it) is held but not reported (`_reported`;
        `held` has it, but no search is guided by it) until its best path is measured
        again after the acceptance or holds `min_distinct` distinct pieces of evidence
        besides its seed; if its tree turns W steps old first, it is dropped, not kept
        dormant: it never was evidence. A wrong alignment matched at two steps and at none
        after is then never reported, and a true one seen again within the window is
        reported from that measurement."""
        # (every change of the main tree, an acceptance, a recall or a drop, clears the mark)
        accepted = self._provisional[0]
        best = int(np.argmin(self._main.cost))
        again = self.step > accepted and self._main.since[best] == 0
        # (once the seed has left the window, leaving it out changes no count)
        if again or self._distinct_enough(self._main, best, without_root=True):
            self._provisional = None
        elif self._steps_since_root(self._main.choice[[best]])[0] > self.params.window:
            log.debug("step %d: provisional hypothesis %d dropped", self.step, self.hypothesis)
            self._drop_main()

    def _drop_main(self) -> None:
        """Forget the main tree and what belongs to it: its rival and switch count, the
        return count, a provisional mark, the recall's claim on its place and the record of
        its drift (`hold_for`)."""
        self._main, self._rival, self._switch_streak, self._returning = None, None, 0, 0
        self._provisional, self._reclaiming, self._drift_as_assumed = None, False, False

    def _keep_dormant(self, leaf: Leaves) -> None:
        """Keep the main tree's leaf (one-leaf Leaves) as the dormant hypothesis, with the
        most measurements its window held (`_peak`)."""
        self._dormant, self._dormant_age, self._dormant_peak = leaf, 0, self._peak

    def _age_dormant(self) -> None:
        """One more step of the dormant hypothesis: its covariance grows by Q, and it is
        forgotten after `recall_for` steps."""
        self._dormant_age += 1
        if self._dormant_age > self.params.recall_for:
            self._dormant = None
            return
        d = self._dormant
        self._dormant = Leaves(d.x, d.P + self.params.Q, d.choice, d.edge, d.since + 1, d.tree)

    def _contest(self) -> np.ndarray:
        """(L,) whether each open exploring leaf agrees with the dormant hypothesis. Seen
        again, even once in the last W steps, the dormant hypothesis contests the main tree
        (`_reclaiming`, so `_contested`): a decoy that displaced it in its gap is not reported
        on the truth's return."""
        agree = self._consistent(self._explore, self._dormant)
        if self._main is not None and agree.any():
            self._reclaiming = True
        return agree

    def _recall(self) -> None:
        """Make the dormant hypothesis the main tree again once an open exploring hypothesis
        consistent with it has taken `early_measurements` measurements, the latest this step,
        and none inconsistent with it has taken more (a rival that appeared in the gap must
        win by the acceptance rules). A main tree accepted in the gap (inconsistent with the
        dormant one) gives way when the dormant hypothesis's history, the most measurements
        its window held, is at least the main path's measurements in the window; until then
        the main tree is contested (`_contested`). The dormant state is fused with the
        confirming hypothesis's, which goes on as the main tree's leaf: under the dormant
        id, or a new one when an id issued since was reported. Any open hypothesis consistent
        with the dormant one (a measurement of it in the last W steps) contests the main
        tree, before it is confirmed."""
        prm, dormant, explore = self.params, self._dormant, self._explore
        if len(explore) == 0:
            return
        taken = self._taken(explore.choice)
        agree = self._contest()
        confirmed = agree & (taken >= prm.early_measurements)
        fresh = np.flatnonzero(confirmed & (explore.choice[:, -1] >= 0))
        if fresh.size == 0:
            return
        best = int(fresh[np.lexsort((explore.cost[fresh], -taken[fresh]))[0]])
        if np.any(taken[~agree] > taken[best]):
            return
        if self._main is not None:
            main_taken = self._taken(self._main.choice[int(np.argmin(self._main.cost))])
            if max(self._dormant_peak, int(taken[best])) < main_taken:
                return
            self._reclaiming = False
        if self._highest_reported <= int(dormant.tree[0]):
            # no id issued since the dormant one was reported: it goes on under its own
            self.hypothesis = int(dormant.tree[0])
        else:
            self.hypothesis += 1  # never an id that was reported for another hypothesis
        x, P = kalman_children(dormant, [0], [0], explore.x[[best]], explore.P[[best]],
                               self._model)
        leaf = explore.take([best])
        log.debug("step %d: hypothesis %d recalled, %d steps after it was dropped",
                  self.step, self.hypothesis, self._dormant_age)
        self._explore = explore.take(explore.tree != leaf.tree[0])
        self._switch_streak, self._rival, self._empty_windows = 0, None, 0
        self._fresh = self.step
        self._peak, self._returning = self._dormant_peak, 0
        self._dormant, self._provisional, self._drift_as_assumed = None, None, False
        self._main = Leaves(x, P, leaf.choice, leaf.edge, leaf.since,
                            np.full(1, self.hypothesis, np.int64))

    def _consider_switch(self, complete: Leaves) -> None:
        """Switch to a rival hypothesis: one inconsistent with the main tree's best leaf and
        below tau that, for `switch_after` steps in a row, is either `switch_margin` better
        at a step on which the main tree's best path took no measurement, or cheaper and seen
        `switch_support` more times in the window (`_support`) at any step. Steps on which no
        exploring tree completes neither extend nor break the streak."""
        prm = self.params
        if len(complete) == 0:
            return
        cost = complete.cost
        main_cost = self._main.cost
        m = int(np.argmin(main_cost))
        inconsistent = ~self._consistent(complete, self._main.take([m])) & (cost < prm.tau)
        rival = inconsistent & (cost + prm.switch_margin < main_cost[m])
        # a main hypothesis that a measurement confirmed this step is not abandoned for a
        # cheaper one: in a repetitive world a wrong rival can hold a full window while the
        # truth has gaps. One that only re-matches objects it already used is confirmed by
        # nothing new, though.
        stale = prm.switch_stale and self.step - self._fresh >= prm.window
        if self._main.since[m] == 0 and not stale:
            rival[:] = False
        if rival.any() and prm.min_distinct > 1:
            rival[rival] = [self._distinct_enough(complete, r) for r in np.flatnonzero(rival)]
        if prm.switch_support is not None:
            # ... but one seen less often than a rival is, confirmed or not
            need = self._outvote_need(m, prm.window)
            for r in np.flatnonzero(inconsistent & ~rival & (cost < main_cost[m])):
                rival[r] = (self._support(complete.choice[r]) >= need
                            and self._distinct_enough(complete, r))
        if not rival.any():
            self._switch_streak, self._rival = 0, None
            return
        best = int(np.flatnonzero(rival)[np.argmin(cost[rival])])
        leaf = complete.take([best])
        same = self._rival is not None and bool(self._consistent(leaf, self._rival)[0])
        self._switch_streak = self._switch_streak + 1 if same else 1
        self._rival = leaf
        if self._switch_streak >= prm.switch_after:
            log.debug("step %d: switching from main tree %d (cost %.2f) to one of cost %.2f",
                      self.step, self.hypothesis, main_cost[m], cost[best])
            silent = bool(self._main.since[m] >= prm.window or self._returning)
            if prm.recall_for is not None and silent:
                # left in a gap of its measurements, or before a return from one is
                # confirmed, it is recallable as a dropped one is
                self._keep_dormant(self._main.take([m]))
            # replacing a main tree that itself replaced one in a gap (or was accepted by its
            # window, unmeasured, over the dormant one) and was not measured since: the one
            # left in the gap is no more contradicted than before
            unconfirmed = self._silent_switch is not None
            self._accept(complete, best)
            if silent or unconfirmed:
                self._silent_switch = (self.step, self.hypothesis)

    def _record_jitter(self, zs: np.ndarray, Rs: np.ndarray) -> None:
        """Record the jitter of this step's measurement on the main path against the previous
        step's, when both are of the same hypothesis (`jitter_reference`), and forget what
        is older than `jitter_span` steps."""
        estimate, prm, jitter = self._estimate, self.params, self._jitter
        if estimate is not None and estimate.measurement >= 0:
            z, R = zs[estimate.measurement], Rs[estimate.measurement]
            last = self._last_taken
            if last is not None and last[0] == self.step - 1 and last[1] == estimate.hypothesis:
                distance = mahalanobis_to(z[None], R[None], last[2], last[3],
                                          self._model.angular)[0]
                value = float(distance) / prm.dim
                # beyond the cap (and for a distance that overflows) the two disagree wildly,
                # which is all the record needs to say
                jitter.append((self.step, value if value <= JITTER_CAP else JITTER_CAP,
                               estimate.hypothesis))
            self._last_taken = (self.step, estimate.hypothesis, z.copy(), R.copy())
        while jitter and jitter[0][0] <= self.step - prm.jitter_span:
            jitter.popleft()

    def _jittered(self, estimate: AlignmentEstimate | None) -> AlignmentEstimate | None:
        """`estimate` with its covariance scaled by the jitter over `jitter_reference` where
        that is more than 1."""
        if estimate is None or self.params.jitter_reference is None:
            return estimate
        scale = self._jitter_scale()
        if scale is None or scale <= 1.0:
            return estimate
        largest = float(np.abs(estimate.P).max())
        if scale * largest > _LARGEST_ENTRY:
            scale = max(1.0, _LARGEST_ENTRY / largest)
        return replace(estimate, P=estimate.P * scale)

    def _jitter_scale(self, hypothesis: int | None = None) -> float | None:
        """The mean jitter recorded (of `hypothesis`'s measurements only, when given) over
        `jitter_reference` (which must be set); None without such records."""
        values = [value for _, value, of in self._jitter if hypothesis is None or of == hypothesis]
        return sum(values) / (len(values) * self.params.jitter_reference) if values else None

    def _consistent(self, leaves: Leaves, other: Leaves) -> np.ndarray:
        """(L,) whether each leaf's state agrees with the single leaf `other`'s (Mahalanobis
        distance under P_a + P_b within the gate of `gate_probability`)."""
        maha = mahalanobis_to(leaves.x, leaves.P, other.x[0], other.P[0], self._model.angular)
        return maha <= self._model.gate_chi2

    def _accept(self, complete: Leaves, best: int) -> None:
        """Make the tree of leaf `best` the main tree."""
        prm = self.params
        self.hypothesis += 1
        self._switch_streak, self._rival, self._empty_windows = 0, None, 0
        self._fresh = self.step
        self._peak = 0
        self._returning = 0
        self._provisional, self._drift_as_assumed = None, False
        in_tree = np.flatnonzero(complete.tree == complete.tree[best])
        tree = complete.take(in_tree)
        best = int(np.searchsorted(in_tree, best))
        if prm.promotion == "branch":
            main = tree.take(self._main_keep(tree.cost, tree.choice, best))
        else:
            main = self._reseeded(tree, best)
        main.tree[:] = self.hypothesis
        self._main = main

    def _reseeded(self, tree: Leaves, best: int) -> Leaves:
        """The released code's promotion: a fresh tree at the state after the accepted path's
        first step, covariance P0, fed the window's measurements again (that first step too)."""
        prm = self.params
        steps = list(self._bank)  # steps n - W .. n
        (z_root, _), (z1, R1) = steps[0], steps[1]
        root = seed(z_root[tree.choice[best, 1]][None], prm.P0, np.zeros(1), np.zeros(1),
                    self._columns)
        x1, _ = kalman_children(root, [0], [tree.choice[best, 2]], z1, R1, self._model)
        main = seed(x1, prm.P0, np.zeros(1), np.zeros(1), self._columns)
        for zs, Rs in steps[1:]:
            main = extend(main, zs, Rs, self._model, prm.max_children,
                          lambda cost, choice, _: self._main_keep(cost, choice))
        return main

    # -- main tree -----------------------------------------------------------------------------

    def _main_keep(self, cost: np.ndarray, choice: np.ndarray, best: int | None = None
                   ) -> np.ndarray:
        """Main-tree pruning: once the window is full keep the branch of the root that holds
        leaf `best` (default: the cheapest), then the B best leaves. The root is the single node
        W steps back (paper) or, with `root_in_window`, the first node of the window."""
        column = 2 if self.params.root_in_window else 1
        keep = np.arange(cost.size)
        if choice[0, column - 1] != BEFORE_ROOT:
            keep = branch(choice, int(np.argmin(cost)) if best is None else best, column)
        return keep[lowest(cost[keep], self.params.max_leaves)]

    def _main_best(self) -> Leaves:
        """The main tree's best leaf, as one-leaf Leaves (there is a main tree)."""
        return self._main.take([int(np.argmin(self._main.cost))])

    def _main_is_stale(self) -> bool:
        """Checked before the main tree takes the new step, on its best path so far."""
        prm = self.params
        main = self._main
        best = int(np.argmin(main.cost))
        if prm.drop_rule == "best_path":
            limit = prm.drop_after
            if prm.hold_for is not None and prm.held_Q is not None and self._drift_as_assumed:
                limit = max(limit, prm.hold_for)
            return bool(main.since[best] >= limit)
        return self._empty_windows > prm.drop_after

    def _main_estimate(self) -> AlignmentEstimate | None:
        if self._main is None:
            return None
        main = self._main
        cost = main.cost
        best = int(np.argmin(cost))
        path = main.choice[best]
        return AlignmentEstimate(main.x[best].copy(), main.P[best].copy(), float(cost[best]),
                                 self.hypothesis, self.step, self._taken(path), int(path[-1]))
