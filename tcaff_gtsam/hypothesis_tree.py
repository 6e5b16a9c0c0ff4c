"""Hypothesis trees of Kalman updates, stored as arrays of leaves.

Only leaves are kept. A leaf's path through its tree is its row of `choice`: the index of the
measurement it took at each of the last W + 2 steps (`NO_MEASUREMENT` for the no-measurement
child, `BEFORE_ROOT` for steps before its tree's root). After the extension at step n, column c
holds step n - W - 1 + c, so the last column is the current step and the last W columns are the
window a path is judged on. Two leaves of one tree share the node at column c exactly when they
share the node at column c - 1 and took the same measurement at column c, which is what the
sliding-window pruning (`branch`) uses. `edge` holds the cost of the edge into each node, so a
leaf's path cost over the window is the sum of its last W columns.

Many trees live in one set of arrays (`tree` names each leaf's tree), so the exploring trees
are extended, gated and pruned together.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from .inputs import kernel_array

__all__ = [
    "BEFORE_ROOT",
    "NO_MEASUREMENT",
    "CostModel",
    "Leaves",
    "best_per_tree",
    "branch",
    "extend",
    "kalman_children",
    "lowest",
    "mahalanobis_to",
    "measurement_costs",
    "not_positive_definite",
    "seed",
]

NO_MEASUREMENT = -1
BEFORE_ROOT = -2
_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class CostModel:
    """How a leaf scores and updates with a measurement (see `TCAFFParams`).

    Attributes:
        Q: (d, d) process noise per step.
        angular: (d,) bool, components wrapped to [-pi, pi).
        reference: the released code's cost and gain (diagonal inverses, S = P + R, the squared
            Mahalanobis distance squared again, + d/2 log 2 pi per measurement).
        use_box: box gate instead of the Mahalanobis gate.
        gate_chi2: squared Mahalanobis distance above which a measurement is gated out.
        gate_box: (d,) box half-widths.
        no_measurement_cost: cost of a no-measurement child.
        held_Q: (d, d) process noise of a no-measurement child whose path has gone more than
            `held_after` steps without a measurement, instead of Q; None: Q.
        held_after: steps.
    """

    Q: np.ndarray
    angular: np.ndarray
    reference: bool
    use_box: bool
    gate_chi2: float
    gate_box: np.ndarray
    no_measurement_cost: float
    held_Q: np.ndarray | None = None
    held_after: int = 0


#: every field of `Leaves`, in order, with its dtype
LEAF_DTYPES = {"x": np.float64, "P": np.float64, "choice": np.int32, "edge": np.float64,
               "since": np.int64, "tree": np.int64}


@dataclass(frozen=True, eq=False)
class Leaves:
    """The leaves of one or more hypothesis trees.

    Attributes:
        x: (L, d) filtered states.
        P: (L, d, d) their covariances.
        choice: (L, W + 2) int32, measurement index per step (see the module docstring).
        edge: (L, W + 2) cost of the edge into each node of the path.
        since: (L,) int64, steps since the path last took a measurement.
        tree: (L,) int64, id of the tree each leaf belongs to.
    """

    x: np.ndarray
    P: np.ndarray
    choice: np.ndarray
    edge: np.ndarray
    since: np.ndarray
    tree: np.ndarray

    @classmethod
    def empty(cls, d: int, columns: int) -> Leaves:
        shapes = ((0, d), (0, d, d), (0, columns), (0, columns), (0,), (0,))
        return cls(*(np.empty(shape, LEAF_DTYPES[f]) for f, shape in
                     zip(LEAF_DTYPES, shapes, strict=True)))

    def __len__(self) -> int:
        return self.x.shape[0]

    @cached_property
    def cost(self) -> np.ndarray:
        """(L,) path cost over the window, the last W = columns - 2 columns (computed once:
        the filter reads it several times per step)."""
        return self.edge[:, 2:].sum(axis=1)

    def take(self, index) -> Leaves:
        """Leaves selected by an index array or boolean mask."""
        return Leaves(self.x[index], self.P[index], self.choice[index], self.edge[index],
                      self.since[index], self.tree[index])

    @staticmethod
    def concat(parts: list[Leaves]) -> Leaves:
        return Leaves(*(np.concatenate([getattr(p, f) for p in parts]) for f in LEAF_DTYPES))


def seed(x0: np.ndarray, P0: np.ndarray, tree_ids: np.ndarray, root_choice: np.ndarray,
         columns: int) -> Leaves:
    """One root leaf per row of x0 (n, d), each its own tree, rooted at the current step."""
    n, d = x0.shape
    choice = np.full((n, columns), BEFORE_ROOT, np.int32)
    choice[:, -1] = root_choice
    return Leaves(np.array(x0, dtype=float), np.broadcast_to(P0, (n, d, d)).copy(), choice,
                  np.zeros((n, columns)), np.zeros(n, np.int64), np.asarray(tree_ids, np.int64))


@numba.njit(cache=True, inline="always")
def _residual(z, x, angular, r):
    """r = z - x with angular components wrapped to [-pi, pi)."""
    two_pi = 2.0 * np.pi
    for a in range(r.shape[0]):
        ra = z[a] - x[a]
        if angular[a]:
            ra -= two_pi * np.floor((ra + np.pi) / two_pi)
        r[a] = ra


@numba.njit(cache=True, inline="always")
def _cholesky(S, C):
    """Lower Cholesky factor of S (d, d) into C, in place (S = C C'); whether every pivot was
    positive (S positive definite). A pivot <= 0 is clamped to a tiny positive value."""
    positive = True
    for a in range(S.shape[0]):
        for b in range(a + 1):
            s = S[a, b]
            for e in range(b):
                s -= C[a, e] * C[b, e]
            if a == b:
                positive = positive and s > 0.0
                C[a, a] = np.sqrt(max(s, 1e-300))
            else:
                C[a, b] = s / C[b, b]
    return positive


@numba.njit(cache=True, inline="always")
def _whitened(C, r):
    """r <- C^-1 r in place for a lower Cholesky factor C (d, d); returns |r|^2, the squared
    Mahalanobis distance under C C'."""
    maha = 0.0
    for a in range(r.shape[0]):
        y = r[a]
        for c in range(a):
            y -= C[a, c] * r[c]
        r[a] = y / C[a, a]
        maha += r[a] * r[a]
    return maha


@numba.njit(cache=True, inline="always")
def _product(A, B, out, transpose_b):
    """out = A B (or A B' with transpose_b), all (d, d)."""
    d = A.shape[0]
    for a in range(d):
        for b in range(d):
            s = 0.0
            for e in range(d):
                s += A[a, e] * (B[b, e] if transpose_b else B[e, b])
            out[a, b] = s


@numba.njit(cache=True)
def _mahalanobis_to(x, P, x0, P0, angular):
    """(L,) squared Mahalanobis distance of each state x[l] from x0 under P[l] + P0."""
    L, d = x.shape
    out = np.empty(L)
    r = np.empty(d)
    S = np.empty((d, d))
    C = np.zeros((d, d))
    for leaf in range(L):
        _residual(x[leaf], x0, angular, r)
        for a in range(d):
            for b in range(d):
                S[a, b] = P[leaf, a, b] + P0[a, b]
        _cholesky(S, C)
        out[leaf] = _whitened(C, r)
    return out


def mahalanobis_to(x: np.ndarray, P: np.ndarray, x0: np.ndarray, P0: np.ndarray,
                   angular: np.ndarray) -> np.ndarray:
    """(L,) squared Mahalanobis distance of states x (L, d) with covariances P (L, d, d) from
    one state x0 (d,) with covariance P0 (d, d), under P + P0; the components where angular
    (d,) bool is set are wrapped."""
    return _mahalanobis_to(kernel_array(x), kernel_array(P), kernel_array(x0), kernel_array(P0),
                           angular)


@numba.njit(cache=True)
def _first_not_positive_definite(P):
    """Index of the first matrix of P (n, d, d) whose Cholesky factorisation meets a pivot
    <= 0, or -1."""
    n, d, _ = P.shape
    C = np.zeros((d, d))
    for i in range(n):
        if not _cholesky(P[i], C):
            return i
    return -1


def not_positive_definite(P: np.ndarray) -> int:
    """Index of the first of the symmetric matrices P (n, d, d) that is not positive definite
    (its Cholesky factorisation fails), or -1 when all are."""
    return int(_first_not_positive_definite(kernel_array(P)))


@numba.njit(cache=True)
def _measurement_costs(x, P, zs, Rs, Q, angular, reference, use_box, gate_chi2, gate_box):
    """(L, k) cost of giving leaf l measurement j; inf where the gate rejects it."""
    L, d = x.shape
    k = zs.shape[0]
    out = np.empty((L, k))
    r = np.empty(d)
    S = np.empty((d, d))
    C = np.zeros((d, d))
    for leaf in range(L):
        for j in range(k):
            _residual(zs[j], x[leaf], angular, r)
            gated_out = False
            for a in range(d):
                if use_box and abs(r[a]) > gate_box[a]:
                    gated_out = True
            if gated_out:
                out[leaf, j] = np.inf
                continue
            if reference:
                maha = 0.0
                logdet = 0.0
                for a in range(d):
                    s = P[leaf, a, a] + Rs[j, a, a]
                    maha += r[a] * r[a] / s
                    logdet += np.log(s)
                cost = 0.5 * (maha * maha + logdet + d * _LOG_2PI)
            else:
                # r' S^-1 r >= r_a^2 / S_aa for every a (Cauchy-Schwarz): most pairs leave the
                # gate on one component, before any factorisation or logarithm
                if not use_box:
                    for a in range(d):
                        if r[a] * r[a] > gate_chi2 * (P[leaf, a, a] + Q[a, a] + Rs[j, a, a]):
                            gated_out = True
                            break
                    if gated_out:
                        out[leaf, j] = np.inf
                        continue
                for a in range(d):
                    for b in range(d):
                        S[a, b] = P[leaf, a, b] + Q[a, b] + Rs[j, a, b]
                # S = C C', then C y = r gives maha = |y|^2 and log|S| = 2 sum log C_aa
                _cholesky(S, C)
                maha = _whitened(C, r)
                logdet = 0.0
                for a in range(d):
                    logdet += 2.0 * np.log(C[a, a])
                cost = 0.5 * (maha + logdet)
            if not use_box and maha > gate_chi2:
                cost = np.inf
            out[leaf, j] = cost
    return out


@numba.njit(cache=True)
def _kalman_children(x, P, parent, meas, zs, Rs, Q, angular, reference):
    """States (n, d) and covariances (n, d, d) of the children (parent[c], meas[c]).

    meas[c] < 0 is the no-measurement child: the prediction x, P + Q (identity motion).
    """
    n = parent.shape[0]
    d = x.shape[1]
    x_out = np.empty((n, d))
    P_out = np.empty((n, d, d))
    Pp = np.empty((d, d))
    S = np.empty((d, d))
    C = np.zeros((d, d))
    Ci = np.zeros((d, d))
    Si = np.empty((d, d))
    K = np.empty((d, d))
    A = np.empty((d, d))
    T = np.empty((d, d))
    r = np.empty(d)
    two_pi = 2.0 * np.pi
    for c in range(n):
        leaf = parent[c]
        j = meas[c]
        for a in range(d):
            for b in range(d):
                Pp[a, b] = P[leaf, a, b] + Q[a, b]
        if j < 0:
            for a in range(d):
                x_out[c, a] = x[leaf, a]
                for b in range(d):
                    P_out[c, a, b] = Pp[a, b]
            continue
        _residual(zs[j], x[leaf], angular, r)
        for a in range(d):
            for b in range(d):
                S[a, b] = Pp[a, b] + Rs[j, a, b]
        if reference:
            for a in range(d):
                for b in range(d):
                    Si[a, b] = 1.0 / S[a, a] if a == b else 0.0
        else:
            # S^-1 = C^-T C^-1 from the Cholesky factor
            _cholesky(S, C)
            for b in range(d):
                for a in range(d):
                    if a < b:
                        Ci[a, b] = 0.0
                        continue
                    s = 1.0 if a == b else 0.0
                    for e in range(b, a):
                        s -= C[a, e] * Ci[e, b]
                    Ci[a, b] = s / C[a, a]
            for a in range(d):
                for b in range(d):
                    s = 0.0
                    for e in range(max(a, b), d):
                        s += Ci[e, a] * Ci[e, b]
                    Si[a, b] = s
        _product(Pp, Si, K, False)
        for a in range(d):
            s = x[leaf, a]
            for b in range(d):
                s += K[a, b] * r[b]
            if angular[a]:
                s -= two_pi * np.floor((s + np.pi) / two_pi)
            x_out[c, a] = s
            for b in range(d):
                A[a, b] = (1.0 if a == b else 0.0) - K[a, b]
        # reference: P = (I - K) Pp; paper: Joseph form (I - K) Pp (I - K)' + K R K'
        _product(A, Pp, T, False)
        if reference:
            P_out[c] = T
        else:
            _product(T, A, P_out[c], True)
            _product(K, Rs[j], S, False)
            _product(S, K, T, True)
            P_out[c] += T
        for a in range(d):
            for b in range(a):
                m = 0.5 * (P_out[c, a, b] + P_out[c, b, a])
                P_out[c, a, b] = m
                P_out[c, b, a] = m
    return x_out, P_out


@numba.njit(cache=True)
def _children(costs, max_children, no_measurement_cost):
    """Children of every leaf in leaf order: its `max_children` cheapest gated measurements
    (ties to the lower index), then its no-measurement child. Returns parent, measurement
    index (-1 for none) and edge cost, each (n,)."""
    L, k = costs.shape
    take = min(max_children, k)
    n_max = L * (take + 1)
    parent = np.empty(n_max, np.int64)
    meas = np.empty(n_max, np.int64)
    edge = np.empty(n_max)
    best = np.empty(take, np.int64)
    n = 0
    for leaf in range(L):
        m = 0
        for j in range(k):
            c = costs[leaf, j]
            if not np.isfinite(c):
                continue
            if m < take:
                m += 1
            elif c >= costs[leaf, best[m - 1]]:
                continue
            pos = m - 1  # insertion into the sorted short list
            while pos > 0 and costs[leaf, best[pos - 1]] > c:
                best[pos] = best[pos - 1]
                pos -= 1
            best[pos] = j
        for i in range(m):
            parent[n], meas[n], edge[n] = leaf, best[i], costs[leaf, best[i]]
            n += 1
        parent[n], meas[n], edge[n] = leaf, -1, no_measurement_cost
        n += 1
    return parent[:n], meas[:n], edge[:n]


@numba.njit(cache=True)
def _best_per_group(cost, group, count):
    """Indices (sorted) of the `count` lowest costs within each run of equal `group` values."""
    n = cost.shape[0]
    keep = np.empty(n, np.int64)
    m = 0
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and group[stop] == group[start]:
            stop += 1
        if stop - start <= count:
            for i in range(start, stop):
                keep[m] = i
                m += 1
        else:
            chosen = np.sort(np.argsort(cost[start:stop], kind="mergesort")[:count])
            for i in chosen:
                keep[m] = start + i
                m += 1
        start = stop
    return keep[:m]


def lowest(cost: np.ndarray, count: int) -> np.ndarray:
    """Indices (sorted) of the `count` lowest costs, all if there are fewer."""
    if cost.size <= count:
        return np.arange(cost.size)
    return np.sort(np.argpartition(cost, count - 1)[:count])


def best_per_tree(cost: np.ndarray, tree: np.ndarray, count: int) -> np.ndarray:
    """Indices of the `count` lowest costs of every tree; leaves of a tree must be adjacent."""
    if cost.size <= count:
        return np.arange(cost.size)
    return _best_per_group(cost, tree, count)


def branch(choice: np.ndarray, best: int, column: int) -> np.ndarray:
    """Slide one tree's window: indices of the leaves below the node at `column` on leaf
    `best`'s path, which becomes the root (paper: sliding-window pruning). The node before it
    must be shared by all leaves."""
    return np.flatnonzero(choice[:, column] == choice[best, column])


def measurement_costs(leaves: Leaves, zs: np.ndarray, Rs: np.ndarray, model: CostModel
                      ) -> np.ndarray:
    """(L, k) edge cost of giving each leaf each measurement; inf where the gate rejects it."""
    if zs.shape[0] == 0 or len(leaves) == 0:
        return np.empty((len(leaves), zs.shape[0]))
    return _measurement_costs(leaves.x, leaves.P, kernel_array(zs), kernel_array(Rs), model.Q,
                              model.angular, model.reference, model.use_box, model.gate_chi2,
                              model.gate_box)


def kalman_children(leaves: Leaves, parents: np.ndarray, meas: np.ndarray, zs: np.ndarray,
                    Rs: np.ndarray, model: CostModel) -> tuple[np.ndarray, np.ndarray]:
    """States (n, d) and covariances (n, d, d) of the children (leaf parents[c] updated with
    measurement meas[c], or only predicted where meas[c] < 0)."""
    return _kalman_children(leaves.x, leaves.P, np.asarray(parents, np.int64),
                            np.asarray(meas, np.int64), kernel_array(zs), kernel_array(Rs),
                            model.Q, model.angular, model.reference)


def extend(leaves: Leaves, zs: np.ndarray, Rs: np.ndarray, model: CostModel,
           max_children: int, prune: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
           ) -> Leaves:
    """Advance every leaf by one step: its best `max_children` gated measurements and one
    no-measurement child (its covariance grown by Q, or by `model.held_Q` once its path has
    gone more than `model.held_after` steps without a measurement). Columns shift left by
    one; the new step is the last column.

    Children are pruned before their Kalman updates are computed: `prune(cost, choice, tree)`
    gets the children's window costs (n,), paths (n, W + 2) and tree ids (n,) and returns
    the indices to keep. Children come out in the order of their parents, so the leaves of a
    tree stay adjacent.

    Args:
        zs: (k, d) measurements, angles wrapped; Rs: (k, d, d) their covariances; k may be 0.
    """
    costs = measurement_costs(leaves, zs, Rs, model)
    parents, meas, edge_new = _children(costs, max_children, model.no_measurement_cost)
    columns = leaves.choice.shape[1]
    choice = np.empty((parents.size, columns), np.int32)
    choice[:, :-1] = leaves.choice[parents, 1:]
    choice[:, -1] = meas
    edge = np.empty((parents.size, columns))
    edge[:, :-1] = leaves.edge[parents, 1:]
    edge[:, -1] = edge_new
    tree = leaves.tree[parents]
    keep = prune(edge[:, 2:].sum(axis=1), choice, tree)
    parents, meas = parents[keep], meas[keep]
    x, P = kalman_children(leaves, parents, meas, zs, Rs, model)
    since = np.where(meas >= 0, 0, leaves.since[parents] + 1)
    if model.held_Q is not None:
        held = np.flatnonzero(since > model.held_after)
        if held.size:
            P[held] = leaves.P[parents[held]] + model.held_Q
    return Leaves(x, P, choice[keep], edge[keep], since, tree[keep])
