"""Team consistency: the pairwise alignments of three or more robots that agree around cycles,
and alignments chained through a third robot where two robots have none of their own.

Every robot pair's filter (TCAFF) decides alone. With three robots i, j, k the alignments must
close the cycle: T_oi_oj T_oj_ok T_ok_oi = I. `TeamConsistency.update` takes the pairs'
current estimates, tests every cycle of three robots whose three alignments are all known
(squared Mahalanobis distance of the cycle's error against the chi-square quantile), keeps the
largest set of pair alignments no failed cycle lies entirely inside (ties: the set whose
alignments are the most certain), and fills the pairs it lacks by composing kept alignments
along the shortest chain of robots. A pair that no cycle tests is kept: nothing speaks against
it.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincinv  # chi2.ppf's own formula, without scipy.stats' import

from .errors import DataError
from .geometry import _se2_from_params, _wrap_angle
from .inputs import real_array, shown
from .params import _int_at_least, _require

__all__ = ["TeamConsistency", "TeamEstimate", "TeamParams"]


@dataclass(frozen=True)
class TeamParams:
    """Settings of `TeamConsistency`.

    Attributes:
        cycle_probability: a cycle of three alignments fails when its error's squared
            Mahalanobis distance exceeds the chi-square quantile of 3 degrees of freedom at this
            probability.
        max_chain: most pair alignments composed into a chained one (2: through one robot).
        exact_up_to: the largest consistent set is searched exactly over up to this many
            undirected pairs (2^n subsets); larger teams drop the alignment in the most failed
            cycles until none is left.
    """

    cycle_probability: float = 0.999
    max_chain: int = 2
    exact_up_to: int = 12

    def __post_init__(self) -> None:
        o = "TeamParams"
        p = self.cycle_probability
        _require(isinstance(p, (int, float)) and not isinstance(p, bool) and 0 < p < 1, o,
                 "cycle_probability", p, "must be in (0, 1)")
        _require(_int_at_least(self.max_chain, 1), o, "max_chain", self.max_chain,
                 "must be an int >= 1")
        _require(_int_at_least(self.exact_up_to, 0) and self.exact_up_to <= 20, o,
                 "exact_up_to", self.exact_up_to, "must be an int in [0, 20]")


@dataclass(frozen=True)
class TeamEstimate:
    """A team-consistent T_oi_oj.

    Attributes:
        x: (3,) (x [m], y [m], theta [rad]) of T_oi_oj; P: (3, 3) its covariance.
        path: the robots it runs through, (i, j) for the pair's own alignment, (i, k, j) for one
            chained through robot k.
    """

    x: np.ndarray
    P: np.ndarray
    path: tuple[int, ...]

    @property
    def T(self) -> np.ndarray:
        """(3, 3) the SE(2) matrix."""
        return _se2_from_params(self.x)

    @property
    def chained(self) -> bool:
        return len(self.path) > 2


def _compose(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
             ) -> tuple[np.ndarray, np.ndarray]:
    """(x, P) of T_a T_b, the covariance propagated to first order."""
    (xa, Pa), (xb, Pb) = a, b
    c, s = math.cos(xa[2]), math.sin(xa[2])
    R = np.array([[c, -s], [s, c]])
    t = R @ xb[:2]
    x = np.array([xa[0] + t[0], xa[1] + t[1], _wrap_angle(xa[2] + xb[2])])
    Ja = np.array([[1.0, 0.0, -t[1]], [0.0, 1.0, t[0]], [0.0, 0.0, 1.0]])
    Jb = np.eye(3)
    Jb[:2, :2] = R
    return x, Ja @ Pa @ Ja.T + Jb @ Pb @ Jb.T


def _invert(a: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(x, P) of T_a^-1, the covariance propagated to first order."""
    x, P = a
    c, s = math.cos(x[2]), math.sin(x[2])
    Rt = np.array([[c, s], [-s, c]])
    t = -Rt @ x[:2]
    J = -np.eye(3)
    J[:2, :2] = -Rt
    J[:2, 2] = [t[1], -t[0]]
    return np.array([t[0], t[1], _wrap_angle(-x[2])]), J @ P @ J.T


