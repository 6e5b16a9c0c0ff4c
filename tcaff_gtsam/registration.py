"""Weighted Arun registration (Arun 1987, Umeyama) of associated points, its residual, the objects
an alignment explains (mutual inliers) and their spread. The putative associations and their
ranking are in `association`, whose public names are re-exported here."""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.spatial import cKDTree

from .association import neighbourhood_agreement, putative_associations  # re-exported
from .errors import DataError
from .geometry import _transform_points
from .inputs import kernel_array, point_array, real_array, shown
from .param_checks import MAX_COORDINATE
from .params import _finite, _require

__all__ = [
    "arun_weights",
    "mutual_inliers",
    "neighbourhood_agreement",
    "putative_associations",
    "registration_rmse",
    "spread",
    "weighted_arun",
]

#: the largest Arun weight; with coordinates within MAX_COORDINATE no weighted sum overflows
MAX_WEIGHT = 1e100
#: object pairs above which mutual inliers are found with k-d trees: the dense distance matrix
#: costs 8 bytes per pair, several times over in temporaries
_DENSE_INLIERS = 1 << 20


def arun_weights(ages_ego: np.ndarray, ages_other: np.ndarray, offset: float = 0.01) -> np.ndarray:
    """Per-association weights 1 / (offset + age_i * age_j): recently seen objects count more.

    The paper weights by (l_i l_j)^-1; the offset keeps objects seen just now finite.

    Args:
        ages_ego, ages_other: (k,) seconds, finite and >= 0 (any shape, the same for both).
        offset: seconds^2, a finite number > 0.
    Raises:
        ConfigError: offset not a finite number > 0.
        DataError: ages not real, of different shapes, negative or not finite.
    """
    o = "arun_weights"
    _require(_finite(offset) and offset > 0, o, "offset", offset,
             "must be a finite number > 0 seconds^2")
    a = real_array(o, "ages_ego", ages_ego)
    b = real_array(o, "ages_other", ages_other)
    if a.shape != b.shape:
        raise DataError(f"{o}: ages_ego and ages_other must have the same shape, got "
                        f"{a.shape} and {b.shape}")
    for name, ages in (("ages_ego", a), ("ages_other", b)):
        bad = ~((ages >= 0) & (ages < math.inf))  # NaN fails both
        if bad.any():
            raise DataError(f"{o}: {name} must be finite numbers >= 0 seconds, got "
                            f"{ages[bad].flat[0]}")
    with np.errstate(over="ignore"):  # ages whose product overflows weigh 0, their limit
        return _weights(a * b, offset)


def _weights(age_products: np.ndarray, offset: float) -> np.ndarray:
    """`arun_weights` from age_i * age_j, for callers whose ages are a map's (valid by
    construction of the ObjectMap) and offset a validated parameter."""
    return 1.0 / (offset + age_products)


