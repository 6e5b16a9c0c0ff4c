"""Maps that fit themselves: an alignment's twins, and a covariance that covers them.

A map of few objects can fit itself. Moved by a rigid motion S of its robot's odometry frame,
the objects a candidate registers land on other objects of the same map: MRCLAM's landmarks
stand in twos and threes, and six of them in a near-equilateral triangle fit themselves
turned by about 120 deg. Then S o x (S a motion of the ego's map) or x o S^-1 (of the
other's) explains those objects as alignment x does: a twin of x. Where the robot's map has fitted
itself so at each of the last W + 1 steps, time has not told the twin from the estimate either,
and the covariance the estimate reports covers both (`Twins`). docs/repetitive-worlds.md,
"A covariance that covers the twins".
"""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numba
import numpy as np

from .association import size_gates
from .errors import DataError
from .frame_aligner import AlignmentMeasurement, _alignment
from .geometry import _se2_from_params, _se2_to_params, _wrap_angle, invert
from .inputs import check_within, finite_time, kernel_array, point_array, real_array, shown
from .object_map import ObjectMap, as_object_map
from .param_checks import MAX_COORDINATE, MAX_VARIANCE, _finite
from .params import FrameAlignerParams, _require
from .tcaff import AlignmentEstimate

__all__ = ["Twins", "covering", "map_motions", "self_fit", "self_motions"]


#: the most motions `self_motions` returns: a set fits its map under a handful of them at most
MAX_MOTIONS = 64


def self_motions(points: np.ndarray, recent: np.ndarray, gate: np.ndarray, radius: float,
                 distinct: tuple[float, float]) -> np.ndarray:
    """The rigid motions under which a set of objects fits its own map.

    Args:
        points: (k, 2) the set's centroids (m, in the robot's odometry frame).
        recent: (n, 2) the map's centroids, in the same frame.
        gate: (k, n) bool, which of the map's objects each of the set's may land on (the
            aligner's size gate).
        radius: metres (`inlier_radius`): how near an object must land.
        distinct: (metres, radians): how far from the identity, and from each other, the
            motions must be (`distinct_translation`, `distinct_heading`).
    Returns:
        (m, 3) motions S (x [m], y [m], theta [rad]), at most `MAX_MOTIONS`, with every point
        of the set within `radius` of a map object it may be, each refined by least squares
        on the objects it lands on (twice: landed again after the first); (0, 3) when none,
        or when the set has fewer than two points or spans less than 2 `radius` (no heading
        to fit). The set's two farthest objects are tried onto every ordered pair of the
        map's objects about as far apart.
    Raises:
        DataError: points or recent not (k, 2) finite points within `MAX_COORDINATE`, a gate
            not (k, n) bool, radius not a finite number > 0, distinct not two finite numbers
            >= 0.
    """
    o = "self_motions"
    points, recent = point_array(o, "points", points, 2), point_array(o, "recent", recent, 2)
    gate = _gate(o, gate, (len(points), len(recent)))
    return _motions_of(points, recent, gate, _radius(o, radius), _distinct(o, distinct))


def _motions_of(points: np.ndarray, recent: np.ndarray, gate: np.ndarray, radius: float,
                distinct: tuple[float, float]) -> np.ndarray:
    """`self_motions` on checked arguments."""
    out = np.empty((MAX_MOTIONS, 3))
    found = _self_motions(kernel_array(points, np.float64), kernel_array(recent, np.float64),
                          kernel_array(gate, np.bool_), float(radius), float(distinct[0]),
                          float(distinct[1]), out)
    return out[:found].copy()


