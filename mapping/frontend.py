"""The mapping front end of one robot: RGB-D frame + odometry pose -> its object map.

One `process` call per frame runs the paper's mapping step: register depth to the colour image
(when the cameras differ), segment with the frame's own gravity, filter the masks, lift them to
observations in the odometry frame (each with its cleaned cloud and the colour histogram of its
pixels), and track them in the `ObjectMapper`, which merges each object's views. Each call
reports how long each stage took.
"""

from __future__ import annotations

import inspect
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
from .objects import colour_bins
from .segment import (
    DepthSegmenter,
    MaskFilter,
    Segmenter,
    check_masks,
    check_rgb,
    filter_labels,
    filter_masks,
)

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
        self._segmenter_takes_up = _takes_keyword(self.segmenter.segment, "up")
        self.mask_filter = MaskFilter() if mask_filter is None else mask_filter
        self.lifter = MaskLifter(camera, 1.0, lift_params)
        self.mapper = ObjectMapper(mapper_params)

    def process(self, t: float, rgb: np.ndarray, depth: np.ndarray,
                T_odom_body: np.ndarray, T_body_camera: np.ndarray | None = None
                ) -> FrameResult:
        """Map one frame.

        The odometry frame is gravity aligned (z up, as VIO gives it), so the camera's
        attitude at this frame, T_odom_body @ T_body_camera, tells the segmenter which planes
        are level (a segmenter whose `segment` takes the keyword `up`, as `DepthSegmenter`'s
        does): a hand-held, tilting or pan-tilt camera is segmented with its own gravity.

        Args:
            t: seconds, the frame's time (not earlier than the previous frame's).
            rgb: (H, W, 3) uint8 colour image.
            depth: raw depth image, in the depth camera when `registration` is set, else
                registered to the colour image.
            T_odom_body: (4, 4) the body pose in the gravity-aligned odometry frame at time t.
            T_body_camera: (4, 4) the camera's optical frame in the body frame at time t, for
                a camera that moves on the body (a pan-tilt unit); None: the one given at
                construction.
        """
        seconds = {}
        clock = time.perf_counter()

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            seconds[stage] = now - clock
            clock = now

        check_rgb(rgb, self.camera.shape)
        T_odom_camera = rigid_transform("T_odom_body", T_odom_body) @ (
            self.T_body_camera if T_body_camera is None
            else rigid_transform("T_body_camera", T_body_camera))
        reg = self.registration
        if reg is None:
            z = depth_in_metres(depth, self.depth_scale, self.camera.shape)
        else:
            z = register_depth(depth, reg.camera, self.camera, reg.T_color_depth,
                               depth_scale=self.depth_scale)
        lap("register")
        # the odometry frame's up axis (z) in the optical frame
        up = {"up": T_odom_camera[2, :3].copy()} if self._segmenter_takes_up else {}
        labels = None
        if type(self.segmenter).segment is DepthSegmenter.segment:
            # the label image is filtered as it is; only the kept masks are ever made
            labels, n_masks = self.segmenter.label(rgb, z, **up)
            lap("segment")
            kept = filter_labels(labels, n_masks, z, self.mask_filter)
            candidates = labels[None] == (kept + 1).astype(labels.dtype)[:, None, None]
        else:
            masks = check_masks(self.segmenter.segment(rgb, z, **up), self.camera.shape,
                                f"{type(self.segmenter).__name__}.segment's masks")
            n_masks = masks.shape[0]
            lap("segment")
            kept = filter_masks(masks, z, self.mask_filter)
            candidates = masks[kept]
        lap("filter")
        obs = self.lifter.measure(candidates, z, T_odom_camera)
        lifted_masks = candidates[obs.mask_indices]
        obs = Observations(obs.centroids, obs.widths, obs.heights, obs.point_counts,
                           kept[obs.mask_indices], obs.points, obs.cloud_starts)
        colours = self._colours(rgb, lifted_masks, None if labels is None
                                else (labels, obs.mask_indices + 1))
        lap("lift")
        track_ids = self.mapper.update(t, obs.centroids, obs.widths, obs.heights,
                                       obs.clouds(), colours)
        lap("track")
        return FrameResult(obs, lifted_masks, track_ids, int(n_masks), seconds)

    def _colours(self, rgb: np.ndarray, masks: np.ndarray,
                 labelled: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """(k, B) the hue-saturation histogram of each of the k masks' pixels, from every
        second row and column (a histogram of a few hundred pixels or more is as good as of
        all). With `labelled` = (the (H, W) label image the masks come from, (k,) each mask's
        label), one pass over the label image gives the same counts as one pass per mask."""
        p = self.mapper.params
        n_bins = p.hue_bins * p.saturation_bins + 1
        k = masks.shape[0]
        if k == 0:
            return np.zeros((0, n_bins))
        index = colour_bins(np.ascontiguousarray(rgb[::2, ::2]), p.hue_bins, p.saturation_bins)
        if labelled is None:
            counts = np.zeros((k, n_bins), dtype=np.int64)
            sampled = masks[:, ::2, ::2]
            for r, mask in enumerate(sampled):
                counts[r] = np.bincount(index[mask], minlength=n_bins)
        else:
            labels, ids = labelled
            row_of = np.full(int(labels.max()) + 1, -1, dtype=np.int64)
            row_of[ids] = np.arange(k)
            row = row_of[labels[::2, ::2]]
            inside = row >= 0
            counts = np.bincount(row[inside] * n_bins + index[inside],
                                 minlength=k * n_bins).reshape(k, n_bins)
        for r in np.flatnonzero(counts.sum(axis=1) == 0):
            # a mask thinner than the sampling: its own pixels then
            counts[r] = np.bincount(colour_bins(rgb[masks[r]][None], p.hue_bins,
                                                p.saturation_bins)[0], minlength=n_bins)
        return counts / np.maximum(counts.sum(axis=1, keepdims=True), 1)

    def object_map(self) -> ObjectMap:
        """The robot's current map (confirmed tracks) in its odometry frame."""
        return self.mapper.object_map()


def _takes_keyword(method, name: str) -> bool:
    """Whether `method` accepts the keyword argument `name`."""
    try:
        params = inspect.signature(method).parameters
    except (TypeError, ValueError):  # a builtin without a signature
        return False
    return name in params or any(p.kind is inspect.Parameter.VAR_KEYWORD
                                 for p in params.values())
