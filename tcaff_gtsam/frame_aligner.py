"""FrameAligner: two object maps -> candidate alignment measurements z = (x, y, theta) of T_oi_oj.

Pipeline (paper, "Map Alignment" and Algorithm 1): keep objects seen within kappa seconds, gate
putative associations by size, build the consistency graph, draw N near-optimal CLIPPER
solutions, register each by weighted Arun, keep the good ones.

Each candidate's covariance R (`FrameAlignerParams.covariance`): "constant" (the original's),
"residual" or "calibrated" (the `covariance` module's, re-exported here).
"""

from __future__ import annotations

import copy
import functools
import logging
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.spatial import cKDTree

from .association import (
    _descriptor_gate,
    _neighbourhood_pairs,
    _pair_similarity,
    _partial_pairs_kept,
    _partial_ranking_pays,
    _true_pairs,
    size_gates,
)
from .clipper import _solutions
from .clipper_graph import _graph, _height_slack
from .covariance import (
    _calibrated_covariance,
    _inverse_Q,
    _residual_covariance,
    calibrated_covariance,
    residual_covariance,
)
from .errors import ConfigError, DataError
from .geometry import (
    _se2_from_params,
    _se2_to_params,
    _se3_to_se2,
    _transform_points,
    _wrap_angle,
)
from .inputs import finite_time, real_array, shown
from .object_map import _ALL_FIELDS, ObjectMap, as_object_map
from .param_checks import MAX_VARIANCE
from .params import (
    FrameAlignerParams,
    _given_or_default,
    _real,
    _require,
)
from .registration import (
    MAX_COORDINATE,
    MAX_WEIGHT,
    _mutual_inliers,
    _registration_rmse,
    _spread,
    _weighted_arun,
    _weights,
    weighted_arun,
)

