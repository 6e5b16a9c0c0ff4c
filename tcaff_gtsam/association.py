"""Putative associations of two object maps: the size gates (the paper's, and the partial-view
rule for objects seen in part), the descriptor gate, and the ranking of pairs by how well their
neighbourhoods agree, which thins look-alike maps and chooses among the partial-view rule's
pairs. The registration of associated points is in `registration`."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from .errors import DataError
from .inputs import index_pairs, kernel_array, point_array, shown
from .object_map import ObjectMap, as_object_map
from .params import _finite, _int_at_least, _require

__all__ = ["neighbourhood_agreement", "putative_associations"]

#: object pairs (rows x columns) in one block of the descriptor gate: its float temporaries
#: then take tens of MB whatever the map sizes
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
#: points up to which `_neighbour_distances` computes every distance (`_nearest_rows`) rather
#: than querying a k-d tree: about a third of the tree's cost at 128 points and 48
#: neighbours, a fifth of it at 100 points and 8, half of it at 300 and 48
_DENSE_NEIGHBOURS = 128


@numba.njit(cache=True)
def _size_gate(ego_w, ego_h, other_w, other_h, ratio, abs_diff, partial_ratio, compatible,
               partial):
    """The size gate of objects of widths and heights (n,) and (m,) [m]: compatible (n, m)
    bool written with the pairs it passes and partial (n, m) bool with those of them that
    only the partial-view rule (`partial_ratio`, 0 for none) passes. Two sizes are similar
    within a ratio when the larger is at most ratio times the smaller or they differ by at
    most abs_diff. One pass, no (n, m) float temporaries."""
    use_partial = partial_ratio > ratio
    for i in range(ego_w.shape[0]):
        for j in range(other_w.shape[0]):
            w_large, w_small = max(ego_w[i], other_w[j]), min(ego_w[i], other_w[j])
            h_large, h_small = max(ego_h[i], other_h[j]), min(ego_h[i], other_h[j])
            w_close = abs(ego_w[i] - other_w[j]) <= abs_diff
            h_close = abs(ego_h[i] - other_h[j]) <= abs_diff
            w_ok = w_large <= ratio * w_small or w_close
            h_ok = h_large <= ratio * h_small or h_close
            both = w_ok and h_ok
            cut = False
            if use_partial and not both:
                cut = ((w_ok and (h_large <= partial_ratio * h_small or h_close))
                       or (h_ok and (w_large <= partial_ratio * w_small or w_close)))
            compatible[i, j] = both or cut
            partial[i, j] = cut


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
    return _true_pairs(size_gates(ego, other, ratio, abs_diff, partial_ratio)[0])


@numba.njit(cache=True)
def _true_pairs(mask):
    """(k, 2) int64 (row, column) of the True entries of mask (n, m) bool, in row-major order
    (np.argwhere's pairs), C-contiguous: one compiled pass, a fifth of argwhere's time on a
    step's gate. Each entry is written and the count moves past it only when it is True."""
    n, m = mask.shape
    count = 0
    for i in range(n):
        for j in range(m):
            count += mask[i, j]
    out = np.empty((count + 1, 2), np.int64)  # a row to spare for the entries past the last
    k = 0
    for i in range(n):
        for j in range(m):
            out[k, 0], out[k, 1] = i, j
            k += mask[i, j]
    return out[:count]


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
    partial = np.empty((len(ego), len(other)), bool)
    _size_gate(kernel_array(ego.widths), kernel_array(ego.heights), kernel_array(other.widths),
               kernel_array(other.heights), float(ratio), float(abs_diff),
               0.0 if partial_ratio is None else float(partial_ratio), compatible, partial)
    return compatible, partial


def _block_rows(n_other: int) -> int:
    """Ego rows per block of the descriptor gate against `n_other` objects."""
    return max(1, _GATE_BLOCK // max(n_other, 1))


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
    p = point_array(o, "ego_points", ego_points)
    q = point_array(o, "other_points", other_points, p.shape[1])
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
    return _mutual_best(best_row, best_col, partial)


@numba.njit(cache=True)
def _mutual_best(best_row, best_col, partial):
    """(n, m) bool: the pairs of `partial` ((n, m) bool) that are the best pair of both their
    objects: ego object i's best pair is (i, best_row[i]), other object j's (best_col[j], j),
    -1 for none (`_best_pair_of_each`)."""
    kept = np.zeros(partial.shape, np.bool_)
    for i in range(best_row.shape[0]):
        j = best_row[i]
        if j >= 0 and best_col[j] == i:
            kept[i, j] = partial[i, j]
    return kept


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
    # (score, age, pick) of each object's best pair so far, pick -1 for none yet
    best_row = np.full((n, 3), -1.0)
    best_col = np.full((m, 3), -1.0)
    cols = np.empty(m, np.int64)
    at_ego = np.empty(m, np.int64)
    at_other = np.empty(m, np.int64)
    count = np.empty(m, np.int64)
    for i in range(n):
        k = _row_agreements(compatible, i, d_ego, d_other, epsilon, cols, at_ego, at_other,
                            count)
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
    ranks above it: a higher score, or the same and a smaller age. Without a branch on the
    outcome, which no predictor learns: each entry is written, kept or replaced."""
    take = (best[2] < 0) | (score > best[0]) | ((score == best[0]) & (age < best[1]))
    best[0] = score if take else best[0]
    best[1] = age if take else best[1]
    best[2] = pick if take else best[2]


def _neighbour_distances(points: np.ndarray, neighbours: int) -> np.ndarray:
    """(n, k + 1) float64: each point's distances to its k = min(neighbours, n - 1) nearest
    other points, ascending, then an inf that ends the row for `_agreement` and
    `_best_per_object`."""
    n = points.shape[0]
    k = min(neighbours, n - 1)
    if k > 0 and n <= _DENSE_NEIGHBOURS:
        # a step's maps: every distance, the nearest kept in order, costs a fraction of a
        # tree query for as many neighbours
        return _nearest_rows(kernel_array(points), k)
    out = np.full((n, k + 1), np.inf)
    if k > 0:
        # the nearest is the point itself (or a duplicate of it: distance 0 either way)
        distances, _ = cKDTree(points).query(points, k + 1)
        out[:, :k] = distances[:, 1:]
    return out


@numba.njit(cache=True)
def _nearest_rows(points, k):
    """(n, k + 1): each of the points' (n, d) distances to its k nearest other points,
    ascending, then an inf (`_neighbour_distances`). The distances are summed over the axes in
    order and rooted, as scipy's cdist computes them (without fused multiply-adds: the same to
    the last bit), and the point itself is left out as the first of its sorted row is (its
    distance 0 sorts first; a duplicate's 0 is the same value). Rows are ranked by squared
    distance and only the kept are rooted: the root does not decrease, so the roots of the
    k + 1 smallest squares are the k + 1 smallest distances.

    Every row takes each point's squared distance at once: one pass of min and max down the
    rows' sorted lists (the larger value carried on, the largest falling off the end) keeps
    each list the smallest values seen, in order, as inserting them one at a time would (only
    values are kept, so ties do not matter), without a branch and along the rows, so that it
    runs in vector instructions: about a third of the time of an insertion per row."""
    n, dim = points.shape
    axes = np.empty((dim, n))  # the coordinates, each axis contiguous
    for i in range(n):
        for a in range(dim):
            axes[a, i] = points[i, a]
    best = np.full((k + 1, n), np.inf)  # each row's k + 1 smallest squares so far, ascending
    carry = np.empty(n)
    for j in range(n):
        carry[:] = 0.0
        for a in range(dim):  # 0 + dx^2 is dx^2: the same sums as cdist's
            x = axes[a]
            for i in range(n):
                diff = x[i] - x[j]
                carry[i] += diff * diff
        for r in range(k + 1):
            kept = best[r]
            for i in range(n):
                smaller = min(kept[i], carry[i])
                carry[i] = max(kept[i], carry[i])
                kept[i] = smaller
    out = np.empty((n, k + 1))
    for i in range(n):
        for r in range(k):
            out[i, r] = np.sqrt(best[r + 1, i])
        out[i, k] = np.inf
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
        k = _row_agreements(compatible, i, d_ego, d_other, epsilon, cols, at_ego, at_other,
                            count)
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
def _row_agreements(compatible, i, d_ego, d_other, epsilon, cols, at_ego, at_other, count):
    """The compatible pairs ((n, m) bool) of ego object i: their other objects in cols[:k]
    and their `_agreement` in count[:k], from `_neighbour_distances` rows; returns k.
    at_ego, at_other, count and cols are (m,) int64 buffers the caller keeps across rows.

    The greedy matching of `_agreement`, run on all the row's pairs in lockstep and without
    branches: each pair's step waits on none of the others, which makes it about twice as fast
    as one pair after another. By bursts of 8 steps: a pair is done once either index reached
    its row's inf (the steps after that match nothing), and most rows are done well before
    the longest matching's steps. Indices are read as unsigned, which spares numba's
    negative-index wraparound (a tenth of the time)."""
    # listed without a branch per object (a fraction pass, in no order a predictor learns):
    # each is written, and the count moves past it only when it is compatible
    k = 0
    for j in range(compatible.shape[1]):
        cols[np.uint64(k)] = j
        k += compatible[i, j]
    if k == 0:
        return 0
    a = d_ego[i]
    at_ego[:k] = 0
    at_other[:k] = 0
    count[:k] = 0
    steps = d_ego.shape[1] + d_other.shape[1] - 2
    done = 0
    while done < steps:
        for _ in range(8):
            for c in range(k):
                d = (a[np.uint64(at_ego[c])]
                     - d_other[np.uint64(cols[c]), np.uint64(at_other[c])])
                hit = abs(d) < epsilon
                count[c] += hit
                at_ego[c] += hit | (d < 0)
                at_other[c] += hit | (d > 0)
        done += 8
        busy = False
        for c in range(k):
            if (a[np.uint64(at_ego[c])] < np.inf
                    and d_other[np.uint64(cols[c]), np.uint64(at_other[c])] < np.inf):
                busy = True
                break
        if not busy:
            break
    return k


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
