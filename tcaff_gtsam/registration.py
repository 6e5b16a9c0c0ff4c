"""Putative associations by object size, and weighted Arun registration (Arun 1987, Umeyama)."""

from __future__ import annotations

import math

import numba
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from .errors import DataError
from .geometry import _transform_points
from .inputs import index_pairs, kernel_array, real_array, shown
from .object_map import ObjectMap, as_object_map
from .params import _finite, _int_at_least, _require

__all__ = [
    "arun_weights",
    "mutual_inliers",
    "neighbourhood_agreement",
    "putative_associations",
    "registration_rmse",
    "spread",
    "weighted_arun",
]

#: metres; coordinates beyond this are no robot's odometry (and squared sums of them overflow
#: long before they would stop being rounding noise)
MAX_COORDINATE = 1e9
#: the largest Arun weight; with coordinates within MAX_COORDINATE no weighted sum overflows
MAX_WEIGHT = 1e100
#: object pairs (rows x columns) in one block of the size gate: its float temporaries then take
#: tens of MB whatever the map sizes, where the whole gate at 5000 objects per map took 1 GB
_GATE_BLOCK = 1 << 20
#: neighbours that describe an object for `_neighbourhood_pairs`: enough to reach past its own
#: cluster (a row of cars, a group of chairs) to the next ones, whose distances tell apart
#: objects that look alike up close (at most 254: a kept pair's score + 1 takes one byte)
NEIGHBOURS = 48
#: the most merge steps (compatible pairs x both neighbour lists) one `_neighbourhood_pairs`
#: takes, about half a second: beyond it each object is described by fewer neighbours
_RANKING_STEPS = 1 << 27
#: the most merge steps (compatible pairs x both neighbour lists) `_partial_pairs_kept` takes,
#: a few hundredths of a millisecond (it runs on every step of the aligner): beyond them each
#: object is described by fewer neighbours, down to `_PARTIAL_NEIGHBOURS`
_PARTIAL_STEPS = 1 << 14
_PARTIAL_NEIGHBOURS = 8
#: consistency checks the partial-view rule's pairs may add to a graph before they are ranked
#: (`_partial_ranking_pays`), about a tenth of a millisecond of graph: the simulator's maps
#: add at most 43 000, the 7-Scenes kitchen's 61 000 (68 000 with the defaults' gate, which
#: takes no descriptors); a hundred objects of assorted sizes per map add millions
_PARTIAL_CHECKS = 1 << 16
#: points up to which `_neighbour_distances` sorts the rows of their distance matrix rather
#: than querying a k-d tree: a fraction of the tree's cost up to about 150 points (a quarter
#: of it at 100 points and 48 neighbours), several times it at 500
_DENSE_NEIGHBOURS = 128
#: object pairs above which mutual inliers are found with k-d trees: the dense distance matrix
#: costs 8 bytes per pair, several times over in temporaries
_DENSE_INLIERS = 1 << 20


def _sizes_similar(a: np.ndarray, b: np.ndarray, ratios: tuple[float, ...], abs_diff: float
                   ) -> list[np.ndarray]:
    """(n,) x (m,) sizes -> per ratio of `ratios` an (n, m) bool: larger <= ratio * smaller,
    or |a - b| <= abs_diff (the larger, the smaller and the difference made once)."""
    a = a[:, None]
    b = b[None, :]
    larger, smaller = np.maximum(a, b), np.minimum(a, b)
    close = np.abs(a - b) <= abs_diff
    return [(larger <= ratio * smaller) | close for ratio in ratios]


