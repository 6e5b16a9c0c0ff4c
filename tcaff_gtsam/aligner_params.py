"""Settings of the frame aligner: CLIPPER's consistency graph and solver (`ClipperParams`) and
the candidates made from two maps (`FrameAlignerParams`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .errors import DataError
from .param_checks import (
    MAX_COORDINATE,
    MAX_FACTOR,
    MAX_ITERATIONS,
    MAX_OBJECTS,
    MAX_SECONDS,
    MAX_STEPS,
    _ByValue,
    _count,
    _finite,
    _int_at_least,
    _number,
    _one_of,
    _real,
    _reals,
    _require,
    _spd,
)

#: the most MNO-CLIPPER solutions asked for: each holds its (m,) relaxed vector and, with a
#: downweight, its (m,) start draws; the paper asks for 4
MAX_SOLUTIONS = 1000

#: metres, the largest per-point noise (`residual_floor`): centroids placed a kilometre apart
#: from where they are make no map, and a registration of such points with the calibrated
#: covariance's inflation would give a covariance beyond MAX_VARIANCE
MAX_POINT_NOISE = 1e3

#: (metres, radians) per square root of a second, the largest odometry drift (`map_drift`): a
#: metre and 6 degrees in the first second, 60 m and 6 rad after an hour, is no odometry; with
#: the other settings at their defaults the calibrated covariance stays below MAX_VARIANCE
MAX_MAP_DRIFT = (1.0, 0.1)

#: metres, the narrowest affinity kernel (`ClipperParams.sigma`): its 1 / (2 sigma^2) overflows
#: below about 1e-154 m, where pairs that agree exactly got NaN weights, and 2 sigma^2 is zero
#: (a ZeroDivisionError) below about 1e-162 m; no map places objects to a nanometre
MIN_SIGMA = 1e-9

#: the most earlier maps searched for look-alikes in one step (`memory_searches`): each search
#: costs one to three times the step's own alignment
MAX_MEMORY_SEARCHES = 1000


def _kappa(owner: str, name: str, value) -> None:
    """A `ParameterError` unless `value` is a map span: seconds > 0, at most a year
    (`MAX_SECONDS`), or inf (maps that keep every object). The aligner's, and what a node
    publishes and a replay holds for it."""
    _number(owner, name, value, 0, MAX_SECONDS, "seconds", "MAX_SECONDS", above=True, inf=True)


def constant_alignment_covariance() -> np.ndarray:
    """The original code's fixed measurement covariance diag(0.5 m, 0.5 m, 5 deg)^2, (3, 3)."""
    return np.diag([0.5**2, 0.5**2, math.radians(5.0) ** 2])


def _alignment_process_noise() -> np.ndarray:
    """Drift of T_oi_oj per step, diag(0.1 m, 0.1 m, 0.5 deg)^2, (3, 3) (the original's Q)."""
    return np.diag([0.1**2, 0.1**2, math.radians(0.5) ** 2])


def as_map_drift(owner: str, value) -> tuple[float, float]:
    """`value` as a map drift (metres, radians) per square root of a second, two numbers >= 0,
    at most MAX_MAP_DRIFT (1 m and 0.1 rad); else a ParameterError of `owner`'s field
    map_drift."""
    drift = _reals(value)
    _require(drift is not None and len(drift) == 2
             and all(0 <= v <= high for v, high in zip(drift, MAX_MAP_DRIFT, strict=True)),
             owner, "map_drift", value, "must be (metres, radians) per square root of a second, "
             f"two numbers >= 0 and <= {MAX_MAP_DRIFT} (MAX_MAP_DRIFT)")
    return drift


