"""People walking between random waypoints, and what each robot's person detector reports.

A walker stands at a uniform random point, walks to another at a speed drawn for that leg,
pauses, and goes on. Detections are made from the robot's true pose and placed in its odometry
frame through its odometry pose, as a real detector with depth would place them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se2_from_params, transform_points_batch
from tcaff_gtsam.inputs import real_array

from ..config import PedestriansConfig, PersonDetectorConfig
from .motion import odometry_frame
from .sizes import count

#: the most people `walk` moves: fifty times a scenario's (`PedestriansConfig.count`)
MAX_PEOPLE = 10_000

#: the most legs (walks to a waypoint and rests there) of all people together in one `walk`,
#: a few seconds of drawing: bounds that leave no room to walk, or times far in the future,
#: would need without end
MAX_LEGS = 1_000_000

__all__ = ["PeopleRun", "detect_people", "simulate_people", "walk"]


@dataclass(frozen=True, eq=False)
class PeopleRun:
    """The people of a run and every robot's detections of them, at the tracking frames.

    Attributes:
        times: (F,) seconds of the tracking frames.
        xy: (F, n_people, 2) metres, the people's true positions in the world frame.
        in_view: (F, n_people) bool, within some robot's detector field of view and range
            (detected or not): the people the team could track.
        poses_true, poses_odom: (n_robots, F, 3) the robots' body poses in the world frame and
            in their own odometry frames.
        detections: per robot, (frame (D,) int, xy (D, 2) metres in that robot's odometry
            frame, person (D,) int, -1 for a false detection), sorted by frame.
    """

    times: np.ndarray
    xy: np.ndarray
    in_view: np.ndarray
    poses_true: np.ndarray
    poses_odom: np.ndarray
    detections: list[tuple[np.ndarray, np.ndarray, np.ndarray]]

    @property
    def n_robots(self) -> int:
        return self.poses_true.shape[0]

    def T_w_o(self, robot: int) -> np.ndarray:
        """(F, 3, 3) the robot's odometry frame in the world frame at each frame."""
        return odometry_frame(self.poses_true[robot], self.poses_odom[robot])

    def truth_in_odom(self, robot: int) -> np.ndarray:
        """(F, n_people, 2) metres, the people's true positions in the robot's odometry frame:
        where the robot itself believes them to be when it sees them without error."""
        return transform_points_batch(invert(self.T_w_o(robot))[:, None], self.xy)


def walk(rng: np.random.Generator, n: int, bounds: tuple[float, float, float, float],
         speed: tuple[float, float], pause: tuple[float, float], times: np.ndarray
         ) -> np.ndarray:
    """(F, n, 2) positions at `times` of n people walking between random waypoints in
    `bounds` (x_min, y_min, x_max, y_max) metres, from a random start at time 0.

    Raises:
        DataError: n not an int in [0, MAX_PEOPLE], times not finite (F,) seconds, bounds
            spanning no distance, more than MAX_LEGS legs to walk until the last time.
    """
    n = count("walk", "n", n, MAX_PEOPLE, "MAX_PEOPLE")
    times = real_array("walk", "times", times)
    if times.ndim != 1 or not np.isfinite(times).all():
        raise DataError(f"walk: times must be finite (F,) seconds, got shape {times.shape}")
    x0, y0, x1, y1 = bounds
    if not (x1 >= x0 and y1 >= y0 and (x1 > x0 or y1 > y0)):
        raise DataError(f"walk: bounds (x_min, y_min, x_max, y_max) must span some distance, "
                        f"got {bounds}")
    end = float(times[-1]) if len(times) else 0.0
    legs_needed = f"{n} people walking in {bounds} until {end:g} s need more than MAX_LEGS = "
    # no leg takes longer than the diagonal at the slowest speed plus the longest pause, so a
    # span of more than MAX_LEGS of those is refused before any walking
    slowest = min(speed)
    longest = math.hypot(x1 - x0, y1 - y0) / slowest + max(pause) if slowest > 0 else math.inf
    if n * (end / longest) > MAX_LEGS:
        raise DataError(f"walk: {legs_needed}{MAX_LEGS} legs: wider bounds, longer pauses or "
                        f"earlier times")
    out = np.zeros((len(times), n, 2))
    legs = 0
    for person in range(n):
        knot_t, knot_xy = [0.0], [rng.uniform((x0, y0), (x1, y1))]
        while knot_t[-1] <= end:
            legs += 1
            if legs > MAX_LEGS:
                raise DataError(f"walk: {legs_needed}{MAX_LEGS} legs: wider bounds, longer "
                                f"pauses or earlier times")
            goal = rng.uniform((x0, y0), (x1, y1))
            arrive = knot_t[-1] + np.linalg.norm(goal - knot_xy[-1]) / rng.uniform(*speed)
            rest = rng.uniform(*pause)
            knot_t += [arrive, arrive + rest]
            knot_xy += [goal, goal]
        knot_t, knot_xy = np.asarray(knot_t), np.asarray(knot_xy)
        out[:, person, 0] = np.interp(times, knot_t, knot_xy[:, 0])
        out[:, person, 1] = np.interp(times, knot_t, knot_xy[:, 1])
    return out


