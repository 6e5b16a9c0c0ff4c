"""Robot motion: true trajectories from waypoints, loops and lawnmower patterns, and odometry
that drifts like visual-inertial odometry.

Poses are (x [m], y [m], theta [rad]) arrays: true poses in the world frame, odometry poses in
the robot's odometry frame, which starts at the robot's first true pose.
"""

from __future__ import annotations

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se2_from_params, wrap_angle

from .sizes import amount, count

__all__ = ["MAX_WAYPOINTS", "drifting_odometry", "lawnmower", "loop", "odometry_frame",
           "poses_along", "then", "timed_waypoints", "wait"]

#: the most waypoints `loop` and `lawnmower` make: two hours of a scenario's fastest loops
#: round its smallest room are two million; ten million are 160 MB
MAX_WAYPOINTS = 10_000_000


def timed_waypoints(waypoints, speed: float, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Knot times (m,) [s] and positions (m, 2) [m] of driving through `waypoints` at `speed`
    m/s, leaving the first one at t0. `wait` and `then` extend such knots."""
    xy = np.asarray(waypoints, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 1 or speed <= 0:
        raise DataError(f"timed_waypoints: need waypoints (m, 2) and speed > 0, got shape "
                        f"{xy.shape} and speed {speed}")
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1) / speed
    return t0 + np.r_[0.0, np.cumsum(step)], xy


def wait(knot_t: np.ndarray, knot_xy: np.ndarray, seconds: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """The knots extended by standing still at the last position for `seconds`."""
    return np.r_[knot_t, knot_t[-1] + seconds], np.vstack([knot_xy, knot_xy[-1]])


def then(first: tuple[np.ndarray, np.ndarray], waypoints, speed: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """The knots `first` followed by driving on from its last position through `waypoints`."""
    t, xy = timed_waypoints(np.vstack([first[1][-1], waypoints]), speed, first[0][-1])
    return np.r_[first[0], t[1:]], np.vstack([first[1], xy[1:]])


def loop(center, radius: float, laps: float, start_angle: float = 0.0, ccw: bool = True,
         points_per_lap: int = 36) -> np.ndarray:
    """(m, 2) waypoints of `laps` turns around a circle: points_per_lap an int in
    [1, MAX_WAYPOINTS], laps a finite number >= 0 with points_per_lap x laps at most
    MAX_WAYPOINTS (DataError otherwise)."""
    points_per_lap = count("loop", "points_per_lap", points_per_lap, MAX_WAYPOINTS,
                           "MAX_WAYPOINTS", low=1)
    laps = amount("loop", "laps", laps, MAX_WAYPOINTS / points_per_lap,
                  "MAX_WAYPOINTS / points_per_lap")
    n = max(round(points_per_lap * laps), 1)
    angle = start_angle + (1.0 if ccw else -1.0) * np.linspace(0, 2 * np.pi * laps, n + 1)
    return np.asarray(center, dtype=float) + radius * np.column_stack([np.cos(angle),
                                                                       np.sin(angle)])


def lawnmower(bounds: tuple[float, float, float, float], lanes: int, along_x: bool = True
              ) -> np.ndarray:
    """(2 lanes, 2) waypoints sweeping a rectangle (x0, y0, x1, y1) in parallel lanes; lanes
    an int in [1, MAX_WAYPOINTS / 2] (DataError otherwise)."""
    lanes = count("lawnmower", "lanes", lanes, MAX_WAYPOINTS // 2, "MAX_WAYPOINTS / 2", low=1)
    x0, y0, x1, y1 = bounds
    points = []
    for k, c in enumerate(np.linspace(y0 if along_x else x0, y1 if along_x else x1, lanes)):
        lo, hi = (x0, x1) if along_x else (y0, y1)
        a, b = (lo, hi) if k % 2 == 0 else (hi, lo)
        points += [(a, c), (b, c)] if along_x else [(c, a), (c, b)]
    return np.asarray(points, dtype=float)


def poses_along(knot_t: np.ndarray, knot_xy: np.ndarray, times: np.ndarray,
                lookahead: float = 0.5) -> np.ndarray:
    """(T, 3) poses at `times`: positions interpolated between knots (held before the first and
    after the last), heading along the motion over +-`lookahead` seconds, so corners are
    rounded. While standing still the robot keeps its last heading."""
    times = np.asarray(times, dtype=float)
    x = np.interp(times, knot_t, knot_xy[:, 0])
    y = np.interp(times, knot_t, knot_xy[:, 1])
    dx = np.interp(times + lookahead, knot_t, knot_xy[:, 0]) - np.interp(
        times - lookahead, knot_t, knot_xy[:, 0])
    dy = np.interp(times + lookahead, knot_t, knot_xy[:, 1]) - np.interp(
        times - lookahead, knot_t, knot_xy[:, 1])
    # While standing still the robot keeps the heading of the last leg it drove (the first
    # leg's before it starts), which depends on the knots only, not on the query times.
    step = np.diff(knot_xy, axis=0)
    leg = np.where(np.hypot(step[:, 0], step[:, 1]) > 1e-9,
                   np.arctan2(step[:, 1], step[:, 0]), np.nan)
    if len(leg) == 0 or np.all(np.isnan(leg)):
        leg = np.zeros(max(len(leg), 1))
    driven = np.flatnonzero(~np.isnan(leg))
    last = np.maximum.accumulate(np.where(np.isnan(leg), -1, np.arange(len(leg))))
    leg = leg[np.where(last < 0, driven[0], last)]
    current = np.clip(np.searchsorted(knot_t, times, side="right") - 1, 0, len(leg) - 1)
    moving = np.hypot(dx, dy) > 1e-6
    heading = np.where(moving, np.arctan2(dy, dx), leg[current])
    return np.column_stack([x, y, heading])


def drifting_odometry(rng: np.random.Generator, poses: np.ndarray, dt: float,
                      heading_rw: float, position_rw: float) -> np.ndarray:
    """Odometry poses (T, 3) of a robot whose true poses are `poses` (T, 3), sampled every `dt`
    seconds.

    Each step's true motion in the body frame is perturbed by white noise of std
    heading_rw * sqrt(dt) [rad] in heading and position_rw * sqrt(dt) [m] per axis in position,
    and integrated; the heading error is a random walk, so position drift grows with distance.
    The odometry frame is the robot's first true pose (odometry starts at the identity).
    """
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3 or dt <= 0:
        raise DataError(f"drifting_odometry: need poses (T, 3) and dt > 0, got {poses.shape}, "
                        f"dt = {dt}")
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    d = np.diff(poses[:, :2], axis=0)
    step_xy = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    step_theta = wrap_angle(np.diff(poses[:, 2]))
    step_xy = step_xy + rng.normal(0.0, position_rw * np.sqrt(dt), step_xy.shape)
    step_theta = step_theta + rng.normal(0.0, heading_rw * np.sqrt(dt), step_theta.shape)
    theta = np.r_[0.0, np.cumsum(step_theta)]
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    xy = np.vstack([np.zeros(2), np.cumsum(np.column_stack(
        [c * step_xy[:, 0] - s * step_xy[:, 1], s * step_xy[:, 0] + c * step_xy[:, 1]]),
        axis=0)])
    return np.column_stack([xy, wrap_angle(theta)])


def odometry_frame(poses_true: np.ndarray, poses_odom: np.ndarray) -> np.ndarray:
    """(..., 3, 3) T_w_o, a robot's odometry frame in the world frame, T_w_b T_o_b^-1, from its
    true poses (..., 3) and odometry poses (..., 3) at the same times."""
    return se2_from_params(poses_true) @ invert(se2_from_params(poses_odom))