__all__ = [
    "AlignmentMeasurement",
    "FrameAligner",
    "MapMemory",
    "calibrated_covariance",
    "confirms",
    "residual_covariance",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class AlignmentMeasurement:
    """One candidate alignment of the other robot's odometry frame into the ego's.

    Attributes:
        z: (3,) (x [m], y [m], theta [rad]) of T_oi_oj (i = ego, j = other), theta wrapped.
        R: (3, 3) measurement covariance of z.
        associations: (k, 2) int64 (ego index, other index) into the maps that were aligned.
        score: MNO-CLIPPER score of the association set (u'Mu / u'u on the original affinity).
        rmse: metres, registration residual RMS of the associated centroids.
        inliers: recent objects the candidate explains (`FrameAlignerParams.min_inliers`);
            0 when the aligner does not count them.
        ambiguous: another alignment, distinct from this one, explains at least as many
            objects, in these maps or in the robots' earlier maps (`check_ambiguity`): the
            maps alone do not tell the two apart.
        tracked: the held alignment re-registered on the objects it pairs (`track_min`),
            not a MNO-CLIPPER solution; its score is 0. Like an ambiguous candidate it may
            confirm the held alignment, never start or move one.
    """

    z: np.ndarray
    R: np.ndarray
    associations: np.ndarray
    score: float
    rmse: float
    inliers: int = 0
    ambiguous: bool = False
    tracked: bool = False

    @property
    def T(self) -> np.ndarray:
        """(3, 3) SE(2) matrix T_oi_oj."""
        return _se2_from_params(self.z)


class FrameAligner:
    """Candidate alignments T_oi_oj between an ego map and another robot's map.

    Stateless apart from its parameters; one instance can serve every robot pair.
    """

    def __init__(self, params: FrameAlignerParams | None = None) -> None:
        """An aligner with `params` (None: the defaults).

        Raises:
            ConfigError: params is neither a FrameAlignerParams nor None.
        """
        self.params = (_default_params() if params is None else
                       _given_or_default(FrameAlignerParams, params, "FrameAligner"))
        #: steps on which the size gate passed more than `max_associations` pairs, so that
        #: each object kept only its `pairs_per_object` best
        self.thinned = 0
        #: guided steps on which nothing guided confirmed the held alignment, so that they
        #: searched in full
        self.guided_misses = 0
        # (ego, other, now, what `_recent_pair` made of them): the last maps gated
        self._last_pair: tuple | None = None
        # `_calibrated_settings`, made on first use
        self._calibrated: tuple | None = None

    def lookalike_share(self, ego: ObjectMap, other: ObjectMap, now: float) -> float:
        """The share of the object pairs of two maps (objects seen within kappa of `now`)
        that pass the size and descriptor gates, in [0, 1]: 1 when every object could be any
        other (MRCLAM's landmarks carry no size), low in a room of distinct objects. 0 when
        either map has no recent object.

        Raises:
            DataError: ego or other not an ObjectMap; now not a finite number.
        """
        o = "FrameAligner.lookalike_share"
        ego, other = as_object_map(o, "ego", ego), as_object_map(o, "other", other)
        compatible = self._recent_pair(ego, other, finite_time(o, "now", now))[4][0]
        return _gated_share(compatible)

    def _recent_pair(self, ego: ObjectMap, other: ObjectMap, now: float) -> tuple:
        """(ego_idx, other_idx, ego_r, other_r, gates): the indices and maps of the objects
        seen within kappa of `now`, and `_gates` of them. The last maps' are kept, so that a
        step asking `lookalike_share` and `measurements` of the same maps gates them once."""
        last = self._last_pair
        if last is not None and last[0] is ego and last[1] is other and last[2] == now:
            return last[3]
        kappa = self.params.kappa
        ego_idx, other_idx = ego.recent_indices(now, kappa), other.recent_indices(now, kappa)
        ego_r, other_r = _recent_map(ego, ego_idx), _recent_map(other, other_idx)
        pair = (ego_idx, other_idx, ego_r, other_r, self._gates(ego_r, other_r))
        self._last_pair = (ego, other, now, pair)
        return pair

    def measurements(self, ego: ObjectMap, other: ObjectMap, now: float,
                     ego_past: Sequence[tuple[float, ObjectMap]] = (),
                     other_past: Sequence[tuple[float, ObjectMap]] = (),
                     held: np.ndarray | None = None, guided: bool = False
                     ) -> list[AlignmentMeasurement]:
        """Candidate alignments, best score first; empty when nothing qualifies.

        Args:
            ego: map of robot i in its odometry frame.
            other: map of robot j in its odometry frame.
            now: seconds, current time on the clock of the maps' `last_seen`.
            ego_past, other_past: earlier maps of each robot with their times, (t, map)
                (`MapMemory.snapshots`). With `check_ambiguity`, a candidate whose objects
                also match somewhere else in them is flagged ambiguous.
            held: (3,) the alignment the caller's filter holds, if any. Candidates within
                `confirm_translation` and `confirm_heading` of it may confirm it even when
                ambiguous, so only the step's own solutions are searched for their rivals,
                not the earlier maps: a filter that holds a steady estimate costs no search.
            guided: with held and `guide_radius`, search only the pairs that agree under the
                held alignment and return only candidates confirming it, not searched for
                rivals (`ambiguous` compares them only with each other: they may confirm
                the hold either way); a full search when none confirms it. Ignored without
                held or guide_radius.
        Raises:
            DataError: ego or other not an ObjectMap; now not a finite number (a string, None,
                an array, NaN); ego_past or other_past not a sequence of (finite time,
                ObjectMap); held neither None nor a finite (3,) array; guided not a bool; or a
                registration the maps make impossible (coordinates beyond
                `registration.MAX_COORDINATE`).
            ConfigError: a candidate's covariance beyond `MAX_VARIANCE` (settings such as a
                year-long kappa with the largest map_drift, for objects that far out).
        """
        o = "FrameAligner.measurements"
        ego, other = as_object_map(o, "ego", ego), as_object_map(o, "other", other)
        now = finite_time(o, "now", now)
        ego_past, other_past = _snapshots(o, "ego_past", ego_past), _snapshots(o, "other_past",
                                                                              other_past)
        if held is not None:
            held = real_array(o, "held", held)
            # NaN fails the comparison; a translation beyond the coordinates a registration
            # takes would overflow the guided search's distances
            if held.shape != (3,) or not (np.abs(held) <= MAX_COORDINATE).all():
                raise DataError(f"{o}: held must be None or a finite (3,) (x, y, theta) within "
                                f"{MAX_COORDINATE:g} m and rad, got {shown(held)}")
        if not isinstance(guided, (bool, np.bool_)):
            raise DataError(f"{o}: guided must be True or False, got {shown(guided)}")
        prm = self.params
        ego_idx, other_idx, ego_r, other_r, gates = self._recent_pair(ego, other, now)
        compatible = gates[0]
        kept: list[_Solution] = []
        if guided and held is not None and prm.guide_radius is not None:
            found = self._registered(ego_r, other_r, now, held, gates)
            kept = [f for f in self._passing(found) if _confirms(f.z, held, prm)]
            self.guided_misses += not kept
        if not kept:
            found = self._registered(ego_r, other_r, now, gates=gates)
            kept = self._passing(found)
        ambiguous = [False] * len(kept)
        if kept and prm.check_ambiguity:
            ambiguous = [self._has_rival(f, found) for f in kept]
            # the earlier maps are searched only for rivals of candidates that could start or
            # move the caller's estimate: an ambiguous one may still confirm it
            search = [k for k, f in enumerate(kept)
                      if not ambiguous[k] and not _confirms(f.z, held, prm)]
            if search and (ego_past or other_past):
                fewest = min(kept[k].inliers for k in search)
                for ego_m, other_m in self._earlier(ego_r, other_r, ego_past, other_past,
                                                    fewest):
                    rivals = self._registered(ego_m, other_m, now)
                    for k in search:
                        ambiguous[k] = ambiguous[k] or self._has_rival(kept[k], rivals)
                    search = [k for k in search if not ambiguous[k]]
                    if not search:  # every candidate has its rival: the rest cannot change that
                        break
        out = []
        for f, flag in zip(kept, ambiguous, strict=True):
            R = self._covariance(f.T, f.p, f.q, f.w)
            a = f.associations
            associations = np.column_stack([ego_idx[a[:, 0]], other_idx[a[:, 1]]])
            out.append(AlignmentMeasurement(f.z, R, associations, f.score, f.rmse, f.inliers,
                                            flag))
        out.sort(key=lambda meas: -meas.score)
        if (held is not None and prm.track_min is not None
                and not any(_confirms(m.z, held, prm) for m in out)):
            tracked = self._tracked(ego_r, other_r, now, held, compatible)
            if tracked is not None:
                a = tracked.associations
                out.append(replace(tracked, associations=np.column_stack(
                    [ego_idx[a[:, 0]], other_idx[a[:, 1]]])))
        return out

    def _passing(self, found: list[_Solution]) -> list[_Solution]:
        """The solutions that pass every check of a candidate."""
        prm = self.params
        return [f for f in found if f.qualifies
                and (prm.min_inliers is None or f.inliers >= prm.min_inliers)
                and (prm.min_spread == 0 or _spread(f.p[:, :2]) >= prm.min_spread)]

    def _tracked(self, ego_r: ObjectMap, other_r: ObjectMap, now: float, held: np.ndarray,
                 compatible: np.ndarray) -> AlignmentMeasurement | None:
        """The held alignment re-registered on the objects it pairs (`track_min`), or None
        when too few pair, they fail the spread or residual checks, or the result leaves the
        confirmation bounds. Associations index the maps of recent objects; `compatible` is
        their gate (`_gates`)."""
        # The spread check matters most here: on MRCLAM, correctly paired landmarks of a
        # tight cluster gave headings 3-7 deg off, the same bias second after second, and
        # tracking on them walked the estimate out of the 5 deg bound.
        prm = self.params
        if min(len(ego_r), len(other_r)) < prm.track_min:
            return None
        p_all = ego_r.centroids[:, : prm.dim]
        q_all = other_r.centroids[:, : prm.dim]
        pairs = _mutual_inliers(_se2_from_params(held), p_all[:, :2], q_all[:, :2], compatible,
                                prm.confirm_translation)
        if pairs.shape[0] < prm.track_min:
            return None
        p, q = p_all[pairs[:, 0]], q_all[pairs[:, 1]]
        if prm.min_spread and _spread(p[:, :2]) < prm.min_spread:
            return None
        w = _weights(ego_r.ages(now)[pairs[:, 0]] * other_r.ages(now)[pairs[:, 1]],
                     prm.weight_offset)
        fit = self._fit(weighted_arun, p, q, w)
        if fit is None:
            return None
        T2, rmse = fit
        z = _se2_to_params(T2)
        if (prm.max_rmse is not None and rmse > prm.max_rmse) or not _confirms(z, held, prm):
            return None
        return AlignmentMeasurement(z, self._covariance(T2, p, q, w), pairs.astype(np.int64),
                                    0.0, rmse, pairs.shape[0], tracked=True)

    def _fit(self, arun, p: np.ndarray, q: np.ndarray, w: np.ndarray, residual: bool = True
             ) -> tuple[np.ndarray, float] | None:
        """The registration of q (k, dim) onto p by `arun` (checked or not) with weights w:
        (T (3, 3) SE(2), residual RMS in the plane [m], NaN unless `residual`), or None when
        it is degenerate."""
        T = arun(p, q, w)
        if T is None:
            return None
        T2 = _se3_to_se2(T) if self.params.dim == 3 else T
        return T2, _registration_rmse(T2, p[:, :2], q[:, :2]) if residual else math.nan

    def _covariance(self, T2: np.ndarray, p: np.ndarray, q: np.ndarray, w: np.ndarray
                    ) -> np.ndarray:
        """R (3, 3) of a registered alignment T2 of q onto p (k, dim) with weights w.

        Raises:
            ConfigError: R beyond what a filter takes (an entry above `MAX_VARIANCE` or not
                finite), naming the settings that, with objects that far from the ego frame's
                origin, made it so; a DataError with covariance="residual", whose R the data
                alone sets.
        """
        prm = self.params
        if prm.covariance == "constant":
            return prm.R_constant.copy()
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below
            if prm.covariance == "calibrated":
                span = prm.kappa
                if not math.isfinite(span):
                    # maps that keep every object: the span is the oldest association's, its
                    # age the geometric mean of its two objects' (w = 1 / (offset + age_i
                    # age_j))
                    span = float(np.sqrt(np.maximum(1.0 / w - prm.weight_offset, 0.0)).max())
                R = _calibrated_covariance(T2, p[:, :2], q[:, :2], w, span,
                                           prm.residual_floor, *self._calibrated_settings())
            else:
                R = _residual_covariance(T2, p[:, :2], q[:, :2], w, prm.residual_floor)
        if not np.abs(R).max() <= MAX_VARIANCE:  # NaN fails it too
            settings = f"residual_floor = {prm.residual_floor:g} m"
            if prm.covariance == "calibrated":
                Q = "TCAFF's default" if prm.repeat_Q is None else np.diag(prm.repeat_Q)
                settings = (f"kappa = {prm.kappa:g} s, map_drift = {prm.map_drift}, "
                            f"{settings}, repeat_inflation = {prm.repeat_inflation:g} and "
                            f"repeat_Q's diagonal {Q}")
            # the calibrated covariance's size is its settings' (drift over the span, the
            # inflation); the residual one's is the data's (far or degenerate objects)
            error = ConfigError if prm.covariance == "calibrated" else DataError
            raise error(
                f"FrameAligner: a candidate's covariance reaches {np.abs(R).max():.3g}, beyond "
                f"{MAX_VARIANCE:g} (MAX_VARIANCE), from covariance = {prm.covariance!r} with "
                f"{settings}, the objects up to {np.abs(p[:, :2]).max():.3g} m from the ego "
                f"frame's origin: lower these settings, or give coordinates in metres near "
                f"the robots")
        return R

    def _epsilon(self, ages_ego: np.ndarray, ages_other: np.ndarray) -> float:
        """Metres, CLIPPER's epsilon widened for the maps' drift over their span
        (`FrameAlignerParams.epsilon_drift`); ages (n,), (m,) seconds of the recent objects."""
        prm = self.params
        span = (prm.kappa if math.isfinite(prm.kappa)
                else float(max(ages_ego.max(initial=0.0), ages_other.max(initial=0.0))))
        return prm.span_epsilon(span)

    def _calibrated_settings(self) -> tuple:
        """(prior_dof, map_drift, repeat_inflation, Q^-1) of covariance="calibrated" (the
        parameters checked them); Q^-1 computed once."""
        prm = self.params
        if self._calibrated is None:
            Q_inv = (_default_Q_inverse() if prm.repeat_Q is None else
                     _inverse_Q("FrameAlignerParams.repeat_Q", prm.repeat_Q))
            self._calibrated = (prm.residual_prior_dof, prm.map_drift, prm.repeat_inflation,
                                Q_inv)
        return self._calibrated

    def _registered(self, ego_r: ObjectMap, other_r: ObjectMap, now: float,
                    guide: np.ndarray | None = None, gates: tuple | None = None
                    ) -> list[_Solution]:
        """Every registrable MNO-CLIPPER solution between two maps of recent objects, with
        whether it passes the size, score and residual checks and (when the aligner counts
        them) the objects it explains. Those that do not pass are still rivals of the others.
        With guide (3,), a held alignment, only the pairs agreeing under it are searched;
        without, the pairs only the partial-view rule passes are thinned (`partial_pairs`).
        `gates`: the maps' `_gates` when already made (`_recent_pair`)."""
        prm = self.params
        # the gate of the putative associations, kept whole for counting the inliers
        compatible, partial = self._gates(ego_r, other_r) if gates is None else gates
        n_compatible = int(np.count_nonzero(compatible))
        fewest = prm.fewest_associations(len(ego_r), len(other_r),
                                         _gated_share(compatible, n_compatible))
        if min(len(ego_r), len(other_r)) < fewest:
            return []
        p_all = ego_r.centroids[:, : prm.dim]
        q_all = other_r.centroids[:, : prm.dim]
        ages_ego, ages_other = ego_r.ages(now), other_r.ages(now)
        epsilon = self._epsilon(ages_ego, ages_other)
        if guide is not None:
            # pairs that agree under the held alignment: a partial pair among them is most
            # likely its object's counterpart, and the graph is small either way
            searched = compatible & self._agree(p_all, q_all, guide)
        elif prm.partial_pairs != "all" and partial.any() and (
                prm.partial_pairs == "best" or _partial_ranking_pays(
                    n_compatible, int(np.count_nonzero(partial)))):
            searched = (compatible & ~partial) | _partial_pairs_kept(
                compatible, partial, p_all, q_all, ages_ego, ages_other, epsilon)
        else:
            searched = compatible
        n_pairs = int(np.count_nonzero(searched))
        if n_pairs < fewest:
            return []
        if n_pairs > prm.max_associations:
            assoc = _neighbourhood_pairs(searched, p_all, q_all, ages_ego, ages_other,
                                        epsilon, prm.pairs_per_object,
                                        prm.max_associations)
            self._thin(n_compatible, n_pairs, len(ego_r), len(other_r))
        else:
            assoc = _true_pairs(searched)
        # the maps and parameters were checked when they were made, so the graph and solver
        # skip their checks; so does registration unless coordinates or weights (at most
        # 1 / weight_offset) are beyond what it takes, where weighted_arun says which
        prior = (_pair_similarity(ego_r, other_r, assoc) if prm.descriptor_prior else None)
        z = slack = None
        if prm.height_epsilon is not None:
            z = (ego_r.centroids[:, 2], other_r.centroids[:, 2])
            slack = _height_slack(ego_r.heights[assoc[:, 0]], other_r.heights[assoc[:, 1]])
        graph = _graph(p_all, q_all, assoc, epsilon, prm.clipper.sigma,
                       np.ones(assoc.shape[0]) if prior is None else prior, z,
                       prm.height_epsilon, slack)
        solutions = [s for s in _solutions(graph, prm.n_solutions, prm.clipper,
                                           prm.mno_downweight) if len(s)]
        if not solutions:
            return []
        for side, points in (("ego", p_all), ("other", q_all)):
            largest = np.abs(points).max()
            if not largest <= MAX_COORDINATE:
                raise DataError(f"FrameAligner.measurements: {side}'s objects must lie within "
                                f"{MAX_COORDINATE:g} m of its origin to be registered, got a "
                                f"coordinate of magnitude {largest:.3g} (weighted_arun's "
                                f"bound)")
        in_range = 1.0 / prm.weight_offset <= MAX_WEIGHT
        arun = _weighted_arun if in_range else weighted_arun
        best = max(s.score for s in solutions)
        counting = prm.min_inliers is not None or prm.check_ambiguity
        # a guided step returns only candidates confirming the hold, which need no rivals
        rivals = prm.check_ambiguity and guide is None
        # the mutual-inlier kernel takes C-contiguous points: copied once, not per solution
        p_plane = np.ascontiguousarray(p_all[:, :2])
        found = []
        for sol in solutions:
            supported = (len(sol) >= fewest
                         and sol.score >= prm.min_score_ratio * best)
            if not (supported or rivals):
                continue  # it cannot qualify and nothing needs it as a rival
            a = sol.associations
            p, q = p_all[a[:, 0]], q_all[a[:, 1]]
            w = _weights(ages_ego[a[:, 0]] * ages_other[a[:, 1]], prm.weight_offset)
            # one that cannot qualify is kept only as a rival, whose residual nothing asks
            fit = self._fit(arun, p, q, w, residual=supported)
            if fit is None:
                continue
            T2, rmse = fit
            qualifies = supported and (prm.max_rmse is None or rmse <= prm.max_rmse)
            if not (qualifies or rivals):
                continue
            level = self._same_level(compatible, ego_r, other_r, a)
            explained = (_mutual_inliers(T2, p_plane, q_all[:, :2], level, prm.inlier_radius)
                         if counting or prm.refit else None)
            if prm.refit and qualifies and explained.shape[0] >= len(sol):
                refitted = self._refit(arun, explained, p_all, q_all, ages_ego, ages_other,
                                       level)
                if refitted is not None:
                    T2, p, q, w, rmse, explained = refitted
            inliers = explained.shape[0] if counting else 0
            found.append(_Solution(a, sol.score, T2, p, q, w, rmse, qualifies, inliers))
        return found

    def _refit(self, arun, pairs: np.ndarray, p_all: np.ndarray, q_all: np.ndarray,
               ages_ego: np.ndarray, ages_other: np.ndarray, compatible: np.ndarray):
        """A candidate registered again on every pair it explains (`pairs` (k, 2), the mutual
        inliers under it): (T2, p, q, w, rmse, the inliers under T2), or None when the fit is
        degenerate or fails the residual check. MNO-CLIPPER's clique is often a subset of
        the pairs an alignment explains, and the few most recently seen of it outweigh the
        rest (the Arun weights): a heading fixed by a handful of nearby objects."""
        prm = self.params
        p, q = p_all[pairs[:, 0]], q_all[pairs[:, 1]]
        w = _weights(ages_ego[pairs[:, 0]] * ages_other[pairs[:, 1]], prm.weight_offset)
        fit = self._fit(arun, p, q, w)
        if fit is None or (prm.max_rmse is not None and fit[1] > prm.max_rmse):
            return None
        T2, rmse = fit
        explained = _mutual_inliers(T2, p_all[:, :2], q_all[:, :2], compatible,
                                    prm.inlier_radius)
        return T2, p, q, w, rmse, explained

    def _same_level(self, compatible: np.ndarray, ego_r: ObjectMap, other_r: ObjectMap,
                    associations: np.ndarray) -> np.ndarray:
        """`compatible` without, under the gravity prior (`height_epsilon`), the pairs whose
        height difference is not the solution's (the median over its associations (k, 2)),
        within height_epsilon and the pair's slack for partial views: an alignment explains
        an object only if it matches it in height too. Unchanged without the prior."""
        prm = self.params
        if prm.height_epsilon is None:
            return compatible
        z_ego, z_other = ego_r.centroids[:, 2], other_r.centroids[:, 2]
        offset = float(np.median(z_ego[associations[:, 0]] - z_other[associations[:, 1]]))
        gap = np.abs(z_ego[:, None] - z_other[None, :] - offset)
        slack = _height_slack(ego_r.heights[:, None], other_r.heights[None, :])
        return compatible & (gap < prm.height_epsilon + slack)

    def _gates(self, ego_r: ObjectMap, other_r: ObjectMap) -> tuple[np.ndarray, np.ndarray]:
        """(compatible, partial), each (n_ego, n_other) bool: the pairs that may be associated
        (sizes within the size gate and, when both maps carry descriptors, similarity at least
        `descriptor_min`), and those of them that only the partial-view rule passes
        (`size_partial`; none without it)."""
        prm = self.params
        compatible, partial = size_gates(ego_r, other_r, prm.size_ratio, prm.size_abs_diff,
                                         prm.size_partial)
        compatible = _descriptor_gate(ego_r, other_r, compatible, prm.descriptor_min)
        return compatible, partial & compatible

    def _agree(self, p_all: np.ndarray, q_all: np.ndarray, held: np.ndarray) -> np.ndarray:
        """(n_ego, n_other) whether each pair's centroids agree in the plane under the held
        alignment (3,), within `guide_radius` + `confirm_heading` * |q|."""
        prm = self.params
        q = q_all[:, :2]
        moved = _transform_points(_se2_from_params(held), q)
        reach = prm.guide_radius + prm.confirm_heading * np.hypot(q[:, 0], q[:, 1])
        # a k-d tree, not an n_ego x n_other distance matrix: large maps stay at one byte a pair
        near = cKDTree(p_all[:, :2]).query_ball_point(moved, reach, return_sorted=False)
        agree = np.zeros((p_all.shape[0], q_all.shape[0]), dtype=bool)
        counts = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
        if counts.any():
            agree[np.concatenate(near).astype(np.int64), np.repeat(np.arange(len(near)),
                                                                   counts)] = True
        return agree

    def _thin(self, n_gate: int, n_pairs: int, n_ego: int, n_other: int) -> None:
        """Count a step whose associations were thinned for exceeding `max_associations`,
        and say so: a warning the first time, then at debug level. `n_gate`: the pairs the
        gates passed; `n_pairs`: those searched (fewer after `partial_pairs` or a guide)."""
        self.thinned += 1
        level = logging.WARNING if self.thinned == 1 else logging.DEBUG
        log.log(level, "FrameAligner: the size gate passed %d pairs of %d x %d recent objects%s, "
                "more than max_associations=%d; kept each object's pairs_per_object=%d whose "
                "neighbourhoods agree best%s",
                n_gate, n_ego, n_other,
                f" ({n_pairs} of them searched)" if n_pairs != n_gate else "",
                self.params.max_associations, self.params.pairs_per_object,
                " (repeats are logged at debug level; FrameAligner.thinned counts them)"
                if self.thinned == 1 else "")

    def _earlier(self, ego_r: ObjectMap, other_r: ObjectMap,
                 ego_past: Sequence[tuple[float, ObjectMap]],
                 other_past: Sequence[tuple[float, ObjectMap]], fewest: int
                 ) -> list[tuple[ObjectMap, ObjectMap]]:
        """The map pairs of the look-alike search, at most `memory_searches` of them: one
        robot's earlier map (its objects seen within kappa of the snapshot's time) against the
        other's current map. The snapshots with the fewest objects farther than `inlier_radius`
        from the robot's current map go first, the latest first among equals. Snapshots of
        fewer than `fewest` objects are left out: no alignment of theirs explains as many
        objects as a searched candidate does."""
        # A snapshot that mostly repeats the current map is a subset of it, and MNO-CLIPPER on
        # a subset surfaces alignments of the same objects that the full map's best solutions
        # hide: on MRCLAM (vio, seed 0, 8 of 20 searched, none left out by size) these were
        # the rivals that mattered: most novel first 18.9 % false accepts, most familiar first
        # 2.5 %, all 20 searched 3.9 %.
        prm = self.params
        found = [(side, order, current, earlier)
                 for side, (current, past) in enumerate(((ego_r, ego_past),
                                                         (other_r, other_past)))
                 for order, (t, snapshot) in enumerate(past)
                 if len(earlier := snapshot.recent(t, prm.kappa)) >= fewest]
        if len(found) > prm.memory_searches:  # else all are searched: the order is moot
            found.sort(key=lambda f: (_count_novel(f[3], f[2], prm.inlier_radius), -f[1], f[0]))
        return [(earlier, other_r) if side == 0 else (ego_r, earlier)
                for side, _, _, earlier in found[: prm.memory_searches]]

    def _has_rival(self, candidate: _Solution, rivals: list[_Solution]) -> bool:
        """Whether a solution distinct from the candidate explains at least as many objects."""
        prm = self.params
        for r in rivals:
            if r.inliers < candidate.inliers:
                continue
            dz = r.z - candidate.z
            if (math.hypot(dz[0], dz[1]) > prm.distinct_translation
                    or abs(float(_wrap_angle(dz[2]))) > prm.distinct_heading):
                return True
        return False


@functools.cache
def _checked_defaults() -> tuple[FrameAlignerParams, tuple[str, ...]]:
    """FrameAlignerParams(), made (and its fields checked) once, and its fields that hold
    arrays."""
    params = FrameAlignerParams()
    return params, tuple(f.name for f in fields(params)
                         if isinstance(getattr(params, f.name), np.ndarray))


def _default_params() -> FrameAlignerParams:
    """A FrameAlignerParams() of the aligner's own, its arrays its own copies: a copy of the
    checked defaults, since checking every field again costs about a tenth of a
    millisecond, as much as a small step's search."""
    defaults, arrays = _checked_defaults()
    params = copy.copy(defaults)
    for name in arrays:
        object.__setattr__(params, name, getattr(defaults, name).copy())
    return params


@functools.cache
def _default_Q_inverse() -> np.ndarray:
    """Q^-1 (3, 3) of `repeat_Q` = None (TCAFF's default), inverted once; read-only."""
    Q_inv = _inverse_Q("FrameAlignerParams.repeat_Q", None)
    Q_inv.flags.writeable = False
    return Q_inv


def _gated_share(compatible: np.ndarray, passed: int | None = None) -> float:
    """The share of the object pairs (n_ego, n_other) bool that pass the gates, 0 for none;
    `passed`: their count when already made."""
    if not compatible.size:
        return 0.0
    # the count over the size is the mean to the last bit (both one rounding of exact
    # integers), without a float copy of the pairs
    return (int(np.count_nonzero(compatible)) if passed is None else passed) / compatible.size


def _recent_map(objects: ObjectMap, idx: np.ndarray) -> ObjectMap:
    """`objects.subset(idx)` for the indices (k,) of its recent objects (ascending), or the
    map itself when they are all of them and its arrays are laid out as a subset's (C order):
    the same objects without copying them."""
    if idx.shape[0] != len(objects):
        return objects.subset(idx)
    for name in _ALL_FIELDS:
        arr = getattr(objects, name)
        if arr is not None and not arr.flags.c_contiguous:
            return objects.subset(idx)
    return objects


def _snapshots(owner: str, name: str, value) -> list[tuple[float, ObjectMap]]:
    """`value` as a list of (finite time, ObjectMap); DataError naming `name` otherwise."""
    if isinstance(value, (str, bytes, ObjectMap)) or not isinstance(value, Sequence):
        raise DataError(f"{owner}: {name} must be a sequence of (t, ObjectMap), got "
                        f"{type(value).__name__} {shown(value)}")
    out = []
    for i, entry in enumerate(value):
        if not (isinstance(entry, (tuple, list)) and len(entry) == 2):
            raise DataError(f"{owner}: {name}[{i}] must be a (t, ObjectMap) pair, got "
                            f"{shown(entry)}")
        out.append((finite_time(owner, f"{name}[{i}] time", entry[0]),
                    as_object_map(owner, f"{name}[{i}] map", entry[1])))
    return out


def _seconds(value) -> float:
    """A real number of seconds as a float; an int beyond the floats is infinitely long."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _count_novel(earlier: ObjectMap, current: ObjectMap, radius: float) -> int:
    """How many objects of `earlier` lie farther than `radius` (m, in the plane) from every
    object of `current` (two maps of one robot, in its odometry frame)."""
    if len(earlier) == 0 or len(current) == 0:
        return len(earlier)
    nearest, _ = cKDTree(current.centroids[:, :2]).query(earlier.centroids[:, :2],
                                                         distance_upper_bound=radius)
    return int(np.count_nonzero(nearest > radius))  # inf: none within the radius


def confirms(z: np.ndarray, held: np.ndarray | None, params: FrameAlignerParams) -> bool:
    """Whether alignment z (3,) lies within `confirm_translation` and `confirm_heading` of the
    held alignment (3,) (False when nothing is held).

    Raises:
        DataError: z or held not three finite numbers; ConfigError: params not a
            FrameAlignerParams.
    """
    _require(isinstance(params, FrameAlignerParams), "confirms", "params", params,
             "must be a FrameAlignerParams")
    z = _alignment("confirms", "z", z)
    return _confirms(z, None if held is None else _alignment("confirms", "held", held), params)


def _alignment(owner: str, name: str, value) -> np.ndarray:
    """`value` as three finite numbers (x [m], y [m], theta [rad]), else DataError."""
    arr = real_array(owner, name, value)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise DataError(f"{owner}: {name} must be three finite numbers (x, y, theta), got "
                        f"{shown(value)}")
    return arr


def _confirms(z: np.ndarray, held: np.ndarray | None, params: FrameAlignerParams) -> bool:
    if held is None:
        return False
    dz = z - held
    return bool(math.hypot(dz[0], dz[1]) <= params.confirm_translation
                and abs(float(_wrap_angle(dz[2]))) <= params.confirm_heading)


@dataclass(frozen=True, eq=False)
class _Solution:
    """One registered MNO-CLIPPER solution (indices into the maps of recent objects): its
    associations (k, 2), score, SE(2) registration T (3, 3) with its (x, y, theta) z (3,)
    made when first asked for (a rival with fewer inliers than every candidate is never
    asked), the registered points p, q (k, dim) and weights w (k,), residual RMS [m] (NaN
    for one that cannot qualify: a rival only), whether it passes the checks, and the
    objects it explains."""

    associations: np.ndarray
    score: float
    T: np.ndarray
    p: np.ndarray
    q: np.ndarray
    w: np.ndarray
    rmse: float
    qualifies: bool
    inliers: int

    @functools.cached_property
    def z(self) -> np.ndarray:
        return _se2_to_params(self.T)


class MapMemory:
    """Earlier maps of one robot, for the aligner's look-alike search: one snapshot every
    `every` seconds, kept for `span` seconds.

    Each snapshot is the map as it was, objects of every age; the aligner takes those seen
    within kappa of the snapshot's time.
    """

    def __init__(self, span: float, every: float) -> None:
        """An empty memory.

        Raises:
            ConfigError: span not a number >= 0 seconds, or every not a number > 0 (inf
                keeps only the first map).
        """
        _require(_real(span) and span >= 0, "MapMemory", "span", span,
                 "must be a number >= 0 seconds")
        _require(_real(every) and every > 0, "MapMemory", "every", every,
                 "must be a number > 0 seconds")
        self.span, self.every = _seconds(span), _seconds(every)
        self._snapshots: deque[tuple[float, ObjectMap]] = deque()

    @classmethod
    def of(cls, params: FrameAlignerParams) -> MapMemory:
        """The memory an aligner with these settings searches: `memory_span` seconds, one map
        every kappa; nothing kept when it does not check ambiguity.

        Raises:
            ConfigError: params not a FrameAlignerParams.
        """
        _require(isinstance(params, FrameAlignerParams), "MapMemory.of", "params", params,
                 "must be a FrameAlignerParams")
        return cls(params.memory_span if params.check_ambiguity else 0.0, params.kappa)

    def snapshots(self) -> list[tuple[float, ObjectMap]]:
        """(t, map) of the snapshots kept, oldest first."""
        return list(self._snapshots)

    def add(self, t: float, objects: ObjectMap) -> None:
        """Offer the map of time t (s, increasing): kept when `every` has passed since the last
        snapshot; snapshots older than `span` are dropped.

        Raises:
            DataError: t not a finite number, or objects not an ObjectMap.
        """
        t = finite_time("MapMemory.add", "t", t)
        objects = as_object_map("MapMemory.add", "objects", objects)
        if self.span <= 0:
            return
        if not self._snapshots or t - self._snapshots[-1][0] >= self.every:
            self._snapshots.append((t, objects))
        while self._snapshots and t - self._snapshots[0][0] > self.span:
            self._snapshots.popleft()
