"""Segmentation: the `Segmenter` protocol, the mask filters, and the weight-free depth segmenter.

A segmenter turns one RGB-D frame into instance masks, (k, H, W) bool, one per candidate object.
`filter_masks` then drops the masks the original systems also dropped: touching the image
border (a cut-off object has a wrong centroid and size), too small, too large, too elongated,
or with too little valid depth to lift (`filter_labels`: the same from a label image, without
making the masks). FastSAM through onnxruntime is in `fastsam.py`.

The hot loops are numba kernels (at the end of the module, cached on disk; `_compile_kernels`
runs each once, so that an install step can compile them before any run needs them).

Real depth cameras return no depth in bands along the image edges (registration, lens
vignetting) and beyond their range. Every border rule therefore treats the band of missing
depth that reaches the image edge (`depth_border`) as part of the edge: an object cut by the
edge of the valid depth is as cut off as one cut by the edge of the image.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numba
import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.params import _int_at_least, _real, _require

from .camera import (
    R_BODY_OPTICAL,
    PinholeCamera,
    check_camera,
    check_depth_scale,
    depth_in_metres,
    rigid_transform,
)
from .objects import check_rgb

__all__ = [
    "INVALID_MARGIN",
    "DepthSegmenter",
    "DepthSegmenterParams",
    "MaskFilter",
    "Segmenter",
    "check_masks",
    "check_rgb",
    "depth_border",
    "filter_labels",
    "filter_masks",
    "stands_in_front",
    "up_direction",
]

#: sample points on which each RANSAC hypothesis is scored
_RANSAC_SCORED = 1000
#: pixels; no-depth regions this close to the image edge, and reaching it, count as the edge
INVALID_MARGIN = 40


@runtime_checkable
class Segmenter(Protocol):
    """Anything that turns an RGB-D frame into instance masks. A segmenter whose `segment`
    also takes the keyword `up` ((3,) the up direction in the camera's optical frame at this
    frame) is given it by `RgbdFrontEnd` at every frame, from the frame's pose."""

    def segment(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Masks of one frame.

        Args:
            rgb: (H, W, 3) uint8, RGB order.
            depth: (H, W) depth registered to the colour image; `RgbdFrontEnd` passes float32
                metres (0 = no return).

        Returns:
            (k, H, W) bool, one mask per candidate object (k may be 0).
        """
        ...


@dataclass(frozen=True)
class MaskFilter:
    """Which masks are worth lifting to objects.

    Attributes:
        min_area: pixels; smaller masks are dropped.
        max_area_share: share of the image; larger masks (floor, walls, sky) are dropped.
        border: pixels; masks reaching within this distance of the image edge, or of the
            band without depth along it (see `invalid_margin`), are dropped (0 keeps them).
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
        _require(_int_at_least(self.border, 0), o, "border", self.border,
                 "must be an int >= 0 pixels")
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


@dataclass(frozen=True)
class DepthSegmenterParams:
    """Settings of `DepthSegmenter`.

    Attributes:
        median: pixels, odd kernel size (1, 3 or 5) of the median filter applied to depth
            first (1: none).
        jump: metres; a pixel is an occlusion edge when a 4-neighbour is nearer by more than
            jump + jump_per_m * its depth.
        jump_per_m: metres of extra jump allowed per metre of depth.
        jump_reach: pixels; depth is compared with the neighbours up to this far along rows
            and columns, so that a jump smeared over a few pixels (as real sensors and the
            median filter give) still cuts: a chair in front of a wall is split from it.
        max_planes: largest number of dominant planes (floor, walls) removed.
        plane_share: a plane must hold this share of the valid pixels to count as dominant.
        level_tolerance_deg: degrees; a plane whose normal lies this close to the gravity axis
            is level (a floor, ceiling or table top).
        level_plane_share: a level plane needs only this share of the valid pixels; it is
            removed whole, however it is cut up (floor between chair legs, ceiling in a
            corridor), since no object is a large level surface, except where its band is a
            thin slice through an object (`level_slice`).
        level_slice: pixels; a run of at most this many pixels of a level plane's band along the
            image's up direction (image columns unless the camera is rolled past 45 deg) is a
            slice of the band through a taller object beside the plane (a chair back next to a
            table) and stays with the object when the pixels just before and after it are kept,
            differ in depth by jump + jump_per_m * depth at most, and lie on a surface steeper
            than 45 deg (their points rise at least as far as they are apart horizontally along
            the line of sight), and none of its own pixels is on the far side of a depth jump
            (0: no run is kept). The default is about the height of the band on an upright
            surface at 0.8-8 m in a 640 x 480 image with a 525-585 px focal length.
        plane_distance: metres; a pixel belongs to a plane within this distance plus
            plane_distance_per_m2 * depth^2 (noise grows with the square of range).
        plane_distance_per_m2: metres per square metre of depth.
        plane_min_extent: metres; a part of a (not level) plane's pixels that does not reach
            the border of the valid depth is still a wall when it spans this far, unless it
            stands in front of what is around it (`stands_in_front`) and does not meet the
            ceiling (a tall or wide cabinet's front).
        ransac_iterations: plane hypotheses tried per plane.
        ransac_stride: pixels; RANSAC scores hypotheses on every stride-th pixel per axis.
        seed: RANSAC's random seed; the same frame always gives the same masks.
        min_area: pixels; smaller components are dropped.
        max_area_share: share of the image; larger components are dropped.
        depth_min, depth_max: metres; depths outside are treated as no return.
        invalid_margin: pixels; how far from the image edge a band without depth still
            counts as the edge (see `depth_border`).
        work_width: pixels; an image wider than this is segmented on a grid of every s-th
            row and column, s the smallest step that makes it this wide or less (640 x 480 is
            segmented at 320 x 240), and the labels are brought back to full resolution by
            depth (see `DepthSegmenter`); 0: always at full resolution. The other pixel sizes
            are full-resolution pixels whatever the step (on the grid: median / s rounded up
            to an odd size, jump_reach / s, invalid_margin / s and level_slice / s rounded up;
            RANSAC samples the full-resolution image).
    """

    median: int = 5
    jump: float = 0.05
    jump_per_m: float = 0.04
    jump_reach: int = 3
    max_planes: int = 4
    plane_share: float = 0.08
    level_tolerance_deg: float = 15.0
    level_plane_share: float = 0.03
    level_slice: int = 24
    plane_distance: float = 0.015
    plane_distance_per_m2: float = 0.002
    plane_min_extent: float = 1.5
    ransac_iterations: int = 120
    ransac_stride: int = 8
    seed: int = 0
    min_area: int = 200
    max_area_share: float = 0.5
    depth_min: float = 0.2
    depth_max: float = 8.0
    invalid_margin: int = INVALID_MARGIN
    work_width: int = 400

    def __post_init__(self) -> None:
        o = "DepthSegmenterParams"
        _require(_int_at_least(self.median, 0) and self.median in (1, 3, 5), o, "median",
                 self.median, "must be 1, 3 or 5")
        for name in ("jump", "jump_per_m", "plane_distance", "plane_distance_per_m2",
                     "plane_min_extent"):
            v = getattr(self, name)
            _require(_real(v) and math.isfinite(v) and v >= 0, o, name, v,
                     "must be a finite number >= 0")
        for name in ("max_planes", "ransac_iterations", "ransac_stride", "min_area", "seed",
                     "invalid_margin", "work_width", "level_slice"):
            v = getattr(self, name)
            _require(_int_at_least(v, 0), o, name, v, "must be an int >= 0")
        _require(self.ransac_stride >= 1, o, "ransac_stride", self.ransac_stride, "must be >= 1")
        _require(_int_at_least(self.jump_reach, 1), o, "jump_reach", self.jump_reach,
                 "must be an int >= 1 pixels")
        for name in ("plane_share", "level_plane_share"):
            v = getattr(self, name)
            _require(_real(v) and 0 < v <= 1, o, name, v, "must be in (0, 1]")
        _require(_real(self.level_tolerance_deg) and 0 <= self.level_tolerance_deg <= 90, o,
                 "level_tolerance_deg", self.level_tolerance_deg, "must be in [0, 90] degrees")
        _require(_real(self.max_area_share) and 0 < self.max_area_share <= 1,
                 o, "max_area_share", self.max_area_share, "must be in (0, 1]")
        _require(_real(self.depth_min) and math.isfinite(self.depth_min)
                 and self.depth_min >= 0, o, "depth_min", self.depth_min,
                 "must be a finite number >= 0 metres")
        # finite: the kernels compare depths to it under fastmath, which assumes no infinities
        _require(_real(self.depth_max) and math.isfinite(self.depth_max)
                 and self.depth_max > self.depth_min, o, "depth_max", self.depth_max,
                 f"must be a finite number > depth_min = {self.depth_min}")


def up_direction(name: str, up) -> np.ndarray:
    """`up` as a (3,) float unit vector if it is three finite numbers, not all zero; else
    DataError naming `name`."""
    try:
        v = np.asarray(up, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be three numbers, got {type(up).__name__}") from None
    norm = float(np.linalg.norm(v)) if v.shape == (3,) and np.all(np.isfinite(v)) else 0.0
    if not norm > 1e-9:
        raise DataError(f"{name} must be a finite nonzero (3,) direction, got {v.tolist()}")
    return v / norm


def stands_in_front(mask: np.ndarray, z: np.ndarray, jump: float, jump_per_m: float,
                    reach: int) -> bool:
    """Whether a mask stands in front of what is around it, as an object's face does and a
    wall does not: on at least two of its left, right and top sides, the surface seen just
    past it is farther by a depth jump. A side has the step when, in at least half of the
    image rows (columns, for the top) the mask spans, the farthest depth within `reach` pixels
    past its outermost pixel is farther than that pixel's by more than
    jump + jump_per_m * depth. A cabinet against a wall shows the wall beside it and above it
    (in a room's corner, on one side and above it); a wall ends at the image border, in a
    corner or at the ceiling (no step), and has a step on one side at most (a door, a corner
    jutting into the room).

    Args:
        mask: (H, W) bool (an empty one stands in front of nothing).
        z: (H, W) metres, 0 = no return (never farther).
        jump: metres; jump_per_m: metres per metre of depth; reach: pixels (>= 1).

    Raises:
        DataError: z not an (H, W) float array, or mask not an (H, W) bool array.
    """
    if not (isinstance(z, np.ndarray) and z.ndim == 2 and z.dtype.kind == "f"):
        got = f"{z.shape} {z.dtype}" if isinstance(z, np.ndarray) else type(z).__name__
        raise DataError(f"stands_in_front: z must be an (H, W) float array of metres, got {got}")
    if not (isinstance(mask, np.ndarray) and mask.dtype == np.bool_ and mask.shape == z.shape):
        got = f"{mask.shape} {mask.dtype}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise DataError(f"stands_in_front: mask must be a {z.shape} bool array, got {got}")
    if not mask.any():
        return False
    left, right = _stepped_ends(mask, z, jump, jump_per_m, reach)
    top, _ = _stepped_ends(mask.T, z.T, jump, jump_per_m, reach)
    return left + right + top >= 2


def _stepped_ends(mask: np.ndarray, z: np.ndarray, jump: float, jump_per_m: float,
                  reach: int) -> tuple[bool, bool]:
    """Whether the first and whether the last pixels of a non-empty mask's rows have a depth
    step past them (see `stands_in_front`) in at least half of those rows."""
    W = mask.shape[1]
    rows = np.flatnonzero(mask.any(axis=1))
    sub = mask[rows]
    first = sub.argmax(axis=1)
    last = W - 1 - sub[:, ::-1].argmax(axis=1)
    beyond = np.arange(1, reach + 1)
    stepped = []
    for end, cols in ((first, first[:, None] - beyond), (last, last[:, None] + beyond)):
        inside = (cols >= 0) & (cols < W)
        farthest = np.where(inside, z[rows[:, None], np.clip(cols, 0, W - 1)], 0.0).max(axis=1)
        own = z[rows, end]
        steps = (own > 0) & (farthest - own > jump + jump_per_m * own)
        stepped.append(bool(2 * np.count_nonzero(steps) >= rows.size))
    return stepped[0], stepped[1]


@dataclass(frozen=True, eq=False)
class _Grid:
    """The pixel grid a `DepthSegmenter` works on: every `step`-th row and column of the
    camera's image, with the full-resolution pixel sizes of its params in that grid's pixels.

    Attributes:
        step: rows and columns of the full image per grid pixel (1: full resolution).
        shape: (h, w) of the grid.
        x_over_z, y_over_z: (h, w) float32, the rays of the grid's pixels (as `camera.rays`).
        fx, fy: pixels of the grid per unit of x / z and y / z.
        median: odd kernel size of the median filter (1: none).
        reach: pixels over which depth jumps are looked for.
        margin: `invalid_margin` in grid pixels.
        seam: odd size of the window that finds a wall's contact with the ceiling.
        level_slice: `level_slice` in grid pixels.
    """

    step: int
    shape: tuple[int, int]
    x_over_z: np.ndarray
    y_over_z: np.ndarray
    fx: float
    fy: float
    median: int
    reach: int
    margin: int
    seam: int
    level_slice: int

    @classmethod
    def of(cls, camera: PinholeCamera, p: DepthSegmenterParams) -> _Grid:
        s = 1 if p.work_width == 0 else max(1, -(-camera.width // p.work_width))
        x_over_z, y_over_z = (np.ascontiguousarray(r[::s, ::s], dtype=np.float32)
                              for r in camera.rays())

        def odd(pixels: float) -> int:  # the odd window at least this wide (>= 1)
            return 2 * max(0, math.ceil((pixels - 1) / 2)) + 1

        return cls(s, x_over_z.shape, x_over_z, y_over_z, camera.fx / s, camera.fy / s,
                   odd(p.median / s), math.ceil(p.jump_reach / s),
                   math.ceil(p.invalid_margin / s), odd(5 / s), math.ceil(p.level_slice / s))


class DepthSegmenter:
    """Weight-free segmentation of objects from depth alone.

    Dominant planes found by a seeded RANSAC are removed, occlusion edges cut surfaces at
    depth jumps, and the connected components of what is left are the masks. The colour image
    is not used. The same frame always gives the same masks.

    Room structure is removed by these rules:
    - a level plane (normal within `level_tolerance_deg` of gravity: floor, ceiling, table
      top) holding `level_plane_share` of the valid pixels is removed whole, however it is
      cut up, except the slices of its band through taller objects beside it: runs of at
      most `level_slice` pixels along the image's up direction between kept pixels of one
      steep surface, without a depth jump (a chair back or a bin next to a table stays one
      object);
    - any other plane holding `plane_share` of them is a wall: its parts that reach the border
      of the valid depth or are seen only past nearer things (a piece of wall under a chair)
      are removed, and so are those spanning `plane_min_extent` metres unless they stand in
      front of the room: a depth step past two of their left, right and top ends in at least
      half their rows or columns (`stands_in_front`) and no contact with the ceiling (a
      removed level plane above the camera). That is a cabinet's front before the wall it
      stands against; a wall ends at the border, in a corner or at the ceiling, with a step on
      one side at most;
    - what is left is cut at depth jumps (`jump`, `jump_per_m`, over up to `jump_reach`
      pixels), and components larger than `max_area_share` of the image are dropped.

    An image wider than `work_width` is segmented on a grid of every s-th row and column (a
    quarter of the pixels of a 640 x 480 image): the rules look at surfaces of many pixels,
    which the coarser grid still shows, at a quarter of the cost. RANSAC still samples the
    full-resolution image, median-filtered as before, so it finds the same planes. The labels
    come back to full resolution pixel by pixel: a pixel takes the label of its grid pixel
    if their depths agree (within the jump threshold); where labels change, a pixel its grid
    pixel does not label takes that of the neighbouring grid pixel whose depth agrees best,
    unless its own grid pixel is room structure (the floor at an object's foot is as near as
    the object there); pixels without depth in range get none. So outlines follow the depth
    at full resolution: the background just behind an object's outline does not join it.

    Args:
        camera: intrinsics of the (registered) depth image.
        depth_scale: raw depth units per metre (1000 for millimetres, 1 for metres).
        params: `DepthSegmenterParams`.
        T_body_camera: (4, 4) the camera's optical frame in a gravity-aligned frame (z up), of
            which only the rotation is used: it says which planes are level. Default: a level
            camera (optical y points down), as `T_body_camera(height)` gives.

    Raises:
        ConfigError: a camera, depth scale, params or T_body_camera of the wrong kind.
    """

    def __init__(self, camera: PinholeCamera, depth_scale: float = 1000.0,
                 params: DepthSegmenterParams | None = None,
                 T_body_camera: np.ndarray | None = None) -> None:
        self.camera = check_camera("DepthSegmenter.camera", camera)
        self.depth_scale = check_depth_scale("DepthSegmenter.depth_scale", depth_scale)
        self.params = DepthSegmenterParams() if params is None else params
        _require(isinstance(self.params, DepthSegmenterParams), "DepthSegmenter", "params",
                 params, "must be a DepthSegmenterParams")
        R = (R_BODY_OPTICAL if T_body_camera is None else
             rigid_transform("DepthSegmenter.T_body_camera", T_body_camera, ConfigError)[:3, :3])
        #: (3,) the gravity-aligned frame's up axis in the optical frame
        self.up = R[2].copy()
        self._grid = _Grid.of(camera, self.params)
        #: (2, h, w) float32 x / z and y / z (`camera.rays`) of the image's every
        #: ransac_stride-th pixel, where RANSAC samples
        r = self.params.ransac_stride
        self._sample_rays = np.stack([a[::r, ::r] for a in camera.rays()]).astype(np.float32)

    @property
    def step(self) -> int:
        """Rows and columns of the image per pixel of the grid the segmenter works on (1: full
        resolution; see `DepthSegmenterParams.work_width`)."""
        return self._grid.step

    def segment(self, rgb: np.ndarray | None, depth: np.ndarray,
                up: np.ndarray | None = None) -> np.ndarray:
        """(k, H, W) bool masks, largest first; `rgb` is only checked (it may be None).

        Args:
            up: (3,) the up direction (against gravity) in the camera's optical frame at this
                frame, for a camera whose attitude changes (hand-held, on a pan-tilt or a
                legged body); None: the attitude given at construction (`self.up`).
        """
        labels, count = self._label(rgb, depth, up)
        if labels.dtype == np.uint8:
            # written in one pass (zeroing the stack first costs as much again)
            return _stack(labels, count)
        return labels[None] == np.arange(1, count + 1, dtype=labels.dtype)[:, None, None]

    def label(self, rgb: np.ndarray | None, depth: np.ndarray,
              up: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """(H, W) int32 label image (0: background, 1..count: masks, largest first) and count;
        `up` as in `segment`."""
        labels, count = self._label(rgb, depth, up)
        return labels.astype(np.int32, copy=False), count

    def _label(self, rgb: np.ndarray | None, depth: np.ndarray,
               up: np.ndarray | None) -> tuple[np.ndarray, int]:
        """(H, W) label image (uint8 when it holds fewer than 256 labels, else int32; 0:
        background, 1..count: masks, largest first) and count."""
        p, g = self.params, self._grid
        if rgb is not None:
            check_rgb(rgb, self.camera.shape)
        up = self.up if up is None else up_direction("DepthSegmenter.label: up", up)
        # read only (the grid below is a copy)
        z_full = np.ascontiguousarray(
            depth_in_metres(depth, self.depth_scale, self.camera.shape, copy=False))
        s = g.step
        z = np.ascontiguousarray(z_full[::s, ::s]) if s > 1 else z_full.copy()
        if g.median > 1:
            z = cv2.medianBlur(z, g.median)
        # `returned`: the sensor gave depth (the border band is where it gave nothing, not
        # where returns are out of range); z is then 0 out of range
        returned, valid, near = _in_range(z, np.float32(p.depth_min), np.float32(p.depth_max))
        behind, fronts = self._jumps(z, near)
        border = cv2.dilate(depth_border(returned, g.margin).view(np.uint8),
                            np.ones((3, 3), np.uint8)).view(bool)
        # RANSAC samples the pixels it samples at full resolution, median-filtered there: it
        # finds the planes the full-resolution segmenter finds (a plane search is chaotic:
        # another sample, another set of planes)
        r = p.ransac_stride
        sample = (z[::r, ::r] if s == 1 else
                  _sampled_median(z_full, r, p.median, _MEDIAN_NETWORKS[p.median]))
        sample = np.where((sample >= p.depth_min) & (sample <= p.depth_max), sample,
                          np.float32(0.0))
        structure = self._planes(z, valid, sample, border, (behind, fronts), up)
        foreground = valid & ~structure & ~behind
        count, labels = cv2.connectedComponents(foreground.view(np.uint8), connectivity=4,
                                                ltype=cv2.CV_32S)
        H, W = self.camera.shape
        if s == 1:
            area = np.bincount(labels.ravel(), minlength=count)[1:]
            out, kept = labels, np.arange(1, count)
        else:
            # Components that cannot reach min_area, even with the ring of blocks around
            # their box, get no label (there are many specks, and uint8 labels are faster).
            grid = _grid_stats(labels, count)
            reach = (grid[1:, 2] - grid[1:, 1] + 2) * (grid[1:, 4] - grid[1:, 3] + 2) * s * s
            kept = np.flatnonzero(reach >= max(p.min_area, 1)) + 1
            table = np.zeros(count, dtype=np.uint8 if kept.size < 256 else np.int32)
            table[kept] = np.arange(1, kept.size + 1)
            out = np.empty((H, W), dtype=table.dtype)
            area = _expand(labels, table, structure, z, z_full, s,
                           np.float32(max(p.depth_min, np.finfo(np.float32).tiny)),
                           np.float32(p.depth_max), np.float32(p.jump),
                           np.float32(p.jump_per_m), out)[1:]
        ok = (area > 0) & _area_ok(area, p.min_area, p.max_area_share, H * W)
        order = np.flatnonzero(ok)[np.argsort(-area[ok], kind="stable")]  # into kept
        n = order.size
        relabel = np.zeros(kept.size + 1, dtype=np.uint8 if n < 256 else np.int32)
        relabel[order + 1] = np.arange(1, n + 1)
        if out.dtype == np.uint8:
            lut = np.zeros(256, dtype=np.uint8)
            lut[:relabel.size] = relabel
            return cv2.LUT(out, lut), n
        return relabel[out], n

    def _jumps(self, z: np.ndarray, near: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(h, w) bool each: the far and the near side of depth jumps. A pixel is on the far
        side when a pixel up to `jump_reach` away along its row or column is nearer by more
        than jump + jump_per_m * depth, and on the near side when one is farther by that much.
        Only the far side is cut, so the nearer object keeps its whole silhouette. `z` is
        (h, w) float32 metres, 0 = no depth, and `near` the same with `_FAR` for 0."""
        p = self.params
        r = self._grid.reach
        cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (2 * r + 1, 2 * r + 1))
        # pixels outside the image count as neither nearest nor farthest (OpenCV's default
        # border for erode and dilate), nor do pixels without depth (_FAR, 0)
        return _steps(z, cv2.erode(near, cross), cv2.dilate(z, cross), np.float32(p.jump),
                      np.float32(p.jump_per_m))

    def _planes(self, z: np.ndarray, valid: np.ndarray, sample: np.ndarray,
                border: np.ndarray, jumps: tuple[np.ndarray, np.ndarray],
                up: np.ndarray) -> np.ndarray:
        """(h, w) bool: pixels of room structure (see the class's rules). `sample` is the
        (median-filtered) depth of the image's every ransac_stride-th pixel, 0 where none, on
        which RANSAC searches; `up` (3,) is the up direction in the optical frame.

        RANSAC finds one plane after another on a sample of the pixels; the level ones are
        then removed before the others. A level plane's band of pixels is removed whole but
        for the slices through objects (`_restore_slices`, after the walls); a wall's band
        is split into connected parts, and only the wall parts (`_wall_parts`) are removed,
        if together they hold `plane_share` of the valid pixels. An object face
        that lies on a wall's plane, or that RANSAC fitted a plane to, is kept unless it
        reaches the border (the mask filter drops those anyway), is seen only past nearer
        things, or is as large as a wall without standing in front of the room."""
        p, g = self.params, self._grid
        out = np.zeros(z.shape, dtype=bool)
        n_valid = np.count_nonzero(valid)
        if p.max_planes == 0 or n_valid == 0:
            return out
        keep = sample > 0
        x_over_z, y_over_z = self._sample_rays
        pts = np.stack([x_over_z * sample, y_over_z * sample, sample],
                       axis=-1)[keep].astype(float)
        tol = p.plane_distance + p.plane_distance_per_m2 * pts[:, 2] ** 2
        n_sampled = pts.shape[0]
        need = min(p.plane_share, p.level_plane_share) * n_sampled
        cos_level = math.cos(math.radians(p.level_tolerance_deg))
        rng = np.random.default_rng(p.seed)
        planes = []  # (normal, offset, level) of the planes holding their share of the sample
        n = n_sampled  # pts[:n] are the points no plane found so far holds
        for _ in range(p.max_planes + 3):
            if n < max(need, 3):
                break
            tri = rng.integers(n, size=(p.ransac_iterations, 3))
            # hypotheses are scored on a random subset: ranking them needs far fewer points
            scored = (rng.choice(n, _RANSAC_SCORED, replace=False) if n > _RANSAC_SCORED
                      else np.arange(n))
            normal, offset, n_in, found = _ransac_round(pts, tol, n, tri, scored)
            if not found or n_in < need:
                break
            level = abs(float(normal @ up)) >= cos_level
            if n_in >= (p.level_plane_share if level else p.plane_share) * n_sampled:
                planes.append((normal, offset, level))
            n -= n_in
        # Level planes go first: a wall's band must not hold the strip where the floor or the
        # ceiling crosses it, which would join every face on the wall's plane (a cabinet
        # against a wall) to the image border.
        planes.sort(key=lambda plane: not plane[2])
        accepted = 0
        ceiling = np.zeros(z.shape, dtype=bool)  # removed level planes above the camera
        level_bands = np.zeros(z.shape, dtype=bool)  # the removed level planes' bands
        band = np.empty(z.shape, dtype=bool)
        for normal, offset, level in planes:
            n_band = _plane_band(z, g.x_over_z, g.y_over_z, valid, out,
                                 normal.astype(np.float32), np.float32(offset),
                                 np.float32(p.plane_distance),
                                 np.float32(p.plane_distance_per_m2), band)
            if level:
                enough = n_band >= p.level_plane_share * n_valid
                if enough:
                    out |= band
                    level_bands |= band
                    # the plane's height above the camera is -offset / (normal . up)
                    if -offset / float(normal @ up) > 0:
                        ceiling |= band
            else:
                enough = self._wall_parts(band, z, border, jumps, ceiling, out,
                                          p.plane_share * n_valid)
            if enough:
                accepted += 1
                if accepted == p.max_planes:
                    break
        if g.level_slice > 0 and level_bands.any():
            # A level band holds every pixel at the plane's height, anywhere in the image: a
            # table top's band also cuts a thin slice through a taller object beside the table
            # (a chair back, a bin), which would make two objects of it. Such a slice is a
            # short run of the band along the image's up direction with the object's kept
            # pixels at both ends, on one steep surface; a piece of the plane itself (floor
            # between chair legs, a table top between an object on it and the table's front)
            # meets structure, a depth jump or a level surface there. This runs after the
            # walls are removed: a run that ends on a wall is not an object's slice. Runs go
            # along columns unless the camera is rolled past 45 deg (up is then more across
            # the image than along it).
            _restore_slices(level_bands, out, jumps[0], z, g.x_over_z, g.y_over_z,
                            up.astype(np.float32), g.level_slice, np.float32(p.jump),
                            np.float32(p.jump_per_m), bool(abs(up[1]) >= abs(up[0])))
        return out

    def _wall_parts(self, band: np.ndarray, z: np.ndarray, border: np.ndarray,
                    jumps: tuple[np.ndarray, np.ndarray], ceiling: np.ndarray,
                    out: np.ndarray, enough: float) -> bool:
        """Whether the wall parts of a (not level) plane's band of pixels hold `enough` pixels,
        and if so adds them to `out` ((h, w) bool).

        The wall parts are the 8-connected parts of `band` ((h, w) bool) that are wall, not an
        object's face: those that reach `border` ((h, w) bool, the image edge and the band
        without depth along it, grown by one pixel); those seen only past nearer things,
        holding pixels on the far side of depth jumps but none on the near side (`jumps`, both
        (h, w) bool), like a piece of wall seen under a chair; and those that span
        `plane_min_extent` metres (2D box in pixels times mean depth over focal length) unless
        they stand in front of what is around them (`stands_in_front`) and do not meet
        `ceiling` ((h, w) bool, the removed level planes above the camera), as a tall or wide
        cabinet's front does before the wall it stands against."""
        p, g = self.params, self._grid
        behind, fronts = jumps
        # cut at the far side of jumps, so that an object's face does not join the band's
        # background through its silhouette
        count, labels = cv2.connectedComponents((band & ~behind).view(np.uint8),
                                                connectivity=8, ltype=cv2.CV_32S)
        # occluded: next to a pixel of the band behind a jump (the part the jump cut off)
        in_front, occluded, at_border, stats = _part_flags(labels, count, z, behind, fronts,
                                                           band, border)
        area, top, bottom, left, right, sum_z = stats.T
        mean_z = sum_z / np.maximum(area, 1)
        extent = mean_z * np.maximum((right - left) / g.fx, (bottom - top) / g.fy)
        large = extent >= p.plane_min_extent
        structure = (occluded & ~in_front) | large
        candidates = np.flatnonzero(large & in_front & ~at_border)
        if candidates.size:
            # the seam between a wall and the ceiling is a pixel or two wide
            near_ceiling = cv2.dilate(ceiling.view(np.uint8),
                                      np.ones((g.seam, g.seam), np.uint8)).view(bool)
        for c in candidates:
            # the part's rows and the few above it, where the step over its top is looked for
            rows = slice(max(int(top[c]) - g.reach, 0), int(bottom[c]))
            part = labels[rows] == c
            structure[c] = near_ceiling[rows][part].any() or not stands_in_front(
                part, z[rows], p.jump, p.jump_per_m, g.reach)
        structure |= at_border
        structure[0] = False
        if area[structure].sum() < enough:
            return False
        _mark(labels, structure, out)
        return True


def _compile_kernels() -> None:
    """Run every compiled kernel of this module once, with the argument types the segmenter
    and the filters give them, so that numba compiles them (or loads them from its cache):
    for the package's precompile step (seconds, once per install)."""
    camera = PinholeCamera(416, 48, 300.0, 300.0, 208.0, 24.0)  # segmented at half resolution
    depth = np.full(camera.shape, 3.0, dtype=np.float32)  # a wall 3 m ahead
    depth[10:40, 150:250] = 2.0  # a box before it
    depth[:, :4] = 0.0  # a band without depth
    segmenter = DepthSegmenter(camera, 1.0)
    masks = segmenter.segment(None, depth)
    labels, count = segmenter.label(None, depth)
    filter_masks(masks, depth, MaskFilter(min_area=1))
    filter_labels(labels, count, depth, MaskFilter(min_area=1))
    filter_labels(labels.astype(np.int64), count, depth, MaskFilter(min_area=1))
    # the path of 256 labels or more
    grid = np.arange(24 * 208, dtype=np.int32).reshape(24, 208) % 300
    _expand(grid, np.arange(300, dtype=np.int32), np.zeros(grid.shape, dtype=bool),
            depth[::2, ::2].copy(), depth, 2, np.float32(0.2), np.float32(8.0),
            np.float32(0.05), np.float32(0.04), np.empty(camera.shape, dtype=np.int32))
    # a level camera facing a wall finds no level plane: the slices' kernel is run here
    z = depth[::2, ::2].copy()
    g = segmenter._grid
    _restore_slices(np.zeros(z.shape, dtype=bool), np.zeros(z.shape, dtype=bool),
                    np.zeros(z.shape, dtype=bool), z, g.x_over_z, g.y_over_z,
                    segmenter.up.astype(np.float32), g.level_slice, np.float32(0.05),
                    np.float32(0.04), True)


# ---------------------------------------------------------------------------------------------
# compiled kernels (numba, cached on disk; `_compile_kernels` compiles every one of them)


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
def _ransac_round(pts: np.ndarray, tol: np.ndarray, n: int, tri: np.ndarray,
                  scored: np.ndarray):  # pragma: no cover
    """One RANSAC search among the first n points of pts ((m, 3) metres) and their tolerances
    tol ((m,) metres): the planes through the point triples `tri` ((it, 3) indices) are scored
    by their inliers among the points `scored` ((s,) indices); the best (the first of the most
    inliers) is refined by least squares on all its inliers. Returns (unit normal (3,),
    offset, number of inliers of the refined plane, True) and moves the points it does not
    hold, in their order, to the front of pts and tol; or (zeros, 0, 0, False) when every
    triple was degenerate."""
    it = tri.shape[0]
    normals = np.zeros((it, 3))
    offsets = np.zeros(it)
    ok = np.zeros(it, dtype=np.bool_)
    for j in range(it):
        a, b, c = tri[j, 0], tri[j, 1], tri[j, 2]
        u0, u1, u2 = pts[b, 0] - pts[a, 0], pts[b, 1] - pts[a, 1], pts[b, 2] - pts[a, 2]
        v0, v1, v2 = pts[c, 0] - pts[a, 0], pts[c, 1] - pts[a, 1], pts[c, 2] - pts[a, 2]
        n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if norm > 1e-9:
            ok[j] = True
            normals[j, 0], normals[j, 1], normals[j, 2] = n0 / norm, n1 / norm, n2 / norm
            offsets[j] = -(normals[j, 0] * pts[a, 0] + normals[j, 1] * pts[a, 1]
                           + normals[j, 2] * pts[a, 2])
    inliers = np.zeros(n, dtype=np.bool_)
    if not ok.any():
        return np.zeros(3), 0.0, 0, False
    m = scored.size
    x, y, z, t = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    for i in range(m):
        k = scored[i]
        x[i], y[i], z[i], t[i] = pts[k, 0], pts[k, 1], pts[k, 2], tol[k]
    best, best_count = -1, -1
    for j in range(it):
        if not ok[j]:
            continue
        a, b, c, d = normals[j, 0], normals[j, 1], normals[j, 2], offsets[j]
        count = 0
        for i in range(m):
            count += abs(x[i] * a + y[i] * b + z[i] * c + d) <= t[i]
        if count > best_count:
            best, best_count = j, count
    a, b, c, d = normals[best, 0], normals[best, 1], normals[best, 2], offsets[best]
    n_in = 0
    c0 = c1 = c2 = 0.0
    for i in range(n):
        if abs(pts[i, 0] * a + pts[i, 1] * b + pts[i, 2] * c + d) <= tol[i]:
            inliers[i] = True
            c0, c1, c2 = c0 + pts[i, 0], c1 + pts[i, 1], c2 + pts[i, 2]
            n_in += 1
    c0, c1, c2 = c0 / n_in, c1 / n_in, c2 / n_in
    scatter = np.zeros((3, 3))
    for i in range(n):
        if inliers[i]:
            e0, e1, e2 = pts[i, 0] - c0, pts[i, 1] - c1, pts[i, 2] - c2
            scatter[0, 0] += e0 * e0
            scatter[0, 1] += e0 * e1
            scatter[0, 2] += e0 * e2
            scatter[1, 1] += e1 * e1
            scatter[1, 2] += e1 * e2
            scatter[2, 2] += e2 * e2
    scatter[1, 0], scatter[2, 0], scatter[2, 1] = scatter[0, 1], scatter[0, 2], scatter[1, 2]
    # the normal is the direction of least spread: the smallest eigenvector of the scatter
    normal = np.linalg.eigh(scatter)[1][:, 0].copy()
    offset = -(normal[0] * c0 + normal[1] * c1 + normal[2] * c2)
    k = 0
    for i in range(n):
        if abs(pts[i, 0] * normal[0] + pts[i, 1] * normal[1] + pts[i, 2] * normal[2]
               + offset) > tol[i]:  # not held: kept for the next search
            pts[k, 0], pts[k, 1], pts[k, 2], tol[k] = pts[i, 0], pts[i, 1], pts[i, 2], tol[i]
            k += 1
    return normal, offset, n - k, True


@numba.njit(cache=True)
def _plane_band(z: np.ndarray, x_over_z: np.ndarray, y_over_z: np.ndarray,
                valid: np.ndarray, taken: np.ndarray, normal: np.ndarray, offset: np.float32,
                distance: np.float32, per_m2: np.float32,
                band: np.ndarray) -> int:  # pragma: no cover
    """Writes into `band` ((h, w) bool) the pixels of `valid` and not `taken` ((h, w) bool)
    whose point (depth z (h, w) float32 metres along the rays x_over_z, y_over_z) lies within
    distance + per_m2 z^2 of the plane normal . p + offset = 0 (normal (3,) float32); returns
    their number."""
    n0, n1, n2 = normal[0], normal[1], normal[2]
    count = 0
    for r in range(z.shape[0]):
        for c in range(z.shape[1]):
            d = z[r, c]
            # the distance from the plane is z (normal . ray) + offset
            on = valid[r, c] and not taken[r, c] and (
                abs(d * (x_over_z[r, c] * n0 + y_over_z[r, c] * n1 + n2) + offset)
                <= distance + per_m2 * d * d)
            band[r, c] = on
            count += on
    return count


@numba.njit(cache=True, fastmath=_FAST)
def _restore_slices(level: np.ndarray, out: np.ndarray, behind: np.ndarray, z: np.ndarray,
                    x_over_z: np.ndarray, y_over_z: np.ndarray, up: np.ndarray, k: int,
                    jump: np.float32, jump_per_m: np.float32,
                    along_columns: bool) -> int:  # pragma: no cover
    """Takes the slices of level bands through objects out of `out` ((h, w) bool, the room
    structure) and returns how many pixels it took out.

    A slice is a run of at most k pixels of `level` ((h, w) bool, the removed level planes'
    bands, all in `out`) along an image column (along a row if not `along_columns`), none of
    them in `behind` ((h, w) bool, the far side of depth jumps), such that the pixels just
    before and after it are kept (with depth, neither in `out` nor in `behind`), their depths
    (z (h, w) float32 metres, 0 = none) differ by at most jump + jump_per_m * depth, and
    their points (along the rays x_over_z, y_over_z, (h, w) float32) are no farther apart
    horizontally along the line of sight than along `up` ((3,) float32 unit vector, the up
    direction in the optical frame): they lie on a surface that rises, seen from the camera,
    steeper than 45 deg."""
    h, w = z.shape
    # The image is read row by row (as it lies in memory), each line (column, or row) with
    # its open run: where it began (-1: none) and whether a pixel of it is behind a jump.
    start = np.full(max(h, w), -1, dtype=np.int64)
    cut = np.zeros(max(h, w), dtype=np.bool_)
    taken = 0
    u0, u1, u2 = up[0], up[1], up[2]
    for r in range(h):
        for c in range(w):
            line, pos = (c, r) if along_columns else (r, c)
            if level[r, c]:
                if start[line] < 0:
                    start[line], cut[line] = pos, behind[r, c]
                else:
                    cut[line] |= behind[r, c]
                continue
            first = start[line]
            if first < 0:
                continue
            start[line] = -1  # the run [first, pos) ends here, at (r, c)
            if cut[line] or pos - first > k or first == 0:
                continue
            ra, ca = (first - 1, c) if along_columns else (r, first - 1)
            za, zb = z[ra, ca], z[r, c]
            if not ((za > 0) & (zb > 0) & ~out[ra, ca] & ~out[r, c] & ~behind[ra, ca]
                    & ~behind[r, c]):
                continue
            # one surface across the run, not two things at different depths
            if abs(za - zb) > jump + jump_per_m * min(za, zb):
                continue
            # An object's side rises through the band; the plane itself lies across it. A
            # table top seen nearly edge-on between an object on it and the table's front
            # is a few pixels tall and continuous in depth too, but its ends are at one
            # height, the table's depth apart along the line of sight; so is the floor
            # between the specks of it that depth noise leaves outside the band. Only the
            # horizontal part along the line of sight counts: a run across the image's up
            # direction (a rolled camera) also moves sideways along an upright surface.
            xa, ya = x_over_z[ra, ca], y_over_z[ra, ca]
            d0, d1, d2 = za * xa - zb * x_over_z[r, c], za * ya - zb * y_over_z[r, c], za - zb
            rise = d0 * u0 + d1 * u1 + d2 * u2
            # the line of sight to the first end, without its part along up
            along = xa * u0 + ya * u1 + u2
            s0, s1, s2 = xa - along * u0, ya - along * u1, 1.0 - along * u2
            sight = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            if abs(d0 * s0 + d1 * s1 + d2 * s2) > abs(rise) * sight:
                continue
            for j in range(first, pos):
                if along_columns:
                    out[j, c] = False
                else:
                    out[r, j] = False
            taken += pos - first
        if not along_columns:
            start[r] = -1  # a run reaching the row's end has no kept pixel after it
    return taken


@numba.njit(cache=True)
def _part_flags(labels: np.ndarray, count: int, z: np.ndarray, behind: np.ndarray,
                fronts: np.ndarray, band: np.ndarray, border: np.ndarray
                ):  # pragma: no cover
    """For each of the `count` labels of `labels` ((h, w) int32, 0 = none): whether it holds a
    pixel of `fronts`, whether it is the largest label next to (3 x 3) a pixel of
    `behind & band`, whether it holds a pixel of `border` (all (h, w) bool), and (count, 6)
    float64 its pixel count, bounding box (top, bottom, left, right, ends exclusive) and sum
    of depths `z`."""
    h, w = labels.shape
    in_front = np.zeros(count, dtype=np.bool_)
    occluded = np.zeros(count, dtype=np.bool_)
    at_border = np.zeros(count, dtype=np.bool_)
    stats = np.zeros((count, 6))
    stats[:, 1], stats[:, 3] = h, w
    for r in range(h):
        for c in range(w):
            if behind[r, c] and band[r, c]:
                top = 0
                for rr in range(max(r - 1, 0), min(r + 2, h)):
                    for cc in range(max(c - 1, 0), min(c + 2, w)):
                        top = max(top, labels[rr, cc])
                occluded[top] = True
            lab = labels[r, c]
            if lab == 0:
                continue
            if fronts[r, c]:
                in_front[lab] = True
            if border[r, c]:
                at_border[lab] = True
            stats[lab, 0] += 1
            stats[lab, 1] = min(stats[lab, 1], r)
            stats[lab, 2] = max(stats[lab, 2], r + 1)
            stats[lab, 3] = min(stats[lab, 3], c)
            stats[lab, 4] = max(stats[lab, 4], c + 1)
            stats[lab, 5] += z[r, c]
    return in_front, occluded, at_border, stats


@numba.njit(cache=True)
def _mark(labels: np.ndarray, chosen: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """Sets `out` ((h, w) bool) where `chosen` ((count,) bool) holds for the pixel's label
    (`labels` (h, w) int32)."""
    for r in range(labels.shape[0]):
        for c in range(labels.shape[1]):
            if chosen[labels[r, c]]:
                out[r, c] = True


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