def weighted_arun(p: np.ndarray, q: np.ndarray, weights: np.ndarray | None = None
                  ) -> np.ndarray | None:
    """Least-squares rigid transform T_a_b with p_k ~ T_a_b q_k, weighted (2D or 3D).

    Minimises sum_k w_k |p_k - (R q_k + t)|^2 over rotations R (det = +1, so a mirror image is
    never returned) and translations t.

    Args:
        p: (k, d) points in frame a, d = 2 or 3.
        q: (k, d) corresponding points in frame b.
        weights: (k,) non-negative weights; None means all ones.

    Returns:
        (d+1, d+1) homogeneous T_a_b, or None when the set is degenerate: fewer than d points
        with positive weight, all points coincident, or (3D) all points on one line.
    Raises:
        DataError: mismatched shapes, d not 2 or 3, values that are not real numbers,
            non-finite values, negative weights, coordinates beyond `MAX_COORDINATE` metres
            or weights beyond `MAX_WEIGHT` (where the weighted sums could overflow).
    """
    o = "weighted_arun"
    p = real_array(o, "p", p)
    q = real_array(o, "q", q)
    if p.ndim != 2 or p.shape != q.shape or p.shape[1] not in (2, 3):
        raise DataError(f"weighted_arun: p and q must both be (k, 2) or (k, 3), "
                        f"got {p.shape} and {q.shape}")
    k = p.shape[0]
    w = np.ones(k) if weights is None else real_array(o, "weights", weights)
    if w.shape != (k,):
        raise DataError(f"weighted_arun: weights must have shape ({k},), got {w.shape}")
    # one pass per array on the usual path (NaN fails every comparison); the slow path names
    # the problem
    if not ((np.abs(p) <= MAX_COORDINATE).all() and (np.abs(q) <= MAX_COORDINATE).all()
            and (w >= 0).all() and (w <= MAX_WEIGHT).all()):
        for name, arr in (("p", p), ("q", q), ("weights", w)):
            bad = ~np.isfinite(arr)
            if bad.any():
                at = tuple(int(i) for i in np.argwhere(bad)[0])
                raise DataError(f"weighted_arun: {name} must be finite, got {arr[at]} at "
                                f"{list(at)}")
        if (w < 0).any():
            raise DataError(f"weighted_arun: weights must be >= 0, got min {w.min()}")
        if (w > MAX_WEIGHT).any():
            raise DataError(f"weighted_arun: weights must be <= {MAX_WEIGHT:g}, got "
                            f"{w.max():.3g}")
        name, arr = ("p", p) if np.abs(p).max() > MAX_COORDINATE else ("q", q)
        raise DataError(f"weighted_arun: coordinates must lie within {MAX_COORDINATE:g} "
                        f"metres of the origin, got one of magnitude {np.abs(arr).max():.3g} "
                        f"in {name}")
    return _weighted_arun(p, q, w)


def _weighted_arun(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """`weighted_arun` on checked arguments: (k, d) finite points within MAX_COORDINATE and
    (k,) weights in [0, MAX_WEIGHT]."""
    d = p.shape[1]
    if np.count_nonzero(w > 0) < 2:
        return None
    w_sum = w.sum()
    p_mean = w @ p / w_sum
    q_mean = w @ q / w_sum
    p_c = p - p_mean
    q_c = q - q_mean
    # 2D needs two distinct points; 3D needs the points off a single line. Centring loses
    # about 1e-16 of the coordinates' magnitude and the eigensolver about 1e-16 of the largest
    # spread, so spreads below those (with a wide margin) are rounding, not geometry.
    floor = w_sum * (1e-9 * max(1.0, float(np.abs(q).max()))) ** 2
    if d == 2:
        return _planar_arun(p_c, q_c, w, floor, p_mean, q_mean)
    scatter = (q_c * w[:, None]).T @ q_c
    spread = np.sort(np.linalg.eigvalsh(scatter))[::-1]
    if spread[0] <= floor or (d == 3 and spread[1] <= max(floor, 1e-12 * spread[0])):
        return None
    H = (q_c * w[:, None]).T @ p_c
    U, _, Vt = np.linalg.svd(H)
    V = Vt.T
    D = np.eye(d)
    D[-1, -1] = np.sign(np.linalg.det(V @ U.T)) or 1.0
    R = V @ D @ U.T
    T = np.eye(d + 1)
    T[:d, :d] = R
    T[:d, d] = p_mean - R @ q_mean
    return T


def _planar_arun(p_c: np.ndarray, q_c: np.ndarray, w: np.ndarray, floor: float,
                 p_mean: np.ndarray, q_mean: np.ndarray) -> np.ndarray | None:
    """`_weighted_arun` in the plane on centred points, None when the weighted scatter of q
    is not above `floor` (rounding): the rotation that maximises sum w p_c . R q_c is the
    angle of sum w (q_c . p_c, q_c x p_c), with no decomposition (the same optimum as the
    SVD's, at a fraction of its cost on the few points of a candidate)."""
    wq_x, wq_y = (q_c * w[:, None]).T  # the columns, as views
    q_x, q_y = q_c.T
    p_x, p_y = p_c.T
    if _eigenvalues_2x2(wq_x @ q_x, wq_y @ q_y, wq_x @ q_y)[1] <= floor:
        return None
    dot = wq_x @ p_x + wq_y @ p_y
    cross = wq_x @ p_y - wq_y @ p_x
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, p_mean[0] - (c * q_mean[0] - s * q_mean[1])],
                     [s, c, p_mean[1] - (s * q_mean[0] + c * q_mean[1])],
                     [0.0, 0.0, 1.0]])


