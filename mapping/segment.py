"""Segmentation: the `Segmenter` protocol and the weight-free depth segmenter.

A segmenter turns one RGB-D frame into instance masks, (k, H, W) bool, one per candidate object.
The mask filter that then drops the masks not worth lifting is in `masks.py`, the rules that
tell room structure from objects in `structure.py`, and the depth segmenter's passes over the
pixels in `depth_grid.py`; their public names are imported here too (`MaskFilter`,
`filter_masks`, `filter_labels`, `depth_border`, `stands_in_front`, ...). FastSAM through
onnxruntime is in `fastsam.py`.

The hot loops are numba kernels (in those modules, cached on disk; `_compile_kernels` runs each
once, so that an install step can compile them before any run needs them).
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
from .depth_grid import (
    _MEDIAN_NETWORKS,
    _expand,
    _grid_stats,
    _in_range,
    _sampled_median,
    _stack,
    _steps,
)
from .depth_grid import _median_network as _median_network
from .masks import (
    INVALID_MARGIN,
    MaskFilter,
    _area_ok,
    check_masks,
    depth_border,
    filter_labels,
    filter_masks,
)
from .objects import check_rgb
from .structure import _find_planes, _plane_band, _restore_slices, _wall_parts, stands_in_front

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


#: the most dominant planes a `DepthSegmenter` removes, and the most RANSAC hypotheses it
#: draws for each ((n, 3) indices, each scored on a sample of the pixels)
MAX_PLANES = 100
MAX_RANSAC_ITERATIONS = 100_000


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
        max_planes: largest number of dominant planes (floor, walls) removed, at most
            `MAX_PLANES`.
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
        ransac_iterations: plane hypotheses tried per plane, at most
            `MAX_RANSAC_ITERATIONS`.
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
        for name, high, limit in (("max_planes", MAX_PLANES, "MAX_PLANES"),
                                  ("ransac_iterations", MAX_RANSAC_ITERATIONS,
                                   "MAX_RANSAC_ITERATIONS")):
            v = getattr(self, name)
            _require(v <= high, o, name, v, f"must be an int in [0, {high}] ({limit})")
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

        RANSAC finds one plane after another on a sample of the pixels (`_find_planes`); the
        level ones are then removed before the others. A level plane's band of pixels is
        removed whole but for the slices through objects (`_restore_slices`, after the walls);
        a wall's band is split into connected parts, and only the wall parts (`_wall_parts`)
        are removed, if together they hold `plane_share` of the valid pixels. An object face
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
        planes = _find_planes(pts, tol, up, max_planes=p.max_planes,
                              iterations=p.ransac_iterations, seed=p.seed,
                              plane_share=p.plane_share, level_plane_share=p.level_plane_share,
                              level_tolerance_deg=p.level_tolerance_deg)
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
                enough = _wall_parts(band, z, border, jumps, ceiling, out,
                                     p.plane_share * n_valid, min_extent=p.plane_min_extent,
                                     fx=g.fx, fy=g.fy, reach=g.reach, seam=g.seam,
                                     jump=p.jump, jump_per_m=p.jump_per_m)
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


def _compile_kernels() -> None:
    """Run every compiled kernel of the segmenter and the mask filter (in `depth_grid`,
    `structure` and `masks`) once, with the argument types the segmenter and the filters give
    them, so that numba compiles them (or loads them from its cache): for the package's
    precompile step (seconds, once per install)."""
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
