"""Lifting: instance masks + depth -> Open3D object point clouds -> object observations.

Each mask's pixels with a depth return are back-projected through the camera intrinsics and
moved into the robot's odometry frame through `T_odom_camera`. Open3D then cleans the cloud:
voxel downsampling, statistical outlier removal, and DBSCAN keeping the largest cluster (a mask
that spills onto the background gives a second, far cluster). The observation is the cloud's
centroid, its width (the longer side of the smallest-perimeter rectangle holding its footprint
on the ground plane, which does not depend on the viewing direction for boxes and cylinders) and its
height (its extent along the odometry frame's z axis, which is up).

Level room structure that reaches the lifter (a strip of floor or ceiling, a table top) is a
horizontal slab: a cloud is dropped when 90 % of its points lie within `slab_thickness` along z
while its width is `slab_extent` or more; objects stand up from the floor. A piece of wall the
segmenter could not tell from an object (too small a share of the image to be found as a
plane, cut off by nearer objects) is a vertical slab: dropped when 90 % of its footprint lies
within `wall_thickness` across its long axis while its width is `wall_extent` or more, unless
its mask stands in front of what is around it (a depth step past two of its left, right and
top ends, `segment.stands_in_front`), as a wide cabinet's front does before the wall it stands
against and a wall does not. A box seen face on is a vertical slab too, but narrower than a
wall or standing in front of one.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.params import _int_at_least, _real, _require

from .camera import PinholeCamera, check_camera, check_depth_scale, depth_in_metres, rigid_transform
from .objects import footprint_rectangles
from .segment import check_masks, stands_in_front

__all__ = ["LiftParams", "MaskLifter", "Observations"]

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
# metres between the clouds of different masks while they are cleaned together
_SEPARATION = 1000.0


@dataclass(frozen=True)
class LiftParams:
    """Settings of `MaskLifter`.

    Attributes:
        voxel_size: metres, the voxel edge for downsampling.
        max_points: masks with more pixels are sampled on a regular pixel grid down to about
            this many points before the cloud is built; this bounds the cost of the cleaning
            steps for near, large objects while keeping sizes to a few per cent.
        outlier_neighbors: neighbours in the statistical outlier removal.
        outlier_std: points whose mean neighbour distance is more than this many standard
            deviations above the cloud's mean are removed.
        cluster_eps: DBSCAN neighbourhood radius in units of the point spacing (the larger of
            the voxel edge and the sampled pixels' spacing at the object's depth) ...
        cluster_eps_per_m: ... or this many metres per metre of the object's depth, whichever
            is larger: surfaces seen at a slant have sparser points, and two faces of one box
            must stay one cluster while background behind an occlusion edge splits off.
        cluster_min_points: DBSCAN core-point neighbour count (of cells eps / 2 wide, see
            `MaskLifter._clean`).
        min_points: objects with fewer cleaned points are dropped.
        depth_min, depth_max: metres; depths outside are ignored.
        slab_thickness: metres; a cloud this thin (5th to 95th percentile) along z ...
        slab_extent: metres; ... and at least this wide is level room structure and
            dropped. math.inf keeps every cloud.
        wall_thickness: metres; a cloud this thin (5th to 95th percentile) across the long
            axis of its footprint ...
        wall_extent: metres; ... and at least this wide is a piece of wall and dropped
            (math.inf keeps every cloud), unless its mask stands in front of what is around
            it: an object's face, such as a wide cabinet's seen face on.
        jump, jump_per_m: metres, and metres per metre of the mask's depth: the depth step
            past a mask's ends that makes it stand in front (as `DepthSegmenterParams`; see
            `segment.stands_in_front`).
        jump_reach: pixels past the mask's ends where the step is looked for.
    """

    voxel_size: float = 0.01
    max_points: int = 150
    outlier_neighbors: int = 8
    outlier_std: float = 3.0
    cluster_eps: float = 3.0
    cluster_eps_per_m: float = 0.03
    cluster_min_points: int = 3
    min_points: int = 12
    depth_min: float = 0.2
    depth_max: float = 8.0
    slab_thickness: float = 0.04
    slab_extent: float = 0.5
    wall_thickness: float = 0.1
    wall_extent: float = 1.5
    jump: float = 0.05
    jump_per_m: float = 0.04
    jump_reach: int = 3

    def __post_init__(self) -> None:
        o = "LiftParams"
        for name in ("voxel_size", "outlier_std", "cluster_eps", "cluster_eps_per_m",
                     "depth_max"):
            v = getattr(self, name)
            _require(_real(v) and math.isfinite(v) and v > 0, o, name, v,
                     "must be a finite number > 0")
        for name in ("max_points", "outlier_neighbors", "cluster_min_points", "min_points",
                     "jump_reach"):
            v = getattr(self, name)
            _require(_int_at_least(v, 1), o, name, v, "must be an int >= 1")
        _require(_real(self.slab_thickness) and math.isfinite(self.slab_thickness)
                 and self.slab_thickness >= 0, o, "slab_thickness", self.slab_thickness,
                 "must be a finite number >= 0 metres")
        for name in ("wall_thickness", "jump", "jump_per_m"):
            v = getattr(self, name)
            _require(_real(v) and math.isfinite(v) and v >= 0, o, name, v,
                     "must be a finite number >= 0")
        for name in ("slab_extent", "wall_extent"):
            v = getattr(self, name)
            _require(_real(v) and v > 0, o, name, v,
                     "must be a number > 0 metres (inf keeps every cloud)")
        _require(_real(self.depth_min) and 0 <= self.depth_min < self.depth_max,
                 o, "depth_min", self.depth_min, f"must be in [0, depth_max = {self.depth_max})")


@dataclass(frozen=True)
class Observations:
    """Objects seen in one frame, in the robot's odometry frame (metres, z up).

    Attributes:
        centroids: (k, 3) centroids of the cleaned clouds.
        widths: (k,) horizontal extents; heights: (k,) vertical extents.
        point_counts: (k,) surface samples left after cleaning (the centroid's support).
        mask_indices: (k,) which input mask each observation came from.
        points: (N, 3) the cleaned clouds, one after another in observation order (the
            surface samples and the outline samples of each mask).
        cloud_starts: (k + 1,) int64, observation o's cloud is
            points[cloud_starts[o]:cloud_starts[o + 1]].
    """

    centroids: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    point_counts: np.ndarray
    mask_indices: np.ndarray
    points: np.ndarray
    cloud_starts: np.ndarray

    def __len__(self) -> int:
        return self.centroids.shape[0]

    def clouds(self) -> list[np.ndarray]:
        """The k clouds, (n_o, 3) each."""
        return [self.points[a:b] for a, b in itertools.pairwise(self.cloud_starts)]


def _footprint_widths(xy: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Longer side of the smallest-perimeter rectangle around each cloud's footprint
    (`objects.footprint_rectangles`).

    Args:
        xy: (n, 2) metres, the clouds' points on the ground plane, one cloud after another;
        starts, ends: (c,) each cloud's slice of `xy`.
    Returns:
        (c,) metres.
    """
    hulls = [cv2.convexHull(xy[a:b].astype(np.float32)).reshape(-1, 2) for a, b in
             zip(starts, ends, strict=True)]
    sizes = np.array([h.shape[0] for h in hulls], dtype=np.int64)
    stacked = np.concatenate(hulls).astype(np.float64) if hulls else np.zeros((0, 2))
    return footprint_rectangles(stacked, np.concatenate([[0], np.cumsum(sizes)]))[0]


class MaskLifter:
    """Lifts masks of one camera to object observations.

    Args:
        camera: intrinsics of the image the masks and the (registered) depth belong to.
        depth_scale: raw depth units per metre (1000 for millimetres, 1 for metres).
        params: `LiftParams`.

    Raises:
        ConfigError: a camera, depth scale or params of the wrong kind, or a `depth_max` at
            which the camera's widest rays reach 500 m or more to the side (the clouds of the
            masks are cleaned 1000 m apart).
    """

    def __init__(self, camera: PinholeCamera, depth_scale: float = 1000.0,
                 params: LiftParams | None = None) -> None:
        self.camera = check_camera("MaskLifter.camera", camera)
        self.depth_scale = check_depth_scale("MaskLifter.depth_scale", depth_scale)
        self.params = LiftParams() if params is None else params
        _require(isinstance(self.params, LiftParams), "MaskLifter", "params", params,
                 "must be a LiftParams")
        x_over_z, y_over_z = camera.rays()
        # the clouds are cleaned side by side, _SEPARATION metres apart along x
        reach = float(np.max(np.abs(x_over_z))) * self.params.depth_max
        _require(reach < _SEPARATION / 2, "LiftParams", "depth_max", self.params.depth_max,
                 f"with this camera's widest ray (x / z = {np.max(np.abs(x_over_z)):.4g}) a "
                 f"point at depth_max lies {reach:.4g} m to the side; must stay under "
                 f"{_SEPARATION / 2:g} m")
        self._rays = np.stack([x_over_z.ravel(), y_over_z.ravel()], axis=1)

    def lift(self, masks: np.ndarray, depth: np.ndarray, T_odom_camera) -> Observations:
        """Observations of the masks that give enough clean points.

        Args:
            masks: (k, H, W) bool, in the image of `camera`.
            depth: (H, W) raw depth registered to that image.
            T_odom_camera: (4, 4) the camera's optical frame in the odometry frame at the
                frame's time.
        """
        return self.measure(masks, depth_in_metres(depth, self.depth_scale, self.camera.shape),
                            T_odom_camera)

    def measure(self, masks: np.ndarray, z: np.ndarray, T_odom_camera) -> Observations:
        """`lift` on depth already in metres, for a pipeline that has converted and checked it.

        Args:
            masks: (k, H, W) bool, in the image of `camera`.
            z: (H, W) float metres registered to that image; pixels at 0, negative or not
                finite have no return. Its values are not scanned again (that is `lift`'s
                job); only its type and shape are checked.
            T_odom_camera: (4, 4) the camera's optical frame in the odometry frame.
        Raises:
            DataError: masks or z of the wrong type, dtype or shape; T_odom_camera not rigid.
        """
        shape = self.camera.shape
        check_masks(masks, shape)
        if not (isinstance(z, np.ndarray) and z.dtype.kind == "f" and z.shape == tuple(shape)):
            got = f"{z.shape} {z.dtype}" if isinstance(z, np.ndarray) else type(z).__name__
            raise DataError(f"MaskLifter.measure: z must be a {tuple(shape)} float array of "
                            f"metres, got {got}")
        T = rigid_transform("T_odom_camera", T_odom_camera)
        p = self.params
        usable = (z >= p.depth_min) & (z <= p.depth_max) & (z > 0)
        rows_hit, cols_hit = masks.any(axis=2), masks.any(axis=1)  # (k, H), (k, W)
        z_flat = z.ravel()
        pixels, outlines, sources, eps = [], [], [], []
        for m in range(masks.shape[0]):
            sample = self._sample(masks[m], usable, rows_hit[m], cols_hit[m])
            if sample is None:
                continue
            pix, outline, step = sample
            z_mean = float(z_flat[pix].mean())
            spacing = max(p.voxel_size, step * z_mean / self.camera.fx)  # metres between samples
            eps.append(max(p.cluster_eps * spacing, p.cluster_eps_per_m * z_mean))
            pixels.append(pix)
            outlines.append(outline)
            sources.append(m)
        if not sources:
            return _no_observations()
        sizes = np.array([pix.size for pix in pixels])
        pix = np.concatenate(pixels)
        zs = z_flat[pix]
        points_cam = np.column_stack([self._rays[pix] * zs[:, None], zs])
        owner = np.repeat(np.arange(len(sources)), sizes)
        points, on_grid, owner = self._clean(points_cam, np.concatenate(outlines), owner,
                                             np.array(eps))
        points = points @ T[:3, :3].T + T[:3, 3]  # camera -> odometry frame
        counts = np.bincount(owner, weights=on_grid, minlength=len(sources)).astype(np.int64)
        enough = counts[owner] >= p.min_points
        points, on_grid, owner = points[enough], on_grid[enough], owner[enough]
        if owner.size == 0:
            return _no_observations()
        lifted, starts = np.unique(owner, return_index=True)
        ends = np.r_[starts[1:], owner.size]
        # The outline samples only extend the extent; the grid samples the surface evenly.
        centroids = np.add.reduceat(points * on_grid[:, None], starts) / counts[lifted, None]
        # Voxel averaging pulls the extreme points about half a voxel inside each edge.
        widths = _footprint_widths(points[:, :2], starts, ends) + p.voxel_size
        heights = (np.maximum.reduceat(points[:, 2], starts)
                   - np.minimum.reduceat(points[:, 2], starts) + p.voxel_size)
        source = np.array(sources, dtype=np.int64)[lifted]
        level, wall = self._slabs(points, starts, ends, widths)
        if wall.any():
            z_usable = np.where(usable, z, 0.0)
            for g in np.flatnonzero(wall):
                wall[g] = not stands_in_front(masks[source[g]], z_usable, p.jump,
                                              p.jump_per_m, p.jump_reach)
        solid = ~(level | wall)
        if not solid.any():
            return _no_observations()
        lengths = (ends - starts)[solid]
        return Observations(centroids[solid], widths[solid], heights[solid],
                            counts[lifted][solid], source[solid],
                            np.concatenate([points[a:b] for a, b in
                                            zip(starts[solid], ends[solid], strict=True)]),
                            np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64))

    def _slabs(self, points: np.ndarray, starts: np.ndarray, ends: np.ndarray,
               widths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c,) bool each: which clouds (points[starts[g]:ends[g]], (n, 3) metres in the
        odometry frame, widths (c,)) are level slabs and which are vertical slabs as wide as
        a wall (see the module's docstring)."""
        p = self.params
        level = np.zeros(starts.size, dtype=bool)
        wall = np.zeros(starts.size, dtype=bool)
        for g in np.flatnonzero(widths >= min(p.slab_extent, p.wall_extent)):
            cloud = points[starts[g]:ends[g]]
            if widths[g] >= p.slab_extent:
                lo, hi = np.percentile(cloud[:, 2], (5, 95))
                level[g] = hi - lo <= p.slab_thickness
            if not level[g] and widths[g] >= p.wall_extent:
                xy = cloud[:, :2] - cloud[:, :2].mean(axis=0)
                across = xy @ np.linalg.eigh(xy.T @ xy)[1][:, 0]  # the footprint's short axis
                lo, hi = np.percentile(across, (5, 95))
                wall[g] = hi - lo <= p.wall_thickness
        return level, wall

    def _sample(self, mask: np.ndarray, usable: np.ndarray, rows_hit: np.ndarray,
                cols_hit: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The pixels of one mask to lift, or None when it has too few with depth.

        Args:
            mask: (H, W) bool; usable: (H, W) bool, pixels with depth in range;
            rows_hit, cols_hit: (H,), (W,) bool, the rows and columns the mask touches.
        Returns:
            flat pixel indices (n,), which of them are outline samples (n,) bool, and the
            grid step in pixels.

        Masks with more than `max_points` pixels are sampled on a grid of every `step`-th
        image row and column (`step` need not be a whole number, so that about `max_points`
        remain: the cleaning steps cost more than linearly in points), plus the outline pixels
        on those rows and columns, so that the extent is not cut short by the grid.
        """
        p = self.params
        hit_rows, hit_cols = np.flatnonzero(rows_hit), np.flatnonzero(cols_hit)
        if hit_rows.size == 0:
            return None
        r0, r1, c0, c1 = hit_rows[0], hit_rows[-1] + 1, hit_cols[0], hit_cols[-1] + 1
        inside = mask[r0:r1, c0:c1] & usable[r0:r1, c0:c1]
        n = np.count_nonzero(inside)
        if n < p.min_points:
            return None
        W = self.camera.shape[1]
        step = math.sqrt(n / p.max_points)
        if step <= 1.0:
            ys, xs = np.nonzero(inside)
            return (ys + r0) * W + (xs + c0), np.zeros(ys.size, dtype=bool), 1.0
        grid_rows, grid_cols = _grid_lines(r0, r1, step), _grid_lines(c0, c1, step)
        # pixels beyond the crop count as outside, so the crop's edge pixels are outline
        edge = inside & ~cv2.erode(inside.view(np.uint8), _CROSS, borderType=cv2.BORDER_CONSTANT,
                                   borderValue=0).view(bool)
        gy, gx = np.nonzero(inside[np.ix_(grid_rows, grid_cols)])
        on_rows = edge[grid_rows]  # outline on the grid rows, off the grid columns
        on_rows[:, grid_cols] = False
        ry, rx = np.nonzero(on_rows)
        on_cols = edge[:, grid_cols]  # outline on the grid columns, off the grid rows
        on_cols[grid_rows] = False
        cy, cx = np.nonzero(on_cols)
        ys = np.concatenate([grid_rows[gy], grid_rows[ry], cy])
        xs = np.concatenate([grid_cols[gx], rx, grid_cols[cx]])
        outline = np.ones(ys.size, dtype=bool)
        outline[:gy.size] = False
        return (ys + r0) * W + (xs + c0), outline, step

    def _clean(self, points: np.ndarray, outline: np.ndarray, owner: np.ndarray,
               eps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Voxel downsampling, statistical outlier removal, and the largest DBSCAN cluster of
        every mask's cloud.

        Args:
            points: (n, 3) metres; outline: (n,) bool, which points are extra outline samples;
            owner: (n,) int, non-decreasing, which cloud each point belongs to;
            eps: (c,) metres, each cloud's DBSCAN radius.
        Returns:
            the kept points (m, 3), which of them are grid samples (m,) bool, and their owners
            (m,), non-decreasing.

        The clouds are cleaned together, each moved `_SEPARATION` metres from the previous
        one, so that Open3D is called once per step rather than once per mask; only the
        outlier removal, whose statistics are per cloud, runs cloud by cloud. The outline
        flag rides through the voxel averaging as a colour channel. DBSCAN runs on the
        centroids of cells eps / 2 wide, in coordinates scaled by each cloud's eps, and each
        point takes its cell's label: Open3D's DBSCAN slows down with the number of neighbours
        within eps, and a few cells per eps are enough to tell one surface from another
        behind a gap.
        """
        p = self.params
        shift = np.zeros((eps.size, 3))
        shift[:, 0] = _SEPARATION * np.arange(eps.size)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points + shift[owner]))
        flag = np.zeros((points.shape[0], 3))
        flag[:, 0] = outline
        cloud.colors = o3d.utility.Vector3dVector(flag)
        cloud = cloud.voxel_down_sample(p.voxel_size)
        out = np.asarray(cloud.points)
        owner = np.rint(out[:, 0] / _SEPARATION).astype(np.int64)
        order = np.argsort(owner, kind="stable")
        owner, out = owner[order], out[order] - shift[owner[order]]
        on_grid = np.asarray(cloud.colors)[order, 0] < 0.5

        keep = np.ones(owner.size, dtype=bool)
        bounds = np.searchsorted(owner, np.arange(eps.size + 1))
        for a, b in itertools.pairwise(bounds):
            if b - a > p.outlier_neighbors:
                one = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(out[a:b]))
                _, inliers = one.remove_statistical_outlier(p.outlier_neighbors, p.outlier_std)
                keep[a:b] = False
                keep[a + np.asarray(inliers, dtype=np.int64)] = True
        out, on_grid, owner = out[keep], on_grid[keep], owner[keep]
        if owner.size == 0:
            return out, on_grid, owner

        scaled = out / eps[owner, None]  # in units of the cloud's eps
        ijk = np.floor(2.0 * scaled).astype(np.int64)
        ijk -= ijk.min(axis=0)
        span = ijk.max(axis=0) + 1
        key = ((owner * span[0] + ijk[:, 0]) * span[1] + ijk[:, 1]) * span[2] + ijk[:, 2]
        _, cell, count = np.unique(key, return_inverse=True, return_counts=True)
        centres = np.column_stack([np.bincount(cell, weights=scaled[:, d]) for d in range(3)])
        centres /= count[:, None]
        cell_owner = np.zeros(count.size, dtype=np.int64)
        cell_owner[cell] = owner
        centres[:, 0] += (2.0 * np.abs(centres).max() + 10.0) * cell_owner  # apart by > eps
        coarse = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centres))
        labels = np.asarray(coarse.cluster_dbscan(1.0, p.cluster_min_points))
        clustered = labels >= 0
        # each cloud keeps its cluster holding the most points (not the most cells)
        weight = np.bincount(labels[clustered], weights=count[clustered])
        cluster_owner = np.zeros(weight.size, dtype=np.int64)
        cluster_owner[labels[clustered]] = cell_owner[clustered]
        ranked = np.lexsort((-weight, cluster_owner))
        first = ranked[np.r_[True, np.diff(cluster_owner[ranked]) != 0]]
        best = np.full(eps.size, -2)
        best[cluster_owner[first]] = first
        kept = labels[cell] == best[owner]
        return out[kept], on_grid[kept], owner[kept]


def _grid_lines(start: int, stop: int, step: float) -> np.ndarray:
    """Image rows (or columns) in [start, stop) on a grid of every `step`-th line (step >= 1),
    anchored at line 0 of the image, as offsets from `start`."""
    j = np.arange(math.floor(start / step), math.ceil(stop / step) + 1)
    lines = np.ceil(j * step).astype(np.int64)
    return lines[(lines >= start) & (lines < stop)] - start


def _no_observations() -> Observations:
    return Observations(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64),
                        np.zeros(0, dtype=np.int64), np.zeros((0, 3)),
                        np.zeros(1, dtype=np.int64))
