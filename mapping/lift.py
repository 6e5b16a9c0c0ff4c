"""Lifting: instance masks + depth -> Open3D object point clouds -> object observations.

Each mask's pixels with a depth return are back-projected through the camera intrinsics and
moved into the robot's odometry frame through `T_odom_camera`. Open3D then cleans the cloud:
voxel downsampling, statistical outlier removal, and DBSCAN keeping the largest cluster (a mask
that spills onto the background gives a second, far cluster). The observation is the cloud's
centroid, its width (the longer side of the smallest-perimeter rectangle holding its footprint
on the ground plane, which does not depend on the viewing direction for boxes and cylinders) and its
height (its extent along the odometry frame's z axis, which is up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from tcaff_gtsam.params import _int_at_least, _real, _require

from .camera import PinholeCamera, check_camera, check_depth_scale, depth_in_metres, rigid_transform
from .segment import check_masks

__all__ = ["LiftParams", "MaskLifter", "Observations"]

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


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

    def __post_init__(self) -> None:
        o = "LiftParams"
        for name in ("voxel_size", "outlier_std", "cluster_eps", "cluster_eps_per_m",
                     "depth_max"):
            v = getattr(self, name)
            _require(_real(v) and math.isfinite(v) and v > 0, o, name, v,
                     "must be a finite number > 0")
        for name in ("max_points", "outlier_neighbors", "cluster_min_points", "min_points"):
            v = getattr(self, name)
            _require(_int_at_least(v, 1), o, name, v, "must be an int >= 1")
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
    """

    centroids: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    point_counts: np.ndarray
    mask_indices: np.ndarray

    def __len__(self) -> int:
        return self.centroids.shape[0]


def _footprint_width(xy: np.ndarray) -> float:
    """Longer side of the smallest-perimeter rectangle around (n, 2) points.

    Not the smallest-area one: for the L of a box's two visible faces the smallest-area
    rectangle ties between the box itself and one along the diagonal, while the smallest
    perimeter picks the box. One side of the optimal rectangle lies along a hull edge.
    """
    hull = cv2.convexHull(xy.astype(np.float32)).reshape(-1, 2).astype(float)
    if hull.shape[0] < 3:
        return float(np.ptp(hull, axis=0).max()) if hull.shape[0] == 2 else 0.0
    edges = np.roll(hull, -1, axis=0) - hull
    u = edges / np.maximum(np.linalg.norm(edges, axis=1, keepdims=True), 1e-12)
    along = np.ptp(hull @ u.T, axis=0)  # (h,) extent along each edge direction
    across = np.ptp(hull @ np.column_stack([-u[:, 1], u[:, 0]]).T, axis=0)
    best = int(np.argmin(along + across))
    return float(max(along[best], across[best]))


