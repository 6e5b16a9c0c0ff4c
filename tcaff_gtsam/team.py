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

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from .errors import DataError
from .geometry import _chi2_quantile, _se2_from_params, _wrap_angle
from .inputs import real_array, shown
from .param_checks import MAX_COORDINATE, MAX_VARIANCE
from .params import _int_at_least, _require
from .tcaff_state import _not_spd

__all__ = ["TeamConsistency", "TeamEstimate", "TeamParams"]


#: what `TeamConsistency.update` requires of an estimate (`usable_estimates`)
ESTIMATE_RULE = (f"x (3,) finite within {MAX_COORDINATE:g} and P (3, 3) symmetric positive "
                 f"definite with entries within {MAX_VARIANCE:g}")


def usable_estimates(x: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(m,) bool: which of m estimates `TeamConsistency.update` takes (`ESTIMATE_RULE`).

    Args:
        x: (m, 3) (x [m], y [m], theta [rad]), each within MAX_COORDINATE.
        P: (m, 3, 3) covariances, symmetric positive definite (the cycle test inverts them)
            with entries within MAX_VARIANCE. NaN fails both.
    The one test of an estimate, for the team consistency and for the messages that feed it
    (`node.messages.decode`, `node.ros2.alignment_of`).
    """
    ok = ((np.abs(x) <= MAX_COORDINATE).all(axis=1)
          & (np.abs(P) <= MAX_VARIANCE).all(axis=(1, 2)))
    rest = np.flatnonzero(ok)
    # one pass over all of them on the usual path; after a failure, again over the others (the
    # first asymmetric one is found before any that is not positive definite)
    while len(rest) and (bad := _not_spd(P[rest])) is not None:
        ok[rest[bad[0]]] = False
        rest = np.delete(rest, bad[0])
    return ok


@dataclass(frozen=True)
class TeamParams:
    """Settings of `TeamConsistency`.

    Attributes:
        cycle_probability: a cycle of three alignments fails when its error's squared
            Mahalanobis distance exceeds the chi-square quantile of 3 degrees of freedom at this
            probability.
        max_chain: most pair alignments composed into a chained one (2: through one robot),
            at most 1023 (`TeamConsistency.MAX_ROBOTS` - 1: a chain through every robot of
            the largest team).
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
        high = TeamConsistency.MAX_ROBOTS - 1
        _require(_int_at_least(self.max_chain, 1, high), o, "max_chain", self.max_chain,
                 f"must be an int in [1, {high}] (TeamConsistency.MAX_ROBOTS - 1)")
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


def _compose(xa: np.ndarray, Pa: np.ndarray, xb: np.ndarray, Pb: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """(x (m, 3), P (m, 3, 3)) of T_a T_b for m pairs of alignments given as x (m, 3) and
    P (m, 3, 3), the covariance propagated to first order."""
    c, s = np.cos(xa[:, 2]), np.sin(xa[:, 2])
    tx = c * xb[:, 0] - s * xb[:, 1]
    ty = s * xb[:, 0] + c * xb[:, 1]
    x = np.column_stack([xa[:, 0] + tx, xa[:, 1] + ty, _wrap_angle(xa[:, 2] + xb[:, 2])])
    Ja = np.broadcast_to(np.eye(3), (len(xa), 3, 3)).copy()
    Ja[:, 0, 2], Ja[:, 1, 2] = -ty, tx
    Jb = Ja.copy()
    Jb[:, :2, 2] = 0.0
    Jb[:, 0, 0], Jb[:, 0, 1], Jb[:, 1, 0], Jb[:, 1, 1] = c, -s, s, c
    return x, (Ja @ Pa @ Ja.transpose(0, 2, 1)) + (Jb @ Pb @ Jb.transpose(0, 2, 1))


def _invert(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x (m, 3), P (m, 3, 3)) of T^-1 for m alignments x (m, 3), P (m, 3, 3), the covariance
    propagated to first order."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    tx = -(c * x[:, 0] + s * x[:, 1])  # t = -R' x[:2]
    ty = s * x[:, 0] - c * x[:, 1]
    J = np.zeros((len(x), 3, 3))
    J[:, 0, 0], J[:, 0, 1], J[:, 1, 0], J[:, 1, 1] = -c, -s, s, -c  # -R'
    J[:, 0, 2], J[:, 1, 2], J[:, 2, 2] = ty, -tx, -1.0
    return (np.column_stack([tx, ty, _wrap_angle(-x[:, 2])]),
            J @ P @ J.transpose(0, 2, 1))


def _distances(xa: np.ndarray, Pa: np.ndarray, xb: np.ndarray, Pb: np.ndarray) -> np.ndarray:
    """(m,) squared Mahalanobis distances of xa - xb (m, 3), heading wrapped, under Pa + Pb."""
    r = xa - xb
    r[:, 2] = _wrap_angle(r[:, 2])
    return np.einsum("mi,mi->m", r, np.linalg.solve(Pa + Pb, r[:, :, None])[:, :, 0])


def _three_cycles(edges) -> list[tuple[int, int, int]]:
    """Every (i, j, k), i < j < k, whose three pairs (i, j), (j, k), (i, k) are keys of
    `edges` (pairs (a, b), a < b), in lexicographic order; found from the pairs, not by
    visiting every triple of robots (n^3 / 6 of them)."""
    pairs = sorted(edges)
    above = defaultdict(list)  # robot -> the robots after it it has an alignment with
    for a, b in pairs:
        above[a].append(b)
    return [(i, j, k) for i, j in pairs for k in above[j] if (i, k) in edges]


class TeamConsistency:
    """The jointly consistent pairwise alignments of a team, one step at a time (`update`).

    Args:
        n_robots: robots 0 .. n_robots - 1, at most MAX_ROBOTS.
    """

    #: an update holds (n, n, 3, 3) covariances and multiplies (n, n) reachability matrices:
    #: 75 MB and about 10^9 operations per chain length at 1024 robots, far past any team
    #: whose every pair exchanges maps
    MAX_ROBOTS = 1024

    def __init__(self, n_robots: int, params: TeamParams | None = None) -> None:
        _require(_int_at_least(n_robots, 2) and n_robots <= self.MAX_ROBOTS, "TeamConsistency",
                 "n_robots", n_robots, f"must be an int in [2, {self.MAX_ROBOTS}]")
        self.n_robots = int(n_robots)
        self.params = TeamParams() if params is None else params
        _require(isinstance(self.params, TeamParams), "TeamConsistency", "params", params,
                 "must be a TeamParams")
        self._gate = _chi2_quantile(self.params.cycle_probability, 3)
        self.rejected: list[tuple[int, int]] = []

    def _given(self, estimates: Mapping) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
        """(i, j) -> (x (3,), P (3, 3)) of every estimate given, checked."""
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
                raise DataError(f"{o}: estimates key {shown(key)} is not a pair of two "
                                f"different robots of 0 to {self.n_robots - 1}")
            if not (hasattr(est, "x") and hasattr(est, "P")):
                raise DataError(f"{o}: estimates[{key}] must have x and P (an "
                                f"AlignmentEstimate), got {shown(est)}")
            x = real_array(o, f"estimates[{key}].x", est.x)
            P = real_array(o, f"estimates[{key}].P", est.P)
            if x.shape != (3,) or P.shape != (3, 3):
                raise DataError(f"{o}: estimates[{key}] needs a finite x (3,) and P (3, 3), "
                                f"got shapes {x.shape} and {P.shape}")
            i, j = int(key[0]), int(key[1])
            given[(i, j)] = (x, P)
        if given:  # checked for all at once
            ok = usable_estimates(np.array([x for x, _ in given.values()]),
                                  np.array([P for _, P in given.values()]))
            if not ok.all():
                key = list(given)[int(np.argmin(ok))]
                raise DataError(f"{o}: estimates[{key}] needs {ESTIMATE_RULE}, got "
                                f"x = {shown(given[key][0])}, P = {shown(given[key][1])}")
        return given

    def _edges(self, given: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]
               ) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
        """One (x, P) of T_oi_oj per unordered pair i < j of the checked estimates `given`: the
        (i, j) one where both directions are given, else the (j, i) one inverted. When both
        are given and disagree, the pair is left out: its two filters contradict each other."""
        # every given (j, i), j > i, turned into (i, j) at once
        down = [key for key in given if key[0] > key[1]]
        turned = {}
        if down:
            x, P = _invert(np.array([given[k][0] for k in down]),
                           np.array([given[k][1] for k in down]))
            turned = {(i, j): (x[n], P[n]) for n, (j, i) in enumerate(down)}
        edges = {pair: given[pair] if pair in given else turned[pair]
                 for pair in sorted({(min(k), max(k)) for k in given})}
        both = [pair for pair in edges if pair in given and pair in turned]
        if both:  # both directions given: a pair whose two filters disagree is left out
            apart = _distances(np.array([given[p][0] for p in both]),
                               np.array([given[p][1] for p in both]),
                               np.array([turned[p][0] for p in both]),
                               np.array([turned[p][1] for p in both])) > self._gate
            for pair in np.array(both)[apart].tolist():
                del edges[tuple(pair)]
        return edges

    def _failed_cycles(self, edges) -> list[tuple]:
        """The cycles ((i, j), (j, k), (i, k)), i < j < k, of three known alignments where
        T_ij T_jk does not close on T_ik within the gate."""
        cycles = _three_cycles(edges)
        if not cycles:
            return []

        def stacked(links):
            return (np.array([edges[e][0] for e in links]),
                    np.array([edges[e][1] for e in links]))

        ij = stacked([(i, j) for i, j, _ in cycles])
        jk = stacked([(j, k) for _, j, k in cycles])
        ik = stacked([(i, k) for i, _, k in cycles])
        fails = _distances(*_compose(*ij, *jk), *ik) > self._gate
        return [((i, j), (j, k), (i, k))
                for (i, j, k), fail in zip(cycles, fails.tolist(), strict=True) if fail]

    def _largest_consistent(self, edges, failed: list[tuple]) -> set[tuple[int, int]]:
        pairs = sorted(edges)
        if not failed:
            return set(pairs)
        index = {p: b for b, p in enumerate(pairs)}
        masks = [sum(1 << index[e] for e in cycle) for cycle in failed]
        if len(pairs) <= self.params.exact_up_to:
            spread = [float(np.trace(edges[p][1][:2, :2])) for p in pairs]
            subsets = np.arange(1 << len(pairs), dtype=np.int64)
            valid = np.ones(len(subsets), dtype=bool)
            for m in masks:
                valid &= (subsets & m) != m
            subsets = subsets[valid]
            size, summed = np.zeros(len(subsets), dtype=np.int64), np.zeros(len(subsets))
            for b in range(len(pairs)):  # summed in pair order, as ties are decided
                member = (subsets >> b) & 1
                size += member
                summed += member * spread[b]
            # the most pairs, then the smallest summed spread, then the first subset
            best = subsets[np.lexsort((summed, -size))[0]]
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
        edges, kept = self._consistent(self._given(estimates))
        self.rejected = [p for p in sorted(edges) if p not in kept]
        n = self.n_robots
        want = np.ones((n, n), dtype=bool)
        if pairs is not None:
            want[:] = False
            for i, j in self._wanted(pairs):
                want[i, j] = True
        # every kept alignment in both directions, as (n, n) arrays
        linked = np.zeros((n, n), dtype=bool)
        X, P = np.zeros((n, n, 3)), np.zeros((n, n, 3, 3))
        if kept:
            up = sorted(kept)
            i, j = np.array(up).T
            linked[i, j] = linked[j, i] = True
            X[i, j] = [edges[p][0] for p in up]
            P[i, j] = [edges[p][1] for p in up]
            X[j, i], P[j, i] = _invert(X[i, j], P[i, j])
        out = {(int(i), int(j)): TeamEstimate(X[i, j].copy(), P[i, j].copy(), (int(i), int(j)))
               for i, j in zip(*np.nonzero(linked & want), strict=True)}
        out.update(self._chains(linked, X, P, want))
        return out

    def _rejected(self, given: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]
                  ) -> list[tuple[int, int]]:
        """The undirected pairs (i < j) that `update` would leave out, from estimates already
        checked, (i, j) -> (x (3,), P (3, 3)): what the graph's cycle check needs, without
        the chains."""
        edges, kept = self._consistent(given)
        return [p for p in sorted(edges) if p not in kept]

    def _consistent(self, given: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]
                    ) -> tuple[dict, set[tuple[int, int]]]:
        """The undirected alignments of the checked estimates `given` (`_edges`) and the
        largest consistent set of their pairs."""
        edges = self._edges(given)
        return edges, self._largest_consistent(edges, self._failed_cycles(edges))

    def _wanted(self, pairs: Iterable) -> list[tuple[int, int]]:
        n, wanted = self.n_robots, []
        try:  # not isinstance(pairs, Iterable): a 0-d array is one and cannot be iterated
            pairs = list(pairs)
        except TypeError:
            raise DataError(f"TeamConsistency.update: pairs must be ordered pairs of robots, "
                            f"got {shown(pairs)}") from None
        for pair in pairs:
            if not (isinstance(pair, tuple) and len(pair) == 2
                    and all(isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                            and 0 <= r < n for r in pair) and pair[0] != pair[1]):
                raise DataError(f"TeamConsistency.update: pairs holds {shown(pair)}, not a "
                                f"wanted pair of two different robots of 0 to {n - 1}")
            wanted.append((int(pair[0]), int(pair[1])))
        return wanted

    def _chains(self, linked: np.ndarray, X: np.ndarray, P: np.ndarray, want: np.ndarray
                ) -> dict[tuple[int, int], TeamEstimate]:
        """For every ordered pair (i, j) without a kept alignment, the chain of kept ones from
        i to j with the fewest links (2 up to max_chain), the most certain (smallest
        translation covariance) among those.

        Args:
            linked: (n, n) bool, where a kept alignment exists; X (n, n, 3), P (n, n, 3, 3):
                the kept alignments T_oi_oj and their covariances; want: (n, n) bool, the
                ordered pairs whose chains are searched.
        """
        n = self.n_robots
        longest = min(self.params.max_chain, n - 1)  # no chain without repeats is longer
        # hops[a, b]: the fewest links from robot a to robot b (longest + 1: none within
        # reach); every chain with the fewest links visits no robot twice
        hops = np.where(linked, 1, longest + 1)
        np.fill_diagonal(hops, 0)
        # 0/1 products in floating point: BLAS, and counts up to n are exact
        step = linked.astype(np.float64)
        reach = step
        for d in range(2, longest + 1):
            reach = ((reach @ step) > 0).astype(np.float64)
            hops[(hops > d) & (reach > 0)] = d
        paths: list[tuple[int, ...]] = []
        for i, j in zip(*np.nonzero((hops >= 2) & (hops <= longest) & want), strict=True):
            grown = [(int(i),)]
            for left in range(int(hops[i, j]) - 1, -1, -1):
                grown = [(*path, int(k)) for path in grown
                         for k in np.flatnonzero(linked[path[-1]] & (hops[:, j] == left))]
            paths += grown
        out: dict[tuple[int, int], TeamEstimate] = {}
        for length in range(2, longest + 1):
            chains = np.array([path for path in paths if len(path) == length + 1],
                              dtype=np.int64).reshape(-1, length + 1)
            if not len(chains):
                continue
            x, cov = X[chains[:, 0], chains[:, 1]], P[chains[:, 0], chains[:, 1]]
            for link in range(1, length):
                a, b = chains[:, link], chains[:, link + 1]
                x, cov = _compose(x, cov, X[a, b], P[a, b])
            spread = np.trace(cov[:, :2, :2], axis1=1, axis2=2)
            for c in np.lexsort((spread, chains[:, -1], chains[:, 0])):
                key = (int(chains[c, 0]), int(chains[c, -1]))
                if key not in out:  # the first of the pair's chains is its most certain
                    out[key] = TeamEstimate(x[c].copy(), cov[c].copy(),
                                            tuple(int(r) for r in chains[c]))
        return out
