"""Segmentation: the `Segmenter` protocol, the mask filters, and the weight-free depth segmenter.

A segmenter turns one RGB-D frame into instance masks, (k, H, W) bool, one per candidate object.
`filter_masks` then drops the masks the original systems also dropped: touching the image
border (a cut-off object has a wrong centroid and size), too small, too large, too elongated,
or with too little valid depth to lift. FastSAM through onnxruntime is in `fastsam.py`.

Real depth cameras return no depth in bands along the image edges (registration, lens
vignetting) and beyond their range. Every border rule therefore treats the band of missing
depth that reaches the image edge (`depth_border`) as part of the edge: an object cut by the
edge of the valid depth is as cut off as one cut by the edge of the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
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

__all__ = [
    "INVALID_MARGIN",
    "DepthSegmenter",
    "DepthSegmenterParams",
    "MaskFilter",
    "Segmenter",
    "check_masks",
    "check_rgb",
    "depth_border",
    "filter_masks",
    "stands_in_front",
]

#: sample points on which each RANSAC hypothesis is scored
_RANSAC_SCORED = 1000
#: pixels; no-depth regions this close to the image edge, and reaching it, count as the edge
INVALID_MARGIN = 40


@runtime_checkable
class Segmenter(Protocol):
    """Anything that turns an RGB-D frame into instance masks."""

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


def check_rgb(rgb, shape: tuple[int, int] | None = None) -> np.ndarray:
    """`rgb` as given if it is an (H, W, 3) uint8 image (of `shape` (H, W) if given); else
    DataError."""
    if not isinstance(rgb, np.ndarray):
        raise DataError(f"rgb must be a numpy array, got {type(rgb).__name__}")
    if rgb.dtype != np.uint8:
        raise DataError(f"rgb has dtype {rgb.dtype}; expected uint8")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or (shape is not None and rgb.shape[:2] != shape):
        want = "(H, W, 3)" if shape is None else str((*shape, 3))
        raise DataError(f"rgb has shape {rgb.shape}; expected {want}")
    return rgb


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


def _elongation(ys: np.ndarray, xs: np.ndarray) -> float:
    """Ratio of the principal standard deviations of a set of pixel coordinates."""
    cov = np.cov(np.vstack([xs, ys]).astype(float), bias=True) + np.eye(2) / 12.0  # pixel extent
    low, high = np.linalg.eigvalsh(cov)
    return math.sqrt(high / low)


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

    A connected region without depth that reaches the image edge is a band of the sensor's
    border (registration, vignetting) when most of its pixels lie within `margin` pixels of
    the edge; its pixels within the margin count as border. A region mostly farther in (open
    space beyond the range, a window, the sky) is something seen, not an edge of the view:
    an object next to it is not cut off.

    Args:
        valid: (H, W) bool, pixels with a depth return.
        margin: pixels (>= 0).
    """
    H, W = valid.shape
    edge = np.zeros((H, W), dtype=bool)
    edge[0], edge[-1], edge[:, 0], edge[:, -1] = True, True, True, True
    if margin == 0:
        return edge
    near = np.ones((H, W), dtype=bool)
    near[margin:H - margin, margin:W - margin] = False
    count, labels, stats, _ = cv2.connectedComponentsWithStats(
        (~valid).view(np.uint8), connectivity=8)
    reaches = np.zeros(count, dtype=bool)
    reaches[labels[edge]] = True
    inside = np.bincount(labels[near], minlength=count)
    band = reaches & (2 * inside > stats[:, cv2.CC_STAT_AREA])
    band[0] = False
    return edge | (band[labels] & near)