@dataclass(frozen=True)
class ClipperParams:
    """CLIPPER consistency graph and solver settings.

    Attributes:
        sigma: metres, width of the affinity kernel exp(-c^2 / (2 sigma^2)).
        epsilon: metres, two associations are consistent when their distance difference c < epsilon.
        rounding: "size" keeps the round(F) largest entries of u (CLIPPER's rule, F the final
            objective); "threshold" keeps entries above `threshold` * max(u).
        threshold: relative threshold for rounding = "threshold", in (0, 1).
        tol_u: stop an inner ascent when the objective changes by less than this. 1e-6 rather
            than CLIPPER's 1e-8: the same solutions on our benchmarks, 25 % less time. In
            (0, 1].
        eps: entries of u (and penalties) below this count as zero; in (0, 1] (u has unit
            norm, so 1 already counts every entry as zero).
        beta: backtracking factor of the line search, in (0, 1).
        max_outer, max_inner, max_line_search: iteration caps of homotopy, ascent and line search.
        power_iterations: power-method steps that shape the seeded random start vector (each
            costs a full pass over the graph; more than 5 changed no solution we measured).
            These four counts are ints of at most 1e6 (`MAX_ITERATIONS`; each iteration
            costs a pass over the graph).
        seed: seed (an int >= 0, any size: numpy's generator takes them all) of the start
            vector; same seed, same graph -> same solution.

    sigma and epsilon are at most 1e9 m (`MAX_COORDINATE`); sigma is at least 1e-9 m
    (`MIN_SIGMA`).

    Raises:
        ConfigError (a `ParameterError` naming the field) for values out of range.
    """

    sigma: float = 0.15
    epsilon: float = 0.25
    rounding: Literal["size", "threshold"] = "size"
    threshold: float = 0.5
    tol_u: float = 1e-6
    eps: float = 1e-9
    beta: float = 0.25
    max_outer: int = 1000
    max_inner: int = 200
    max_line_search: int = 99
    power_iterations: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        o = "ClipperParams"
        _number(o, "sigma", self.sigma, MIN_SIGMA, MAX_COORDINATE, "metres",
                "MIN_SIGMA, MAX_COORDINATE")
        _number(o, "epsilon", self.epsilon, 0, MAX_COORDINATE, "metres", "MAX_COORDINATE",
                above=True)
        _require(_one_of(self.rounding, ("size", "threshold")), o, "rounding", self.rounding,
                 "must be 'size' or 'threshold'")
        for name in ("threshold", "beta"):
            value = getattr(self, name)
            _require(_real(value) and 0 < value < 1, o, name, value, "must be in (0, 1)")
        for name in ("tol_u", "eps"):
            _number(o, name, getattr(self, name), 0, 1, above=True)
        for name, low in (("max_outer", 1), ("max_inner", 1), ("max_line_search", 1),
                          ("power_iterations", 0)):
            _count(o, name, getattr(self, name), low, MAX_ITERATIONS, "MAX_ITERATIONS")
        # the seed goes to numpy's generator, which takes any int >= 0 (a negative one fails
        # there, at solve time): a seed names a stream and is no magnitude, so it has no bound
        _require(_int_at_least(self.seed, 0), o, "seed", self.seed, "must be an int >= 0")


