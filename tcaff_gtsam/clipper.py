"""CLIPPER: consistency graph of putative associations, its relaxed densest-clique solver, and
the multiple-near-optima variant of the paper (MNO-CLIPPER, Algorithm 1).

The graph is stored sparsely (symmetric CSR without the diagonal, plus a diagonal vector), so
its memory grows with the number of consistent pairs, never with m^2. Hot loops are compiled
with numba; the compiled code is cached on disk next to this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import sparse

from .errors import DataError
from .inputs import index_pairs, kernel_array, real_array, shown
from .params import (
    MAX_SOLUTIONS,
    ClipperParams,
    _finite,
    _given_or_default,
    _int_at_least,
    _real,
    _require,
)

__all__ = ["ClipperSolution", "ConsistencyGraph", "clipper_solve", "consistency_graph",
           "mno_clipper"]


@dataclass(frozen=True, eq=False)
class ConsistencyGraph:
    """Weighted consistency graph over m putative associations.

    Attributes:
        associations: (m, 2) int64, (ego index, other index) of each node.
        indptr, indices, weights: symmetric CSR adjacency without self loops; an edge (p, q)
            exists when associations p and q are consistent, with weight exp(-c^2 / 2 sigma^2).
        diag: (m,) prior weight of each association (the affinity's diagonal), 1 by default.

    Construction checks what the compiled solver relies on and would otherwise read past the
    ends of arrays for: shapes, index ranges, finite non-negative weights. The arrays are
    stored as int64 and float64 read-only views (the caller's arrays stay writeable).

    Raises:
        DataError: naming the field: associations not an (m, 2) array of indices >= 0;
            indptr not (m + 1,) non-decreasing from 0 to len(indices); indices not node
            numbers in [0, m); weights not one finite number >= 0 per entry of indices;
            diag not (m,) finite numbers >= 0.
    """

    associations: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    weights: np.ndarray
    diag: np.ndarray

    def __post_init__(self) -> None:
        o = "ConsistencyGraph"
        associations = index_pairs(o, "associations", self.associations)
        m = associations.shape[0]
        indptr = _int_vector(o, "indptr", self.indptr)
        indices = _int_vector(o, "indices", self.indices)
        weights = real_array(o, "weights", self.weights)
        diag = real_array(o, "diag", self.diag)
        n_entries = indices.shape[0]
        if indptr.shape != (m + 1,):
            raise DataError(f"{o}: indptr must have shape ({m + 1},) for {m} nodes, got "
                            f"{indptr.shape}")
        if indptr[0] != 0 or indptr[-1] != n_entries or np.any(np.diff(indptr) < 0):
            raise DataError(f"{o}: indptr must rise from 0 to len(indices) = {n_entries}, "
                            f"got {shown(indptr)}")
        if n_entries and (indices.min() < 0 or indices.max() >= m):
            bad = indices[(indices < 0) | (indices >= m)][0]
            raise DataError(f"{o}: indices must be node numbers in [0, {m}), got {bad}")
        for name, values, shape in (("weights", weights, (n_entries,)), ("diag", diag, (m,))):
            if values.shape != shape:
                raise DataError(f"{o}: {name} must have shape {shape}, got {values.shape}")
            bad = ~(values >= 0) | (values == np.inf)  # NaN fails >= 0
            if bad.any():
                raise DataError(f"{o}: {name} must be finite numbers >= 0, got "
                                f"{values[bad][0]} at index {int(np.flatnonzero(bad)[0])}")
        self._store(associations, indptr, indices, weights, diag)

    def _store(self, *arrays: np.ndarray) -> None:
        for name, value in zip(_GRAPH_FIELDS, arrays, strict=True):
            view = np.ascontiguousarray(value).view()
            view.flags.writeable = False
            object.__setattr__(self, name, view)

    @classmethod
    def _built(cls, *arrays: np.ndarray) -> ConsistencyGraph:
        """A graph from `consistency_graph`, whose arrays are right by construction: the
        checks of `__post_init__` are skipped (they cost as much as a tenth of the build)."""
        graph = object.__new__(cls)
        graph._store(*arrays)
        return graph

    @property
    def m(self) -> int:
        """Number of nodes (putative associations)."""
        return self.associations.shape[0]

    @property
    def n_edges(self) -> int:
        """Number of undirected edges (consistent pairs)."""
        return self.indices.shape[0] // 2

    def affinity(self) -> sparse.csr_matrix:
        """The affinity matrix M (m, m) as a scipy sparse matrix, diagonal included."""
        adjacency = sparse.csr_matrix((self.weights, self.indices, self.indptr),
                                      shape=(self.m, self.m))
        return (adjacency + sparse.diags(self.diag)).tocsr()


_GRAPH_FIELDS = ("associations", "indptr", "indices", "weights", "diag")


@dataclass(frozen=True, eq=False)
class ClipperSolution:
    """One CLIPPER solution.

    Attributes:
        nodes: (k,) int64 indices of the selected graph nodes, ascending.
        associations: (k, 2) int64 (ego index, other index) of the selected associations.
        u: (m,) the relaxed solution on the unit sphere (zeros on removed nodes).
        score: u'Mu / u'u of the selected set's indicator vector on the original affinity
            (for an unweighted clique, its size).
        penalty: final penalty weight d of the homotopy.
    """

    nodes: np.ndarray
    associations: np.ndarray
    u: np.ndarray
    score: float
    penalty: float

    def __len__(self) -> int:
        return self.nodes.shape[0]


#: other-map distances are kept as a matrix up to this many object pairs (8 MB); beyond it each
#: row is computed when it is needed, so memory stays linear in the map sizes
_DISTANCE_MATRIX_MAX = 1 << 20


@numba.njit(cache=True)
def _distances_from(points, j, out):
    """out[l] = |points[j] - points[l]| for every l."""
    for ell in range(points.shape[0]):
        s = 0.0
        for a in range(points.shape[1]):
            diff = points[j, a] - points[ell, a]
            s += diff * diff
        out[ell] = np.sqrt(s)


@numba.njit(cache=True)
def _consistent_pairs(ego_points, other_points, ego_z, other_z, slack, other_idx, group_ego,
                      group_start, inv_two_sigma_sq, epsilon, height_epsilon):
    """Upper-triangle edges (p < q) of the consistency graph: rows, cols, weights. With a
    finite height_epsilon, an edge also needs the height differences z_i - z_k and z_j - z_l
    (ego_z (n1,), other_z (n2,)) to agree within height_epsilon + slack[p] + slack[q]
    (slack (m,) per node, in the sorted order).

    Nodes are sorted by ego index and grouped: group g holds the nodes
    group_start[g]:group_start[g+1], all with ego object group_ego[g]. The ego distances
    |p_i - p_k| from group g to every later group are computed once per group and spread over
    the later nodes, and the i != k rule means skipping g's own group. Other-map distances
    |q_j - q_l| come from a matrix when the map is small (`_DISTANCE_MATRIX_MAX`), else from
    the points, one row per node. Each row is gathered in a fixed scratch buffer so the inner
    loop never reallocates; the output grows only between rows.
    """
    m = other_idx.shape[0]
    n_groups = group_ego.shape[0]
    n_other = other_points.shape[0]
    dim = ego_points.shape[1]
    d_ego = np.empty(m)  # |p_i - p_k| for each later node q = (k, l), i the current group's
    dz_ego = np.zeros(m)  # z_i - z_k likewise
    heights = height_epsilon < np.inf
    matrix = n_other * n_other <= _DISTANCE_MATRIX_MAX
    d_other = np.empty((n_other if matrix else 1, n_other))
    if matrix:
        for j in range(n_other):
            _distances_from(other_points, j, d_other[j])
    row_cols = np.empty(m, np.int64)
    row_c = np.empty(m)
    capacity = max(16, 4 * m)
    rows = np.empty(capacity, np.int64)
    cols = np.empty(capacity, np.int64)
    wts = np.empty(capacity)
    n = 0
    for g in range(n_groups):
        i = group_ego[g]
        for h in range(g + 1, n_groups):
            k = group_ego[h]
            s = 0.0
            for a in range(dim):
                diff = ego_points[i, a] - ego_points[k, a]
                s += diff * diff
            d_ik = np.sqrt(s)
            dz_ik = ego_z[i] - ego_z[k] if heights else 0.0
            for q in range(group_start[h], group_start[h + 1]):
                d_ego[q] = d_ik
                dz_ego[q] = dz_ik
        later = group_start[g + 1]
        for p in range(group_start[g], later):
            j = other_idx[p]
            if matrix:
                d_j = d_other[j]
            else:
                d_j = d_other[0]
                _distances_from(other_points, j, d_j)
            count = 0
            for q in range(later, m):
                ell = other_idx[q]
                c = abs(d_ego[q] - d_j[ell])
                if c < epsilon and ell != j and (
                        not heights or abs(dz_ego[q] - (other_z[j] - other_z[ell]))
                        < height_epsilon + slack[p] + slack[q]):
                    row_cols[count] = q
                    row_c[count] = c
                    count += 1
            if n + count > capacity:
                capacity = max(2 * capacity, n + count)
                rows = np.concatenate((rows[:n], np.empty(capacity - n, np.int64)))
                cols = np.concatenate((cols[:n], np.empty(capacity - n, np.int64)))
                wts = np.concatenate((wts[:n], np.empty(capacity - n)))
            for e in range(count):
                rows[n + e] = p
                cols[n + e] = row_cols[e]
                wts[n + e] = np.exp(-row_c[e] * row_c[e] * inv_two_sigma_sq)
            n += count
    return rows[:n], cols[:n], wts[:n]


@numba.njit(cache=True)
def _symmetric_csr(m, rows, cols, wts):
    """CSR arrays of the symmetric matrix whose upper triangle is (rows, cols, wts)."""
    indptr = np.zeros(m + 1, np.int64)
    for e in range(rows.shape[0]):
        indptr[rows[e] + 1] += 1
        indptr[cols[e] + 1] += 1
    for p in range(m):
        indptr[p + 1] += indptr[p]
    cursor = indptr[:-1].copy()
    indices = np.empty(indptr[m], np.int64)
    weights = np.empty(indptr[m])
    for e in range(rows.shape[0]):
        p, q = rows[e], cols[e]
        indices[cursor[p]] = q
        weights[cursor[p]] = wts[e]
        cursor[p] += 1
        indices[cursor[q]] = p
        weights[cursor[q]] = wts[e]
        cursor[q] += 1
    return indptr, indices, weights


@numba.njit(cache=True)
def _graph_csr(ego_points, other_points, ego_z, other_z, slack, associations,
               inv_two_sigma_sq, epsilon, height_epsilon):
    """CSR arrays (indptr, indices, weights) of the consistency graph: the nodes grouped by
    ego object (a stable counting sort, the identity for sorted input), their consistent
    pairs, and the symmetric matrix of those. One compiled call, so a small graph costs no
    Python steps. Written with loops only: numpy's sorts cost seconds of compilation each."""
    m = associations.shape[0]
    n_ego = 0
    for s in range(m):
        n_ego = max(n_ego, associations[s, 0] + 1)
    group_start = np.zeros(n_ego + 1, np.int64)  # nodes per ego object, then where each starts
    for s in range(m):
        group_start[associations[s, 0] + 1] += 1
    n_groups = 0
    for i in range(n_ego):
        n_groups += group_start[i + 1] > 0
        group_start[i + 1] += group_start[i]
    cursor = group_start[:-1].copy()
    order = np.empty(m, np.int64)
    for s in range(m):
        i = associations[s, 0]
        order[cursor[i]] = s
        cursor[i] += 1
    other_sorted = np.empty(m, np.int64)
    slack_sorted = np.empty(m)
    for s in range(m):
        other_sorted[s] = associations[order[s], 1]
        slack_sorted[s] = slack[order[s]]
    group_ego = np.empty(n_groups, np.int64)
    starts = np.empty(n_groups + 1, np.int64)
    g = 0
    for i in range(n_ego):
        if group_start[i + 1] > group_start[i]:
            group_ego[g] = i
            starts[g] = group_start[i]
            g += 1
    starts[n_groups] = m
    rows, cols, wts = _consistent_pairs(ego_points, other_points, ego_z, other_z, slack_sorted,
                                        other_sorted, group_ego, starts, inv_two_sigma_sq,
                                        epsilon, height_epsilon)
    for e in range(rows.shape[0]):
        rows[e] = order[rows[e]]
        cols[e] = order[cols[e]]
    return _symmetric_csr(m, rows, cols, wts)


def _int_vector(owner: str, name: str, value) -> np.ndarray:
    """`value` as a 1-D int64 array; DataError naming `name` if it is not 1-D integers."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.ndim != 1 or arr.dtype.kind not in "iu":
        raise DataError(f"{owner}: {name} must be a 1-D integer array, got {shown(value)}")
    if arr.dtype == np.uint64 and arr.size and arr.max() > np.iinfo(np.int64).max:
        raise DataError(f"{owner}: {name} holds a value beyond int64, {arr.max()}")
    return arr.astype(np.int64, copy=False)


def _checked_graph(owner: str, graph, params) -> ClipperParams:
    """The parameters to solve `graph` with; DataError when graph is not a ConsistencyGraph
    (its construction checked the rest), ConfigError when params is not ClipperParams."""
    if not isinstance(graph, ConsistencyGraph):
        raise DataError(f"{owner}: graph must be a ConsistencyGraph, got "
                        f"{type(graph).__name__} {shown(graph)}")
    return _given_or_default(ClipperParams, params, owner)


def consistency_graph(ego_points: np.ndarray, other_points: np.ndarray,
                      associations: np.ndarray, epsilon: float = 0.25, sigma: float = 0.15,
                      prior: np.ndarray | None = None,
                      z: tuple[np.ndarray, np.ndarray] | None = None,
                      height_epsilon: float | None = None,
                      vertical_extents: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> ConsistencyGraph:
    """Build CLIPPER's consistency graph.

    Associations a = (i, j) and b = (k, l) with i != k and j != l are consistent when
    c = | |p_i - p_k| - |q_j - q_l| | < epsilon; their edge weight is exp(-c^2 / (2 sigma^2)).
    With `z` and `height_epsilon` (maps whose frames are both gravity aligned, so that
    heights differ between them by a constant at most), they must also climb alike:
    | (z_i - z_k) - (z_j - z_l) | < height_epsilon + s_a + s_b, where an association's slack
    s = | h_i - h_j | / 2 allows for a partial view: with `vertical_extents` (the objects'
    heights h), a view that cuts an object's height by d moves its centre by d / 2 (0
    without them).

    Args:
        ego_points: (n1, d) metres, d = 2 (x, y) or 3, in the ego robot's odometry frame.
        other_points: (n2, d) metres, in the other robot's odometry frame.
        associations: (m, 2) int (ego index, other index).
        epsilon, sigma: metres, finite and > 0.
        prior: optional (m,) non-negative prior weight per association (affinity diagonal).
        z: optional ((n1,), (n2,)) metres, each object's centre's height above its frame's
            origin (along gravity).
        height_epsilon: metres, finite and > 0, with z (None without).
        vertical_extents: optional ((n1,), (n2,)) metres >= 0, the objects' heights
            (`ObjectMap.heights`), with z.

    Raises:
        ConfigError: epsilon, sigma or height_epsilon not a finite number > 0, or z and
            height_epsilon not given together.
        DataError: points, associations, prior, z or vertical_extents of the wrong shape or
            out of range, not real numbers (complex ones included), or associations that are
            not whole numbers: an (m, 3) array is refused, not read as pairs, and 1.5 is not
            truncated to 1.
    """
    o = "consistency_graph"
    for name, value in (("epsilon", epsilon), ("sigma", sigma)):
        _require(_finite(value) and value > 0, o, name, value,
                 "must be a finite number > 0 metres")
    _require((z is None) == (height_epsilon is None), o, "height_epsilon",
             height_epsilon, "must be given with z, and only with it")
    if height_epsilon is not None:
        _require(_finite(height_epsilon) and height_epsilon > 0, o, "height_epsilon",
                 height_epsilon, "must be a finite number > 0 metres")
    ego_points = real_array(o, "ego_points", ego_points)
    other_points = real_array(o, "other_points", other_points)
    associations = index_pairs(o, "associations", associations)
    if (ego_points.ndim != 2 or other_points.ndim != 2 or ego_points.shape[1] not in (2, 3)
            or other_points.shape[1] != ego_points.shape[1]):
        raise DataError(f"consistency_graph: points must be (n, 2) or (n, 3) in both maps, "
                        f"got {ego_points.shape} and {other_points.shape}")
    if not (np.all(np.isfinite(ego_points)) and np.all(np.isfinite(other_points))):
        raise DataError("consistency_graph: points must be finite")
    m = associations.shape[0]
    if m and (associations.min() < 0 or associations[:, 0].max() >= len(ego_points)
              or associations[:, 1].max() >= len(other_points)):
        raise DataError(f"consistency_graph: association indices out of range for maps of "
                        f"{len(ego_points)} and {len(other_points)} points")
    if prior is None:
        diag = np.ones(m)
    else:
        diag = real_array(o, "prior", prior)
        if diag.shape != (m,) or not np.all(np.isfinite(diag)) or np.any(diag < 0):
            raise DataError(f"consistency_graph: prior must be ({m},) finite and >= 0, "
                            f"got shape {diag.shape}")
    sizes = (len(ego_points), len(other_points))
    z = _per_object(o, "z", z, sizes)
    extents = _per_object(o, "vertical_extents", vertical_extents, sizes)
    if extents is not None and (z is None or min(e.min(initial=0.0) for e in extents) < 0):
        raise DataError("consistency_graph: vertical_extents must be >= 0 metres, and given "
                        "with z")
    slack = (np.zeros(m) if extents is None else
             _height_slack(extents[0][associations[:, 0]], extents[1][associations[:, 1]]))
    return _graph(ego_points, other_points, associations, epsilon, sigma, diag, z,
                  height_epsilon, slack)


def _height_slack(ego_heights: np.ndarray, other_heights: np.ndarray) -> np.ndarray:
    """Metres of slack on the gravity prior for pairs of objects of these vertical extents
    (arrays that broadcast): a view that cuts an object's height by d moves its centre by
    d / 2."""
    return 0.5 * np.abs(ego_heights - other_heights)


def _per_object(owner: str, name: str, value, sizes: tuple[int, int]
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """`value` as a pair of finite float arrays of shapes ((n1,), (n2,)), or None."""
    if value is None:
        return None
    if not (isinstance(value, (tuple, list)) and len(value) == 2):
        raise DataError(f"{owner}: {name} must be (ego values, other values), got "
                        f"{shown(value)}")
    out = (real_array(owner, f"{name}[0]", value[0]), real_array(owner, f"{name}[1]", value[1]))
    for side, (arr, n) in enumerate(zip(out, sizes, strict=True)):
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise DataError(f"{owner}: {name}[{side}] must be ({n},) finite metres, got "
                            f"{shown(arr)}")
    return out


def _graph(ego_points: np.ndarray, other_points: np.ndarray, associations: np.ndarray,
           epsilon: float, sigma: float, diag: np.ndarray,
           z: tuple[np.ndarray, np.ndarray] | None = None,
           height_epsilon: float | None = None, slack: np.ndarray | None = None
           ) -> ConsistencyGraph:
    """`consistency_graph` on arguments already checked: (n1, d) and (n2, d) finite points,
    (m, 2) int64 associations in range, (m,) diag, epsilon and sigma finite and > 0, z
    ((n1,), (n2,)) finite with height_epsilon > 0 or both None, slack (m,) >= 0 or None."""
    m = associations.shape[0]
    if z is None:
        ego_z, other_z, cut = np.zeros(len(ego_points)), np.zeros(len(other_points)), np.inf
    else:
        ego_z, other_z, cut = z[0], z[1], float(height_epsilon)
    indptr, indices, weights = _graph_csr(
        kernel_array(ego_points), kernel_array(other_points), kernel_array(ego_z),
        kernel_array(other_z), np.zeros(m) if slack is None else kernel_array(slack),
        kernel_array(associations, np.int64), 1.0 / (2.0 * sigma * sigma), float(epsilon), cut)
    return ConsistencyGraph._built(associations, indptr, indices, weights, diag)


@numba.njit(cache=True)
def _scatter(indptr, indices, weights, diag, u, support, n_support, Mu, Cu, touched, mark, stamp):
    """Mu = M u and Cu = C u (C binary, diagonal included) for u supported on `support`.

    Scatter form: row q of the symmetric adjacency is also its column q, so the cost is the
    sum of the support's degrees, not m. Only the nodes written (the support and its
    neighbours) are valid; they are listed in `touched` and stamped with `stamp` in `mark`.
    Every other node has Mu = Cu = 0. Returns (number touched, sum of u).
    """
    # The first-touch block is written out twice on purpose: moving it into a helper (even an
    # inlined one) made this loop about 9 times slower under numba. Node indices are read as
    # unsigned: numba then skips the negative-index wraparound of every access (a fifth of
    # MNO-CLIPPER's time, with the same arithmetic), here and in the helpers below.
    n_touched = 0
    total = 0.0
    for s in range(n_support):
        q = np.uint64(support[s])
        uq = u[q]
        total += uq
        if mark[q] != stamp:
            mark[q] = stamp
            Mu[q] = 0.0
            Cu[q] = 0.0
            touched[n_touched] = q
            n_touched += 1
        Mu[q] += diag[q] * uq
        Cu[q] += uq
        for e in range(np.uint64(indptr[q]), np.uint64(indptr[q + np.uint64(1)])):
            p = np.uint64(indices[e])
            if mark[p] != stamp:
                mark[p] = stamp
                Mu[p] = 0.0
                Cu[p] = 0.0
                touched[n_touched] = p
                n_touched += 1
            Mu[p] += weights[e] * uq
            Cu[p] += uq
    return n_touched, total


@numba.njit(cache=True)
def _gradient(Mu, Cu, total, d, touched, n_touched, g):
    """g = M_d u on the touched nodes, M_d = M - d (1 - C): (1 - C) u = sum(u) - C u."""
    for t in range(n_touched):
        p = np.uint64(touched[t])
        g[p] = Mu[p] - d * (total - Cu[p])


@numba.njit(cache=True)
def _objective(u, support, n_support, g):
    F = 0.0
    for s in range(n_support):
        p = np.uint64(support[s])
        F += u[p] * g[p]
    return F


@numba.njit(cache=True)
def _project(u, g, alpha, touched, n_touched, active, out, out_support):
    """out = normalize(max(u + alpha g, 0)) over active touched nodes.

    Untouched nodes stay at zero: they have u = 0 and g = -d sum(u) <= 0. Returns the size of
    the new support (listed in out_support); 0 when everything was clipped.
    """
    norm_sq = 0.0
    n = 0
    for t in range(n_touched):
        p = np.uint64(touched[t])
        if not active[p]:
            continue
        v = u[p] + alpha * g[p]
        if v > 0.0:
            out[p] = v
            out_support[n] = p
            n += 1
            norm_sq += v * v
    if n:
        scale = 1.0 / np.sqrt(norm_sq)
        for s in range(n):
            out[np.uint64(out_support[s])] *= scale
    return n


@numba.njit(cache=True)
def _penalty_step(u, support, n_support, Mu, Cu, total, eps, first):
    """Penalty increase that makes active inconsistent pairs costlier; 0 when none is active.

    For each node carrying weight (u_p > eps) with weight on inconsistent nodes
    (s_p = sum_q (1 - C_pq) u_q > eps), Mu_p / s_p is the penalty at which its gradient turns
    negative. The first increase uses their mean; later ones the midpoint of their minimum
    (CLIPPER's step) and their mean, which takes about a third less time at n = 200 for the
    same precision and recall on our benchmarks.
    """
    count = 0
    acc = 0.0
    smallest = np.inf
    for s in range(n_support):
        p = support[s]
        if u[p] <= eps:
            continue
        inconsistent = total - Cu[p]
        if inconsistent > eps:
            ratio = abs(Mu[p] / inconsistent)
            count += 1
            acc += ratio
            smallest = min(smallest, ratio)
    if count == 0:
        return 0.0
    mean = acc / count
    return mean if first else 0.5 * (smallest + mean)


@numba.njit(cache=True)
def _solve(indptr, indices, weights, diag, active, u0, power_iterations, tol_u, eps, beta,
           max_outer, max_inner, max_line_search):
    """Penalty homotopy of CLIPPER: projected gradient ascent of u' M_d u on the non-negative
    unit sphere with backtracking, raising d until no inconsistent pair carries weight.

    Vectors are dense arrays that are zero off an explicit support list; the current iterate
    (u, its products and gradient) and the line-search trial (ub, ...) each own a set of
    buffers, swapped on acceptance. Returns (u, d, final objective u'Mu).
    """
    m = u0.shape[0]
    u, ub = np.zeros(m), np.zeros(m)
    sup, sup_b = np.empty(m, np.int64), np.empty(m, np.int64)
    Mu, Mu_b = np.zeros(m), np.zeros(m)
    Cu, Cu_b = np.zeros(m), np.zeros(m)
    g, g_b = np.zeros(m), np.zeros(m)
    tch, tch_b = np.empty(m, np.int64), np.empty(m, np.int64)
    mark, mark_b = np.full(m, -1, np.int64), np.full(m, -1, np.int64)
    stamp = 0
    n_sup = 0
    for p in range(m):
        if active[p] and u0[p] > 0.0:
            u[p] = u0[p]
            sup[n_sup] = p
            n_sup += 1
    n_tch, total = _scatter(indptr, indices, weights, diag, u, sup, n_sup, Mu, Cu, tch, mark,
                            stamp)
    for _ in range(power_iterations):
        for s in range(n_sup):
            u[sup[s]] = 0.0
        n_new = _project(ub, Mu, 1.0, tch, n_tch, active, u, sup_b)  # u = Mu / |Mu| (ub is 0)
        if n_new == 0:
            break
        sup, sup_b = sup_b, sup
        n_sup = n_new
        stamp += 1
        n_tch, total = _scatter(indptr, indices, weights, diag, u, sup, n_sup, Mu, Cu, tch,
                                mark, stamp)
    d = _penalty_step(u, sup, n_sup, Mu, Cu, total, eps, True)
    _gradient(Mu, Cu, total, d, tch, n_tch, g)
    F = _objective(u, sup, n_sup, g)
    for _ in range(max_outer):
        for _ in range(max_inner):
            alpha = 1.0
            Fb = F
            n_b = 0
            for _ in range(max_line_search):
                for s in range(n_b):
                    ub[sup_b[s]] = 0.0
                n_b = _project(u, g, alpha, tch, n_tch, active, ub, sup_b)
                if n_b == 0:
                    alpha *= beta
                    continue
                stamp += 1
                n_tch_b, total_b = _scatter(indptr, indices, weights, diag, ub, sup_b, n_b,
                                            Mu_b, Cu_b, tch_b, mark_b, stamp)
                _gradient(Mu_b, Cu_b, total_b, d, tch_b, n_tch_b, g_b)
                Fb = _objective(ub, sup_b, n_b, g_b)
                if Fb - F < -eps:
                    alpha *= beta
                else:
                    break
            delta = Fb - F
            if n_b == 0 or delta < -eps:
                for s in range(n_b):
                    ub[sup_b[s]] = 0.0
                break
            for s in range(n_sup):
                u[sup[s]] = 0.0
            u, ub = ub, u
            sup, sup_b = sup_b, sup
            n_sup = n_b
            Mu, Mu_b = Mu_b, Mu
            Cu, Cu_b = Cu_b, Cu
            g, g_b = g_b, g
            tch, tch_b = tch_b, tch
            mark, mark_b = mark_b, mark
            n_tch, total, F = n_tch_b, total_b, Fb
            if abs(delta) < tol_u:
                break
        step = _penalty_step(u, sup, n_sup, Mu, Cu, total, eps, False)
        if step == 0.0:
            break
        d += step
        _gradient(Mu, Cu, total, d, tch, n_tch, g)
        F = _objective(u, sup, n_sup, g)
    F_affinity = 0.0
    for s in range(n_sup):
        F_affinity += u[sup[s]] * Mu[sup[s]]
    return u, d, F_affinity


@numba.njit(cache=True)
def _edges_within(indptr, indices, nodes, member):
    """Positions in the CSR arrays of the edges joining two of `nodes` (ascending), both
    directions, row by row. `member` is (m,) bool scratch, all False on entry and on return."""
    for p in nodes:
        member[p] = True
    count = 0
    for p in nodes:
        for e in range(indptr[p], indptr[p + 1]):
            count += member[indices[e]]
    edges = np.empty(count, np.int64)
    count = 0
    for p in nodes:
        for e in range(indptr[p], indptr[p + 1]):
            if member[indices[e]]:
                edges[count] = e
                count += 1
    for p in nodes:
        member[p] = False
    return edges


@numba.njit(cache=True)
def _sum(a):
    """sum(a) in the order numpy's pairwise summation adds (blocks of up to 128 with eight
    accumulators), so compiled scores equal the ones numpy computes to the last bit."""
    n = a.shape[0]
    if n < 8:
        total = 0.0
        for i in range(n):
            total += a[i]
        return total
    if n <= 128:
        r = np.empty(8)
        for j in range(8):
            r[j] = a[j]
        i = 8
        while i < n - n % 8:
            for j in range(8):
                r[j] += a[i + j]
            i += 8
        total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            total += a[i]
            i += 1
        return total
    half = n // 2
    half -= half % 8
    return _sum(a[:half]) + _sum(a[half:])


@numba.njit(cache=True)
def _largest_first(u, support):
    """`support` reordered by u descending, ties in their given order: a stable merge sort
    (numpy's sorts cost seconds of compilation each)."""
    k = support.shape[0]
    order = support.copy()
    scratch = np.empty(k, np.int64)
    width = 1
    while width < k:
        for lo in range(0, k, 2 * width):
            mid = min(lo + width, k)
            hi = min(lo + 2 * width, k)
            a, b, out = lo, mid, lo
            while a < mid and b < hi:
                if u[order[b]] > u[order[a]]:
                    scratch[out] = order[b]
                    b += 1
                else:
                    scratch[out] = order[a]
                    a += 1
                out += 1
            while a < mid:
                scratch[out] = order[a]
                a += 1
                out += 1
            while b < hi:
                scratch[out] = order[b]
                b += 1
                out += 1
        order, scratch = scratch, order
        width *= 2
    return order


@numba.njit(cache=True)
def _round(u, objective, eps, use_threshold, threshold, member):
    """Nodes (ascending) of a relaxed solution u: of those above eps, the ones above
    `threshold` * max(u), or the round(objective) largest (ties to the lower node).
    `member` is (m,) bool scratch, all False on entry and on return."""
    n_support = 0
    largest = 0.0
    for p in range(u.shape[0]):
        if u[p] > eps:
            n_support += 1
            largest = max(largest, u[p])
    support = np.empty(n_support, np.int64)
    n_support = 0
    for p in range(u.shape[0]):
        if u[p] > eps:
            support[n_support] = p
            n_support += 1
    if use_threshold:
        bound = threshold * largest
        for p in support:
            member[p] = u[p] > bound
    else:
        size = int(max(1.0, min(np.rint(objective), n_support)))
        for p in _largest_first(u, support)[:size]:
            member[p] = True
    count = 0
    for p in support:
        count += member[p]
    chosen = np.empty(count, np.int64)
    count = 0
    for p in support:  # ascending
        if member[p]:
            chosen[count] = p
            count += 1
            member[p] = False
    return chosen


@numba.njit(cache=True)
def _gathered(values, at):
    """values[at], written as a loop (array expressions cost seconds of compilation)."""
    out = np.empty(at.shape[0])
    for s in range(at.shape[0]):
        out[s] = values[at[s]]
    return out


@numba.njit(cache=True)
def _mno(indptr, indices, weights, diag, draws, downweight, use_threshold, threshold,
         power_iterations, tol_u, eps, beta, max_outer, max_inner, max_line_search):
    """MNO-CLIPPER in one compiled call: up to len(draws) solutions, the start vector of
    solution s from draws[s] (uniform [0, 1) per node). After each, the affinities among its
    nodes are multiplied by `downweight` (0: its nodes leave the graph). Stops after the
    first empty solution (which is returned) or when no node is left.

    Returns (k, ends, nodes, us, penalties, scores): solution s < k selected
    nodes[ends[s]:ends[s + 1]], relaxed vector us[s] (m,), final penalty penalties[s] and
    score scores[s] (x'Mx / x'x of its indicator x on the original affinity).
    """
    n_solutions, m = draws.shape
    w = weights.copy()
    dg = diag.copy()
    active = np.ones(m, np.bool_)
    member = np.zeros(m, np.bool_)
    n_active = m
    us = np.zeros((n_solutions, m))
    penalties = np.zeros(n_solutions)
    scores = np.zeros(n_solutions)
    ends = np.zeros(n_solutions + 1, np.int64)
    nodes_all = np.empty(n_solutions * m, np.int64)
    k = 0
    while k < n_solutions and n_active > 0:
        u0 = np.zeros(m)
        for p in range(m):
            if active[p]:
                u0[p] = draws[k, p]
        norm = np.sqrt(np.dot(u0, u0))  # as np.linalg.norm computes it
        for p in range(m):
            u0[p] /= norm
        u, d, objective = _solve(indptr, indices, w, dg, active, u0, power_iterations, tol_u,
                                 eps, beta, max_outer, max_inner, max_line_search)
        nodes = _round(u, objective, eps, use_threshold, threshold, member)
        edges = _edges_within(indptr, indices, nodes, member)
        if nodes.shape[0]:
            scores[k] = ((_sum(_gathered(diag, nodes)) + _sum(_gathered(weights, edges)))
                         / nodes.shape[0])
        for p in range(m):
            us[k, p] = u[p]
        penalties[k] = d
        ends[k + 1] = ends[k] + nodes.shape[0]
        for s in range(nodes.shape[0]):
            nodes_all[ends[k] + s] = nodes[s]
        k += 1
        if nodes.shape[0] == 0:
            break
        if downweight == 0.0:
            for p in nodes:
                active[p] = False
            n_active -= nodes.shape[0]
        else:
            for e in edges:
                w[e] *= downweight
            for p in nodes:
                dg[p] *= downweight
    return k, ends, nodes_all, us, penalties, scores


#: the start draws kept per seed, and the longest stream kept: a few seeds serve every solve
_STREAMS: dict[int, np.ndarray] = {}
_STREAMS_KEPT = 4
_STREAM_LONGEST = 1 << 20


def _start_draws(seed: int, count: int) -> np.ndarray:
    """The first `count` uniform [0, 1) draws of numpy's generator seeded with `seed`, read-only.

    A seed's stream is the same on every solve, and seeding a generator costs as much as the
    rest of a small solve's Python work, so streams are kept (a few seeds, up to
    `_STREAM_LONGEST` draws each) and extended when a longer one is asked for.
    """
    stream = _STREAMS.get(seed)
    if stream is None or stream.shape[0] < count:
        stream = np.random.default_rng(seed).random(max(count, 4096))
        stream.flags.writeable = False
        if count > _STREAM_LONGEST:
            return stream
        if seed not in _STREAMS and len(_STREAMS) >= _STREAMS_KEPT:
            _STREAMS.clear()  # one call, safe beside other threads' solves
        _STREAMS[seed] = stream
    return stream[:count]


def _solutions(graph: ConsistencyGraph, n_solutions: int, params: ClipperParams,
               downweight: float) -> list[ClipperSolution]:
    """`mno_clipper` on checked arguments, the last solution possibly empty (see `_mno`)."""
    m = graph.m
    # one row of start draws per solution that can be found (with downweight 0 each solution
    # removes a node, so there are at most m): the stream drawn one solution at a time
    rows = min(n_solutions, m) if downweight == 0.0 else n_solutions
    draws = _start_draws(params.seed, rows * m).reshape(rows, m)
    k, ends, nodes, us, penalties, scores = _mno(
        graph.indptr, graph.indices, graph.weights, graph.diag, draws, float(downweight),
        params.rounding == "threshold", float(params.threshold), int(params.power_iterations),
        float(params.tol_u), float(params.eps), float(params.beta), int(params.max_outer),
        int(params.max_inner), int(params.max_line_search))
    out = []
    for s in range(k):
        chosen = nodes[ends[s]: ends[s + 1]]
        out.append(ClipperSolution(chosen, graph.associations[chosen], us[s], float(scores[s]),
                                   float(penalties[s])))
    return out


def clipper_solve(graph: ConsistencyGraph, params: ClipperParams | None = None) -> ClipperSolution:
    """The densest consistent set of associations (CLIPPER, Lusk et al.).

    Maximises u'Mu / u'u over u >= 0 with u_p u_q = 0 for inconsistent pairs, relaxed by a
    penalty homotopy, then rounds u to a discrete set (see `ClipperParams.rounding`).
    Deterministic for a given `params.seed`. An empty graph gives an empty solution.

    Raises:
        ConfigError: params is neither a ClipperParams nor None.
        DataError: graph is not a ConsistencyGraph.
    """
    params = _checked_graph("clipper_solve", graph, params)
    found = _solutions(graph, 1, params, 0.0)
    if found:
        return found[0]
    return ClipperSolution(np.zeros(0, np.int64), np.zeros((0, 2), np.int64), np.zeros(graph.m),
                           0.0, 0.0)


def mno_clipper(graph: ConsistencyGraph, n_solutions: int = 4,
                params: ClipperParams | None = None, downweight: float = 0.0
                ) -> list[ClipperSolution]:
    """Multiple near-optimal CLIPPER solutions (the paper's Algorithm 1).

    After each solution the affinities among its associations are multiplied by `downweight`;
    0 (the paper) zeroes them, diagonal included, which removes those associations from later
    solutions. The graph is reused, not rebuilt. Each solution is scored on the original
    affinity. Returns up to `n_solutions` non-empty solutions, in the order found.

    Raises:
        ConfigError: n_solutions not an int in [1, `params.MAX_SOLUTIONS`], downweight not in
            [0, 1), or params neither a ClipperParams nor None.
        DataError: graph is not a ConsistencyGraph.
    """
    params = _checked_graph("mno_clipper", graph, params)
    _require(_int_at_least(n_solutions, 1) and n_solutions <= MAX_SOLUTIONS, "mno_clipper",
             "n_solutions", n_solutions,
             f"must be an int in [1, {MAX_SOLUTIONS}] (params.MAX_SOLUTIONS)")
    _require(_real(downweight) and 0 <= downweight < 1, "mno_clipper", "downweight", downweight,
             "must be in [0, 1)")
    return [s for s in _solutions(graph, n_solutions, params, downweight) if len(s)]