def putative_associations(ego: ObjectMap, other: ObjectMap, ratio: float = 1.35,
                          abs_diff: float = 0.1, partial_ratio: float | None = None
                          ) -> np.ndarray:
    """Pairs of objects of similar size, the nodes of the consistency graph.

    A pair (i, j) is kept when both the widths and the heights of ego object i and other object j
    are similar: the larger is at most `ratio` times the smaller, or they differ by at most
    `abs_diff` metres (which keeps small objects whose ratio is noisy): the paper's gate. With
    `partial_ratio` above `ratio` (the aligner's `size_partial`), one of the two (width or
    height) may differ by up to that ratio instead, as a partial view makes it: a chair behind
    a table loses its height, a box seen on one face its width. None (the default here) or a
    value not above `ratio` is the paper's gate.

    Returns:
        (m, 2) int64 array of (ego index, other index), sorted by ego then other index;
        (0, 2) when either map is empty or nothing passes.
    Raises:
        ConfigError: ratio not a finite number >= 1, abs_diff not a finite number >= 0 (NaN
            included), partial_ratio neither None nor a finite number >= 1.
        DataError: ego or other is not an ObjectMap.
    """
    o = "putative_associations"
    _require(_finite(ratio) and ratio >= 1, o, "ratio", ratio, "must be a finite number >= 1")
    _require(_finite(abs_diff) and abs_diff >= 0, o, "abs_diff", abs_diff,
             "must be a finite number >= 0 metres")
    _require(partial_ratio is None or (_finite(partial_ratio) and partial_ratio >= 1), o,
             "partial_ratio", partial_ratio, "must be None or a finite number >= 1")
    ego, other = as_object_map(o, "ego", ego), as_object_map(o, "other", other)
    pairs = [np.argwhere(block) + np.array([start, 0])
             for start, block, _ in _gate_blocks(ego, other, ratio, abs_diff, partial_ratio)]
    return np.concatenate([np.empty((0, 2), np.int64), *pairs]).astype(np.int64)


def size_compatible(ego: ObjectMap, other: ObjectMap, ratio: float, abs_diff: float,
                    partial_ratio: float | None = None) -> np.ndarray:
    """(n_ego, n_other) bool: the size gate of `putative_associations` for every pair."""
    return size_gates(ego, other, ratio, abs_diff, partial_ratio)[0]