def filter_masks(masks: np.ndarray, depth_m: np.ndarray, mask_filter: MaskFilter) -> np.ndarray:
    """Indices of the masks that pass `mask_filter`.

    Args:
        masks: (k, H, W) bool.
        depth_m: (H, W) metres, 0 = no return.

    Returns:
        (k',) int64 indices into `masks`, increasing.
    """
    check_masks(masks, depth_m.shape)
    k, H, W = masks.shape
    f = mask_filter
    rows_hit = masks.any(axis=2)  # (k, H)
    cols_hit = masks.any(axis=1)  # (k, W)
    valid = depth_m > 0
    near_border = None
    if f.border:
        border = depth_border(valid, f.invalid_margin)
        # within `border` pixels of the border: inside the image, a border pixel is 1 away
        kernel = np.ones((2 * f.border - 1, 2 * f.border - 1), np.uint8)
        near_border = cv2.dilate(border.view(np.uint8), kernel).view(bool)
    keep = []
    for i in range(k):
        rows, cols = np.flatnonzero(rows_hit[i]), np.flatnonzero(cols_hit[i])
        if rows.size == 0:
            continue
        r0, r1, c0, c1 = rows[0], rows[-1], cols[0], cols[-1]
        crop = masks[i, r0:r1 + 1, c0:c1 + 1]
        if near_border is not None and near_border[r0:r1 + 1, c0:c1 + 1][crop].any():
            continue
        ys, xs = np.nonzero(crop)
        if not f.area_ok(np.array([ys.size]), H * W)[0]:
            continue
        if np.count_nonzero(valid[r0:r1 + 1, c0:c1 + 1][crop]) < f.min_depth_share * ys.size:
            continue
        if _elongation(ys, xs) > f.max_elongation:
            continue
        keep.append(i)
    return np.asarray(keep, dtype=np.int64)


@dataclass(frozen=True)
class DepthSegmenterParams:
    """Settings of `DepthSegmenter`.

    Attributes:
        median: pixels, odd kernel size (3 or 5) of the median filter applied to depth first.
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
            corridor), since no object is a large level surface.
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
    """

    median: int = 5
    jump: float = 0.05
    jump_per_m: float = 0.04
    jump_reach: int = 3
    max_planes: int = 4
    plane_share: float = 0.08
    level_tolerance_deg: float = 15.0
    level_plane_share: float = 0.03
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
                     "invalid_margin"):
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
        _require(_real(self.depth_min) and self.depth_min >= 0, o,
                 "depth_min", self.depth_min, "must be a number >= 0 metres")
        _require(_real(self.depth_max) and self.depth_max > self.depth_min,
                 o, "depth_max", self.depth_max, f"must be > depth_min = {self.depth_min}")


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