@numba.njit(cache=True)
def _self_motions(points, recent, gate, radius, distinct_t, distinct_h, out):
    """`self_motions` into out (MAX_MOTIONS, 3); returns how many."""
    k, n = points.shape[0], recent.shape[0]
    if k < 2 or n < 2:
        return 0
    a, b, span = 0, 1, -1.0
    for i in range(k):
        for j in range(i + 1, k):
            dist = math.hypot(points[j, 0] - points[i, 0], points[j, 1] - points[i, 1])
            if dist > span:
                a, b, span = i, j, dist
    if span < 2.0 * radius:
        return 0
    cx, cy = 0.0, 0.0
    for i in range(k):
        cx += points[i, 0] / k
        cy += points[i, 1] / k
    mid_x, mid_y = (points[a, 0] + points[b, 0]) / 2.0, (points[a, 1] + points[b, 1]) / 2.0
    heading_ab = math.atan2(points[b, 1] - points[a, 1], points[b, 0] - points[a, 0])
    landed = np.empty(k, np.int64)
    images = np.empty((out.shape[0], 2))  # where each motion found takes the set's centroid
    r2 = radius * radius
    found = 0
    for c in range(n):
        if not gate[a, c]:
            continue
        for d in range(n):
            if d == c or not gate[b, d]:
                continue
            vx, vy = recent[d, 0] - recent[c, 0], recent[d, 1] - recent[c, 1]
            if abs(math.hypot(vx, vy) - span) > 2.0 * radius:
                continue
            theta = _wrapped(math.atan2(vy, vx) - heading_ab)
            cos, sin = math.cos(theta), math.sin(theta)
            tx = (recent[c, 0] + recent[d, 0]) / 2.0 - (cos * mid_x - sin * mid_y)
            ty = (recent[c, 1] + recent[d, 1]) / 2.0 - (sin * mid_x + cos * mid_y)
            # the identity, and the set's objects onto their own neighbours, are no twin: how
            # far the set's centroid moves, not the frame's origin (a small turn moves an
            # origin far from the objects a long way)
            if (math.hypot(cos * cx - sin * cy + tx - cx, sin * cx + cos * cy + ty - cy)
                    <= distinct_t and abs(theta) <= distinct_h):
                continue
            fits = True
            for i in range(k):
                px = cos * points[i, 0] - sin * points[i, 1] + tx
                py = sin * points[i, 0] + cos * points[i, 1] + ty
                best, at = np.inf, -1
                for j in range(n):
                    if gate[i, j]:
                        dist2 = (recent[j, 0] - px) ** 2 + (recent[j, 1] - py) ** 2
                        if dist2 < best:
                            best, at = dist2, j
                if best > r2:
                    fits = False
                    break
                landed[i] = at
            if not fits:
                continue
            # refined: the planar least-squares turn of the set onto where it lands, twice
            # (landed again under the first refinement: a cluster's objects may swap)
            within = True
            for _ in range(2):
                qx, qy = 0.0, 0.0
                for i in range(k):
                    qx += recent[landed[i], 0] / k
                    qy += recent[landed[i], 1] / k
                cross, dot = 0.0, 0.0
                for i in range(k):
                    ux, uy = points[i, 0] - cx, points[i, 1] - cy
                    wx, wy = recent[landed[i], 0] - qx, recent[landed[i], 1] - qy
                    cross += ux * wy - uy * wx
                    dot += ux * wx + uy * wy
                turn = math.atan2(cross, dot)
                cos, sin = math.cos(turn), math.sin(turn)
                sx, sy = qx - (cos * cx - sin * cy), qy - (sin * cx + cos * cy)
                within = True
                for i in range(k):
                    px = cos * points[i, 0] - sin * points[i, 1] + sx
                    py = sin * points[i, 0] + cos * points[i, 1] + sy
                    best = np.inf
                    for j in range(n):
                        if gate[i, j]:
                            dist2 = (recent[j, 0] - px) ** 2 + (recent[j, 1] - py) ** 2
                            if dist2 < best:
                                best, landed[i] = dist2, j
                    within = within and best <= r2
            # refined, every object must still land within the radius
            if not within:
                continue
            # distinct from the identity and from each other by where the set's centroid goes
            # (the refined motion takes it to (qx, qy))
            new = not (math.hypot(qx - cx, qy - cy) <= distinct_t and abs(turn) <= distinct_h)
            for h in range(found):
                if not new:
                    break
                if (math.hypot(qx - images[h, 0], qy - images[h, 1]) <= distinct_t
                        and abs(_wrapped(turn - out[h, 2])) <= distinct_h):
                    new = False
            if new:
                out[found, 0], out[found, 1], out[found, 2] = sx, sy, turn
                images[found, 0], images[found, 1] = qx, qy
                found += 1
                if found == out.shape[0]:
                    return found
    return found


@numba.njit(cache=True)
def _wrapped(angle):
    """angle (rad) wrapped to [-pi, pi)."""
    wrapped = (angle + math.pi) % (2.0 * math.pi) - math.pi
    return wrapped - 2.0 * math.pi if wrapped >= math.pi else wrapped