def detect_people(rng: np.random.Generator, xy: np.ndarray, poses_true: np.ndarray,
                  poses_odom: np.ndarray, detector: PersonDetectorConfig
                  ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """One robot's person detections over every frame.

    Args:
        xy: (F, n, 2) the people's true positions in the world frame.
        poses_true: (F, 3) the robot's true body poses; poses_odom: (F, 3) its odometry poses.
    Returns:
        (frame (D,), xy (D, 2) in the odometry frame, person (D,), -1 false), sorted by frame,
        and in_view (F, n) bool: in the field of view and range.
    """
    n_frames = xy.shape[0]
    rel = transform_points_batch(invert(se2_from_params(poses_true))[:, None], xy)
    distance = np.hypot(rel[..., 0], rel[..., 1])
    half_fov = np.radians(detector.fov_deg) / 2
    in_view = ((distance >= detector.range_min) & (distance <= detector.range_max)
               & (np.abs(np.arctan2(rel[..., 1], rel[..., 0])) <= half_fov))
    seen = in_view & (rng.random(in_view.shape) < detector.p_detect)
    frame, person = np.nonzero(seen)
    sigma = detector.noise + detector.noise_per_m * distance[frame, person]
    body = rel[frame, person] + rng.normal(0.0, 1.0, (len(frame), 2)) * sigma[:, None]
    n_false = rng.poisson(detector.false_per_frame, n_frames)
    false_frame = np.repeat(np.arange(n_frames), n_false)
    # uniform over the area of the field of view, not over range: clutter is no denser near
    # the camera
    r = np.sqrt(rng.uniform(detector.range_min**2, detector.range_max**2, false_frame.size))
    a = rng.uniform(-half_fov, half_fov, false_frame.size)
    frame = np.r_[frame, false_frame]
    body = np.vstack([body, np.column_stack([r * np.cos(a), r * np.sin(a)])])
    person = np.r_[person, np.full(false_frame.size, -1)]
    order = np.argsort(frame, kind="stable")
    frame, body, person = frame[order], body[order], person[order]
    in_odom = transform_points_batch(se2_from_params(poses_odom[frame]), body)
    return (frame.astype(np.int64), in_odom, person.astype(np.int64)), in_view


def simulate_people(rng: np.random.Generator, config: PedestriansConfig, times: np.ndarray,
                    robot_paths: list[np.ndarray], poses_true: np.ndarray,
                    poses_odom: np.ndarray) -> PeopleRun:
    """The people of a run and every robot's detections.

    Args:
        times: (F,) seconds of the tracking frames.
        robot_paths: per robot, (m, 2) points of its true path, which bound where people walk.
        poses_true, poses_odom: (n_robots, F, 3) the robots' poses at `times`.
    """
    points = np.vstack(robot_paths)
    lo, hi = points.min(axis=0) - config.margin, points.max(axis=0) + config.margin
    xy = walk(rng, config.count, (*lo, *hi), config.speed, config.pause, times)
    detections, in_view = [], np.zeros(xy.shape[:2], dtype=bool)
    for robot in range(poses_true.shape[0]):
        found, seen = detect_people(rng, xy, poses_true[robot], poses_odom[robot],
                                    config.detector)
        detections.append(found)
        in_view |= seen
    return PeopleRun(times, xy, in_view, poses_true, poses_odom, detections)