class TeamConsistency:
    """The jointly consistent pairwise alignments of a team, one step at a time (`update`).

    Args:
        n_robots: robots 0 .. n_robots - 1.
    """

    def __init__(self, n_robots: int, params: TeamParams | None = None) -> None:
        _require(_int_at_least(n_robots, 2), "TeamConsistency", "n_robots", n_robots,
                 "must be an int >= 2")
        self.n_robots = int(n_robots)
        self.params = TeamParams() if params is None else params
        _require(isinstance(self.params, TeamParams), "TeamConsistency", "params", params,
                 "must be a TeamParams")
        self._gate = float(2 * gammaincinv(1.5, self.params.cycle_probability))
        self.rejected: list[tuple[int, int]] = []

    def _edges(self, estimates: Mapping) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
        """One (x, P) of T_oi_oj per unordered pair i < j. When both directions are given and
        disagree, the pair is left out: its two filters contradict each other."""
        o = "TeamConsistency.update"
        if not isinstance(estimates, Mapping):
            raise DataError(f"{o}: estimates must be a mapping (i, j) -> estimate, got "
                            f"{shown(estimates)}")
        given: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        for key, est in estimates.items():
            if est is None:
                continue
            if not (isinstance(key, tuple) and len(key) == 2
                    and all(isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                            and 0 <= r < self.n_robots for r in key) and key[0] != key[1]):
                raise DataError(f"{o}: pair {shown(key)} is not two different robots of 0 to "
                                f"{self.n_robots - 1}")
            if not (hasattr(est, "x") and hasattr(est, "P")):
                raise DataError(f"{o}: pair {key}: the estimate must have x and P (an "
                                f"AlignmentEstimate), got {shown(est)}")
            x = real_array(o, f"estimates[{key}].x", est.x)
            P = real_array(o, f"estimates[{key}].P", est.P)
            if x.shape != (3,) or P.shape != (3, 3) or not (np.all(np.isfinite(x))
                                                         and np.all(np.isfinite(P))):
                raise DataError(f"{o}: pair {key}: need a finite x (3,) and P (3, 3), got "
                                f"shapes {x.shape} and {P.shape}")
            i, j = int(key[0]), int(key[1])
            given[(i, j)] = (x, P)
        edges = {}
        for (i, j), xP in given.items():
            a, b = min(i, j), max(i, j)
            if (a, b) in edges:
                continue
            forward = xP if i < j else _invert(xP)
            other = given.get((j, i))
            if other is not None:
                backward = other if j < i else _invert(other)
                if self._distance(forward, backward) > self._gate:
                    continue
            edges[(a, b)] = forward
        return edges

    def _distance(self, a: tuple[np.ndarray, np.ndarray],
                  b: tuple[np.ndarray, np.ndarray]) -> float:
        r = a[0] - b[0]
        r[2] = _wrap_angle(r[2])
        return float(r @ np.linalg.solve(a[1] + b[1], r))

    def _cycle_fails(self, edges, i: int, j: int, k: int) -> bool:
        """Whether T_ij T_jk closes on T_ik within the gate (i < j < k)."""
        x_ik, P_ik = _compose(edges[(i, j)], edges[(j, k)])
        return self._distance((x_ik, P_ik), edges[(i, k)]) > self._gate

    def _largest_consistent(self, edges, failed: list[tuple]) -> set[tuple[int, int]]:
        pairs = sorted(edges)
        if not failed:
            return set(pairs)
        index = {p: b for b, p in enumerate(pairs)}
        masks = [sum(1 << index[e] for e in cycle) for cycle in failed]
        if len(pairs) <= self.params.exact_up_to:
            spread = [float(np.trace(edges[p][1][:2, :2])) for p in pairs]
            best, best_key = 0, (-1, 0.0)
            for subset in range(1 << len(pairs)):
                if any(subset & m == m for m in masks):
                    continue
                members = [b for b in range(len(pairs)) if subset >> b & 1]
                key = (len(members), -sum(spread[b] for b in members))
                if key > best_key:
                    best, best_key = subset, key
            return {p for p, b in index.items() if best >> b & 1}
        kept = set(pairs)
        cycles = [set(c) for c in failed]
        while cycles:
            worst = max(kept, key=lambda e: sum(e in c for c in cycles))
            kept.discard(worst)
            cycles = [c for c in cycles if worst not in c]
        return kept

    def update(self, estimates: Mapping[tuple[int, int], object],
               pairs: Iterable[tuple[int, int]] | None = None
               ) -> dict[tuple[int, int], TeamEstimate]:
        """The team-consistent alignment of every directed pair that has one.

        Args:
            estimates: (i, j) -> the pair's estimate of T_oi_oj (anything with `.x` (3,) and
                `.P` (3, 3), e.g. an `AlignmentEstimate`), or None.
            pairs: the ordered pairs (i, j) wanted (None: every pair). What is kept is decided
                over every estimate all the same; only the chains of the pairs not wanted are
                not searched (a robot that needs its own pairs only).
        Returns:
            (i, j) -> `TeamEstimate` for every wanted ordered pair of robots that has a kept
            alignment or a chain of at most `max_chain` kept ones. `rejected` holds the
            undirected pairs (i < j) left out this step.
        Raises:
            DataError: a key or wanted pair that is not two robots of the team, a non-finite
                or misshapen estimate.
        """
        edges = self._edges(estimates)
        failed = [((i, j), (j, k), (i, k))
                  for i, j, k in itertools.combinations(range(self.n_robots), 3)
                  if {(i, j), (j, k), (i, k)} <= edges.keys() and self._cycle_fails(edges, i, j,
                                                                                     k)]
        kept = self._largest_consistent(edges, failed)
        self.rejected = [p for p in sorted(edges) if p not in kept]
        directed = {}
        for (i, j) in kept:
            directed[(i, j)] = (edges[(i, j)], (i, j))
            directed[(j, i)] = (_invert(edges[(i, j)]), (j, i))
        wanted = (itertools.permutations(range(self.n_robots), 2) if pairs is None
                  else self._wanted(pairs))
        out = {}
        for i, j in wanted:
            if (i, j) in directed:
                xP, path = directed[(i, j)]
                out[(i, j)] = TeamEstimate(xP[0], xP[1], path)
            else:
                chain = self._chain(i, j, directed)
                if chain is not None:
                    out[(i, j)] = chain
        return out

    def _wanted(self, pairs: Iterable) -> list[tuple[int, int]]:
        n, wanted = self.n_robots, []
        if not isinstance(pairs, Iterable):
            raise DataError(f"TeamConsistency.update: pairs must be ordered pairs of robots, "
                            f"got {shown(pairs)}")
        for pair in pairs:
            if not (isinstance(pair, tuple) and len(pair) == 2
                    and all(isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                            and 0 <= r < n for r in pair) and pair[0] != pair[1]):
                raise DataError(f"TeamConsistency.update: wanted pair {shown(pair)} is not two "
                                f"different robots of 0 to {n - 1}")
            wanted.append((int(pair[0]), int(pair[1])))
        return wanted

    def _chain(self, i: int, j: int, directed: dict) -> TeamEstimate | None:
        """The chain of kept alignments from i to j with the fewest links (up to max_chain),
        the most certain (smallest translation covariance) among those."""
        frontier = [((np.zeros(3), np.zeros((3, 3))), (i,))]
        for _ in range(self.params.max_chain):
            found, grown = [], []
            for xP, path in frontier:
                for (a, b), (step, _) in directed.items():
                    if a != path[-1] or b in path:
                        continue
                    composed = _compose(xP, step) if len(path) > 1 else step
                    (found if b == j else grown).append((composed, (*path, b)))
            if found:
                xP, path = min(found, key=lambda f: np.trace(f[0][1][:2, :2]))
                return TeamEstimate(xP[0], xP[1], path)
            frontier = grown
        return None