def self_fit(S: np.ndarray, recent: np.ndarray, gate: np.ndarray, radius: float) -> int:
    """How many objects of a map land within `radius` of another object of the same map (one
    `gate` lets them be, (n, n) bool) when moved by S (3,): (n, 2) centroids.

    Raises:
        DataError: S not three finite numbers, recent not (n, 2) finite points, gate not
            (n, n) bool, radius not a finite number > 0.
    """
    o = "self_fit"
    S, recent = _alignment(o, "S", S), point_array(o, "recent", recent, 2)
    return _fit(S, recent, _gate(o, gate, (len(recent), len(recent))), _radius(o, radius))


def _fit(S: np.ndarray, recent: np.ndarray, gate: np.ndarray, radius: float) -> int:
    """`self_fit` on checked arguments."""
    if len(recent) < 2:
        return 0
    T = _se2_from_params(S)
    moved = recent @ T[:2, :2].T + T[:2, 2]
    dist = np.where(gate, np.linalg.norm(moved[:, None] - recent[None], axis=2), np.inf)
    np.fill_diagonal(dist, np.inf)
    return int(np.count_nonzero(dist.min(axis=1) <= radius))


def covering(P: np.ndarray, x: np.ndarray, twins: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(3, 3) P + sum_k (R + d_k d_k') / (m + 1), d_k = twins[k] - x with its heading wrapped:
    the second moment about x (3,) of an equal mixture of the estimate (x, P) and its m twins
    (m, 3), each as uncertain as one registration (R, (3, 3)), with the estimate's own P kept
    whole rather than weighted by 1 / (m + 1), so never narrower than P.

    Raises:
        DataError: P or R not (3, 3) finite within `MAX_VARIANCE`, x not three finite numbers,
            twins not (m, 3) finite numbers within `MAX_COORDINATE`.
    """
    o = "covering"
    P, R = _covariance(o, "P", P), _covariance(o, "R", R)
    x = _alignment(o, "x", x)
    twins = real_array(o, "twins", twins)
    if twins.ndim != 2 or twins.shape[1] != 3:
        raise DataError(f"{o}: twins must be (m, 3) alignments, got shape {twins.shape}")
    check_within(o, "twins", twins, MAX_COORDINATE, "m")
    return _covering(P, x, twins, R)


def _covering(P: np.ndarray, x: np.ndarray, twins: np.ndarray, R: np.ndarray) -> np.ndarray:
    """`covering` on checked arguments."""
    d = twins - x
    d[:, 2] = _wrap_angle(d[:, 2])
    return P + (len(twins) * R + d.T @ d) / (len(twins) + 1)


def map_motions(m: AlignmentMeasurement, ego_map: ObjectMap, other_map: ObjectMap, now: float,
                params: FrameAlignerParams) -> list[tuple[int, np.ndarray]]:
    """(robot, S) for each motion S under which the objects candidate m associates fit their
    robot's recent map (robot 0 the ego, 1 the other; `self_motions` with the aligner's size
    gate, `inlier_radius`, `distinct_translation` and `distinct_heading`), the maps as m was
    registered on at time `now` (s).

    Raises:
        DataError: m not an AlignmentMeasurement, a map not an ObjectMap, one m's
            associations index beyond, now not a finite number; ConfigError: params not a
            FrameAlignerParams.
    """
    o = "map_motions"
    _require(isinstance(params, FrameAlignerParams), o, "params", params,
             "must be a FrameAlignerParams")
    if not isinstance(m, AlignmentMeasurement):
        raise DataError(f"{o}: m must be an AlignmentMeasurement, got {shown(m)}")
    maps = (as_object_map(o, "ego_map", ego_map), as_object_map(o, "other_map", other_map))
    _check_associations(o, m, maps)
    now = finite_time(o, "now", now)
    return _map_motions(m, tuple(_Seen(objects, now, params) for objects in maps), params)


def _check_associations(owner: str, m: AlignmentMeasurement, maps: tuple) -> None:
    for robot, (name, objects) in enumerate(zip(("ego_map", "other_map"), maps, strict=True)):
        if len(m.associations) and int(m.associations[:, robot].max()) >= len(objects):
            raise DataError(f"{owner}: m associates object {int(m.associations[:, robot].max())} "
                            f"of {name}, which holds {len(objects)}")


def _map_motions(m: AlignmentMeasurement, seen: tuple[_Seen, _Seen],
                 params: FrameAlignerParams) -> list[tuple[int, np.ndarray]]:
    """`map_motions` on checked arguments, each robot's map as `_Seen`."""
    out = []
    for robot, map_seen in enumerate(seen):
        idx = m.associations[:, robot]
        objects = map_seen.objects
        gate = size_gates(objects.subset(idx), map_seen.recent, params.size_ratio,
                          params.size_abs_diff)[0]
        out += [(robot, S) for S in _motions_of(
            objects.centroids[idx, :2], map_seen.points, gate, params.inlier_radius,
            (params.distinct_translation, params.distinct_heading))]
    return out


class _Seen:
    """One robot's map at one step: its objects seen within kappa, taken when first asked for
    (most steps never ask), and their size gate against each other."""

    def __init__(self, objects: ObjectMap, now: float, params: FrameAlignerParams) -> None:
        self.objects, self.params = objects, params
        self.index = objects.recent_indices(now, params.kappa)

    @functools.cached_property
    def recent(self) -> ObjectMap:
        return self.objects.subset(self.index)

    @functools.cached_property
    def points(self) -> np.ndarray:
        return self.recent.centroids[:, :2]

    @functools.cached_property
    def gate(self) -> np.ndarray:
        """(n, n) the size gate of the recent objects against each other."""
        return size_gates(self.recent, self.recent, self.params.size_ratio,
                          self.params.size_abs_diff)[0]


class Twins:
    """The twins of one pair's estimate, and the covariance that covers them.

    At each step the estimate took a measurement, the motions under which the objects that
    measurement associates fit their own robot's recent map (`map_motions`); they stay the
    estimate's while it holds that hypothesis without measurements. A motion counts where
    that robot's map, at each of the last W + 1 steps at which it held recent objects (this
    one included), has at least as many objects landing on others under it as the
    measurement associates (`self_fit`): the symmetry has lasted the window the filter judged
    the alignment on. The estimate is returned with its covariance widened to cover the twins
    of the motions that count (`covering`, R the measurement's), otherwise as it is; and as it
    is wherever the aligner's covariance is not "calibrated" (the original's constant R, the
    bare residual one), whose P claims no more than its R.
    """

    def __init__(self, params: FrameAlignerParams, window: int) -> None:
        """For a pair of `params` (its `kappa`, size gate, `inlier_radius`,
        `distinct_translation` and `distinct_heading`) and a filter of window W.

        Raises:
            ConfigError: params not a FrameAlignerParams, window not an int >= 1.
        """
        _require(isinstance(params, FrameAlignerParams), "Twins", "params", params,
                 "must be a FrameAlignerParams")
        _require(isinstance(window, int | np.integer) and not isinstance(window, bool)
                 and window >= 1, "Twins", "window", window, "must be an int >= 1")
        self.params = params
        self.window = int(window)
        #: whether it widens anything: the aligner's covariance is "calibrated"
        self.applies = params.covariance == "calibrated"
        #: per robot (ego, other), its maps of the last W + 1 steps with recent objects
        self.seen: tuple[tuple[_Seen, ...], tuple[_Seen, ...]] = ((), ())
        #: (hypothesis, [(robot, S)], R, associations) of the estimate's last measurement
        self.found: tuple[int, list[tuple[int, np.ndarray]], np.ndarray, int] | None = None

    def update(self, estimate: AlignmentEstimate | None, taken: list[AlignmentMeasurement],
               ego_map: ObjectMap, other_map: ObjectMap, now: float
               ) -> AlignmentEstimate | None:
        """The step's estimate, its covariance covering the twins that count.

        Args:
            estimate: the filter's estimate of this step (None: none).
            taken: the measurements the filter was given (`estimate.measurement` indexes it).
            ego_map, other_map: the maps of the step, as aligned; now: seconds, their clock.
        Raises:
            DataError: estimate neither an AlignmentEstimate of (x, y, theta) nor None, taken
                not a list of AlignmentMeasurement holding the estimate's measurement, a map
                not an ObjectMap or one the measurement does not index, now not a finite
                number. A call that raises leaves the twins as they were.
        """
        o = "Twins.update"
        if estimate is not None and not (
                isinstance(estimate, AlignmentEstimate)
                and isinstance(estimate.measurement, int | np.integer)
                and not isinstance(estimate.measurement, bool)
                and np.shape(estimate.x) == (3,) and np.shape(estimate.P) == (3, 3)
                and np.isfinite(estimate.x).all() and np.isfinite(estimate.P).all()):
            raise DataError(f"{o}: estimate must be an AlignmentEstimate of finite (x, y, "
                            f"theta), (3, 3) P and an int measurement, or None, got "
                            f"{shown(estimate)}")
        if not isinstance(taken, list | tuple) or not all(
                isinstance(m, AlignmentMeasurement) for m in taken):
            raise DataError(f"{o}: taken must be a list of AlignmentMeasurement, got "
                            f"{shown(taken)}")
        if estimate is not None and estimate.measurement >= len(taken):
            raise DataError(f"{o}: the estimate took measurement {estimate.measurement} of "
                            f"the {len(taken)} taken")
        maps = (as_object_map(o, "ego_map", ego_map), as_object_map(o, "other_map", other_map))
        if estimate is not None and estimate.measurement >= 0:
            _check_associations(o, taken[estimate.measurement], maps)
        now = finite_time(o, "now", now)
        if not self.applies:
            return estimate
        prm = self.params
        now_seen = tuple(_Seen(objects, now, prm) for objects in maps)
        found = self.found
        if estimate is None or (found is not None and found[0] != estimate.hypothesis):
            found = None
        if estimate is not None and estimate.measurement >= 0:
            m = taken[estimate.measurement]
            found = (estimate.hypothesis, _map_motions(m, now_seen, prm), m.R,
                     len(m.associations))
        seen = tuple((*before, new)[-(self.window + 1):] if len(new.index) else before
                     for before, new in zip(self.seen, now_seen, strict=True))
        reported = estimate
        if estimate is not None and found is not None and found[1]:
            _, motions, R, k = found
            twins = np.array([_twin(S, robot, estimate.x) for robot, S in motions
                              if self._lasted(seen[robot], S, k)]).reshape(-1, 3)
            # a twin beyond the coordinates an estimate may hold is no alignment to cover
            twins = twins[(np.abs(twins[:, :2]) <= MAX_COORDINATE).all(axis=1)]
            if len(twins):
                reported = replace(estimate, P=_covering(estimate.P, estimate.x, twins, R))
        # nothing above raises on checked input; the step counts only now
        self.seen, self.found = seen, found
        return reported

    def _lasted(self, seen: tuple[_Seen, ...], S: np.ndarray, k: int) -> bool:
        """Whether each of a robot's last W + 1 maps (`seen`) fits itself under S with at least
        k objects landing on others."""
        prm = self.params
        return len(seen) == self.window + 1 and all(
            _fit(S, r.points, r.gate, prm.inlier_radius) >= k for r in seen)


def _twin(S: np.ndarray, robot: int, x: np.ndarray) -> np.ndarray:
    """The twin of alignment x (3,) under motion S (3,) of the ego's map (robot 0: S o x, which
    pairs S e_k with o_k) or of the other's (robot 1: x o S^-1, which pairs e_k with S o_k)."""
    T_S, T_x = _se2_from_params(S), _se2_from_params(x)
    return _se2_to_params(T_S @ T_x if robot == 0 else T_x @ invert(T_S))



def _gate(owner: str, gate, shape: tuple[int, int]) -> np.ndarray:
    gate = np.asarray(gate)
    if gate.dtype != np.bool_ or gate.shape != shape:
        raise DataError(f"{owner}: gate must be a {shape} bool array, got {shown(gate)}")
    return gate


def _radius(owner: str, radius) -> float:
    if not (_finite(radius) and radius > 0):
        raise DataError(f"{owner}: radius must be a finite number > 0 metres, got "
                        f"{shown(radius)}")
    return float(radius)


def _distinct(owner: str, distinct) -> tuple[float, float]:
    if not (isinstance(distinct, tuple | list) and len(distinct) == 2
            and all(_finite(v) and v >= 0 for v in distinct)):
        raise DataError(f"{owner}: distinct must be (metres, radians), two finite numbers "
                        f">= 0, got {shown(distinct)}")
    return float(distinct[0]), float(distinct[1])


def _covariance(owner: str, name: str, value) -> np.ndarray:
    arr = real_array(owner, name, value)
    if arr.shape != (3, 3):
        raise DataError(f"{owner}: {name} must be a (3, 3) covariance, got shape {arr.shape}")
    check_within(owner, name, arr, MAX_VARIANCE)
    return arr
