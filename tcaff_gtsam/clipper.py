"""CLIPPER: the relaxed densest-clique solver on a consistency graph (`consistency_graph`), and
the multiple-near-optima variant of the paper (MNO-CLIPPER, Algorithm 1).

Hot loops are compiled with numba; the compiled code is cached on disk next to this module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .clipper_graph import (  # the graph, re-exported where it was
    ConsistencyGraph,
    _checked_graph,
    consistency_graph,
)
from .params import (
    MAX_SOLUTIONS,
    ClipperParams,
    _int_at_least,
    _real,
    _require,
)

__all__ = ["ClipperSolution", "ConsistencyGraph", "clipper_solve", "consistency_graph",
           "mno_clipper"]


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


@numba.njit(cache=True)
def _scatter(indptr, indices, weights, diag, u, support, n_support, Mu, Cu, touched, n_old):
    """Mu = M u and Cu = C u (C binary, diagonal included) for u supported on `support`.

    Scatter form: row q of the symmetric adjacency is also its column q, so the cost is the
    sum of the support's degrees, not m. Only the nodes written (the support and its
    neighbours) are valid; they are listed in `touched` ((m + 1,): one slot past the last is
    written) in the order first written. On entry Mu is 0 and Cu is -1 (never a sum of u >= 0:
    not yet written) off the `n_old` nodes `touched` lists (the buffers' previous product),
    which are reset first; on return every node not touched has Mu = 0 and Cu = -1. Returns
    (number touched, sum of u).
    """
    # Without branches or a mark array: every node written is listed, and the count moves
    # past it only on its first write, which Cu < 0 tells. Each sum starts from 0.0 as it did
    # when the first write set it, so the products are the same to the last bit; a branch on
    # the first write and a mark per node cost about a seventh of MNO-CLIPPER's time. The
    # first-write block is written out twice on purpose: moving it into a helper (even an
    # inlined one) made this loop about 9 times slower under numba. Node indices, and the
    # count as a position in `touched`, are read as unsigned: numba then skips the
    # negative-index wraparound of every access (a fifth of MNO-CLIPPER's time, the count's
    # another twentieth, with the same arithmetic), here and in the helpers below.
    for t in range(n_old):
        p = np.uint64(touched[t])
        Mu[p] = 0.0
        Cu[p] = -1.0
    n_touched = 0
    total = 0.0
    for s in range(n_support):
        q = np.uint64(support[s])
        uq = u[q]
        total += uq
        c = Cu[q]
        first = c < 0.0
        touched[np.uint64(n_touched)] = q
        n_touched += first
        Mu[q] += diag[q] * uq
        Cu[q] = (0.0 if first else c) + uq
        for e in range(np.uint64(indptr[q]), np.uint64(indptr[q + np.uint64(1)])):
            p = np.uint64(indices[e])
            c = Cu[p]
            first = c < 0.0
            touched[np.uint64(n_touched)] = p
            n_touched += first
            Mu[p] += weights[e] * uq
            Cu[p] = (0.0 if first else c) + uq
    return n_touched, total


@numba.njit(cache=True)
def _objective(u, support, n_support, Mu, Cu, total, d):
    """u' M_d u = sum over the support of u_p g_p, g = M_d u (`_project`)."""
    F = 0.0
    for s in range(n_support):
        p = np.uint64(support[s])
        F += u[p] * (Mu[p] - d * (total - Cu[p]))
    return F


@numba.njit(cache=True)
def _project(u, Mu, Cu, total, d, plain, alpha, touched, n_touched, active, out, out_support):
    """out = normalize(max(u + alpha g, 0)) over active touched nodes, g = M_d u =
    Mu - d (sum(u) - Cu) from the products of u (`_scatter`), or g = Mu when `plain`.

    The gradient is formed where it is used, here and in `_objective`, rather than stored: the
    same values, without a pass of its own. Untouched nodes stay at zero: they have u = 0 and
    g = -d sum(u) <= 0. `out` is zero on entry, so a node clipped (or inactive) may be written
    0.0 like any other. Returns the size of the new support (listed in out_support); 0 when
    everything was clipped.
    """
    # Without a branch on which nodes are kept (about half of those touched, in no order a
    # predictor learns): each is written and listed, and the count moves past it only when
    # it is kept; a clipped one adds 0.0 to the norm, which leaves it as it is (it is >= 0).
    norm_sq = 0.0
    n = 0
    for t in range(n_touched):
        p = np.uint64(touched[t])
        g = Mu[p] if plain else Mu[p] - d * (total - Cu[p])
        v = u[p] + alpha * g
        keep = active[p] & (v > 0.0)
        v = v if keep else 0.0
        out[p] = v
        out_support[np.uint64(n)] = p
        n += keep
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
        p = np.uint64(support[s])
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

    Vectors are dense arrays that are zero off an explicit support list (the products Mu, Cu
    off their touched list: see `_scatter`); the current iterate (u, its products and
    gradient) and the line-search trial (ub, ...) each own a set of buffers, swapped on
    acceptance. Returns (u, d, final objective u'Mu).
    """
    m = u0.shape[0]
    u, ub = np.zeros(m), np.zeros(m)
    sup, sup_b = np.empty(m, np.int64), np.empty(m, np.int64)
    Mu, Mu_b = np.zeros(m), np.zeros(m)
    Cu, Cu_b = np.full(m, -1.0), np.full(m, -1.0)
    tch, tch_b = np.empty(m + 1, np.int64), np.empty(m + 1, np.int64)
    n_sup = 0
    for p in range(m):
        if active[p] and u0[p] > 0.0:
            u[p] = u0[p]
            sup[n_sup] = p
            n_sup += 1
    n_tch, total = _scatter(indptr, indices, weights, diag, u, sup, n_sup, Mu, Cu, tch, 0)
    n_tch_b = 0
    for _ in range(power_iterations):
        for s in range(n_sup):
            u[np.uint64(sup[s])] = 0.0
        # u = Mu / |Mu| (ub is 0)
        n_new = _project(ub, Mu, Cu, total, 0.0, True, 1.0, tch, n_tch, active, u, sup_b)
        if n_new == 0:
            break
        sup, sup_b = sup_b, sup
        n_sup = n_new
        n_tch, total = _scatter(indptr, indices, weights, diag, u, sup, n_sup, Mu, Cu, tch,
                                n_tch)
    d = _penalty_step(u, sup, n_sup, Mu, Cu, total, eps, True)
    F = _objective(u, sup, n_sup, Mu, Cu, total, d)
    for _ in range(max_outer):
        for _ in range(max_inner):
            alpha = 1.0
            Fb = F
            n_b = 0
            for _ in range(max_line_search):
                for s in range(n_b):
                    ub[np.uint64(sup_b[s])] = 0.0
                n_b = _project(u, Mu, Cu, total, d, False, alpha, tch, n_tch, active, ub,
                               sup_b)
                if n_b == 0:
                    alpha *= beta
                    continue
                n_tch_b, total_b = _scatter(indptr, indices, weights, diag, ub, sup_b, n_b,
                                            Mu_b, Cu_b, tch_b, n_tch_b)
                Fb = _objective(ub, sup_b, n_b, Mu_b, Cu_b, total_b, d)
                if Fb - F < -eps:
                    alpha *= beta
                else:
                    break
            delta = Fb - F
            if n_b == 0 or delta < -eps:
                for s in range(n_b):
                    ub[np.uint64(sup_b[s])] = 0.0
                break
            for s in range(n_sup):
                u[np.uint64(sup[s])] = 0.0
            u, ub = ub, u
            sup, sup_b = sup_b, sup
            n_sup = n_b
            Mu, Mu_b = Mu_b, Mu
            Cu, Cu_b = Cu_b, Cu
            tch, tch_b = tch_b, tch
            n_tch, n_tch_b, total, F = n_tch_b, n_tch, total_b, Fb
            if abs(delta) < tol_u:
                break
        step = _penalty_step(u, sup, n_sup, Mu, Cu, total, eps, False)
        if step == 0.0:
            break
        d += step
        F = _objective(u, sup, n_sup, Mu, Cu, total, d)
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
def _drop_inactive(indptr, indices, weights, active):
    """Remove, in place, the entries of the CSR arrays (indptr (m + 1,), indices, weights) in
    the rows of nodes no longer `active` ((m,) bool) or pointing at them, keeping the order
    of the rest.

    An inactive node never enters a support, so its row is never read, and the products at
    it are never read either (the projection skips it, the objective and the penalty read
    the support): the solver then sums the same terms in the same order, to the last bit,
    without the fifth to third of its steps that went to such entries once the first
    solutions left the graph. Each active row is compacted without a branch per entry: each
    is written, and the count moves past it only when it points at an active node."""
    kept = 0
    start = indptr[0]
    for q in range(indptr.shape[0] - 1):
        end = indptr[q + 1]
        if active[q]:
            for e in range(start, end):
                p = indices[e]
                indices[kept] = p
                weights[kept] = weights[e]
                kept += active[p]
        start = end
        indptr[q + 1] = kept


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
    # the graph the solver searches: with downweight 0 a solution's nodes leave it, and with
    # them the entries of other rows that point at them (`_drop_inactive`)
    solver_indptr, solver_indices, w = indptr.copy(), indices.copy(), weights.copy()
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
        u, d, objective = _solve(solver_indptr, solver_indices, w, dg, active, u0,
                                 power_iterations, tol_u, eps, beta, max_outer, max_inner,
                                 max_line_search)
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
            if k < n_solutions and n_active > 0:  # another solution follows
                _drop_inactive(solver_indptr, solver_indices, w, active)
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
