"""What a robot's camera and segmentation report about the objects in front of it.

One call is one frame: the objects within the field of view and range, each detected with some
probability, with centroid noise that grows with range, sizes shrunk by partial views, and a few
false segments. Detections are expressed in the robot's odometry frame, through its drifting
odometry pose, exactly as a real mapping front end would place them.
"""

from __future__ import annotations

import numpy as np

from ..config import SensorConfig
from .world import World

__all__ = ["Detections", "observe"]

Detections = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def observe(rng: np.random.Generator, world: World, pose_true: np.ndarray,
            pose_odom: np.ndarray, sensor: SensorConfig) -> Detections:
    """One frame of object detections.

    Args:
        pose_true: (3,) the body's true pose (x, y, theta) in the world frame.
        pose_odom: (3,) the body's pose in the robot's odometry frame.
    Returns:
        centroids (k, 3) metres in the odometry frame, widths (k,), heights (k,) metres, and
        labels (k,) int: the world object each detection comes from, -1 for false segments.
    """
    x, y, theta = pose_true
    c, s = np.cos(theta), np.sin(theta)
    rel = world.xy - (x, y)
    fwd, left = c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]
    rng_m = np.hypot(fwd, left)
    half_fov = np.radians(sensor.fov_deg) / 2
    visible = ((rng_m >= sensor.range_min) & (rng_m <= sensor.range_max)
               & (np.abs(np.arctan2(left, fwd)) <= half_fov))
    index = np.flatnonzero(visible)
    index = index[rng.random(index.size) < sensor.p_detect]
    k = index.size
    sigma = sensor.centroid_noise + sensor.centroid_noise_per_m * rng_m[index]
    # A partial view shows the near side of an object, which pulls its centroid towards the
    # camera by half the unseen depth: a bias that depends on the viewpoint.
    share_w = rng.uniform(sensor.partial_view, 1.0, k)
    share_h = rng.uniform(sensor.partial_view, 1.0, k)
    # at most halfway to the camera, for objects as wide as they are near
    pull = np.minimum((1.0 - share_w) * world.widths[index] / 2
                      / np.maximum(rng_m[index], 1e-6), 0.5)
    body = np.column_stack([fwd[index] * (1 - pull), left[index] * (1 - pull),
                            world.heights[index] * share_h / 2])
    body += rng.normal(0.0, 1.0, (k, 3)) * sigma[:, None]

    def seen(extent: np.ndarray, share: np.ndarray) -> np.ndarray:
        noise = 1 + sensor.size_noise * rng.standard_normal(extent.size)
        return np.maximum(extent * share * noise, 0.02)

    widths, heights = seen(world.widths[index], share_w), seen(world.heights[index], share_h)
    n_false = rng.poisson(sensor.false_per_frame)
    if n_false:
        r = rng.uniform(max(sensor.range_min, min(0.5, sensor.range_max)), sensor.range_max,
                        n_false)
        a = rng.uniform(-half_fov, half_fov, n_false)
        false_h = rng.uniform(0.1, 0.6, n_false)
        body = np.vstack([body, np.column_stack([r * np.cos(a), r * np.sin(a), false_h / 2])])
        widths = np.r_[widths, rng.uniform(0.1, 0.6, n_false)]
        heights = np.r_[heights, false_h]
    labels = np.r_[index, np.full(n_false, -1)].astype(np.int64)
    xo, yo, to = pose_odom
    co, so = np.cos(to), np.sin(to)
    centroids = np.column_stack([xo + co * body[:, 0] - so * body[:, 1],
                                 yo + so * body[:, 0] + co * body[:, 1], body[:, 2]])
    return centroids, widths, heights, labels
