"""Parameter objects. Defaults are the paper's values (and the released code's where the paper
is silent); every object validates itself and raises `ConfigError` naming the field."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Literal

import numpy as np

from .errors import ConfigError

__all__ = [
    "ClipperParams",
    "FrameAlignerParams",
    "GraphParams",
    "ParameterError",
    "TCAFFParams",
    "constant_alignment_covariance",
]


class ParameterError(ConfigError):
    """A `ConfigError` about one field of a parameter object.

    Attributes:
        owner: the parameter class (or function) the field belongs to.
        name: the field.
        value: the rejected value.
        rule: what the field must be, e.g. "must be an int >= 1".
    """

    def __init__(self, owner: str, name: str, value: Any, rule: str) -> None:
        try:
            shown = repr(value)
        except Exception:  # an int beyond Python's digit limit, a broken __repr__
            shown = f"<{type(value).__name__} that has no repr>"
        super().__init__(f"{owner}.{name} = {shown}: {rule}")
        self.owner, self.name, self.value, self.rule = owner, name, value, rule

    def __reduce__(self):
        # the default rebuilds from `args` (the message alone), which this __init__ refuses;
        # errors of study jobs travel between processes
        return type(self), (self.owner, self.name, self.value, self.rule)


def _require(condition: bool, owner: str, name: str, value, rule: str) -> None:
    if not condition:
        raise ParameterError(owner, name, value, rule)


def _given_or_default(cls: type, value, owner: str, name: str = "params"):
    """`value` when it is a `cls`, `cls()` when it is None; a ConfigError naming `owner` and
    `name` otherwise."""
    if value is None:
        return cls()
    _require(isinstance(value, cls), owner, name, value, f"must be a {cls.__name__} or None")
    return value


def _int_at_least(value, low: int) -> bool:
    """An int (Python or numpy, not a bool) >= low."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low


#: the largest count the compiled kernels take
_INT64_MAX = 2**63 - 1


def _real(value) -> bool:
    """A real number (Python or numpy, not a bool); may be NaN or infinite."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _finite(value) -> bool:
    """A finite real number (Python or numpy, not a bool); False for ints beyond the floats,
    which numpy cannot take."""
    try:
        return _real(value) and math.isfinite(value)
    except OverflowError:
        return False


def _one_of(value, choices: tuple) -> bool:
    """One of `choices` (strings or ints) by type as well as value: 2.0 is not 2, True not 1."""
    return (isinstance(value, (str, int, np.integer)) and not isinstance(value, bool)
            and value in choices)


def _reals(value) -> tuple[float, ...] | None:
    """A sequence (tuple, list or 1-D array) of real numbers as a tuple of floats, else None."""
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if not isinstance(value, (tuple, list)) or not all(_real(v) for v in value):
        return None
    try:
        return tuple(float(v) for v in value)
    except OverflowError:  # an int beyond the floats
        return None


def _spd(matrix, d: int | None, owner: str, name: str) -> np.ndarray:
    """`matrix` as a new float (d, d) array if it is a symmetric positive definite matrix of
    real numbers (d None: of any size >= 1); else `ParameterError`."""
    try:
        M = np.array(matrix) if isinstance(matrix, (tuple, list, np.ndarray)) else None
    except ValueError:  # ragged nested lists
        M = None
    ok = (M is not None and M.dtype.kind in "iuf" and M.ndim == 2 and M.shape[0] >= 1
          and M.shape[0] == M.shape[1] and (d is None or M.shape[0] == d))
    if ok:
        # + 0.0 turns -0.0 into 0.0, so matrices equal by value are equal byte for byte
        M = M.astype(float) + 0.0
        ok = (bool(np.all(np.isfinite(M))) and np.allclose(M, M.T)
              and bool(np.all(np.linalg.eigvalsh(M) > 0)))
    size = "(d, d)" if d is None else f"({d}, {d})"
    _require(ok, owner, name, matrix, f"must be a symmetric positive definite {size} matrix")
    return M


def _frozen(value):
    """`value`, or for an array a hashable stand-in equal exactly when the arrays are."""
    if isinstance(value, np.ndarray):
        return value.shape, value.dtype.str, value.tobytes()
    return value


class _ByValue:
    """Equality and hashing of a frozen parameter dataclass by the values of its fields, arrays
    included (the dataclass's own `__eq__` compares arrays elementwise and cannot hash them).
    Its subclasses are declared with `eq=False` so that these methods stay in place. The arrays
    are the object's own copies and must not be modified in place."""

    def _key(self) -> tuple:
        return tuple(_frozen(getattr(self, f.name)) for f in fields(self))

    def __eq__(self, other) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())


