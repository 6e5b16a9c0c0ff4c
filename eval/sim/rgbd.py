"""Rendered RGB-D perception for the simulator: each frame is ray-cast from the robot's true
camera pose and mapped by the real front end (`RgbdFrontEnd`) in the robot's odometry frame.
"""

from __future__ import annotations

import numpy as np
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd
from tcaff_gtsam.mapping.mapper import MapperParams
from tcaff_gtsam.mapping.segment import DepthSegmenter, DepthSegmenterParams, MaskFilter

from tcaff_gtsam.geometry import se3_from_xyz_yaw

from ..config import CameraConfig
from .render import RgbdScene, render
from .world import World

__all__ = ["RenderedCamera", "clear_paths"]


def clear_paths(rng: np.random.Generator, world: World, paths: list[np.ndarray],
                clearance: float, min_gap: float = 1.0) -> World:
    """The world with every object that a path passes too close to moved to a free place, so
    that no camera enters a solid. An object is too close when a path comes within `clearance`
    metres of its outline (a circle through a box's corners); free places are drawn uniformly
    in the objects' bounding rectangle, at least `min_gap` metres from the other objects.
    Objects with no free place left are dropped.

    Args:
        paths: (F, 2 or 3) true positions (x, y, ...) per robot, sampled densely.
    """
    track = np.vstack([p[:, :2] for p in paths])
    reach = clearance + world.widths / np.sqrt(2)

    def path_distance(xy: np.ndarray) -> np.ndarray:
        return np.min(np.linalg.norm(xy[:, None, :] - track[None, :, :], axis=2), axis=1)

    xy = world.xy.copy()
    keep = path_distance(xy) > reach
    lo, hi = world.xy.min(axis=0), world.xy.max(axis=0)
    for k in np.flatnonzero(~keep):
        spots = rng.uniform(lo, hi, (500, 2))
        ok = path_distance(spots) > reach[k]
        if keep.any():
            ok &= np.min(np.linalg.norm(spots[:, None] - xy[keep][None], axis=2), axis=1) >= min_gap
        if ok.any():
            xy[k] = spots[np.argmax(ok)]
            keep[k] = True
    return World(xy[keep], world.widths[keep], world.heights[keep], world.kinds[keep],
                 world.walls)


class RenderedCamera:
    """One robot's RGB-D camera and mapping front end in a rendered world.

    Args:
        scene: the rendered world (shared by the robots).
        config: the camera.
        mapper_params: the tracker's settings.
    """

    def __init__(self, scene: RgbdScene, config: CameraConfig,
                 mapper_params: MapperParams) -> None:
        self.scene = scene
        self.config = config
        self.camera = PinholeCamera.from_fov(config.width, config.height, config.hfov_deg)
        # the masks' smallest areas are set for 640 x 480 images: the same share of this one
        share = config.width * config.height / (640 * 480)
        segmenter = DepthSegmenter(
            self.camera, 1.0, DepthSegmenterParams(
                min_area=round(DepthSegmenterParams.min_area * share)),
            T_body_camera(config.mount_height, config.pitch_deg))
        self.front_end = RgbdFrontEnd(self.camera, T_body_camera(config.mount_height,
                                                                 config.pitch_deg),
                                      depth_scale=1.0, segmenter=segmenter,
                                      mask_filter=MaskFilter(
                                          min_area=round(MaskFilter.min_area * share)),
                                      mapper_params=mapper_params)

    def step(self, rng: np.random.Generator, t: float, pose_true: np.ndarray,
             pose_odom: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Render and map one frame.

        Args:
            pose_true, pose_odom: (3,) the body pose (x, y, theta) in the world and in the
                robot's odometry frame.

        Returns:
            the track id of every observation and its world object (-1: floor or walls,
            which the front end should never report).
        """
        T_world_body = se3_from_xyz_yaw(pose_true[0], pose_true[1], 0.0, pose_true[2])
        T_odom_body = se3_from_xyz_yaw(pose_odom[0], pose_odom[1], 0.0, pose_odom[2])
        frame = render(self.scene, T_world_body @ self.front_end.T_body_camera, self.camera,
                       self.config.depth_noise, rng, self.config.depth_max)
        result = self.front_end.process(t, frame.rgb, frame.depth, T_odom_body)
        labels = np.array([np.bincount(frame.instance[m]).argmax() - 1 for m in result.masks],
                          dtype=np.int64)
        return result.track_ids, labels