class DepthSegmenter:
    """Weight-free segmentation of objects from depth alone.

    Dominant planes found by a seeded RANSAC are removed, occlusion edges cut surfaces at
    depth jumps, and the connected components of what is left are the masks. The colour image
    is not used. The same frame always gives the same masks.

    Room structure is removed by these rules:
    - a level plane (normal within `level_tolerance_deg` of gravity: floor, ceiling, table
      top) holding `level_plane_share` of the valid pixels is removed whole;
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
        self._x_over_z, self._y_over_z = (r.astype(np.float32) for r in camera.rays())

    def segment(self, rgb: np.ndarray | None, depth: np.ndarray) -> np.ndarray:
        """(k, H, W) bool masks, largest first; `rgb` is only checked (it may be None)."""
        labels, count = self.label(rgb, depth)
        if count == 0:
            return np.zeros((0, *self.camera.shape), dtype=bool)
        return labels[None] == np.arange(1, count + 1, dtype=labels.dtype)[:, None, None]

    def label(self, rgb: np.ndarray | None, depth: np.ndarray) -> tuple[np.ndarray, int]:
        """(H, W) int32 label image (0: background, 1..count: masks, largest first) and count."""
        p = self.params
        if rgb is not None:
            check_rgb(rgb, self.camera.shape)
        z = depth_in_metres(depth, self.depth_scale, self.camera.shape)
        if p.median > 1:
            z = cv2.medianBlur(z, p.median)
        # the border band is where the sensor gave nothing, not where returns are out of range
        returned = z > 0
        z[(z < p.depth_min) | (z > p.depth_max)] = 0.0
        valid = z > 0
        border = cv2.dilate(depth_border(returned, p.invalid_margin).view(np.uint8),
                            np.ones((3, 3), np.uint8)).view(bool)
        jumps = self._jumps(z, valid)
        foreground = valid & ~self._planes(z, valid, border, jumps) & ~jumps[0]
        count, labels, stats, _ = cv2.connectedComponentsWithStats(
            foreground.view(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        area = stats[1:, cv2.CC_STAT_AREA]
        ok = _area_ok(area, p.min_area, p.max_area_share, z.size)
        order = np.flatnonzero(ok)[np.argsort(-area[ok], kind="stable")]
        relabel = np.zeros(count, dtype=np.int32)
        relabel[order + 1] = np.arange(1, order.size + 1, dtype=np.int32)
        return relabel[labels], int(order.size)

    def _jumps(self, z: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) bool each: the far and the near side of depth jumps. A pixel is on the far
        side when a pixel up to `jump_reach` away along its row or column is nearer by more
        than jump + jump_per_m * depth, and on the near side when one is farther by that much.
        Only the far side is cut, so the nearer object keeps its whole silhouette."""
        p = self.params
        near = np.where(valid, z, np.inf).astype(np.float32)
        far = np.where(valid, z, -np.inf).astype(np.float32)
        nearest, farthest = near.copy(), far.copy()
        for d in range(1, p.jump_reach + 1):
            for out, src, op in ((nearest, near, np.minimum), (farthest, far, np.maximum)):
                op(out[d:], src[:-d], out=out[d:])
                op(out[:-d], src[d:], out=out[:-d])
                op(out[:, d:], src[:, :-d], out=out[:, d:])
                op(out[:, :-d], src[:, d:], out=out[:, :-d])
        threshold = p.jump + p.jump_per_m * z
        return valid & (z - nearest > threshold), valid & (farthest - z > threshold)

    def _planes(self, z: np.ndarray, valid: np.ndarray, border: np.ndarray,
                jumps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """(H, W) bool: pixels of room structure (see the class's rules).

        RANSAC finds one plane after another on a sample of the pixels; the level ones are
        then removed before the others. A level plane's band of pixels is removed whole; a
        wall's band is split into connected parts, and only the wall parts (`_wall_parts`)
        are removed, if together they hold `plane_share` of the valid pixels. An object face
        that lies on a wall's plane, or that RANSAC fitted a plane to, is kept unless it
        reaches the border (the mask filter drops those anyway), is seen only past nearer
        things, or is as large as a wall without standing in front of the room."""
        p = self.params
        out = np.zeros(z.shape, dtype=bool)
        if p.max_planes == 0 or not valid.any():
            return out
        s = p.ransac_stride
        zs = z[::s, ::s]
        keep = valid[::s, ::s]
        pts = np.stack([self._x_over_z[::s, ::s] * zs, self._y_over_z[::s, ::s] * zs, zs],
                       axis=-1)[keep].astype(float)
        tol = p.plane_distance + p.plane_distance_per_m2 * pts[:, 2] ** 2
        n_sampled = pts.shape[0]
        need = min(p.plane_share, p.level_plane_share) * n_sampled
        n_valid = np.count_nonzero(valid)
        cos_level = math.cos(math.radians(p.level_tolerance_deg))
        rng = np.random.default_rng(p.seed)
        planes = []  # (normal, offset, level) of the planes holding their share of the sample
        for _ in range(p.max_planes + 3):
            if pts.shape[0] < max(need, 3):
                break
            normal, offset = self._ransac_plane(rng, pts, tol)
            if normal is None:
                break
            inliers = np.abs(pts @ normal + offset) <= tol
            n_in = np.count_nonzero(inliers)
            if n_in < need:
                break
            level = abs(float(normal @ self.up)) >= cos_level
            if n_in >= (p.level_plane_share if level else p.plane_share) * n_sampled:
                planes.append((normal, offset, level))
            pts, tol = pts[~inliers], tol[~inliers]
        # Level planes go first: a wall's band must not hold the strip where the floor or the
        # ceiling crosses it, which would join every face on the wall's plane (a cabinet
        # against a wall) to the image border.
        planes.sort(key=lambda plane: not plane[2])
        full_tol = p.plane_distance + p.plane_distance_per_m2 * z * z
        accepted = 0
        ceiling = np.zeros(z.shape, dtype=bool)  # removed level planes above the camera
        for normal, offset, level in planes:
            # a pixel's distance from the plane is z (n . ray) + offset
            along = self._x_over_z * np.float32(normal[0]) + self._y_over_z * np.float32(
                normal[1]) + np.float32(normal[2])
            band = valid & ~out & (np.abs(z * along + np.float32(offset)) <= full_tol)
            if level:
                on_plane = band
                enough = np.count_nonzero(band) >= p.level_plane_share * n_valid
                # the plane's height above the camera is -offset / (normal . up)
                if enough and -offset / float(normal @ self.up) > 0:
                    ceiling |= band
            else:
                on_plane = self._wall_parts(band, z, border, jumps, ceiling)
                enough = np.count_nonzero(on_plane) >= p.plane_share * n_valid
            if enough:
                out |= on_plane
                accepted += 1
                if accepted == p.max_planes:
                    break
        return out

    def _wall_parts(self, band: np.ndarray, z: np.ndarray, border: np.ndarray,
                    jumps: tuple[np.ndarray, np.ndarray], ceiling: np.ndarray) -> np.ndarray:
        """(H, W) bool: the 8-connected parts of a (not level) plane's band of pixels that are
        wall, not an object's face: those that reach `border` ((H, W) bool, the image edge and
        the band without depth along it, grown by one pixel); those seen only past nearer
        things, holding pixels on the far side of depth jumps but none on the near side
        (`jumps`, both (H, W) bool), like a piece of wall seen under a chair; and those that
        span `plane_min_extent` metres (2D box in pixels times mean depth over focal length)
        unless they stand in front of what is around them (`stands_in_front`) and do not
        meet `ceiling` ((H, W) bool, the removed level planes above the camera), as a tall or
        wide cabinet's front does before the wall it stands against."""
        p = self.params
        behind, fronts = jumps
        # cut at the far side of jumps, so that an object's face does not join the band's
        # background through its silhouette
        count, labels, stats, _ = cv2.connectedComponentsWithStats(
            (band & ~behind).view(np.uint8), connectivity=8)
        in_front = np.zeros(count, dtype=bool)
        in_front[labels[fronts]] = True
        occluded = np.zeros(count, dtype=bool)
        grown = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8))
        occluded[grown[behind & band].astype(np.int64)] = True
        mean_z = (np.bincount(labels.ravel(), weights=z.ravel(), minlength=count)
                  / np.maximum(stats[:, cv2.CC_STAT_AREA], 1))
        extent = mean_z * np.maximum(stats[:, cv2.CC_STAT_WIDTH] / self.camera.fx,
                                     stats[:, cv2.CC_STAT_HEIGHT] / self.camera.fy)
        large = extent >= p.plane_min_extent
        structure = (occluded & ~in_front) | large
        at_border = np.zeros(count, dtype=bool)
        at_border[labels[border]] = True
        candidates = np.flatnonzero(large & in_front & ~at_border)
        if candidates.size:
            # the seam between a wall and the ceiling is a pixel or two wide
            near_ceiling = cv2.dilate(ceiling.view(np.uint8),
                                      np.ones((5, 5), np.uint8)).view(bool)
        for c in candidates:
            # the part's rows and the few above it, where the step over its top is looked for
            top = stats[c, cv2.CC_STAT_TOP]
            rows = slice(max(top - p.jump_reach, 0), top + stats[c, cv2.CC_STAT_HEIGHT])
            part = labels[rows] == c
            structure[c] = near_ceiling[rows][part].any() or not stands_in_front(
                part, z[rows], p.jump, p.jump_per_m, p.jump_reach)
        structure |= at_border
        structure[0] = False
        return structure[labels]

    def _ransac_plane(self, rng: np.random.Generator, pts: np.ndarray, tol: np.ndarray):
        """The plane (unit normal (3,), offset) with most inliers among random hypotheses,
        refined by least squares on its inliers; (None, 0) if every sample was degenerate."""
        n = pts.shape[0]
        tri = pts[rng.integers(n, size=(self.params.ransac_iterations, 3))]
        # hypotheses are scored on a random subset: ranking them needs far fewer points
        scored = rng.choice(n, _RANSAC_SCORED, replace=False) if n > _RANSAC_SCORED else slice(None)
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(normals, axis=1)
        ok = norm > 1e-9
        if not ok.any():
            return None, 0.0
        normals = normals[ok] / norm[ok, None]
        offsets = -np.einsum("ij,ij->i", normals, tri[ok, 0])
        counts = (np.abs(pts[scored] @ normals.T + offsets) <= tol[scored, None]).sum(axis=0)
        best = int(np.argmax(counts))
        inl = pts[np.abs(pts @ normals[best] + offsets[best]) <= tol]
        centre = inl.mean(axis=0)
        normal = np.linalg.svd(inl - centre, full_matrices=False)[2][-1]
        return normal, -float(normal @ centre)