def constant_alignment_covariance() -> np.ndarray:
    """The original code's fixed measurement covariance diag(0.5 m, 0.5 m, 5 deg)^2, (3, 3)."""
    return np.diag([0.5**2, 0.5**2, math.radians(5.0) ** 2])


def _alignment_process_noise() -> np.ndarray:
    """Drift of T_oi_oj per step, diag(0.1 m, 0.1 m, 0.5 deg)^2, (3, 3) (the original's Q)."""
    return np.diag([0.1**2, 0.1**2, math.radians(0.5) ** 2])


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
            than CLIPPER's 1e-8: the same solutions on our benchmarks, 25 % less time.
        eps: entries of u (and penalties) below this count as zero.
        beta: backtracking factor of the line search, in (0, 1).
        max_outer, max_inner, max_line_search: iteration caps of homotopy, ascent and line search.
        power_iterations: power-method steps that shape the seeded random start vector (each
            costs a full pass over the graph; more than 5 changed no solution we measured).
            These four counts are ints below 2**63 (the compiled solver's int64).
        seed: seed (an int >= 0, any size: numpy's generator takes them all) of the start
            vector; same seed, same graph -> same solution.

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
        for name in ("sigma", "epsilon"):
            value = getattr(self, name)
            _require(_finite(value) and value > 0, o, name, value,
                     "must be a finite number > 0 metres")
        _require(_one_of(self.rounding, ("size", "threshold")), o, "rounding", self.rounding,
                 "must be 'size' or 'threshold'")
        for name in ("threshold", "beta"):
            value = getattr(self, name)
            _require(_real(value) and 0 < value < 1, o, name, value, "must be in (0, 1)")
        for name in ("tol_u", "eps"):
            value = getattr(self, name)
            _require(_real(value) and value > 0, o, name, value, "must be a number > 0")
        # the compiled solver counts in int64; the seed goes to numpy's generator, which takes
        # any int >= 0 (a negative one fails there, at solve time)
        for name, low in (("max_outer", 1), ("max_inner", 1), ("max_line_search", 1),
                          ("power_iterations", 0)):
            value = getattr(self, name)
            _require(_int_at_least(value, low) and value <= _INT64_MAX, o, name, value,
                     f"must be an int in [{low}, 2**63 - 1]")
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
        dim: 2 matches (x, y) centroids (the original's choice), 3 matches full 3D centroids
            (the alignment is then projected onto the gravity-aligned plane).
        clipper: consistency graph and solver settings.
        n_solutions: N of MNO-CLIPPER (Algorithm 1).
        mno_downweight: factor applied to affinities among an earlier solution's associations;
            0 removes those associations, as in the paper.
        min_associations: solutions with fewer associations are discarded.
        max_associations: the most putative associations (nodes of the consistency graph)
            per map pair. When the size gate passes more (large maps of look-alike objects),
            each object of either map keeps only its `pairs_per_object` best pairs, at most
            max_associations of them, and it is logged. It bounds the step's time and memory
            in large maps: the graph costs about m^2 / 2 distance checks.
        pairs_per_object: with more pairs than `max_associations`, the pairs each object of
            either map keeps: those whose objects' surroundings agree best, each within its
            own map (`registration.neighbourhood_agreement`: the distances to their nearest
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
        map_drift: covariance="calibrated": (metres, radians) per square root of a second,
            the random walk of the two robots' odometries relative to each other, which
            distorts each map over its span kappa (half of it on average).
        repeat_inflation: covariance="calibrated": rho of R = R_s + rho R_s Q^-1 R_s, where
            R_s is one registration's covariance and Q the filter's drift per step. With rho
            = 1 an identity-motion Kalman filter fed the same registration every step settles
            at P = R_s; lower values let consecutive registrations share only part of their
            error. 0: no inflation.
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
            while the filter has a rival hypothesis open every step does (1: always).
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
    """

    kappa: float = 20.0
    size_ratio: float = 1.35
    size_abs_diff: float = 0.1
    size_partial: float | None = 2.0
    dim: Literal[2, 3] = 2
    clipper: ClipperParams = field(default_factory=ClipperParams)
    n_solutions: int = 4
    mno_downweight: float = 0.0
    min_associations: int = 5
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
    repeat_inflation: float = 0.5
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
        _require(_real(self.kappa) and self.kappa > 0, o, "kappa", self.kappa,
                 "must be a number > 0 seconds")
        _require(_real(self.size_ratio) and self.size_ratio >= 1, o, "size_ratio",
                 self.size_ratio, "must be a number >= 1")
        _require(_real(self.size_abs_diff) and self.size_abs_diff >= 0, o, "size_abs_diff",
                 self.size_abs_diff, "must be a number >= 0 metres")
        _require(self.size_partial is None or (_finite(self.size_partial)
                                                and self.size_partial >= 1),
                 o, "size_partial", self.size_partial, "must be None or a finite number >= 1")
        _require(_one_of(self.dim, (2, 3)), o, "dim", self.dim, "must be 2 or 3")
        _require(isinstance(self.clipper, ClipperParams), o, "clipper", self.clipper,
                 "must be a ClipperParams")
        _require(_int_at_least(self.n_solutions, 1), o, "n_solutions",
                 self.n_solutions, "must be an int >= 1")
        _require(_real(self.mno_downweight) and 0 <= self.mno_downweight < 1, o,
                 "mno_downweight", self.mno_downweight, "must be in [0, 1)")
        _require(_int_at_least(self.min_associations, 2), o,
                 "min_associations", self.min_associations, "must be an int >= 2")
        _require(_int_at_least(self.max_associations, self.min_associations), o,
                 "max_associations", self.max_associations,
                 f"must be an int >= min_associations ({self.min_associations})")
        _require(_int_at_least(self.pairs_per_object, 1), o, "pairs_per_object",
                 self.pairs_per_object, "must be an int >= 1")
        _require(_real(self.min_score_ratio) and 0 <= self.min_score_ratio <= 1, o,
                 "min_score_ratio", self.min_score_ratio, "must be in [0, 1]")
        _require(_real(self.weight_offset) and self.weight_offset > 0, o, "weight_offset",
                 self.weight_offset, "must be a number > 0 seconds^2")
        _require(self.max_rmse is None or (_real(self.max_rmse) and self.max_rmse > 0), o,
                 "max_rmse", self.max_rmse, "must be a number > 0 metres or None")
        _require(_one_of(self.covariance, ("constant", "residual", "calibrated")), o,
                 "covariance", self.covariance,
                 "must be 'constant', 'residual' or 'calibrated'")
        object.__setattr__(self, "R_constant", _spd(self.R_constant, 3, o, "R_constant"))
        _require(_finite(self.residual_floor) and self.residual_floor > 0, o, "residual_floor",
                 self.residual_floor, "must be a finite number > 0 metres")
        for name in ("residual_prior_dof", "repeat_inflation"):
            value = getattr(self, name)
            _require(_finite(value) and value >= 0, o, name, value,
                     "must be a finite number >= 0")
        drift = _reals(self.map_drift)
        _require(drift is not None and len(drift) == 2
                 and all(math.isfinite(v) and v >= 0 for v in drift), o, "map_drift",
                 self.map_drift, "must be (metres, radians) per square root of a second, two "
                 "finite numbers >= 0")
        object.__setattr__(self, "map_drift", drift)
        if self.repeat_Q is not None:
            object.__setattr__(self, "repeat_Q", _spd(self.repeat_Q, 3, o, "repeat_Q"))
        _require(self.min_inliers is None or _int_at_least(self.min_inliers, 2), o,
                 "min_inliers", self.min_inliers, "must be an int >= 2 or None")
        _require(self.track_min is None or _int_at_least(self.track_min, 2), o,
                 "track_min", self.track_min, "must be an int >= 2 or None")
        _require(isinstance(self.check_ambiguity, bool), o, "check_ambiguity",
                 self.check_ambiguity, "must be True or False")
        for name in ("inlier_radius", "distinct_translation", "distinct_heading",
                     "confirm_translation", "confirm_heading"):
            value = getattr(self, name)
            _require(_finite(value) and value > 0, o, name, value,
                     "must be a finite number > 0")
        _require(_finite(self.min_spread) and self.min_spread >= 0, o, "min_spread",
                 self.min_spread, "must be a finite number >= 0 metres")
        _require(_finite(self.memory_span) and self.memory_span >= 0, o,
                 "memory_span", self.memory_span, "must be a finite number >= 0 seconds")
        _require(_int_at_least(self.memory_searches, 0), o, "memory_searches",
                 self.memory_searches, "must be an int >= 0")
        _require(self.guide_radius is None
                 or (_finite(self.guide_radius) and self.guide_radius > 0), o, "guide_radius",
                 self.guide_radius, "must be a finite number > 0 metres or None")
        _require(_int_at_least(self.full_search_every, 1), o, "full_search_every",
                 self.full_search_every, "must be an int >= 1")
        _require(self.height_epsilon is None
                 or (_finite(self.height_epsilon) and self.height_epsilon > 0), o,
                 "height_epsilon", self.height_epsilon,
                 "must be a finite number > 0 metres or None")
        _require(_finite(self.descriptor_min) and 0 <= self.descriptor_min <= 1, o,
                 "descriptor_min", self.descriptor_min, "must be in [0, 1]")
        for name in ("descriptor_prior", "refit"):
            _require(isinstance(getattr(self, name), bool), o, name, getattr(self, name),
                     "must be True or False")

    @classmethod
    def reference(cls) -> FrameAlignerParams:
        """The authors' released settings, without this project's residual, spread and
        ambiguity checks, with the paper's size gate and with every search full."""
        return cls(max_rmse=None, min_inliers=None, min_spread=0.0, check_ambiguity=False,
                   guide_radius=None, size_partial=None, covariance="constant")

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


@dataclass(frozen=True, eq=False)
class TCAFFParams(_ByValue):
    """Settings of the TCAFF filter (paper, "Multiple Hypothesis Formulation" and "Frame
    Alignment Filter"). The defaults are the paper's equations and values, and among
    look-alike objects (`lookalike_share`) they count distinct evidence (`min_distinct` = 2,
    `switch_stale`, `withhold_contested`): the same look-alikes re-matched at every step are
    one piece of evidence, not W. They accept a hypothesis as soon as its evidence makes the
    paper's decision certain (`sequential`), weigh a measurement by the objects it explains
    (`object_nats`) and recall a dropped hypothesis on its first confirming measurement
    (`recall_for`). `paper()` is the paper's equations alone in every world; `reference()` the
    authors' released code, quirks included.

    The state x has dimension d = Q.shape[0] (3 for (x [m], y [m], theta [rad]) of T_oi_oj);
    motion and measurement models are the identity. Costs are in nats (negative log
    likelihoods); lower is better.

    Attributes:
        window: W, steps a hypothesis is judged over. Each measurement seeds an exploring tree
            that sees the next W steps; the main tree keeps W steps below its root (see
            `root_in_window`).
        max_leaves: B, leaves kept in the main tree.
        max_children: measurement children per main-tree leaf (the best gated ones), besides the
            one no-measurement child every leaf gets.
        explore_max_leaves, explore_max_children: the same for each exploring tree.
        max_measurements: the most measurements taken in one step; beyond it the first ones
            given are kept (`FrameAligner` lists the best score first) and it is logged. Each
            measurement seeds an exploring tree, so the step's cost grows with their number.
        p_no_measurement: p_NM; a no-measurement child costs -log p_NM - d/2 log 2 pi.
        tau: an exploring tree whose best path cost over W steps is below tau becomes the main
            tree when there is none.
        Q: (d, d) process noise per step (random-walk drift of the alignment).
        P0: (d, d) covariance of an exploring tree's root, which is the seeding measurement.
        angle_indices: state components that are angles (residuals and states are wrapped).
        gate: "mahalanobis" admits a measurement when its squared Mahalanobis distance under
            S = P + Q + R is within the chi-square quantile `gate_probability`; "box" when
            every |z_a - x_a| <= gate_box[a] (the original's rule; None is 2.0 for every
            component, as there, radians included).
        cost_model: "paper" is the cost of the paper's final equation with S = P + Q + R;
            "reference" reproduces the released code: squared Mahalanobis distance squared
            again, S = P + R, diagonal-only inverses and determinants, + d/2 log 2 pi on
            measurement children and -log p_NM on no-measurement children.
        root_in_window: False (paper): the main tree's root is the single node W steps back
            and all W steps after it stay open. True (released code): the root is the first
            step of the window, so W - 1 steps stay open.
        promotion: "branch" makes the accepted exploring tree the main tree as it is;
            "reseed" (released code) starts a fresh tree at the accepted tree's first state
            with covariance P0 and replays the window's measurements (one step twice).
        drop_rule, drop_after: the main tree is dropped when its best path has held no
            measurement for `drop_after` steps ("best_path"), or (released code, "window")
            when the best path's whole window has been empty for more than `drop_after`
            consecutive steps.
        switch_after: while a main tree exists, switch to an exploring hypothesis that is
            inconsistent with it (Mahalanobis test at `gate_probability`), below tau, and
            better by `switch_margin` nats for this many consecutive steps. None never re-checks
            (released code).
        switch_margin: nats.
        switch_support: while a main tree exists, also switch to an exploring hypothesis that
            is inconsistent with it, below tau and cheaper, and whose best path was seen at
            least this many more times in the window than the main tree's best path, for
            `switch_after` consecutive steps, whether or not a measurement confirmed the main
            hypothesis at those steps: an early wrong alignment still seen now and then is
            outvoted by the truth seen more often, W + `switch_after` steps after the truth's
            first measurement. The main path's measurements count as they are; a rival's
            count as one when together they bring fewer than two distinct pieces of evidence
            (see `min_distinct`): a look-alike cluster re-matched at every step outvotes
            nothing (one that also matches other objects now and then counts in full). None:
            only the `switch_margin` rule. Like it, acts only with `switch_after` (None never
            re-checks).
        min_distinct: a hypothesis is accepted, or replaces the main one, only when its best
            path over the window holds at least this many distinct pieces of evidence: a
            measurement is distinct when it associates an object of each robot that no earlier
            measurement of the path used (objects named by the `evidence` ids given to
            `TCAFF.update`; a measurement without ids always counts). The same objects matched
            again a second later are one piece of evidence, not W. 1 counts every measurement.
        switch_stale: a main hypothesis confirmed by a measurement this step is not abandoned
            (in a repetitive world a wrong rival can hold a full window while the truth has
            gaps), unless (True) its best path has brought no distinct evidence for W steps:
            then it only re-matches objects it already used.
        withhold_contested: report no estimate while the main tree's best path took no
            measurement this step and a hypothesis it gates out holds more distinct pieces of
            evidence in the window than that path does (and at least `min_distinct`): the
            robots' frames have likely jumped and the old estimate would be wrong until the
            switch, W + `switch_after` steps later. With `switch_support`, also while a
            hypothesis it gates out is seen that many more times in the window (the
            outvoting streak builds), confirmed this step or not. Only at steps given object
            ids (`lookalike_share`).
        lookalike_share: the distinct-evidence rules (`min_distinct`, `switch_stale`,
            `withhold_contested`, `switch_support`) read object ids only at steps whose two
            maps are of look-alikes: `PairwiseAligner` gives ids when at least this share of
            the maps' object pairs pass the aligner's size and descriptor gates
            (`FrameAligner.lookalike_share`). Landmarks without sizes (MRCLAM) give 1; the
            simulator's streets and rooms 0.1-0.6, its grid of crates 0.7-1 (median 0.84);
            a camera's few objects of a small room 0.6-0.92 (median 0.73): the partial-view
            size gate lets many pairs through. At other steps every measurement is distinct
            evidence, so the rules change nothing there and a small static scene is accepted
            as the paper's filter accepts it. 0: ids at every step (and the rules always on).
        report_after: report no estimate once the main tree's best path has held no
            measurement for this many steps, while the tree itself is kept until
            `drop_after`: unreported, it can still be confirmed (`TCAFF.held`), e.g. by the
            aligner's tracking when the robots see shared objects again. None: reported
            until dropped.
        sequential: accept a hypothesis as soon as its evidence makes acceptance certain,
            not only when its exploring tree is W steps old (docs/tcaff.md, "Sequential
            acceptance"). A hypothesis's score is its path cost less its object support
            (`object_nats`); it is accepted once the score plus the cost of W - a further
            steps without a measurement (a its tree's age) is below tau, so that no outcome
            of the remaining steps could keep the paper's rule from accepting it, when its
            path holds `early_measurements` measurements, `min_distinct` distinct pieces of
            evidence and every open hypothesis inconsistent with it scores at least
            `switch_margin` worse. False: only complete trees are judged (the paper).
        object_nats: nats of evidence per object a measurement explains beyond
            `object_base` (negative below it), given by the `objects` of `TCAFF.update`; a
            path's support is that of its best-supported measurement in the window (a
            maximum, not a sum: the same objects matched again a second later add nothing).
            The odds that one more object lands by chance within the aligner's inlier radius
            (0.3 m) of a compatible object under a wrong alignment are about
            density * pi * 0.3^2: e^-2 for 1.5 compatible objects per square metre, more
            than any map of ours holds. Only with `sequential`.
        object_base: objects a measurement must explain to count as plain evidence: the
            paper's minimum number of associations.
        early_measurements: measurements (at different steps, the seed's included) a path
            needs before it is accepted early: at least two, so the hypothesis has been
            seen consistent over time.
        recall_for: steps after a main tree is dropped during which its last estimate
            stays dormant: a measurement within its gate (its covariance grown by Q each
            step) recalls it as the main hypothesis at once, with its id and history,
            unless an open hypothesis inconsistent with it holds more evidence. With the
            default Q, 100 steps grow its standard deviation by 1 m and 5 degrees, the
            bounds of a correct alignment. None: a dropped hypothesis is forgotten.
    """

    window: int = 8
    max_leaves: int = 200
    max_children: int = 4
    explore_max_leaves: int = 50
    explore_max_children: int = 2
    max_measurements: int = 32
    p_no_measurement: float = 0.001
    tau: float = 8.0
    Q: np.ndarray = field(default_factory=_alignment_process_noise)
    P0: np.ndarray = field(default_factory=constant_alignment_covariance)
    angle_indices: tuple[int, ...] = (2,)
    gate: Literal["mahalanobis", "box"] = "mahalanobis"
    gate_probability: float = 0.999
    gate_box: tuple[float, ...] | None = None
    cost_model: Literal["paper", "reference"] = "paper"
    root_in_window: bool = False
    promotion: Literal["branch", "reseed"] = "branch"
    drop_rule: Literal["best_path", "window"] = "best_path"
    drop_after: int = 40
    switch_after: int | None = 3
    switch_margin: float = 5.0
    switch_support: int | None = 2
    min_distinct: int = 2
    switch_stale: bool = True
    withhold_contested: bool = True
    lookalike_share: float = 0.9
    report_after: int | None = None
    sequential: bool = True
    object_nats: float = 2.0
    object_base: int = 5
    early_measurements: int = 2
    recall_for: int | None = 100

    def __post_init__(self) -> None:
        o = "TCAFFParams"
        Q = _spd(self.Q, None, o, "Q")
        d = Q.shape[0]
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "P0", _spd(self.P0, d, o, "P0"))
        for name, low in (("window", 1), ("max_leaves", 1), ("max_children", 1),
                          ("explore_max_leaves", 1), ("explore_max_children", 1),
                          ("max_measurements", 1),
                          ("drop_after", 1)):
            value = getattr(self, name)
            _require(_int_at_least(value, low), o, name, value, f"must be an int >= {low}")
        for name in ("p_no_measurement", "gate_probability"):
            value = getattr(self, name)
            _require(_real(value) and 0 < value < 1, o, name, value, "must be in (0, 1)")
        _require(_real(self.tau) and math.isfinite(self.tau), o, "tau", self.tau,
                 "must be a finite number (nats)")
        angles = self.angle_indices
        if isinstance(angles, np.ndarray) and angles.ndim == 1:
            angles = angles.tolist()
        ok = (isinstance(angles, (tuple, list))
              and all(_int_at_least(a, 0) and a < d for a in angles)
              and len(set(angles)) == len(angles))
        _require(ok, o, "angle_indices", self.angle_indices, f"must be distinct ints in [0, {d})")
        object.__setattr__(self, "angle_indices", tuple(int(a) for a in angles))
        _require(_one_of(self.gate, ("mahalanobis", "box")), o, "gate", self.gate,
                 "must be 'mahalanobis' or 'box'")
        box = (2.0,) * d if self.gate_box is None else _reals(self.gate_box)
        _require(box is not None and len(box) == d and all(v > 0 for v in box), o, "gate_box",
                 self.gate_box, f"must hold {d} numbers > 0, or be None")
        object.__setattr__(self, "gate_box", box)
        _require(_one_of(self.cost_model, ("paper", "reference")), o, "cost_model",
                 self.cost_model, "must be 'paper' or 'reference'")
        _require(isinstance(self.root_in_window, bool), o, "root_in_window",
                 self.root_in_window, "must be True or False")
        _require(_one_of(self.promotion, ("branch", "reseed")), o, "promotion", self.promotion,
                 "must be 'branch' or 'reseed'")
        _require(_one_of(self.drop_rule, ("best_path", "window")), o, "drop_rule",
                 self.drop_rule, "must be 'best_path' or 'window'")
        _require(self.switch_after is None or _int_at_least(self.switch_after, 1), o,
                 "switch_after", self.switch_after, "must be an int >= 1 or None")
        _require(_finite(self.switch_margin) and self.switch_margin >= 0, o,
                 "switch_margin", self.switch_margin, "must be a finite number >= 0 (nats)")
        _require(_int_at_least(self.min_distinct, 1), o, "min_distinct", self.min_distinct,
                 "must be an int >= 1")
        _require(self.switch_support is None or _int_at_least(self.switch_support, 1), o,
                 "switch_support", self.switch_support, "must be an int >= 1 or None")
        _require(isinstance(self.switch_stale, bool), o, "switch_stale", self.switch_stale,
                 "must be True or False")
        _require(isinstance(self.withhold_contested, bool), o, "withhold_contested",
                 self.withhold_contested, "must be True or False")
        _require(_real(self.lookalike_share) and 0 <= self.lookalike_share <= 1, o,
                 "lookalike_share", self.lookalike_share, "must be a number in [0, 1]")
        _require(self.report_after is None or _int_at_least(self.report_after, 1), o,
                 "report_after", self.report_after, "must be an int >= 1 or None")
        _require(isinstance(self.sequential, bool), o, "sequential", self.sequential,
                 "must be True or False")
        # the released code's promotion replays a full window, which a young tree has not
        _require(not (self.sequential and self.promotion == "reseed"), o, "sequential",
                 self.sequential, "must be False with promotion='reseed'")
        _require(_finite(self.object_nats) and self.object_nats >= 0, o, "object_nats",
                 self.object_nats, "must be a finite number >= 0 (nats)")
        _require(_int_at_least(self.object_base, 0), o, "object_base", self.object_base,
                 "must be an int >= 0")
        _require(_int_at_least(self.early_measurements, 2), o, "early_measurements",
                 self.early_measurements, "must be an int >= 2")
        _require(self.recall_for is None or _int_at_least(self.recall_for, 1), o,
                 "recall_for", self.recall_for, "must be an int >= 1 or None")

    @property
    def dim(self) -> int:
        """d, the dimension of the state and of every measurement."""
        return self.Q.shape[0]

    @property
    def counts_evidence(self) -> bool:
        """Whether the filter reads the object evidence given to `update`."""
        return (self.min_distinct > 1 or self.switch_stale or self.withhold_contested
                or self.switch_support is not None)

    @classmethod
    def paper(cls) -> TCAFFParams:
        """The paper's equations alone: every measurement counts as evidence, and a main
        hypothesis confirmed at a step is never abandoned at that step."""
        return cls(min_distinct=1, switch_stale=False, withhold_contested=False,
                   switch_support=None, sequential=False, recall_for=None)

    @classmethod
    def reference(cls) -> TCAFFParams:
        """The authors' released code: its threshold, gate, cost, promotion and deletion."""
        return cls(tau=9.0, gate="box", cost_model="reference", root_in_window=True,
                   promotion="reseed", drop_rule="window", drop_after=40, switch_after=None,
                   switch_support=None, min_distinct=1, switch_stale=False,
                   withhold_contested=False, sequential=False, recall_for=None)


def _default_odometry_cov(dim: int) -> np.ndarray:
    deg = math.radians(1.0)
    if dim == 2:
        return np.diag([0.05**2, 0.05**2, deg**2])
    return np.diag([(0.5 * deg) ** 2, (0.5 * deg) ** 2, deg**2, 0.05**2, 0.05**2, 0.05**2])


@dataclass(frozen=True, eq=False)
class GraphParams(_ByValue):
    """Settings of `InterRobotGraph` (iSAM2 smoothing of frame alignments and trajectories).

    Attributes:
        dim: 2 for Pose2 (planar robots), 3 for Pose3 with gravity-aligned alignments
            (x, y, z, yaw).
        Q: drift of one pair's alignment per step, the covariance of (x, y, theta) (dim 2,
            (3, 3)) or (x, y, z, yaw) (dim 3, (4, 4)). Each robot's chain gets Q / 2, so the
            relative drift of two robots is Q, as TCAFF assumes. None: TCAFF's default Q
            (z drifting like x and y in 3D).
        robust: M-estimator of the alignment factors: "huber", "cauchy" or "none" (Gaussian).
        robust_k: its threshold, in standard deviations of the whitened residual.
        anchor_sigma: metres and radians; prior on robot 0's first alignment and keyframe.
        free_sigmas: (metres, radians) of the prior that fixes the gauge of robots (or
            groups of robots) not connected to robot 0 by any factor. It is placed on their
            latest variable at its current value and removed as soon as they connect, so it
            never biases an alignment.
        gravity_sigma: radians, roll and pitch uncertainty of a 3D alignment factor.
        odometry_cov: covariance of the odometry between consecutive keyframes in gtsam's
            tangent order ((vx, vy, omega) for Pose2; (wx, wy, wz, vx, vy, vz), rotation first,
            for Pose3). None: 5 cm and 1 deg (0.5 deg roll and pitch) per keyframe.
        relinearize_threshold, relinearize_skip: iSAM2's relinearisation settings. 0.05
            rather than 0.01: with 12 alignments per step, 0.01 kept relinearising old
            alignment variables as smoothing moved them and the update time grew tenfold
            over an hour of steps; noise-free alignments still come out exact.
        max_iterations, settle_threshold: extra iSAM2 iterations, at most `max_iterations`,
            run while a variable the update touched is more than `settle_threshold` (metres or
            radians, tangent) from its linearisation point: big corrections such as a first
            alignment or a removed hypothesis are nonlinear.
        switch_hold: when TCAFF switches a pair to a hypothesis that disagrees with the graph,
            the earlier hypothesis's factors are removed only once the new one has been
            reported at this many steps (the default window W): a late or passing switch then
            leaves the smoothed history in place. 1 removes them at the switch.
        horizon: steps the graph keeps for long runs: `update(k)` marginalises the variables
            of the steps at or before k - horizon (alignment variables, and the keyframes
            committed with those steps) into a linear factor on what they were linked to, one
            step per update, so memory and update time stay bounded. Steps that left keep the
            estimate they had then, and the covariance they had as the latest step; keyframes
            keep their last pose. Factors that left can no longer be removed (a hypothesis
            switch removes only those within the horizon). None keeps every step (offline
            studies).
    """

    dim: Literal[2, 3] = 2
    Q: np.ndarray | None = None
    robust: Literal["huber", "cauchy", "none"] = "huber"
    robust_k: float = 1.345
    anchor_sigma: float = 1e-3
    free_sigmas: tuple[float, float] = (1.0, 1.0)
    gravity_sigma: float = 1e-3
    odometry_cov: np.ndarray | None = None
    relinearize_threshold: float = 0.05
    relinearize_skip: int = 1
    max_iterations: int = 10
    settle_threshold: float = 0.5
    switch_hold: int = TCAFFParams.window
    horizon: int | None = None

    def __post_init__(self) -> None:
        o = "GraphParams"
        _require(_one_of(self.dim, (2, 3)), o, "dim", self.dim, "must be 2 or 3")
        n_param = 3 if self.dim == 2 else 4
        if self.Q is None:
            q = np.diag(_alignment_process_noise())
            Q = np.diag(q if self.dim == 2 else [q[0], q[1], q[0], q[2]])
        else:
            Q = _spd(self.Q, n_param, o, "Q")
        object.__setattr__(self, "Q", Q)
        odo = (_default_odometry_cov(self.dim) if self.odometry_cov is None
               else _spd(self.odometry_cov, 3 if self.dim == 2 else 6, o, "odometry_cov"))
        object.__setattr__(self, "odometry_cov", odo)
        _require(_one_of(self.robust, ("huber", "cauchy", "none")), o, "robust", self.robust,
                 "must be 'huber', 'cauchy' or 'none'")
        for name in ("robust_k", "anchor_sigma", "gravity_sigma", "relinearize_threshold",
                     "settle_threshold"):
            value = getattr(self, name)
            _require(_real(value) and math.isfinite(value) and value > 0, o,
                     name, value, "must be a finite number > 0")
        sig = _reals(self.free_sigmas)
        _require(sig is not None and len(sig) == 2 and all(0 < v < math.inf for v in sig), o,
                 "free_sigmas", self.free_sigmas, "must be (metres, radians), finite and > 0")
        object.__setattr__(self, "free_sigmas", sig)
        _require(_int_at_least(self.relinearize_skip, 1), o, "relinearize_skip",
                 self.relinearize_skip, "must be an int >= 1")
        _require(_int_at_least(self.max_iterations, 0), o, "max_iterations",
                 self.max_iterations, "must be an int >= 0")
        _require(_int_at_least(self.switch_hold, 1), o, "switch_hold", self.switch_hold,
                 "must be an int >= 1")
        _require(self.horizon is None or _int_at_least(self.horizon, 2), o, "horizon",
                 self.horizon, "must be an int >= 2 (steps) or None")