@dataclass(frozen=True, eq=False)
class FrameAlignerParams(_ByValue):
    """Settings of `FrameAligner` (two object maps -> candidate alignments of T_oi_oj).

    Attributes:
        kappa: seconds, only objects seen less than kappa ago take part (paper: 20 s).
        size_ratio, size_abs_diff: the size gate; a pair of objects may be associated when, for
            width and for height alike, the larger over the smaller is <= size_ratio or the
            absolute difference is <= size_abs_diff metres.
        size_partial: None, or a ratio (above size_ratio to matter) by which one of width
            and height may differ when the other is within the gate: a partial view cuts one
            extent (a chair behind a table loses its height, a box seen on one face its width)
            and leaves the other. None: both must be within size_ratio (the paper's gate,
            and the released code's).
        partial_pairs: which of the pairs that only the partial-view rule (`size_partial`)
            passes enter the consistency graph of a full search. In maps of many objects of
            similar sizes they outnumber the paper's gate's pairs several times over (clustered
            maps of 100 objects: about 1700 beside 830), nearly all false, and the graph costs
            their square. "best": only a pair that is the best of all the compatible pairs of
            both its objects, ranked by how well the two objects' surroundings agree
            (`association.neighbourhood_agreement` within `clipper.epsilon`, as
            `pairs_per_object` ranks them), then by recency: a partially seen object and its
            counterpart, whose surroundings are the same; at most one pair per object.
            "auto" (the default): "best" where the partial pairs would add to the graph more
            than 2^16 consistency checks and more than ranking them takes steps (maps of
            many objects: a hundred of assorted sizes per map add millions), else every
            partial pair (maps of a few tens of objects, the simulator's and the kitchen's,
            whose graphs stay small and where a true pair of a small overlap often does not
            rank first). "all": every partial pair. Either way a guided search
            (`guide_radius`), the objects a candidate explains and
            `FrameAligner.lookalike_share` take the whole gate; without `size_partial` this
            changes nothing.
        dim: 2 matches (x, y) centroids (the original's choice), 3 matches full 3D centroids
            (the alignment is then projected onto the gravity-aligned plane).
        clipper: consistency graph and solver settings. Its epsilon is widened by
            `epsilon_drift` for maps of a long span.
        n_solutions: N of MNO-CLIPPER (Algorithm 1), at most `MAX_SOLUTIONS`.
        mno_downweight: factor applied to affinities among an earlier solution's associations;
            0 removes those associations, as in the paper.
        min_associations: solutions with fewer associations are discarded (but see
            `sparse_associations`).
        sparse_associations: in sparse maps of distinct objects, solutions of this many
            associations are kept too: when the smaller map holds at most `sparse_objects`
            recent objects and fewer than `sparse_share` of the object pairs pass the gates
            (`FrameAligner.lookalike_share`). There a clique of four is most of what the
            maps share, and few other cliques are possible; among look-alikes (MRCLAM's
            landmarks carry no size, every pair passes) or in large maps it is often a
            coincidence. The filter weighs such a candidate as weak evidence
            (`TCAFFParams.object_nats`). None, or not below min_associations: no exception.
        sparse_objects, sparse_share: see `sparse_associations`.
        max_associations: the most putative associations (nodes of the consistency graph)
            per map pair. When the size gate passes more (large maps of look-alike objects),
            each object of either map keeps only its `pairs_per_object` best pairs, at most
            max_associations of them, and it is logged. It bounds the step's time and memory
            in large maps: the graph costs about m^2 / 2 distance checks.
        pairs_per_object: with more pairs than `max_associations`, the pairs each object of
            either map keeps: those whose objects' surroundings agree best, each within its
            own map (`association.neighbourhood_agreement`: the distances to their nearest
            neighbours that match within `clipper.epsilon`; then the most recently seen, as
            a tie-break). 2 keeps at most 2 (n_ego + n_other) pairs. Not used below the cap.
        min_score_ratio: solutions scoring below this fraction of the best are discarded.
        weight_offset: Arun weights are 1 / (weight_offset + age_i * age_j), ages in seconds.
        max_rmse: metres; solutions whose registration residual RMS exceeds it are discarded
            (mirror-image cliques pass the distance test but are not rigid). None disables it.
        covariance: how each candidate's covariance R is made. "calibrated" (the default):
            the registration's sandwich covariance with the point noise pooled with a prior
            (`residual_floor`, `residual_prior_dof`), plus the odometries' drift over the
            map's span (`map_drift`), inflated so that a filter re-registering the same
            objects every step does not average their shared error away
            (`repeat_inflation`); see `frame_aligner.calibrated_covariance`. "residual": the
            sandwich covariance alone, its noise floored at `residual_floor`. "constant":
            `R_constant` for every candidate (the original's choice).
        R_constant: (3, 3) covariance of (x [m], y [m], theta [rad]) for covariance="constant".
        residual_floor: metres, the per-point noise: the lower bound of covariance="residual"'s,
            the prior of "calibrated"'s.
        residual_prior_dof: covariance="calibrated": the weight of `residual_floor` as a prior
            on the point noise, in degrees of freedom (0: the residual alone, floored).
        map_drift: (metres, radians) per square root of a second, the random walk of the two
            robots' odometries relative to each other, which distorts each map over its span
            kappa: the calibrated covariance adds it over half the span; `epsilon_drift`
            widens CLIPPER's epsilon by its translation over the whole span.
        epsilon_drift: standard deviations of that distortion by which two maps' distances
            may disagree beyond CLIPPER's epsilon: the consistency graph (and the pair
            rankings) use epsilon' = sqrt(epsilon^2 + (epsilon_drift d_t)^2 span), span = kappa
            (the oldest recent object's age when kappa is inf). Two objects placed through a
            drifting odometry a span apart are that much further from where the other map
            puts them: 0.25 m at 20 s becomes 0.27 m, at 150 s 0.35 m. 0: epsilon as given.
        repeat_inflation: covariance="calibrated": rho of R = R_s + rho R_s Q^-1 R_s, where
            R_s is one registration's covariance and Q the filter's drift per step. With rho
            = 1 (default) an identity-motion Kalman filter fed the same registration every
            step settles at P = R_s: consecutive registrations of mostly the same objects
            share nearly all their error (docs/tcaff.md, "One registration's error, not
            less"). Lower values let them share only part of it. 0: no inflation.
        jitter_reference: covariance="calibrated" with `repeat_inflation` > 0: the jitter
            below which consecutive registrations of one alignment stay where this R holds
            (`TCAFFParams.jitter_reference`: the mean of d' (R_a + R_b)^-1 d / 3 over
            consecutive measurements the filter took, d their difference). `PairwiseAligner`
            gives it to its filter unless the filter names its own, and the filter then
            scales the covariance it reports by the jitter over it where that is more than
            1. Such R counts the error consecutive registrations share, so the jitter is
            small where it holds (0.03-0.13 on MRCLAM's VIO-like maps, the kitchen and the
            simulator's indoor scenarios) and larger where the odometry drifts faster than
            `map_drift` assumes (0.35-0.7 outdoors and on MRCLAM's dead reckoning, whose
            NEES was 5 to 40). None: not given.
        repeat_Q: covariance="calibrated": the (3, 3) Q of that inflation, the drift per step
            of the filter the candidates feed; None: that filter's Q where the aligner knows
            it (`PairwiseAligner`, `pairwise.feeding`), else TCAFF's default Q.
        min_inliers: a candidate must explain at least this many objects: pairs of recent
            objects, one from each map, that are mutual nearest neighbours under the candidate
            within `inlier_radius` and pass the size gate, counted over every recent object of
            the two maps, not only the associated ones. None: no such check.
        inlier_radius: metres.
        min_spread: metres; the associated ego centroids must spread at least this far across
            their least spread direction (`registration.spread`): a line of objects, or two
            tight clusters, fixes no rotation about its own axis.
        check_ambiguity: flag a candidate ambiguous when another alignment, distinct from it
            (more than `distinct_translation` metres or `distinct_heading` radians away),
            explains as many objects: another solution of the same maps, or a solution
            between one robot's current map and the other's earlier maps (`memory_span`).
            The maps then admit several alignments and the best score is no evidence for one
            of them; an ambiguous candidate may confirm the estimate a filter holds, within
            `confirm_translation` and `confirm_heading`, but never start or move one.
        distinct_translation, distinct_heading: metres and radians.
        memory_span: seconds of each robot's earlier maps searched for look-alikes, one map
            every kappa seconds; 0 searches only the current maps.
        memory_searches: the most earlier maps searched in one step, both robots together
            (each search costs one to three times the step's own alignment); those sharing
            the most objects with the robot's current map go first.
        confirm_translation, confirm_heading: metres and radians.
        track_min: with an alignment held by the caller's filter and no candidate confirming
            it, the objects it pairs (mutual nearest neighbours within `confirm_translation`
            that pass the size gate) re-register it when there are at least this many: a
            tracked measurement, which like an ambiguous one may confirm the held alignment
            but never start or move one. None: no tracking.
        guide_radius: metres; with an alignment held by the caller's filter and nothing
            contesting it, a guided search (`FrameAligner.measurements`, guided=True) puts into
            the consistency graph only the size-compatible pairs whose centroids agree under
            the held alignment: the other's centroid q, moved by it, within guide_radius +
            confirm_heading * |q| of the ego's (|q| its distance from its frame's origin, the
            lever of a heading error). The graph then holds little more than the held
            alignment's own pairs and MNO-CLIPPER costs a fraction of a full search. A guided
            step yields only candidates confirming the held alignment; when none does, the
            step searches in full. The radius must cover `confirm_translation`, the map noise
            and the drift between steps: 2 m is four times `confirm_translation`. None: every
            search is full (the paper's and the released code's way).
        full_search_every: with guide_radius set, at least every this many steps of a pair
            search in full (`PairwiseAligner`), so that an alignment elsewhere is still seen;
            while the filter has a rival hypothesis open or holds its alignment provisionally
            every step does (1: always).
        height_epsilon: metres, or None; the gravity prior: two associations (i, j) and
            (k, l) are consistent only when their objects' height differences agree,
            |(z_i - z_k) - (z_j - z_l)| < height_epsilon + s_ij + s_kl, besides their
            distances in the plane. Both robots' odometry frames are gravity aligned (VIO
            gives them so), so heights differ between the maps by a constant, which cancels.
            The slack s_ij = |h_i - h_j| / 2 of an association allows for a partial view,
            which cuts an object's height h by some d and moves its centre by d / 2: objects
            whose heights agree are held to height_epsilon. A shift along a row of objects
            that pairs each with its neighbour keeps the distances in the plane and breaks
            the heights of objects on shelves, a counter and the floor. None: heights are not
            compared (the paper's planar test).
        descriptor_min: in [0, 1]; when both maps carry descriptors (`ObjectMap.descriptors`),
            a pair whose similarity (their dot product) is below this is not associated, as
            a pair of different sizes is not. 0: descriptors gate nothing. Maps without
            descriptors (landmarks that all look alike) are gated by size alone.
        descriptor_prior: when both maps carry descriptors, each putative association's
            similarity is its prior weight in the consistency graph (the affinity's
            diagonal; 1 otherwise), so that CLIPPER prefers sets of look-alike pairs.
        refit: register each candidate again on every pair it explains (the mutual inliers
            within `inlier_radius`) instead of MNO-CLIPPER's clique alone, and take its
            residual and covariance from those pairs.

    Bounds, checked when the object is made (a value beyond one is a `ParameterError` naming
    the field, as are NaN and, but for kappa, infinities): lengths (size_abs_diff, max_rmse,
    inlier_radius, min_spread, distinct_translation, confirm_translation, guide_radius,
    height_epsilon) at most 1e9 m (`MAX_COORDINATE`, the bound of every coordinate the library
    takes), residual_floor at most 1 km (`MAX_POINT_NOISE`), map_drift at most 1 m and 0.1 rad
    per square root of a second (`MAX_MAP_DRIFT`; either at its bound, the other settings at
    their defaults, keeps the calibrated covariance below 1e18, `MAX_VARIANCE`); headings
    (distinct_heading, confirm_heading) at most pi, which no heading differs by more; kappa
    and memory_span at most a year, 31 557 600 s (`MAX_SECONDS`; kappa may be inf, no
    limit), weight_offset at most its square (s^2); the ratios and factors size_ratio,
    size_partial, residual_prior_dof, epsilon_drift, repeat_inflation and jitter_reference at
    most 1e6 (`MAX_FACTOR`; the defaults are 0.15 to 4); counts of objects or associations
    (min_associations, sparse_associations, sparse_objects, max_associations,
    pairs_per_object, min_inliers, track_min) at most 1e6 (`MAX_OBJECTS`), n_solutions at
    most 1000 (`MAX_SOLUTIONS`), memory_searches at most 1000 (`MAX_MEMORY_SEARCHES`),
    full_search_every at most `MAX_STEPS` (a year of steps at 10 Hz); the entries of
    R_constant and repeat_Q at most 1e18 (`MAX_VARIANCE`) in magnitude. The shares and
    probabilities are bounded by their ranges.
    """

    kappa: float = 20.0
    size_ratio: float = 1.35
    size_abs_diff: float = 0.1
    size_partial: float | None = 2.0
    partial_pairs: Literal["all", "best", "auto"] = "auto"
    dim: Literal[2, 3] = 2
    clipper: ClipperParams = field(default_factory=ClipperParams)
    n_solutions: int = 4
    mno_downweight: float = 0.0
    min_associations: int = 5
    sparse_associations: int | None = 4
    sparse_objects: int = 12
    sparse_share: float = 0.9
    max_associations: int = 10000
    pairs_per_object: int = 2
    min_score_ratio: float = 0.75
    weight_offset: float = 0.01
    max_rmse: float | None = 0.5
    covariance: Literal["constant", "residual", "calibrated"] = "calibrated"
    R_constant: np.ndarray = field(default_factory=constant_alignment_covariance)
    residual_floor: float = 0.05
    residual_prior_dof: float = 4.0
    map_drift: tuple[float, float] = (0.01, math.radians(0.25))
    epsilon_drift: float = 2.0
    repeat_inflation: float = 1.0
    jitter_reference: float | None = 0.15
    repeat_Q: np.ndarray | None = None
    min_inliers: int | None = None
    inlier_radius: float = 0.3
    min_spread: float = 0.25
    check_ambiguity: bool = True
    distinct_translation: float = 1.0
    distinct_heading: float = math.radians(5.0)
    memory_span: float = 200.0
    memory_searches: int = 8
    confirm_translation: float = 0.5
    confirm_heading: float = math.radians(2.5)
    track_min: int | None = None
    guide_radius: float | None = 2.0
    full_search_every: int = 5
    height_epsilon: float | None = None
    descriptor_min: float = 0.0
    descriptor_prior: bool = False
    refit: bool = False

    def __post_init__(self) -> None:
        o = "FrameAlignerParams"
        metres = dict(unit="metres", limit="MAX_COORDINATE")
        _kappa(o, "kappa", self.kappa)
        _number(o, "size_ratio", self.size_ratio, 1, MAX_FACTOR, limit="MAX_FACTOR")
        _number(o, "size_abs_diff", self.size_abs_diff, 0, MAX_COORDINATE, **metres)
        _number(o, "size_partial", self.size_partial, 1, MAX_FACTOR, limit="MAX_FACTOR",
                none=True)
        _require(_one_of(self.partial_pairs, ("all", "best", "auto")), o, "partial_pairs",
                 self.partial_pairs, "must be 'all', 'best' or 'auto'")
        _require(_one_of(self.dim, (2, 3)), o, "dim", self.dim, "must be 2 or 3")
        _require(isinstance(self.clipper, ClipperParams), o, "clipper", self.clipper,
                 "must be a ClipperParams")
        _count(o, "n_solutions", self.n_solutions, 1, MAX_SOLUTIONS, "MAX_SOLUTIONS")
        _require(_real(self.mno_downweight) and 0 <= self.mno_downweight < 1, o,
                 "mno_downweight", self.mno_downweight, "must be in [0, 1)")
        objects = dict(high=MAX_OBJECTS, limit="MAX_OBJECTS")
        _count(o, "min_associations", self.min_associations, 2, **objects)
        _count(o, "sparse_associations", self.sparse_associations, 2, **objects, none=True)
        _count(o, "sparse_objects", self.sparse_objects, 1, **objects)
        _require(_real(self.sparse_share) and 0 <= self.sparse_share <= 1, o, "sparse_share",
                 self.sparse_share, "must be in [0, 1]")
        _require(_int_at_least(self.max_associations, self.min_associations, MAX_OBJECTS), o,
                 "max_associations", self.max_associations,
                 f"must be an int in [min_associations ({self.min_associations}), "
                 f"{MAX_OBJECTS}] (MAX_OBJECTS)")
        _count(o, "pairs_per_object", self.pairs_per_object, 1, **objects)
        _require(_real(self.min_score_ratio) and 0 <= self.min_score_ratio <= 1, o,
                 "min_score_ratio", self.min_score_ratio, "must be in [0, 1]")
        # Arun's weights 1 / (weight_offset + age_i age_j): ages of at most MAX_SECONDS
        _number(o, "weight_offset", self.weight_offset, 0, MAX_SECONDS**2, "seconds^2",
                "MAX_SECONDS^2", above=True)
        _number(o, "max_rmse", self.max_rmse, 0, MAX_COORDINATE, **metres, above=True,
                none=True)
        _require(_one_of(self.covariance, ("constant", "residual", "calibrated")), o,
                 "covariance", self.covariance,
                 "must be 'constant', 'residual' or 'calibrated'")
        object.__setattr__(self, "R_constant",
                           _spd(self.R_constant, 3, o, "R_constant", bounded=True))
        _number(o, "residual_floor", self.residual_floor, 0, MAX_POINT_NOISE, "metres",
                "MAX_POINT_NOISE", above=True)
        for name in ("residual_prior_dof", "repeat_inflation", "epsilon_drift"):
            _number(o, name, getattr(self, name), 0, MAX_FACTOR, limit="MAX_FACTOR")
        object.__setattr__(self, "map_drift", as_map_drift(o, self.map_drift))
        _number(o, "jitter_reference", self.jitter_reference, 0, MAX_FACTOR, limit="MAX_FACTOR",
                above=True, none=True)
        if self.repeat_Q is not None:
            object.__setattr__(self, "repeat_Q",
                               _spd(self.repeat_Q, 3, o, "repeat_Q", bounded=True))
        _count(o, "min_inliers", self.min_inliers, 2, **objects, none=True)
        _count(o, "track_min", self.track_min, 2, **objects, none=True)
        _require(isinstance(self.check_ambiguity, bool), o, "check_ambiguity",
                 self.check_ambiguity, "must be True or False")
        for name in ("inlier_radius", "distinct_translation", "confirm_translation"):
            _number(o, name, getattr(self, name), 0, MAX_COORDINATE, **metres, above=True)
        for name in ("distinct_heading", "confirm_heading"):
            _number(o, name, getattr(self, name), 0, math.pi, "radians", above=True)
        _number(o, "min_spread", self.min_spread, 0, MAX_COORDINATE, **metres)
        _number(o, "memory_span", self.memory_span, 0, MAX_SECONDS, "seconds", "MAX_SECONDS")
        _count(o, "memory_searches", self.memory_searches, 0, MAX_MEMORY_SEARCHES,
               "MAX_MEMORY_SEARCHES")
        _number(o, "guide_radius", self.guide_radius, 0, MAX_COORDINATE, **metres, above=True,
                none=True)
        _count(o, "full_search_every", self.full_search_every, 1, MAX_STEPS, "MAX_STEPS")
        _number(o, "height_epsilon", self.height_epsilon, 0, MAX_COORDINATE, **metres,
                above=True, none=True)
        _require(_finite(self.descriptor_min) and 0 <= self.descriptor_min <= 1, o,
                 "descriptor_min", self.descriptor_min, "must be in [0, 1]")
        for name in ("descriptor_prior", "refit"):
            _require(isinstance(getattr(self, name), bool), o, name, getattr(self, name),
                     "must be True or False")

    def span_epsilon(self, span: float) -> float:
        """Metres: CLIPPER's epsilon for maps whose objects were placed over `span` seconds,
        widened by `epsilon_drift` standard deviations of the odometries' drift.

        Raises:
            DataError: span not a finite number >= 0, or so long with these settings that
                epsilon overflows.
        """
        # called at every search; inputs imports the parameter objects, so `shown` is
        # imported where a message needs it
        o = "FrameAlignerParams.span_epsilon"
        if not (_finite(span) and span >= 0):
            from .inputs import shown

            raise DataError(f"{o}: span must be a finite number >= 0 seconds, got {shown(span)}")
        widen = self.epsilon_drift * self.map_drift[0]
        # products, not powers: a float's ** overflows with an exception, * to inf
        epsilon = math.sqrt(self.clipper.epsilon * self.clipper.epsilon
                            + widen * widen * float(span))
        if not math.isfinite(epsilon):
            from .inputs import shown

            raise DataError(f"{o}: span = {shown(span)} with epsilon_drift = "
                            f"{shown(self.epsilon_drift)} and map_drift = "
                            f"{shown(self.map_drift)} overflows epsilon")
        return epsilon

    def fewest_associations(self, n_ego: int, n_other: int, share: float) -> int:
        """The fewest associations a candidate may have between maps of n_ego and n_other
        recent objects, `share` of whose pairs pass the gates (`sparse_associations`)."""
        sparse = self.sparse_associations
        if (sparse is not None and min(n_ego, n_other) <= self.sparse_objects
                and share < self.sparse_share):
            return min(self.min_associations, sparse)
        return self.min_associations

    @classmethod
    def reference(cls) -> FrameAlignerParams:
        """The authors' released settings, without this project's residual, spread and
        ambiguity checks, with the paper's size gate and epsilon, and with every search
        full."""
        return cls(max_rmse=None, min_inliers=None, min_spread=0.0, check_ambiguity=False,
                   guide_radius=None, size_partial=None, covariance="constant",
                   sparse_associations=None, epsilon_drift=0.0)

    @classmethod
    def camera(cls, **changes) -> FrameAlignerParams:
        """For maps of cameras on gravity-aligned odometry (VIO), as the RGB-D front end
        makes them (objects' clouds merged over views, with descriptors): the gravity prior
        (`height_epsilon` = CLIPPER's epsilon), the calibrated covariances (as the default),
        descriptors as a gate (similarity >= 0.5) and CLIPPER's prior, and candidates of as
        few as 3 associations: with descriptors and heights to agree on, a clique of three is
        rarely a coincidence, and the filter weighs it as weak evidence
        (`TCAFFParams.object_nats`). `changes` are any other fields.

        On the 7-Scenes kitchen (two hand-held halves, VIO-like drift) these take false
        accepts from about 1 in 4 to none and heading errors from 4 to about 1 degree
        (docs/mapping.md); outdoors, where the simulator's partial views move tall objects'
        centres by metres in height, the gravity prior costs availability, so it is not the
        default."""
        clipper = changes.get("clipper", ClipperParams())
        epsilon = clipper.epsilon if isinstance(clipper, ClipperParams) else None
        return cls(**{"height_epsilon": epsilon, "covariance": "calibrated",
                      "descriptor_min": 0.5, "descriptor_prior": True, "min_associations": 3,
                      **changes})