def size_gates(ego: ObjectMap, other: ObjectMap, ratio: float, abs_diff: float,
               partial_ratio: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(compatible, partial), each (n_ego, n_other) bool: the size gate of
    `putative_associations` for every pair, and the pairs of it that only the partial-view
    rule passes (`partial_ratio`; none without it)."""
    compatible = np.empty((len(ego), len(other)), bool)
    partial = np.zeros((len(ego), len(other)), bool)
    for start, block, partial_block in _gate_blocks(ego, other, ratio, abs_diff, partial_ratio):
        compatible[start: start + block.shape[0]] = block
        if partial_block is not None:
            partial[start: start + block.shape[0]] = partial_block
    return compatible, partial


def _block_rows(n_other: int) -> int:
    """Ego rows per block of the size gate against `n_other` objects."""
    return max(1, _GATE_BLOCK // max(n_other, 1))


def _gate_blocks(ego: ObjectMap, other: ObjectMap, ratio: float, abs_diff: float,
                 partial_ratio: float | None = None):
    """The size gate by blocks of ego rows: yields (first row, (rows, n_other) bool, the
    pairs of it only the partial-view rule passes ((rows, n_other) bool, or None without
    the rule))."""
    rows = _block_rows(len(other))
    for start in range(0, len(ego), rows):
        part = slice(start, start + rows)
        ratios = (ratio,) if partial_ratio is None or partial_ratio <= ratio else (
            ratio, partial_ratio)
        widths = _sizes_similar(ego.widths[part], other.widths, ratios, abs_diff)
        heights = _sizes_similar(ego.heights[part], other.heights, ratios, abs_diff)
        block = widths[0] & heights[0]
        partial = None
        if len(ratios) == 2:
            partial = (widths[0] & heights[1]) | (heights[0] & widths[1])
            partial &= ~block
            block |= partial
        yield start, block, partial


def _descriptor_gate(ego: ObjectMap, other: ObjectMap, compatible: np.ndarray,
                    minimum: float) -> np.ndarray:
    """`compatible` ((n_ego, n_other) bool, e.g. `size_compatible`) without the pairs whose
    descriptors' similarity is below `minimum`; unchanged when either map carries no
    descriptors (`_descriptors_comparable`). Computed by blocks of ego rows: large maps never
    hold a dense matrix of similarities.

    Raises:
        DataError: the two maps' descriptors have different lengths.
    """
    if minimum <= 0 or not _descriptors_comparable(ego, other):
        return compatible
    out = compatible.copy()
    rows = _block_rows(len(other))
    for start in range(0, len(ego), rows):
        part = slice(start, start + rows)
        out[part] &= ego.descriptors[part] @ other.descriptors.T >= minimum
    return out


def _pair_similarity(ego: ObjectMap, other: ObjectMap, pairs: np.ndarray) -> np.ndarray | None:
    """(m,) the descriptor similarity (dot product, in [0, 1]) of each pair (m, 2) (ego index,
    other index), or None when either map carries no descriptors."""
    if not _descriptors_comparable(ego, other):
        return None
    return np.einsum("ij,ij->i", ego.descriptors[pairs[:, 0]], other.descriptors[pairs[:, 1]])


def _descriptors_comparable(ego: ObjectMap, other: ObjectMap) -> bool:
    """Whether both maps carry descriptors (and objects) to compare.

    Raises:
        DataError: both carry descriptors, of different lengths (made by front ends with
            other settings: their dot product means nothing).
    """
    a, b = ego.descriptors, other.descriptors
    if a is None or b is None or len(ego) == 0 or len(other) == 0:
        return False
    if a.shape[1] != b.shape[1]:
        raise DataError(f"descriptors of the two maps have different lengths, {a.shape[1]} and "
                        f"{b.shape[1]}: the robots' front ends describe objects differently")
    return True


def neighbourhood_agreement(ego_points: np.ndarray, other_points: np.ndarray,
                            pairs: np.ndarray, epsilon: float = 0.25,
                            neighbours: int = NEIGHBOURS) -> np.ndarray:
    """How well the surroundings of each pair's two objects agree, each within its own map.

    Object i of the ego map is described by the sorted distances to its `neighbours` nearest
    ego objects, object j of the other map likewise; the score of (i, j) is the largest number
    of one-to-one pairs of those distances that differ by less than `epsilon` (CLIPPER's
    consistency test, taken against the pair itself). A true pair scores at least the number
    of neighbours both robots mapped, up to noise; the score is an upper bound on the
    associations among those neighbours that a consistent set holding (i, j) can have. It
    depends on distances only, so it is the same in any frame: rotating or moving either map
    changes nothing.

    Args:
        ego_points: (n1, d) metres, d = 2 or 3. other_points: (n2, d) metres.
        pairs: (m, 2) int (ego index, other index).
        epsilon: metres, finite and > 0. neighbours: an int >= 1 (fewer when a map has fewer
            other objects).
    Returns:
        (m,) int64 scores in [0, neighbours].
    Raises:
        ConfigError: epsilon not a finite number > 0, neighbours not an int >= 1.
        DataError: points not finite (n, 2) or (n, 3) real numbers of one dimension, pairs not
            (m, 2) indices within the maps.
    """
    o = "neighbourhood_agreement"
    _require(_finite(epsilon) and epsilon > 0, o, "epsilon", epsilon,
             "must be a finite number > 0 metres")
    _require(_int_at_least(neighbours, 1), o, "neighbours", neighbours, "must be an int >= 1")
    p = _points(o, "ego_points", ego_points)
    q = _points(o, "other_points", other_points, p.shape[1])
    pairs = index_pairs(o, "pairs", pairs)
    if pairs.size and (pairs[:, 0].max() >= len(p) or pairs[:, 1].max() >= len(q)):
        raise DataError(f"{o}: pair indices out of range for maps of {len(p)} and {len(q)} "
                        f"points, got {shown(pairs)}")
    return _agreement(_neighbour_distances(p, neighbours), _neighbour_distances(q, neighbours),
                      kernel_array(pairs, np.int64), float(epsilon))


def _neighbourhood_pairs(compatible: np.ndarray, ego_points: np.ndarray,
                         other_points: np.ndarray, ages_ego: np.ndarray, ages_other: np.ndarray,
                         epsilon: float, per_object: int, cap: int) -> np.ndarray:
    """The compatible pairs whose neighbourhoods agree best (`neighbourhood_agreement`): for
    each object of either map its `per_object` best pairs, then at most `cap` of those. The
    arguments are not checked: the aligner's are (its maps and parameters were).

    Ties in the score go to the pair whose objects were seen most recently (the smaller sum
    of ages), then to the lower index. Each object is described by `NEIGHBOURS` neighbours,
    fewer when the compatible pairs are so many that comparing them would take more than
    `_RANKING_STEPS` steps (maps of thousands of look-alike objects). Memory: one byte per
    object pair beside `compatible`, and 24 bytes per other object and kept pair.

    Args:
        compatible: (n, m) bool, the size gate (`size_compatible`).
        ego_points, other_points: (n, d) and (m, d) metres, finite.
        ages_ego, ages_other: (n,) and (m,) seconds since each object was last seen.
        epsilon: metres, > 0; per_object: int >= 1; cap: the most pairs returned.
    Returns:
        (k, 2) int64 (ego index, other index), k <= min(cap, per_object * (n + m)), sorted by
        ego then other index, as `putative_associations` sorts.
    """
    n_pairs = int(np.count_nonzero(compatible))
    if n_pairs == 0:
        return np.empty((0, 2), np.int64)
    neighbours = max(1, min(NEIGHBOURS, _RANKING_STEPS // (2 * n_pairs)))
    per_object = min(per_object, max(compatible.shape))  # more than a map holds adds nothing
    d_ego = _neighbour_distances(ego_points, neighbours)
    d_other = _neighbour_distances(other_points, neighbours)
    scored = _best_per_object(kernel_array(compatible, bool), d_ego, d_other,
                              kernel_array(ages_ego), kernel_array(ages_other), float(epsilon),
                              int(per_object))
    kept = np.argwhere(scored)
    if kept.shape[0] > cap:
        score = scored[kept[:, 0], kept[:, 1]]  # the score + 1, which ranks alike
        age = ages_ego[kept[:, 0]] + ages_other[kept[:, 1]]
        best = np.lexsort((kept[:, 1], kept[:, 0], age, -score))[:cap]
        kept = kept[np.sort(best)]  # kept is in index order, so sorted positions keep it
    return kept.astype(np.int64)


def _partial_pairs_kept(compatible: np.ndarray, partial: np.ndarray, ego_points: np.ndarray,
                        other_points: np.ndarray, ages_ego: np.ndarray, ages_other: np.ndarray,
                        epsilon: float) -> np.ndarray:
    """The pairs of `partial` that may enter the consistency graph: those that are the best
    pair of both their objects.

    A partial view cuts one object's extent, so the pair it makes with its counterpart passes
    only the partial-view rule (`size_gates`); in maps of many objects such pairs outnumber
    those of the paper's gate several times over, and nearly all of them are false. A true
    pair is the true pair of both its objects, and neither has another: among all the
    compatible pairs of each object, ranked as `_neighbourhood_pairs` ranks them (how well
    the two objects' surroundings agree, `neighbourhood_agreement`; then the smaller sum of
    ages; then the lower index), it comes first for both, as the surroundings of an object
    and of its counterpart are the same. Each object is described by `NEIGHBOURS`
    neighbours, fewer when the compatible pairs are so many that comparing them would take
    more than `_PARTIAL_STEPS` steps (`_partial_neighbours`). The arguments are not checked:
    the aligner's are.

    Args:
        compatible: (n, m) bool, the gates (`size_gates`' compatible, after any descriptor
            gate); partial: (n, m) bool, the pairs of it that only the partial-view rule
            passes.
        ego_points, other_points: (n, d) and (m, d) metres, finite.
        ages_ego, ages_other: (n,) and (m,) seconds since each object was last seen.
        epsilon: metres, > 0.
    Returns:
        (n, m) bool, a subset of `partial` with at most one pair per object.
    """
    if not partial.any():
        return np.zeros(partial.shape, bool)
    neighbours = _partial_neighbours(int(np.count_nonzero(compatible)))
    best_row, best_col = _best_pair_of_each(
        kernel_array(compatible, bool), _neighbour_distances(ego_points, neighbours),
        _neighbour_distances(other_points, neighbours), kernel_array(ages_ego),
        kernel_array(ages_other), float(epsilon))
    rows = np.flatnonzero(best_row >= 0)
    cols = best_row[rows]
    mutual = best_col[cols] == rows
    kept = np.zeros(partial.shape, bool)
    kept[rows[mutual], cols[mutual]] = True
    return kept & partial


def _partial_neighbours(n_pairs: int) -> int:
    """The neighbours that describe each object when `_partial_pairs_kept` ranks `n_pairs`
    compatible pairs: `NEIGHBOURS`, fewer beyond `_PARTIAL_STEPS` merge steps, but not fewer
    than `_PARTIAL_NEIGHBOURS` (unless `NEIGHBOURS` is)."""
    return min(NEIGHBOURS, max(_PARTIAL_NEIGHBOURS, _PARTIAL_STEPS // (2 * max(n_pairs, 1))))


def _partial_ranking_pays(n_pairs: int, n_partial: int) -> bool:
    """Whether to rank the pairs (`_partial_pairs_kept`) of `n_pairs` compatible pairs, of
    which `n_partial` pass only the partial-view rule: when those partial pairs would add to
    the graph more consistency checks (it checks every two of its m nodes: (m^2 - m_c^2) / 2
    more with them than with the m_c others alone) than `_PARTIAL_CHECKS` and than ranking
    takes merge steps. Below, keeping every partial pair costs a fraction of a millisecond,
    and in such small maps a true pair of a small overlap often fails to rank first."""
    complete = n_pairs - n_partial
    added_checks = (n_pairs * n_pairs - complete * complete) // 2
    return added_checks > max(_PARTIAL_CHECKS, 2 * _partial_neighbours(n_pairs) * n_pairs)


@numba.njit(cache=True)
def _best_pair_of_each(compatible, d_ego, d_other, ages_ego, ages_other, epsilon):
    """(n,) and (m,) int64: the best compatible pair ((n, m) bool) of every ego object (its
    other object) and of every other object (its ego object), -1 for none, ranked as
    `_best_per_object` ranks them, from `_neighbour_distances` rows of both maps."""
    n, m = compatible.shape
    steps = d_ego.shape[1] + d_other.shape[1] - 2
    # (score, age, pick) of each object's best pair so far, pick -1 for none yet
    best_row = np.full((n, 3), -1.0)
    best_col = np.full((m, 3), -1.0)
    cols = np.empty(m, np.int64)
    at_ego = np.empty(m, np.int64)
    at_other = np.empty(m, np.int64)
    count = np.empty(m, np.int64)
    for i in range(n):
        k = 0
        for j in range(m):
            if compatible[i, j]:
                cols[k] = j
                k += 1
        if k == 0:
            continue
        a = d_ego[i]
        at_ego[:k] = 0
        at_other[:k] = 0
        count[:k] = 0
        # `_best_per_object`'s lockstep greedy matching of every pair of the row, by bursts
        # of 8 steps: a pair is done once either index reached its row's inf (the steps after
        # that match nothing), and most rows are done well before `steps`
        done = 0
        while done < steps:
            for _ in range(8):
                for c in range(k):
                    d = a[at_ego[c]] - d_other[cols[c], at_other[c]]
                    hit = abs(d) < epsilon
                    count[c] += hit
                    at_ego[c] += hit | (d < 0)
                    at_other[c] += hit | (d > 0)
            done += 8
            busy = False
            for c in range(k):
                if a[at_ego[c]] < np.inf and d_other[cols[c], at_other[c]] < np.inf:
                    busy = True
                    break
            if not busy:
                break
        for c in range(k):
            j = cols[c]
            age = ages_ego[i] + ages_other[j]
            # offered in index order: a tie keeps the lower index, as `_offer` does
            _take(best_row[i], count[c], age, j)
            _take(best_col[j], count[c], age, i)
    return best_row[:, 2].astype(np.int64), best_col[:, 2].astype(np.int64)


@numba.njit(cache=True)
def _take(best, score, age, pick):
    """Make best ((3,) score, age, pick; pick -1 for none yet) (score, age, pick) when that
    ranks above it: a higher score, or the same and a smaller age."""
    if best[2] < 0 or score > best[0] or (score == best[0] and age < best[1]):
        best[0], best[1], best[2] = score, age, pick


def _neighbour_distances(points: np.ndarray, neighbours: int) -> np.ndarray:
    """(n, k + 1) float64: each point's distances to its k = min(neighbours, n - 1) nearest
    other points, ascending, then an inf that ends the row for `_agreement` and
    `_best_per_object`."""
    n = points.shape[0]
    k = min(neighbours, n - 1)
    out = np.full((n, k + 1), np.inf)
    if k > 0 and n <= _DENSE_NEIGHBOURS:
        # a step's maps: sorting the distance matrix's rows costs a fraction of a tree query
        # for as many neighbours; the diagonal (the point itself) sorts first
        out[:, :k] = np.sort(cdist(points, points), axis=1)[:, 1: k + 1]
    elif k > 0:
        # the nearest is the point itself (or a duplicate of it: distance 0 either way)
        distances, _ = cKDTree(points).query(points, k + 1)
        out[:, :k] = distances[:, 1:]
    return out


@numba.njit(cache=True)
def _agreement(d_ego, d_other, pairs, epsilon):
    """(m,) int64 `neighbourhood_agreement` of pairs (m, 2) from `_neighbour_distances` rows."""
    out = np.empty(pairs.shape[0], np.int64)
    for s in range(pairs.shape[0]):
        a, b = d_ego[pairs[s, 0]], d_other[pairs[s, 1]]
        i = j = count = 0
        while i < a.shape[0] - 1 and j < b.shape[0] - 1:
            d = a[i] - b[j]
            if abs(d) < epsilon:  # greedy in sorted order: the largest one-to-one matching
                count += 1
                i += 1
                j += 1
            elif d < 0:
                i += 1
            else:
                j += 1
        out[s] = count
    return out


@numba.njit(cache=True)
def _best_per_object(compatible, d_ego, d_other, ages_ego, ages_other, epsilon, per_object):
    """(n, m) uint8: the agreement + 1 of the `per_object` best compatible pairs of every ego
    and every other object by (agreement, then smaller age sum, then lower index), 0 for the
    pairs not kept."""
    n, m = compatible.shape
    steps = d_ego.shape[1] + d_other.shape[1] - 2
    keep = np.zeros((n, m), np.uint8)
    cols = np.empty(m, np.int64)
    at_ego = np.empty(m, np.int64)
    at_other = np.empty(m, np.int64)
    count = np.empty(m, np.int64)
    row_score = np.empty(per_object, np.int64)
    row_age = np.empty(per_object)
    row_pick = np.empty(per_object, np.int64)
    col_score = np.full((m, per_object), -1, np.int64)
    col_age = np.full((m, per_object), np.inf)
    col_pick = np.full((m, per_object), -1, np.int64)
    for i in range(n):
        k = 0
        for j in range(m):
            if compatible[i, j]:
                cols[k] = j
                k += 1
        if k == 0:
            continue
        a = d_ego[i]
        at_ego[:k] = 0
        at_other[:k] = 0
        count[:k] = 0
        # The greedy matching of `_agreement`, run on all the row's pairs in lockstep and
        # without branches: each pair's step waits on none of the others, which makes it
        # about twice as fast as one pair after another. The inf ending every row stops an
        # index there; after `steps` steps every matching is finished.
        for _ in range(steps):
            for c in range(k):
                d = a[at_ego[c]] - d_other[cols[c], at_other[c]]
                hit = abs(d) < epsilon
                count[c] += hit
                at_ego[c] += hit | (d < 0)
                at_other[c] += hit | (d > 0)
        row_score[:] = -1
        row_age[:] = np.inf
        row_pick[:] = -1
        for c in range(k):
            j = cols[c]
            age = ages_ego[i] + ages_other[j]
            _offer(row_score, row_age, row_pick, count[c], age, j)
            _offer(col_score[j], col_age[j], col_pick[j], count[c], age, i)
        for r in range(per_object):
            if row_pick[r] >= 0:
                keep[i, row_pick[r]] = row_score[r] + 1
    for j in range(m):
        for r in range(per_object):
            if col_pick[j, r] >= 0:
                keep[col_pick[j, r], j] = col_score[j, r] + 1
    return keep


@numba.njit(cache=True)
def _offer(scores, ages, picks, score, age, pick):
    """Insert (score, age, pick) into the best-first lists if it beats their last entry:
    higher score first, then smaller age; offered in index order, so equals keep the lower."""
    last = scores.shape[0] - 1
    if score < scores[last] or (score == scores[last] and age >= ages[last]):
        return
    r = last
    while r > 0 and (score > scores[r - 1] or (score == scores[r - 1] and age < ages[r - 1])):
        scores[r], ages[r], picks[r] = scores[r - 1], ages[r - 1], picks[r - 1]
        r -= 1
    scores[r], ages[r], picks[r] = score, age, pick


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
        if not (np.isfinite(p).all() and np.isfinite(q).all() and np.isfinite(w).all()):
            raise DataError("weighted_arun: points and weights must be finite")
        if (w < 0).any():
            raise DataError(f"weighted_arun: weights must be >= 0, got min {w.min()}")
        if (w > MAX_WEIGHT).any():
            raise DataError(f"weighted_arun: weights must be <= {MAX_WEIGHT:g}, got "
                            f"{w.max():.3g}")
        largest = max(float(np.abs(p).max()), float(np.abs(q).max()))
        raise DataError(f"weighted_arun: coordinates must lie within {MAX_COORDINATE:g} "
                        f"metres of the origin, got one of magnitude {largest:.3g}")
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
    floor = w_sum * (1e-9 * max(1.0, float(np.max(np.abs(q))))) ** 2
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
    wq = q_c * w[:, None]
    if _eigenvalues_2x2(wq[:, 0] @ q_c[:, 0], wq[:, 1] @ q_c[:, 1], wq[:, 0] @ q_c[:, 1]
                        )[1] <= floor:
        return None
    dot = wq[:, 0] @ p_c[:, 0] + wq[:, 1] @ p_c[:, 1]
    cross = wq[:, 0] @ p_c[:, 1] - wq[:, 1] @ p_c[:, 0]
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    T = np.eye(3)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    T[0, 2] = p_mean[0] - (c * q_mean[0] - s * q_mean[1])
    T[1, 2] = p_mean[1] - (s * q_mean[0] + c * q_mean[1])
    return T


def _eigenvalues_2x2(sxx: float, syy: float, sxy: float) -> tuple[float, float]:
    """(smaller, larger) eigenvalue of the symmetric matrix [[sxx, sxy], [sxy, syy]], in
    closed form (an eigensolver call costs more than the few points it is asked about)."""
    mean, half_gap = 0.5 * (sxx + syy), math.hypot(0.5 * (sxx - syy), sxy)
    return mean - half_gap, mean + half_gap


def _points(owner: str, name: str, value, d: int | None = None) -> np.ndarray:
    """`value` as finite (k, d) points, d = 2 or 3 (or the given d), else DataError."""
    arr = real_array(owner, name, value)
    if arr.ndim != 2 or (arr.shape[1] not in (2, 3) if d is None else arr.shape[1] != d):
        raise DataError(f"{owner}: {name} must be (k, {'2 or 3' if d is None else d}) points, "
                        f"got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DataError(f"{owner}: {name} holds non-finite values")
    return arr


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
    p = _points(o, "p", p)
    q = _points(o, "q", q, p.shape[1])
    if q.shape != p.shape or p.shape[0] == 0:
        raise DataError(f"{o}: p and q must be the same k >= 1 pairs, got {p.shape} and "
                        f"{q.shape}")
    return _registration_rmse(_transform(o, T_a_b, p.shape[1]), p, q)


def _registration_rmse(T_a_b: np.ndarray, p: np.ndarray, q: np.ndarray) -> float:
    d = p.shape[1]
    residual = p - (q @ T_a_b[:d, :d].T + T_a_b[:d, d])
    return float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))


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
    p = _points(o, "p", p, 2)
    q = _points(o, "q", q, 2)
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
    return _mutual_nearest(np.require(p, np.float64, "CW"), np.require(moved, np.float64, "CW"),
                           np.require(compatible, np.bool_, "CW"), float(radius) ** 2)


@numba.njit(cache=True)
def _mutual_nearest(p: np.ndarray, moved: np.ndarray, compatible: np.ndarray, r2: float
                    ) -> np.ndarray:
    """(k, 2) pairs (i, j), sorted by i, where moved[j] is p[i]'s nearest compatible point
    and p[i] moved[j]'s, within squared distance r2; ties go to the lower index. One pass
    over the pairs, no (n, m) temporaries (small maps call this for every candidate)."""
    n, m = p.shape[0], moved.shape[0]
    nearest_q = np.full(n, -1, np.int64)
    nearest_p = np.full(m, -1, np.int64)
    best_q = np.full(n, np.inf)
    best_p = np.full(m, np.inf)
    for i in range(n):
        for j in range(m):
            if compatible[i, j]:
                dx = p[i, 0] - moved[j, 0]
                dy = p[i, 1] - moved[j, 1]
                d2 = dx * dx + dy * dy
                if d2 < best_q[i]:
                    best_q[i], nearest_q[i] = d2, j
                if d2 < best_p[j]:
                    best_p[j], nearest_p[j] = d2, i
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
    return _spread(_points("spread", "points", points, 2))


def _spread(points: np.ndarray) -> float:
    n = points.shape[0]
    if n < 2:
        return 0.0
    c = points - points.sum(0) / n
    smaller = _eigenvalues_2x2(c[:, 0] @ c[:, 0] / n, c[:, 1] @ c[:, 1] / n,
                               c[:, 0] @ c[:, 1] / n)[0]
    return math.sqrt(max(smaller, 0.0))
