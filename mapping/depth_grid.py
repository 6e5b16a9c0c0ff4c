"""The depth segmenter's passes over the pixels, between the camera's image and the grid it
works on.

An image wider than `DepthSegmenterParams.work_width` is segmented on a grid of every s-th row
and column. These kernels give the segmenter its depth and bring its labels back: the
median-filtered depth at the full-resolution pixels RANSAC samples (`_sampled_median`, as
OpenCV's medianBlur there), the depths out of range dropped (`_in_range`), the far and the
near side of depth jumps (`_steps`), the components' sizes on the grid (`_grid_stats`), their
labels at full resolution by depth (`_expand`) and the label image as a stack of masks
(`_stack`). All are numba kernels, cached on disk (`segment._compile_kernels` runs each once);
`_FAR` and `_FAST` are the finite-number conventions of these and `structure`'s kernels.
"""

from __future__ import annotations

import numba
import numpy as np

__all__: list[str] = []

#: no depth, for the nearest-depth filter (finite: the kernels assume no infinities)
_FAR = np.float32(3e38)
#: the kernels below compare and take minima of finite numbers: no NaN, no infinity
_FAST = {"nnan", "ninf", "nsz"}


def _median_network(k: int) -> np.ndarray:
    """(m, 2) int64 compare-exchange pairs that bring the median of k * k values (padded with
    `_FAR` to a power of two) to index k * k // 2: Batcher's odd-even merge sort, without the
    pairs that cannot move that index."""
    n = 1 << max(0, (k * k - 1).bit_length())
    pairs = []
    p = 1
    while p < n:
        q = p
        while q >= 1:
            for j in range(q % p, n - q, 2 * q):
                for i in range(min(q, n - j - q)):
                    if (i + j) // (2 * p) == (i + j + q) // (2 * p):
                        pairs.append((i + j, i + j + q))
            q //= 2
        p *= 2
    needed, kept = {k * k // 2}, []
    for a, b in reversed(pairs):
        if a in needed or b in needed:
            needed |= {a, b}
            kept.append((a, b))
    return np.array(kept[::-1], dtype=np.int64).reshape(-1, 2)


#: the networks of the median filter's kernel sizes
_MEDIAN_NETWORKS = {k: _median_network(k) for k in (1, 3, 5)}


@numba.njit(cache=True, fastmath=_FAST)
def _sampled_median(z: np.ndarray, stride: int, k: int,
                    network: np.ndarray) -> np.ndarray:  # pragma: no cover
    """z[::stride, ::stride] of the k x k median filter of z ((H, W) float32, replicated past
    its border, as OpenCV's medianBlur), through the compare-exchange `network`
    (`_median_network(k)`), all pixels at once."""
    H, W = z.shape
    r = k // 2
    h, w = (H + stride - 1) // stride, (W + stride - 1) // stride
    n = 1
    while n < k * k:  # the network's width, a power of two
        n *= 2
    values = np.full((n, h * w), _FAR, dtype=np.float32)  # value m of pixel i * w + j
    columns = np.empty(w, dtype=np.int64)
    m = 0
    for dr in range(-r, r + 1):
        for dc in range(-r, r + 1):
            for j in range(w):
                columns[j] = min(max(j * stride + dc, 0), W - 1)
            for i in range(h):
                row = min(max(i * stride + dr, 0), H - 1)
                for j in range(w):
                    values[m, i * w + j] = z[row, columns[j]]
            m += 1
    for q in range(network.shape[0]):
        a, b = network[q, 0], network[q, 1]
        for i in range(h * w):
            x, y = values[a, i], values[b, i]
            values[a, i] = min(x, y)
            values[b, i] = max(x, y)
    return values[k * k // 2].copy().reshape(h, w)


@numba.njit(cache=True, fastmath=_FAST)
def _in_range(z: np.ndarray, depth_min: np.float32, depth_max: np.float32
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Sets the depths of z ((h, w) float32 metres) outside [depth_min, depth_max] to 0 and
    returns (h, w) each: bool pixels with a return (before that), bool pixels with depth
    (after), and float32 their depth or `_FAR` where there is none."""
    h, w = z.shape
    returned = np.empty((h, w), dtype=np.bool_)
    valid = np.empty((h, w), dtype=np.bool_)
    near = np.empty((h, w), dtype=np.float32)
    for r in range(h):
        for c in range(w):
            d = z[r, c]
            returned[r, c] = d > 0
            d = d if (d >= depth_min) & (d <= depth_max) else np.float32(0.0)
            z[r, c] = d
            valid[r, c] = d > 0
            near[r, c] = d if d > 0 else _FAR
    return returned, valid, near


@numba.njit(cache=True, fastmath=_FAST)
def _steps(z: np.ndarray, nearest: np.ndarray, farthest: np.ndarray, jump: np.float32,
           jump_per_m: np.float32) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """(h, w) bool each: the pixels with depth (z (h, w) float32 metres, 0 = none) whose
    `nearest` neighbour is nearer, and whose `farthest` is farther, by more than
    jump + jump_per_m * depth."""
    h, w = z.shape
    behind = np.empty((h, w), dtype=np.bool_)
    fronts = np.empty((h, w), dtype=np.bool_)
    for r in range(h):
        for c in range(w):
            d = z[r, c]
            threshold = jump + jump_per_m * d
            behind[r, c] = (d > 0) & (d - nearest[r, c] > threshold)
            fronts[r, c] = (d > 0) & (farthest[r, c] - d > threshold)
    return behind, fronts


@numba.njit(cache=True)
def _grid_stats(labels: np.ndarray, count: int) -> np.ndarray:  # pragma: no cover
    """(count, 5) int64 per label of `labels` ((h, w) int32): its pixel count and bounding
    box r0, r1, c0, c1 (ends exclusive)."""
    h, w = labels.shape
    stats = np.zeros((count, 5), dtype=np.int64)
    stats[:, 1], stats[:, 3] = h, w
    for r in range(h):
        for c in range(w):
            lab = labels[r, c]
            stats[lab, 0] += 1
            stats[lab, 1] = min(stats[lab, 1], r)
            stats[lab, 2] = max(stats[lab, 2], r + 1)
            stats[lab, 3] = min(stats[lab, 3], c)
            stats[lab, 4] = max(stats[lab, 4], c + 1)
    return stats


@numba.njit(cache=True, fastmath=_FAST)
def _expand(labels: np.ndarray, table: np.ndarray, structure: np.ndarray, z: np.ndarray,
            z_full: np.ndarray, step: int, lo: np.float32, hi: np.float32, jump: np.float32,
            jump_per_m: np.float32, out: np.ndarray) -> np.ndarray:  # pragma: no cover
    """Labels the image from its grid: writes into `out` ((H, W), the shape of z_full) the
    label table[labels] ((h, w) int32 on every step-th row and column; table (count,) uint8
    or int32) of the grid pixel whose depth (z (h, w) float32 metres, 0 = none) agrees with
    the pixel's (z_full (H, W) metres) within jump + jump_per_m * depth, or 0. A pixel looks
    at its own grid pixel, and if that one does not agree and the grid pixel is on an edge
    (another label, or none, among its 8 neighbours) and not room structure (`structure`
    (h, w) bool), at the 3 x 3 grid pixels around it, taking the nearest depth: outlines are
    drawn at full resolution, not in blocks. Pixels with depth outside [lo, hi] get 0.
    Returns the number of pixels of each label ((table.max() + 1,) int64; 0 for 0)."""
    H, W = out.shape
    h, w = labels.shape
    value = np.empty((h, w), dtype=out.dtype)
    limit = np.empty((h, w), dtype=np.float32)  # the largest depth difference that agrees
    for r in range(h):
        for c in range(w):
            value[r, c] = table[labels[r, c]]
            limit[r, c] = jump + jump_per_m * z[r, c]
    # the edge: the largest and the smallest label of the 3 x 3 grid pixels around differ
    low = np.empty((h, w), dtype=out.dtype)
    high = np.empty((h, w), dtype=out.dtype)
    for r in range(h):
        for c in range(w):
            low[r, c] = high[r, c] = value[r, c]
        for c in range(1, w):
            low[r, c] = min(low[r, c], value[r, c - 1])
            high[r, c] = max(high[r, c], value[r, c - 1])
        for c in range(w - 1):
            low[r, c] = min(low[r, c], value[r, c + 1])
            high[r, c] = max(high[r, c], value[r, c + 1])
    edge = np.empty((h, w), dtype=np.bool_)
    for r in range(h):
        above, below = max(r - 1, 0), min(r + 1, h - 1)
        for c in range(w):
            smallest = min(low[r, c], min(low[above, c], low[below, c]))
            largest = max(high[r, c], max(high[above, c], high[below, c]))
            edge[r, c] = (smallest != largest) & ~structure[r, c]
    column = np.empty(W, dtype=np.int64)  # the grid column of each image column
    for C in range(W):
        column[C] = C // step
    area = np.zeros(int(table.max()) + 1, dtype=np.int64)
    # each pixel with its own grid pixel, a grid row at a time
    row_value = np.empty(W, dtype=out.dtype)
    row_z = np.empty(W, dtype=np.float32)
    row_limit = np.empty(W, dtype=np.float32)
    agree = np.empty(W, dtype=np.int32)
    for r in range(h):
        if step == 2 and W == 2 * w:  # the usual case, spelt out so that it vectorises
            for c in range(w):
                row_value[2 * c] = row_value[2 * c + 1] = value[r, c]
                row_z[2 * c] = row_z[2 * c + 1] = z[r, c]
                row_limit[2 * c] = row_limit[2 * c + 1] = limit[r, c]
        else:
            for C in range(W):
                c = column[C]
                row_value[C], row_z[C], row_limit[C] = value[r, c], z[r, c], limit[r, c]
        agree[:] = 0
        for R in range(r * step, min(r * step + step, H)):
            for C in range(W):
                d = z_full[R, C]
                ok = (d >= lo) & (d <= hi) & (abs(d - row_z[C]) <= row_limit[C])
                out[R, C] = row_value[C] if ok else 0
                agree[C] += ok
        for C in range(W):
            area[row_value[C]] += agree[C]
    # then the pixels left out on an edge, with the 3 x 3 grid pixels around
    for r in range(h):
        for c in range(w):
            if not edge[r, c]:
                continue
            for R in range(r * step, min(r * step + step, H)):
                for C in range(c * step, min(c * step + step, W)):
                    d = z_full[R, C]
                    if out[R, C] != 0 or not ((d >= lo) & (d <= hi)):
                        continue
                    best, closest = 0, _FAR
                    for rr in range(max(r - 1, 0), min(r + 2, h)):
                        for cc in range(max(c - 1, 0), min(c + 2, w)):
                            v = value[rr, cc]
                            gap = abs(d - z[rr, cc])
                            if v != 0 and gap <= limit[rr, cc] and gap < closest:
                                best, closest = v, gap
                    out[R, C] = best
                    area[best] += 1
    area[0] = 0  # not counted: the background
    return area


@numba.njit(cache=True)
def _stack(labels: np.ndarray, count: int) -> np.ndarray:  # pragma: no cover
    """(count, H, W) bool: labels == 1, labels == 2, ... (`labels` (H, W) uint8)."""
    H, W = labels.shape
    masks = np.empty((count, H, W), dtype=np.bool_)
    for i in range(count):
        value = np.uint8(i + 1)
        for r in range(H):
            for c in range(W):
                masks[i, r, c] = labels[r, c] == value
    return masks
