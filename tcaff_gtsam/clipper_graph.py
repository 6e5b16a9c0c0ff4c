"""The consistency graph of CLIPPER: putative associations of two maps, linked where their
pairwise distances agree (within epsilon, with the gravity prior where heights are given), with
the weights of the paper's kernel.

The graph is stored sparsely (symmetric CSR without the diagonal, plus a diagonal vector), so
its memory grows with the number of consistent pairs, never with m^2. It is built in numba
kernels, cached on disk next to this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import sparse

from .aligner_params import MIN_SIGMA
from .errors import DataError
from .inputs import check_within, index_pairs, kernel_array, real_array, shown
from .param_checks import MAX_COORDINATE, _bound
from .params import (
    ClipperParams,
    _finite,
    _given_or_default,
    _require,
)

__all__ = ["ConsistencyGraph", "consistency_graph"]

#: the largest affinity weight or prior: the solver's products of weights overflow, and it
#: returns no clique, from about 1e154 on
MAX_AFFINITY = 1e100


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
            bad = ~((values >= 0) & (values <= MAX_AFFINITY))  # NaN fails both
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                rule = (f"at most {MAX_AFFINITY:g}" if np.isfinite(values[i]) and values[i] > 0
                        else "finite numbers >= 0")
                raise DataError(f"{o}: {name} must be {rule}, got {values[i]} at index {i}")
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
    the points, one row per node. The inner loop reads them in node order, |q_j - q_l| for
    each later node q = (k, l): rows of an (n_other, m) matrix made once when that is small
    too, else a row gathered per node. Rows are gathered in fixed scratch buffers so the
    inner loop never reallocates; the output grows only between rows.

    The inner loop marks the later nodes within epsilon (a few in a hundred) a byte each in
    one pass of vector instructions, then lists the marked ones by words of eight bytes,
    skipping the words that mark none: several times fewer steps than testing node by node,
    and no branch on a node (whose outcome no predictor learns). The edges and their weights
    are the same to the last bit: the same differences, compared and weighed alike.
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
    # each other object's distances in node order, so that the inner loop reads two arrays
    # in step instead of gathering: a node's other object recurs in many nodes, so this
    # gathers several times less
    by_node = matrix and n_other * m <= _DISTANCE_MATRIX_MAX
    d_nodes = np.empty((n_other if by_node else 1, m))
    if by_node:
        for j in range(n_other):
            d_j, d_node = d_other[j], d_nodes[j]
            for q in range(m):
                d_node[q] = d_j[np.uint64(other_idx[q])]
    # later nodes within epsilon of the current node: a byte each, read eight at a time
    near = np.zeros(8 * (m // 8 + 1), np.bool_)
    near_words = near.view(np.uint64)
    row_cols = np.empty(m + 8, np.int64)
    row_c = np.empty(m)
    capacity = max(16, 4 * m)
    rows = np.empty(capacity, np.int64)
    cols = np.empty(capacity, np.int64)
    wts = np.empty(capacity)
    # the groups' ego objects, each axis contiguous: a group's distances to all later groups
    # are then summed over the axes in order and rooted in passes of vector instructions
    group_points = np.empty((dim, n_groups))
    for h in range(n_groups):
        for a in range(dim):
            group_points[a, h] = ego_points[group_ego[h], a]
    d_group = np.empty(n_groups)
    n = 0
    for g in range(n_groups):
        i = group_ego[g]
        d_group[g + 1:] = 0.0
        for a in range(dim):
            x = group_points[a]
            for h in range(g + 1, n_groups):
                diff = x[g] - x[h]
                d_group[h] += diff * diff
        for h in range(g + 1, n_groups):
            d_group[h] = np.sqrt(d_group[h])
        for h in range(g + 1, n_groups):
            d_gh = d_group[h]
            dz_gh = ego_z[i] - ego_z[group_ego[h]] if heights else 0.0
            # unsigned q: numba then skips the negative-index wraparound, and the stores are
            # contiguous instead of scattered
            for q in range(np.uint64(group_start[h]), np.uint64(group_start[h + 1])):
                d_ego[q] = d_gh
                dz_ego[q] = dz_gh
        later = group_start[g + 1]
        first = np.uint64(later)
        n_later = np.uint64(m) - first
        n_words = (n_later + np.uint64(7)) // np.uint64(8)
        near[n_later:] = False  # the last word's bytes past the last node mark nothing
        for p in range(group_start[g], later):
            j = other_idx[p]
            if by_node:
                d_node = d_nodes[j]
            else:
                d_j = d_other[j] if matrix else d_other[0]
                if not matrix:
                    _distances_from(other_points, j, d_j)
                d_node = d_nodes[0]
                for q in range(later, m):
                    d_node[q] = d_j[other_idx[q]]
            # unsigned positions: numba then skips the negative-index wraparound of every
            # access (a third of these loops' time)
            for t in range(n_later):
                near[t] = abs(d_ego[first + t] - d_node[first + t]) < epsilon
            # the marked nodes listed in order, each node of a word that marks any written
            # and the count moved past it only when it is marked
            n_near = 0
            for w in range(n_words):
                if near_words[w] == 0:
                    continue
                for t in range(np.uint64(8) * w, np.uint64(8) * w + np.uint64(8)):
                    row_cols[np.uint64(n_near)] = first + t
                    n_near += near[t]
            # of those, the ones of another other object (and climbing alike), kept in order
            count = 0
            for t in range(n_near):
                q = row_cols[t]
                ell = other_idx[q]
                if ell != j and (
                        not heights or abs(dz_ego[q] - (other_z[j] - other_z[ell]))
                        < height_epsilon + slack[p] + slack[q]):
                    row_cols[count] = q
                    row_c[count] = abs(d_ego[q] - d_node[q])
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
        epsilon, sigma: metres, finite, epsilon > 0 and sigma >= 1e-9 (`MIN_SIGMA`).
        prior: optional (m,) non-negative prior weight per association (affinity diagonal).
        z: optional ((n1,), (n2,)) metres, each object's centre's height above its frame's
            origin (along gravity).
        height_epsilon: metres, finite and > 0, with z (None without).
        vertical_extents: optional ((n1,), (n2,)) metres >= 0, the objects' heights
            (`ObjectMap.heights`), with z.

    Raises:
        ConfigError: epsilon or height_epsilon not a finite number > 0, sigma not a finite
            number >= MIN_SIGMA, or z and height_epsilon not given together.
        DataError: points, associations, prior, z or vertical_extents of the wrong shape or
            out of range, not real numbers (complex ones included), or associations that are
            not whole numbers: an (m, 3) array is refused, not read as pairs, and 1.5 is not
            truncated to 1.
    """
    o = "consistency_graph"
    _require(_finite(epsilon) and epsilon > 0, o, "epsilon", epsilon,
             "must be a finite number > 0 metres")
    # below MIN_SIGMA the kernel's 1 / (2 sigma^2) overflows into NaN weights (or divides by 0)
    _require(_finite(sigma) and sigma >= MIN_SIGMA, o, "sigma", sigma,
             f"must be a finite number >= {_bound(MIN_SIGMA)} metres (MIN_SIGMA)")
    _require((z is None) == (height_epsilon is None), o, "height_epsilon",
             height_epsilon, "must be given with z, and only with it")
    if height_epsilon is not None:
        _require(_finite(height_epsilon) and height_epsilon > 0, o, "height_epsilon",
                 height_epsilon, "must be a finite number > 0 metres")
    ego_points = real_array(o, "ego_points", ego_points)
    other_points = real_array(o, "other_points", other_points)
    associations = index_pairs(o, "associations", associations)
    for name, arr in (("ego_points", ego_points), ("other_points", other_points)):
        if arr.ndim != 2 or arr.shape[1] not in (2, 3):
            raise DataError(f"consistency_graph: {name} must be (n, 2) or (n, 3) points, got "
                            f"shape {arr.shape}")
    if other_points.shape[1] != ego_points.shape[1]:
        raise DataError(f"consistency_graph: ego_points and other_points must have as many "
                        f"coordinates, got shapes {ego_points.shape} and {other_points.shape}")
    check_within(o, "ego_points", ego_points, MAX_COORDINATE, "m")
    check_within(o, "other_points", other_points, MAX_COORDINATE, "m")
    m = associations.shape[0]
    for side, name in enumerate(("ego_points", "other_points")):
        n = len(ego_points if side == 0 else other_points)
        if m and associations[:, side].max() >= n:
            i = int(np.argmax(associations[:, side]))
            raise DataError(f"consistency_graph: associations[{i}, {side}] = "
                            f"{associations[i, side]} is out of range for {name} of {n} "
                            f"points")
    if prior is None:
        diag = np.ones(m)
    else:
        diag = real_array(o, "prior", prior)
        if diag.shape != (m,) or not ((diag >= 0) & (diag <= MAX_AFFINITY)).all():
            raise DataError(f"consistency_graph: prior must be ({m},) finite numbers in "
                            f"[0, {MAX_AFFINITY:g}], got {shown(diag)}")
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
