"""The mask filter: which instance masks are worth lifting to objects.

`filter_masks` drops the masks the original systems also dropped: touching the image border (a
cut-off object has a wrong centroid and size), too small, too large, too elongated, or with too
little valid depth to lift (`filter_labels`: the same from a label image, without making the
masks). Real depth cameras return no depth in bands along the image edges (registration, lens
vignetting) and beyond their range. Every border rule therefore treats the band of missing
depth that reaches the image edge (`depth_border`) as part of the edge: an object cut by the
edge of the valid depth is as cut off as one cut by the edge of the image. The band and the
masks' moments are numba kernels (at the end of the module, cached on disk;
`segment._compile_kernels` runs each once).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.params import _int_at_least, _real, _require

__all__ = [
    "INVALID_MARGIN",
    "MaskFilter",
    "check_masks",
    "depth_border",
    "filter_labels",
    "filter_masks",
]

#: pixels; no-depth regions this close to the image edge, and reaching it, count as the edge
INVALID_MARGIN = 40

#: the widest border band a `MaskFilter` drops masks in, pixels: the band is grown with a
#: (2 border - 1)^2 kernel, 4 MB at this width, beyond the side of any image the filter sees
MAX_BORDER = 1000


@dataclass(frozen=True)
class MaskFilter:
    """Which masks are worth lifting to objects.

    Attributes:
        min_area: pixels; smaller masks are dropped.
        max_area_share: share of the image; larger masks (floor, walls, sky) are dropped.
        border: pixels; masks reaching within this distance of the image edge, or of the
            band without depth along it (see `invalid_margin`), are dropped (0 keeps them);
            at most `MAX_BORDER`.
        max_elongation: largest ratio of the mask's principal standard deviations (long over
            short axis); thin masks are edges, poles cut by the frame or segmentation slivers.
        min_depth_share: smallest share of mask pixels with a depth return.
        invalid_margin: pixels; a region without depth that reaches the image edge and lies
            mostly within this distance of it counts as the edge there (see `depth_border`;
            0: only the image edge counts).
    """

    min_area: int = 400
    max_area_share: float = 0.25
    border: int = 2
    max_elongation: float = 6.0
    min_depth_share: float = 0.5
    invalid_margin: int = INVALID_MARGIN

    def __post_init__(self) -> None:
        o = "MaskFilter"
        _require(_int_at_least(self.min_area, 0), o, "min_area", self.min_area,
                 "must be an int >= 0 pixels")
        _require(_int_at_least(self.border, 0) and self.border <= MAX_BORDER, o, "border",
                 self.border, f"must be an int in [0, {MAX_BORDER}] pixels (MAX_BORDER)")
        _require(_int_at_least(self.invalid_margin, 0), o, "invalid_margin",
                 self.invalid_margin, "must be an int >= 0 pixels")
        _require(_real(self.max_area_share)
                 and 0 < self.max_area_share <= 1, o, "max_area_share", self.max_area_share,
                 "must be in (0, 1]")
        _require(_real(self.max_elongation) and self.max_elongation >= 1, o,
                 "max_elongation", self.max_elongation, "must be a number >= 1")
        _require(_real(self.min_depth_share)
                 and 0 <= self.min_depth_share <= 1, o, "min_depth_share",
                 self.min_depth_share, "must be in [0, 1]")

    def area_ok(self, area: np.ndarray, image_area: int) -> np.ndarray:
        """(k,) bool: pixel areas within [min_area, max_area_share * image_area]."""
        return _area_ok(area, self.min_area, self.max_area_share, image_area)


def _area_ok(area: np.ndarray, min_area: int, max_share: float, image_area: int) -> np.ndarray:
    return (area >= min_area) & (area <= max_share * image_area)


def check_masks(masks, shape: tuple[int, int], owner: str = "masks") -> np.ndarray:
    """`masks` as given if it is a (k, H, W) bool array with (H, W) = `shape`; else
    DataError naming `owner`."""
    if not (isinstance(masks, np.ndarray) and masks.dtype == np.bool_ and masks.ndim == 3
            and masks.shape[1:] == tuple(shape)):
        got = (f"{masks.shape} {masks.dtype}" if isinstance(masks, np.ndarray)
               else type(masks).__name__)
        raise DataError(f"{owner} must be a (k, {shape[0]}, {shape[1]}) bool array, got {got}")
    return masks


def depth_border(valid: np.ndarray, margin: int) -> np.ndarray:
    """(H, W) bool: the image's outermost pixels plus the band without depth along them.

    A connected region without depth (8-connected) that reaches the image edge is a band of
    the sensor's border (registration, vignetting) when most of its pixels lie within `margin`
    pixels of the edge; its pixels within the margin count as border. A region mostly farther
    in (open space beyond the range, a window, the sky) is something seen, not an edge of the
    view: an object next to it is not cut off.

    Args:
        valid: (H, W) bool, pixels with a depth return.
        margin: pixels (>= 0).
    """
    H, W = valid.shape
    out = np.zeros((H, W), dtype=bool)
    out[0], out[-1], out[:, 0], out[:, -1] = True, True, True, True
    if margin == 0:
        return out
    # Only the regions that reach the edge matter: they are flood-filled from it (a few regions
    # of a few thousand pixels), instead of labelling every hole in the image.
    return out | _edge_band(np.ascontiguousarray(~valid), margin)


def filter_masks(masks: np.ndarray, depth_m: np.ndarray, mask_filter: MaskFilter
                 ) -> np.ndarray:
    """Indices of the masks that pass `mask_filter`.

    Args:
        masks: (k, H, W) bool.
        depth_m: (H, W) metres, 0 = no return.

    Returns:
        (k',) int64 indices into `masks`, increasing.

    Raises:
        DataError: masks or depth_m of the wrong kind or shape.
    """
    valid, near = _filter_images(depth_m, mask_filter, "filter_masks")
    k, (H, W) = len(check_masks(masks, valid.shape)), valid.shape
    if k == 0:
        return np.zeros(0, dtype=np.int64)
    if W % 8 == 0 and masks.flags.c_contiguous and sys.byteorder == "little":
        # one pass over the stack, eight pixels at a time: most of each mask is empty
        stats = _mask_moments(masks.view(np.uint64), valid.view(np.uint64),
                              near.view(np.uint64))
    else:
        stats = np.array([_moments_of(m, valid, near) for m in masks]).reshape(k, 8)
    return _passing(stats, mask_filter, H * W)


def filter_labels(labels: np.ndarray, count: int, depth_m: np.ndarray,
                  mask_filter: MaskFilter) -> np.ndarray:
    """`filter_masks` of the masks of a label image, without making them: the indices of the
    labels 1..count (as 0..count - 1) whose masks (labels == i + 1) pass `mask_filter`. One
    pass over the image, where `filter_masks` reads every mask of the stack.

    Args:
        labels: (H, W) integer label image, 0 = no mask (as `DepthSegmenter.label` gives).
        count: the number of labels (labels outside 1..count are ignored).
        depth_m: as in `filter_masks`.

    Returns:
        (k',) int64 increasing indices i of the labels i + 1 that pass.

    Raises:
        DataError: labels, count or depth_m of the wrong kind or shape.
    """
    valid, near = _filter_images(depth_m, mask_filter, "filter_labels")
    if not (isinstance(labels, np.ndarray) and labels.dtype.kind in "iu"
            and labels.shape == valid.shape):
        got = (f"{labels.shape} {labels.dtype}" if isinstance(labels, np.ndarray)
               else type(labels).__name__)
        raise DataError(f"filter_labels: labels must be a {valid.shape} integer array, got "
                        f"{got}")
    if not _int_at_least(count, 0):
        raise DataError(f"filter_labels: count must be an int >= 0, got {count!r}")
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    # int32 (as `DepthSegmenter.label` gives) as it is, any other integers widened
    labels = (labels if labels.dtype == np.int32 and labels.flags.c_contiguous
              else np.ascontiguousarray(labels, dtype=np.int64))
    stats = _label_moments(labels, int(count), valid, near)
    return _passing(stats, mask_filter, labels.size)


def _filter_images(depth_m, mask_filter: MaskFilter, owner: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool each, C-contiguous: the pixels with depth, and those within
    `mask_filter.border` pixels of the border (none when it is 0)."""
    if not (isinstance(depth_m, np.ndarray) and depth_m.ndim == 2
            and depth_m.dtype.kind in "fiu"):
        got = (f"{depth_m.shape} {depth_m.dtype}" if isinstance(depth_m, np.ndarray)
               else type(depth_m).__name__)
        raise DataError(f"{owner}: depth_m must be an (H, W) array of metres, got {got}")
    valid = np.ascontiguousarray(depth_m > 0)
    if not mask_filter.border:
        return valid, np.zeros(valid.shape, dtype=bool)
    border = depth_border(valid, mask_filter.invalid_margin)
    # within `border` pixels of the border: inside the image, a border pixel is 1 away
    kernel = np.ones((2 * mask_filter.border - 1,) * 2, np.uint8)
    return valid, np.ascontiguousarray(cv2.dilate(border.view(np.uint8), kernel).view(bool))


def _passing(stats: np.ndarray, f: MaskFilter, image_area: int) -> np.ndarray:
    """(k',) int64 increasing indices of the masks that pass `f`, from their (k, 8) moments
    (`_mask_moments`) in an image of `image_area` pixels."""
    area, sx, sy, sxx, syy, sxy, with_depth, near = stats.T
    keep = ((area > 0) & f.area_ok(area, image_area) & (near == 0)
            & (with_depth >= f.min_depth_share * area))
    ok = np.flatnonzero(keep)
    n = area[ok]
    # covariance of the pixel centres plus that of a unit square (1/12 per axis)
    a = (sxx[ok] - sx[ok] ** 2 / n) / n + 1.0 / 12.0
    b = (syy[ok] - sy[ok] ** 2 / n) / n + 1.0 / 12.0
    c = (sxy[ok] - sx[ok] * sy[ok] / n) / n
    mid, half = 0.5 * (a + b), np.hypot(0.5 * (a - b), c)
    # the ratio of the principal standard deviations, long over short axis
    elongation = np.sqrt((mid + half) / (mid - half))
    return ok[elongation <= f.max_elongation].astype(np.int64)


def _moments_of(mask: np.ndarray, valid: np.ndarray, near: np.ndarray) -> list[float]:
    """`_mask_moments` of one (H, W) bool mask."""
    rows, cols = np.nonzero(mask)
    rows, cols = rows.astype(float), cols.astype(float)
    return [rows.size, cols.sum(), rows.sum(), cols @ cols, rows @ rows, cols @ rows,
            np.count_nonzero(valid[mask]), np.count_nonzero(near[mask])]


# ---------------------------------------------------------------------------------------------
# compiled kernels (numba, cached on disk; `segment._compile_kernels` compiles every one of them)


@numba.njit(cache=True)
def _edge_band(missing: np.ndarray, margin: int) -> np.ndarray:  # pragma: no cover
    """(H, W) bool: the pixels within `margin` of the image edge of the 8-connected regions of
    `missing` ((H, W) bool) that reach the edge with most of their pixels within the margin
    (`depth_border` without the outermost pixels). Each region is flood-filled from the edge
    a row span at a time."""
    H, W = missing.shape
    seen = np.zeros((H, W), dtype=np.bool_)
    band = np.zeros((H, W), dtype=np.bool_)
    # one region's spans (row, first column, last column), and the pixels they came from
    span_r = np.empty(H * W, dtype=np.int32)
    span_a = np.empty(H * W, dtype=np.int32)
    span_b = np.empty(H * W, dtype=np.int32)
    # pixels where spans may start: a span of n pixels queues at most n + 3 (runs in the rows
    # above and below, one past its ends), so 4 H W pixels are never outgrown
    stack_r = np.empty(4 * H * W + 8, dtype=np.int32)
    stack_c = np.empty(4 * H * W + 8, dtype=np.int32)
    lo_c, hi_c = margin, W - margin  # interior columns [lo_c, hi_c), rows likewise
    for s in range(2 * (H + W)):
        if s < 2 * W:  # the top and the bottom row, then the left and the right column
            r0, c0 = (0 if s < W else H - 1), s % W
        else:
            r0, c0 = (s - 2 * W) % H, (0 if s < 2 * W + H else W - 1)
        if not missing[r0, c0] or seen[r0, c0]:
            continue
        stack_r[0], stack_c[0] = r0, c0
        top, n_spans, area, interior = 1, 0, 0, 0
        while top > 0:
            top -= 1
            r, c = stack_r[top], stack_c[top]
            if seen[r, c]:
                continue
            a, b = c, c
            while a > 0 and missing[r, a - 1] and not seen[r, a - 1]:
                a -= 1
            while b < W - 1 and missing[r, b + 1] and not seen[r, b + 1]:
                b += 1
            for cc in range(a, b + 1):
                seen[r, cc] = True
            span_r[n_spans], span_a[n_spans], span_b[n_spans] = r, a, b
            n_spans += 1
            area += b - a + 1
            if margin <= r < H - margin:
                interior += max(0, min(b + 1, hi_c) - max(a, lo_c))
            # 8-connected: the rows above and below, one column past each end
            for rr in (r - 1, r + 1):
                if rr < 0 or rr >= H:
                    continue
                open_run = False
                for cc in range(max(a - 1, 0), min(b + 2, W)):
                    free = missing[rr, cc] and not seen[rr, cc]
                    if free and not open_run:
                        stack_r[top], stack_c[top] = rr, cc
                        top += 1
                    open_run = free
        if 2 * (area - interior) > area:
            for i in range(n_spans):
                r, a, b = span_r[i], span_a[i], span_b[i]
                if margin <= r < H - margin:
                    for cc in range(a, min(b + 1, lo_c)):
                        band[r, cc] = True
                    for cc in range(max(a, hi_c), b + 1):
                        band[r, cc] = True
                else:
                    for cc in range(a, b + 1):
                        band[r, cc] = True
    return band


def _byte_tables() -> np.ndarray:
    """(4, 256) int64: for each set of the 8 pixels of a word (bit b: pixel b), their number,
    the sum of their indices b and of b^2, and the set itself (the identity)."""
    sets = np.arange(256)
    bits = (sets[:, None] >> np.arange(8)) & 1
    return np.stack([bits.sum(axis=1), bits @ np.arange(8), bits @ np.arange(8) ** 2, sets])


_BYTES = _byte_tables()
#: bit 0 of every byte of a word
_LOW_BITS = np.uint64(0x0101010101010101)
#: times a word of bytes 0 or 1, moves byte b's bit to bit 56 + b (byte 7 of the product)
_GATHER = np.uint64(0x0102040810204080)


@numba.njit(cache=True)
def _bits(word: np.uint64) -> int:  # pragma: no cover
    """The 8 bytes of `word` as 8 bits (bit b: byte b is not 0)."""
    word |= word >> np.uint64(4)
    word |= word >> np.uint64(2)
    word |= word >> np.uint64(1)
    return int(((word & _LOW_BITS) * _GATHER) >> np.uint64(56))


@numba.njit(cache=True)
def _mask_moments(words: np.ndarray, valid: np.ndarray, near: np.ndarray
                  ) -> np.ndarray:  # pragma: no cover
    """(k, 8) float64 per mask: pixel count, sums of x, y, x^2, y^2 and x y (columns and rows),
    pixels in `valid`, pixels in `near`. `words` is the (k, H, W) bool stack seen as
    (k, H, W / 8) uint64, `valid` and `near` the (H, W) bool images seen so too (little
    endian: byte b of word j is column 8 j + b); words of eight empty pixels are skipped."""
    k, H, n_words = words.shape
    count, index, square = _BYTES[0], _BYTES[1], _BYTES[2]
    out = np.zeros((k, 8))
    rows = np.empty(H, dtype=np.bool_)
    columns = np.empty(n_words, dtype=np.uint64)
    for i in range(k):
        # fast passes (no branches) find the rows, then the words, the mask is on
        for r in range(H):
            anything = np.uint64(0)
            for j in range(n_words):
                anything |= words[i, r, j]
            rows[r] = anything != 0
        columns[:] = 0
        for r in range(H):
            if rows[r]:
                for j in range(n_words):
                    columns[j] |= words[i, r, j]
        j0, j1 = 0, n_words
        while j0 < j1 and columns[j0] == 0:
            j0 += 1
        while j1 > j0 and columns[j1 - 1] == 0:
            j1 -= 1
        n = sx = sy = sxx = syy = sxy = n_valid = n_near = 0
        for r in range(H):
            if not rows[r]:
                continue
            rn = rsx = rsxx = 0
            for j in range(j0, j1):
                word = words[i, r, j]
                if word == 0:
                    continue
                b = _bits(word)
                m, x0 = count[b], 8 * j
                rn += m
                rsx += m * x0 + index[b]
                rsxx += m * x0 * x0 + 2 * x0 * index[b] + square[b]
                n_valid += count[b & _bits(valid[r, j])]
                n_near += count[b & _bits(near[r, j])]
            n += rn
            sx += rsx
            sxx += rsxx
            sy += r * rn
            syy += r * r * rn
            sxy += r * rsx
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = n, sx, sy, sxx
        out[i, 4], out[i, 5], out[i, 6], out[i, 7] = syy, sxy, n_valid, n_near
    return out


@numba.njit(cache=True)
def _label_moments(labels: np.ndarray, count: int, valid: np.ndarray,
                   near: np.ndarray) -> np.ndarray:  # pragma: no cover
    """`_mask_moments` of the masks labels == 1 .. count of `labels` ((H, W) int32 or
    int64)."""
    H, W = labels.shape
    out = np.zeros((count + 1, 8))
    for r in range(H):
        for c in range(W):
            lab = labels[r, c]
            if lab < 1 or lab > count:
                continue
            out[lab, 0] += 1
            out[lab, 1] += c
            out[lab, 2] += r
            out[lab, 3] += c * c
            out[lab, 4] += r * r
            out[lab, 5] += c * r
            out[lab, 6] += valid[r, c]
            out[lab, 7] += near[r, c]
    return out[1:]