def _eigenvalues_2x2(sxx: float, syy: float, sxy: float) -> tuple[float, float]:
    """(smaller, larger) eigenvalue of the symmetric matrix [[sxx, sxy], [sxy, syy]], in
    closed form (an eigensolver call costs more than the few points it is asked about)."""
    mean, half_gap = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    return mean - half_gap, mean + half_gap


def _transform(owner: str, T_a_b, d: int) -> np.ndarray:
    """`T_a_b` as a finite (d+1, d+1) matrix, else DataError."""
    T = real_array(owner, "T_a_b", T_a_b)
    if T.shape != (d + 1, d + 1) or not np.isfinite(T).all():
        raise DataError(f"{owner}: T_a_b must be a finite ({d + 1}, {d + 1}) transform for "
                        f"{d}D points, got {shown(T_a_b)}")
    return T


def registration_rmse(T_a_b: np.ndarray, p: np.ndarray, q: np.ndarray) -> float:
    """Root mean square of |p_k - T_a_b q_k| over the k pairs, metres (k >= 1).

    Args:
        T_a_b: (d+1, d+1) transform; p: (k, d) points in frame a, q: (k, d) in frame b.
    Raises:
        DataError: arguments not real, not finite, of mismatched shapes, or k = 0.
    """
    o = "registration_rmse"
    p = point_array(o, "p", p)
    q = point_array(o, "q", q, p.shape[1])
    if q.shape != p.shape or p.shape[0] == 0:
        raise DataError(f"{o}: p and q must be the same k >= 1 pairs, got {p.shape} and "
                        f"{q.shape}")
    return _registration_rmse(_transform(o, T_a_b, p.shape[1]), p, q)


def _registration_rmse(T_a_b: np.ndarray, p: np.ndarray, q: np.ndarray) -> float:
    d = p.shape[1]
    residual = p - (q @ T_a_b[:d, :d].T + T_a_b[:d, d])
    # the sum over the pairs divided by their count is np.mean's arithmetic, without its
    # dispatch
    return math.sqrt((residual**2).sum(axis=1).sum() / p.shape[0])


def mutual_inliers(T_a_b: np.ndarray, p: np.ndarray, q: np.ndarray, compatible: np.ndarray,
                   radius: float) -> np.ndarray:
    """Pairs (p_k, q_l) that explain each other under T_a_b: mutual nearest neighbours among the
    `compatible` pairs, within `radius`.

    Args:
        T_a_b: (3, 3) SE(2) transform; p: (n, 2) points in frame a; q: (m, 2) in frame b.
        compatible: (n, m) bool, pairs allowed to match (e.g. by object size).
        radius: metres.
    Returns:
        (k, 2) int64 (index into p, index into q), one row per inlier, sorted by p index.
    Raises:
        DataError: arguments not real or not finite, shapes that do not match, radius not a
            finite number >= 0.
    """
    o = "mutual_inliers"
    p = point_array(o, "p", p, 2)
    q = point_array(o, "q", q, 2)
    T_a_b = _transform(o, T_a_b, 2)
    compatible = np.asarray(compatible)
    if compatible.dtype != np.bool_ or compatible.shape != (len(p), len(q)):
        raise DataError(f"{o}: compatible must be a ({len(p)}, {len(q)}) bool array, got "
                        f"{shown(compatible)}")
    if not (_finite(radius) and radius >= 0):
        raise DataError(f"{o}: radius must be a finite number >= 0 metres, got "
                        f"{shown(radius)}")
    return _mutual_inliers(T_a_b, p, q, compatible, float(radius))


def _mutual_inliers(T_a_b: np.ndarray, p: np.ndarray, q: np.ndarray, compatible: np.ndarray,
                    radius: float) -> np.ndarray:
    if p.shape[0] == 0 or q.shape[0] == 0:
        return np.empty((0, 2), np.int64)
    moved = _transform_points(T_a_b, q)
    if p.shape[0] * q.shape[0] > _DENSE_INLIERS:
        return _mutual_inliers_by_tree(p, moved, compatible, radius)
    # one compiled signature (the one precompiled) whatever the callers' layouts, types and
    # write flags (numba compiles read-only arrays apart)
    return _mutual_nearest(kernel_array(p), kernel_array(moved), kernel_array(compatible, bool),
                           float(radius) ** 2)


