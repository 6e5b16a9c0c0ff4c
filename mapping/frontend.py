"""The mapping front end of one robot: RGB-D frame + odometry pose -> its object map.

One `process` call per frame runs the paper's mapping step: register depth to the colour image
(when the cameras differ), segment, filter the masks, lift them to observations in the odometry
frame, and track them in the `ObjectMapper`. Each call reports how long each stage took.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.object_map import ObjectMap

from .camera import (
    PinholeCamera,
    check_camera,
    check_depth_scale,
    depth_in_metres,
    register_depth,
    rigid_transform,
)
from .lift import LiftParams, MaskLifter, Observations
from .mapper import MapperParams, ObjectMapper
from .segment import DepthSegmenter, MaskFilter, Segmenter, check_masks, check_rgb, filter_masks

__all__ = ["DepthRegistration", "FrameResult", "RgbdFrontEnd"]


@dataclass(frozen=True)
class DepthRegistration:
    """A depth camera that is not the colour camera.

    Attributes:
        camera: the depth camera's intrinsics.
        T_color_depth: (4, 4) the depth camera's optical frame in the colour camera's.
    """

    camera: PinholeCamera
    T_color_depth: np.ndarray


@dataclass(frozen=True)
class FrameResult:
    """What one frame gave.

    Attributes:
        observations: the lifted objects, in the odometry frame; `mask_indices` index the
            segmenter's masks.
        masks: (k, H, W) bool, the mask each observation was lifted from.
        track_ids: (k,) int64, the mapper track of each observation.
        n_masks: masks from the segmenter, before filtering.
        seconds: wall time per stage: "register", "segment", "filter", "lift", "track".
    """

    observations: Observations
    masks: np.ndarray
    track_ids: np.ndarray
    n_masks: int
    seconds: dict[str, float]


class RgbdFrontEnd:
    """One robot's mapping front end.

    Args:
        camera: the colour camera's intrinsics (masks and registered depth live in its image).
        T_body_camera: (4, 4) the colour camera's optical frame in the body frame.
        depth_scale: raw depth units per metre of the incoming depth images (1000 for 16-bit
            millimetres, 1 for float metres).
        segmenter: any `Segmenter`; it is given depth as float32 metres registered to the
            colour image. Default: `DepthSegmenter` told the camera's attitude (which planes
            are level) by `T_body_camera`.
        registration: set when depth comes from a different camera than colour.
        mask_filter, lift_params, mapper_params: settings of the stages.
    """

    def __init__(self, camera: PinholeCamera, T_body_camera: np.ndarray,
                 depth_scale: float = 1000.0, segmenter: Segmenter | None = None,
                 registration: DepthRegistration | None = None,
                 mask_filter: MaskFilter | None = None, lift_params: LiftParams | None = None,
                 mapper_params: MapperParams | None = None) -> None:
        self.camera = check_camera("RgbdFrontEnd.camera", camera)
        self.T_body_camera = rigid_transform("RgbdFrontEnd.T_body_camera", T_body_camera,
                                             ConfigError)
        if registration is not None:
            if not isinstance(registration, DepthRegistration):
                raise ConfigError(f"RgbdFrontEnd.registration = {registration!r}: must be a "
                                  "DepthRegistration or None")
            check_camera("DepthRegistration.camera", registration.camera)
            rigid_transform("DepthRegistration.T_color_depth", registration.T_color_depth,
                            ConfigError)
        self.registration = registration
        self.depth_scale = check_depth_scale("RgbdFrontEnd.depth_scale", depth_scale)
        # Every stage after the first is given float32 metres (depth_scale 1).
        self.segmenter = (DepthSegmenter(camera, 1.0, T_body_camera=self.T_body_camera)
                          if segmenter is None else segmenter)
        if not callable(getattr(self.segmenter, "segment", None)):
            raise ConfigError(f"RgbdFrontEnd.segmenter = {segmenter!r}: needs a "
                              "segment(rgb, depth) method")
        self.mask_filter = MaskFilter() if mask_filter is None else mask_filter
        self.lifter = MaskLifter(camera, 1.0, lift_params)
        self.mapper = ObjectMapper(mapper_params)

    def process(self, t: float, rgb: np.ndarray, depth: np.ndarray,
                T_odom_body: np.ndarray) -> FrameResult:
        """Map one frame.

        Args:
            t: seconds, the frame's time (not earlier than the previous frame's).
            rgb: (H, W, 3) uint8 colour image.
            depth: raw depth image, in the depth camera when `registration` is set, else
                registered to the colour image.
            T_odom_body: (4, 4) the body pose in the odometry frame at time t.
        """
        seconds = {}
        clock = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            seconds[stage] = now - clock
            clock = now

        check_rgb(rgb, self.camera.shape)
        T_ob = rigid_transform("T_odom_body", T_odom_body)
        reg = self.registration
        if reg is None:
            z = depth_in_metres(depth, self.depth_scale, self.camera.shape)
        else:
            z = register_depth(depth, reg.camera, self.camera, reg.T_color_depth,
                               depth_scale=self.depth_scale)
        lap("register")
        masks = check_masks(self.segmenter.segment(rgb, z), self.camera.shape,
                            f"{type(self.segmenter).__name__}.segment's masks")
        lap("segment")
        kept = filter_masks(masks, z, self.mask_filter)
        lap("filter")
        obs = self.lifter.measure(masks[kept], z, T_ob @ self.T_body_camera)
        lifted = kept[obs.mask_indices]
        obs = Observations(obs.centroids, obs.widths, obs.heights, obs.point_counts, lifted)
        lap("lift")
        track_ids = self.mapper.update(t, obs.centroids, obs.widths, obs.heights)
        lap("track")
        return FrameResult(obs, masks[lifted], track_ids, int(masks.shape[0]), seconds)

    def object_map(self) -> ObjectMap:
        """The robot's current map (confirmed tracks) in its odometry frame."""
        return self.mapper.object_map()