class MaskLifter:
    """Lifts masks of one camera to object observations.

    Args:
        camera: intrinsics of the image the masks and the (registered) depth belong to.
        depth_scale: raw depth units per metre (1000 for millimetres, 1 for metres).
        params: `LiftParams`.
    """

    def __init__(self, camera: PinholeCamera, depth_scale: float = 1000.0,
                 params: LiftParams | None = None) -> None:
        self.camera = check_camera("MaskLifter.camera", camera)
        self.depth_scale = check_depth_scale("MaskLifter.depth_scale", depth_scale)
        self.params = LiftParams() if params is None else params
        _require(isinstance(self.params, LiftParams), "MaskLifter", "params", params,
                 "must be a LiftParams")
        x_over_z, y_over_z = camera.rays()
        self._rays = np.stack([x_over_z.ravel(), y_over_z.ravel()], axis=1)

    def lift(self, masks: np.ndarray, depth: np.ndarray, T_odom_camera) -> Observations:
        """Observations of the masks that give enough clean points.

        Args:
            masks: (k, H, W) bool, in the image of `camera`.
            depth: (H, W) raw depth registered to that image.
            T_odom_camera: (4, 4) the camera's optical frame in the odometry frame at the
                frame's time.
        """
        H, W = self.camera.shape
        z = depth_in_metres(depth, self.depth_scale, (H, W))
        check_masks(masks, (H, W))
        T = rigid_transform("T_odom_camera", T_odom_camera)
        p = self.params
        z_flat = z.ravel()
        usable = (z >= p.depth_min) & (z <= p.depth_max) & (z > 0)
        rows_hit = masks.any(axis=2)  # (k, H): one pass, then work inside each mask's rows
        rows = []
        for m in range(masks.shape[0]):
            hit = np.flatnonzero(rows_hit[m])
            if hit.size == 0:
                continue
            r0, r1 = hit[0], hit[-1] + 1
            inside = masks[m, r0:r1] & usable[r0:r1]
            ys, xs = np.nonzero(inside)
            if ys.size < p.min_points:
                continue
            # Keep every g-th pixel along both image axes, so that about max_points remain (the
            # cleaning steps cost more than linearly in points), plus the outline pixels on
            # those rows and columns, so that the extent is not cut short by the grid.
            g = max(1, int(math.sqrt(ys.size / p.max_points)))
            outline = np.zeros(ys.size, dtype=bool)
            if g > 1:
                # pixels beyond the crop count as outside, so the mask's lowest row is outline
                outline = ~cv2.erode(inside.view(np.uint8), _CROSS, borderType=cv2.BORDER_CONSTANT,
                                     borderValue=0).view(bool)[ys, xs]
                on_row, on_col = ys % g == 0, xs % g == 0
                on_grid = on_row & on_col
                keep = on_grid | (outline & (on_row | on_col))
                ys, xs, outline = ys[keep], xs[keep], ~on_grid[keep]
            pixels = (ys + r0) * W + xs
            zm = z_flat[pixels]
            points_cam = np.column_stack([self._rays[pixels] * zm[:, None], zm])
            z_mean = float(zm.mean())
            spacing = max(p.voxel_size, g * z_mean / self.camera.fx)  # metres between samples
            eps = max(p.cluster_eps * spacing, p.cluster_eps_per_m * z_mean)
            cloud, on_grid = self._clean(points_cam @ T[:3, :3].T + T[:3, 3], outline, eps)
            if on_grid.sum() < p.min_points:
                continue
            rows.append((m, cloud, on_grid))
        k = len(rows)
        centroids, widths, heights = np.zeros((k, 3)), np.zeros(k), np.zeros(k)
        counts = np.zeros(k, dtype=np.int64)
        for r, (_, cloud, on_grid) in enumerate(rows):
            # The outline samples only extend the extent; the grid samples the surface evenly.
            centroids[r] = cloud[on_grid].mean(axis=0)
            # Voxel averaging pulls the extreme points about half a voxel inside each edge.
            widths[r] = _footprint_width(cloud[:, :2]) + p.voxel_size
            heights[r] = np.ptp(cloud[:, 2]) + p.voxel_size
            counts[r] = on_grid.sum()
        return Observations(centroids, widths, heights, counts,
                            np.array([row[0] for row in rows], dtype=np.int64))

    def _clean(self, points: np.ndarray, outline: np.ndarray, eps: float
               ) -> tuple[np.ndarray, np.ndarray]:
        """Voxel downsampling, statistical outlier removal, and the largest DBSCAN cluster
        (radius `eps` metres).

        Args:
            points: (n, 3); outline: (n,) bool, which points are extra outline samples.
        Returns:
            the kept points (m, 3) and which of them are grid samples (m,) bool.

        The outline flag rides through the voxel averaging as a colour channel. DBSCAN runs on
        the centroids of cells eps / 2 wide, and each point takes its cell's label: Open3D's
        DBSCAN slows down with the number of neighbours within eps, and a few cells per eps
        are enough to tell one surface from another behind a gap.
        """
        p = self.params
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        flag = np.zeros((points.shape[0], 3))
        flag[:, 0] = outline
        cloud.colors = o3d.utility.Vector3dVector(flag)
        cloud = cloud.voxel_down_sample(p.voxel_size)
        if len(cloud.points) > p.outlier_neighbors:
            cloud, _ = cloud.remove_statistical_outlier(p.outlier_neighbors, p.outlier_std)
        out = np.asarray(cloud.points)
        on_grid = np.asarray(cloud.colors)[:, 0] < 0.5
        if out.shape[0] == 0:
            return out, on_grid
        ijk = np.floor(out / (eps / 2)).astype(np.int64)
        ijk -= ijk.min(axis=0)
        span = ijk.max(axis=0) + 1
        key = (ijk[:, 0] * span[1] + ijk[:, 1]) * span[2] + ijk[:, 2]
        _, cell, count = np.unique(key, return_inverse=True, return_counts=True)
        centres = np.zeros((count.size, 3))
        np.add.at(centres, cell, out)
        centres /= count[:, None]
        coarse = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(centres))
        labels = np.asarray(coarse.cluster_dbscan(eps, p.cluster_min_points))
        if labels.max(initial=-1) < 0:
            return out[:0], on_grid[:0]
        # the cluster holding the most points (not the most cells)
        largest = np.argmax(np.bincount(labels[labels >= 0], weights=count[labels >= 0]))
        kept = labels[cell] == largest
        return out[kept], on_grid[kept]