@numba.njit(cache=True)
def _mutual_nearest(p: np.ndarray, moved: np.ndarray, compatible: np.ndarray, r2: float
                    ) -> np.ndarray:
    """(k, 2) pairs (i, j), sorted by i, where moved[j] is p[i]'s nearest compatible point
    and p[i] moved[j]'s, within squared distance r2; ties go to the lower index. One pass
    over the pairs, no (n, m) temporaries (small maps call this for every candidate).

    A row's squared distances are made first (inf for the pairs not compatible, which then
    are never nearer than anything), then the columns' nearest so far are updated along the
    row and the row's own nearest is taken, each without a branch: the first two run in
    vector instructions, and none waits on a guess of which pairs are compatible."""
    n, m = p.shape[0], moved.shape[0]
    nearest_q = np.full(n, -1, np.int64)
    nearest_p = np.full(m, -1, np.int64)
    best_q = np.full(n, np.inf)
    best_p = np.full(m, np.inf)
    moved_x, moved_y = moved[:, 0].copy(), moved[:, 1].copy()
    row = np.empty(m)
    for i in range(n):
        for j in range(m):
            dx = p[i, 0] - moved_x[j]
            dy = p[i, 1] - moved_y[j]
            row[j] = dx * dx + dy * dy if compatible[i, j] else np.inf
        for j in range(m):
            nearer = row[j] < best_p[j]
            best_p[j] = row[j] if nearer else best_p[j]
            nearest_p[j] = i if nearer else nearest_p[j]
        for j in range(m):
            nearer = row[j] < best_q[i]
            best_q[i] = row[j] if nearer else best_q[i]
            nearest_q[i] = j if nearer else nearest_q[i]
    out = np.empty((n, 2), np.int64)
    k = 0
    for i in range(n):
        j = nearest_q[i]
        if j >= 0 and nearest_p[j] == i and best_q[i] <= r2:
            out[k, 0], out[k, 1] = i, j
            k += 1
    return out[:k]


def _mutual_inliers_by_tree(p: np.ndarray, moved: np.ndarray, compatible: np.ndarray,
                            radius: float) -> np.ndarray:
    """`mutual_inliers` for large maps, in memory linear in the pairs within `radius`.

    A nearest compatible neighbour that lies within the radius is among the pairs within it,
    so mutual nearest neighbours among those pairs are the dense search's inliers.
    """
    close = cKDTree(p).sparse_distance_matrix(cKDTree(moved), radius, output_type="ndarray")
    i, j, d = close["i"], close["j"], close["v"]
    ok = compatible[i, j]
    i, j, d = i[ok], j[ok], d[ok]
    # the first pair of each row (column) in (row, distance, column) order is its nearest,
    # ties to the lowest index as argmin takes them
    mutual = np.intersect1d(_nearest(i, d, j), _nearest(j, d, i))
    mutual = mutual[np.argsort(i[mutual])]  # one pair per row at most: sorted by p index
    return np.column_stack([i[mutual], j[mutual]]).astype(np.int64)


def _nearest(owner: np.ndarray, d: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """Of pairs (owner, partner) at distance d, the position of each owner's nearest pair."""
    order = np.lexsort((partner, d, owner))
    first = np.ones(order.size, bool)
    first[1:] = owner[order][1:] != owner[order][:-1]
    return order[first]


def spread(points: np.ndarray) -> float:
    """Metres: the standard deviation of (k, 2) points along their least spread direction (the
    square root of the smallest eigenvalue of their covariance); 0 for fewer than two points.
    Points on one line have spread 0.

    Raises:
        DataError: points not finite (k, 2) real numbers.
    """
    return _spread(point_array("spread", "points", points, 2))


def _spread(points: np.ndarray) -> float:
    n = points.shape[0]
    if n < 2:
        return 0.0
    c = points - points.sum(0) / n
    smaller = _eigenvalues_2x2(c[:, 0] @ c[:, 0] / n, c[:, 1] @ c[:, 1] / n,
                               c[:, 0] @ c[:, 1] / n)[0]
    return math.sqrt(max(smaller, 0.0))
