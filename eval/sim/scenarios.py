"""The simulated scenarios, after the paper's experiments.

Each builder turns a layout configuration into a `Scene`: the world and, per robot, the knots
(times, positions) of its true path. The simulator samples poses from the knots.

- indoor_return: two robots in a 10 x 10 m room of boxes; robot 1 leaves for another room full
  of boxes and comes back (the paper's leave-and-return experiment).
- same_direction / opposite_directions: two robots on an outdoor path lined with trees, poles,
  signs, cars, rocks and benches, driving the same way, or starting apart and crossing.
- room: several robots looping, sweeping and touring one room.
- grid: a regular grid of identical objects, which single-shot matching cannot disambiguate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import GridLayout, IndoorReturnLayout, PathLayout, RoomLayout, ScenarioConfig
from . import motion
from .world import World, along_path, combine, grid, room_walls, scatter

__all__ = ["Scene", "build_scene"]

Knots = tuple[np.ndarray, np.ndarray]

OUTDOOR = ("tree", "pole", "sign", "car", "rock", "bench", "bin")
INDOOR = ("box", "furniture", "bin")


@dataclass(frozen=True, eq=False)
class Scene:
    """A world and each robot's true path as knots: times (m,) [s], positions (m, 2) [m]."""

    world: World
    knots: list[Knots]


def _laps(seconds: float, radius: float, speed: float) -> float:
    return max(seconds, 0.0) * speed / (2 * np.pi * radius)


def _indoor_return(rng: np.random.Generator, lay: IndoorReturnLayout, duration: float
                   ) -> Scene:
    side = lay.room
    mid = side / 2
    away_x0 = side + 6.0
    home = scatter(rng, lay.boxes, (1.0, 1.0, side - 1, side - 1), ("box",), min_gap=1.2)
    # a similar-looking room: part of the home layout again, jittered, plus other boxes
    n_copy = min(round(lay.away_similarity * lay.away_boxes), lay.boxes)
    copied = rng.choice(lay.boxes, n_copy, replace=False)
    similar = World(home.xy[copied] + (away_x0, 0.0) + rng.normal(0.0, 0.3, (n_copy, 2)),
                    home.widths[copied] * rng.uniform(0.9, 1.1, n_copy),
                    home.heights[copied] * rng.uniform(0.9, 1.1, n_copy), home.kinds[copied])
    others = scatter(rng, lay.away_boxes - n_copy,
                     (away_x0 + 1, 1.0, away_x0 + side - 1, side - 1), ("box",), min_gap=1.2)
    away = combine(similar, others)
    walls = np.concatenate([room_walls(0, 0, side, side, door=(mid - 0.75, mid + 0.75)),
                            room_walls(away_x0, 0, away_x0 + side, side)[[0, 1, 3]]])
    world = combine(home, away, walls=walls)
    r0, r1 = 0.3 * side, 0.22 * side
    robot0 = motion.timed_waypoints(
        motion.loop((mid, mid), r0, _laps(duration, r0, lay.speed) + 0.1), lay.speed)
    first = motion.timed_waypoints(motion.loop(
        (mid, mid), r1, _laps(lay.leave_at, r1, lay.speed), np.pi, ccw=False), lay.speed)
    door, away_door = np.array([side, mid]), np.array([away_x0, mid])
    away_mid = np.array([away_x0 + mid, mid])
    away_start = away_mid + np.array([r1, 0.0])
    out = motion.then(first, [door, away_door, away_start], lay.speed)
    back_path = np.array([away_door, door, (mid + r1, mid)])
    back_time = (np.linalg.norm(back_path[0] - (away_start))
                 + np.sum(np.linalg.norm(np.diff(back_path, axis=0), axis=1))) / lay.speed
    stay = motion.then(out, motion.loop(away_mid, r1, _laps(
        lay.return_at - back_time - out[0][-1], r1, lay.speed))[1:], lay.speed)
    back = motion.then(stay, back_path, lay.speed)
    robot1 = motion.then(back, motion.loop((mid, mid), r1, _laps(
        duration - back[0][-1], r1, lay.speed) + 0.1)[1:], lay.speed)
    return Scene(world, [robot0, robot1])


def _path(length: float) -> np.ndarray:
    """(m, 2) a gently winding outdoor path of the given length (approximately)."""
    x = np.linspace(0.0, length, int(length / 2) + 1)
    return np.column_stack([x, 6.0 * np.sin(x / 25.0)])


def _arc(path: np.ndarray, s_from: float, s_to: float) -> np.ndarray:
    """(m, 2) the part of a polyline between arc lengths s_from and s_to (reversed if
    s_to < s_from)."""
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))]
    lo, hi = sorted((s_from, s_to))
    inner = (s > lo) & (s < hi)
    points = np.vstack([[np.interp(lo, s, path[:, 0]), np.interp(lo, s, path[:, 1])],
                        path[inner],
                        [np.interp(hi, s, path[:, 0]), np.interp(hi, s, path[:, 1])]])
    return points if s_to >= s_from else points[::-1]


def _outdoor(rng: np.random.Generator, lay: PathLayout, duration: float) -> Scene:
    path = _path(lay.length)
    world = along_path(rng, path, lay.objects_per_100m, lay.lateral, OUTDOOR)
    travel = lay.speed * duration
    if lay.kind == "same_direction":
        starts, ends = (lay.separation + 5, 5.0), (lay.separation + 5 + travel, 5 + travel)
    else:
        s0 = lay.length / 2 - lay.separation / 2
        starts, ends = (s0, s0 + lay.separation), (s0 + travel, s0 + lay.separation - travel)
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    ends = tuple(float(np.clip(e, 0.0, length)) for e in ends)
    knots = [motion.timed_waypoints(_arc(path, a, b), lay.speed) for a, b in zip(starts, ends,
                                                                                 strict=True)]
    return Scene(world, knots)


def _room(rng: np.random.Generator, lay: RoomLayout, duration: float) -> Scene:
    side, mid = lay.room, lay.room / 2
    world = combine(scatter(rng, lay.objects, (1.0, 1.0, side - 1, side - 1), INDOOR,
                            min_gap=1.2), walls=room_walls(0, 0, side, side))
    knots = []
    for r in range(lay.robots):
        kind = r % 3
        if kind == 0:  # loops around centres spread over the room
            angle = 2 * np.pi * r / lay.robots
            centre = mid + 0.18 * side * np.array([np.cos(angle), np.sin(angle)])
            radius = 0.22 * side
            way = motion.loop(centre, radius, _laps(duration, radius, lay.speed) + 0.1,
                              start_angle=angle, ccw=r % 2 == 0)
        elif kind == 1:  # a lawnmower sweep, back and forth
            sweep = motion.lawnmower((1.5, 1.5, side - 1.5, side - 1.5), 4, along_x=r % 2 == 1)
            way = np.vstack([sweep, sweep[::-1]] * 20)
        else:  # a tour of random waypoints
            way = rng.uniform(1.5, side - 1.5, (200, 2))
        knots.append(motion.timed_waypoints(way, lay.speed))
    return Scene(world, knots)


def _grid(rng: np.random.Generator, lay: GridLayout, duration: float) -> Scene:
    s = lay.spacing
    x1, y1 = (lay.cols - 1) * s, (lay.rows - 1) * s
    objects = grid(lay.rows, lay.cols, s, lay.size)
    keep = rng.permutation(len(objects)) >= round(lay.holes * len(objects))
    objects = World(objects.xy[keep], objects.widths[keep], objects.heights[keep],
                    objects.kinds[keep])
    ring = scatter(rng, lay.landmarks, (-s, -s, x1 + s, y1 + s), ("furniture", "bench", "sign"),
                   min_gap=1.5) if lay.landmarks else None
    world = combine(objects, *([ring] if ring is not None else []))
    sweep = motion.lawnmower((-0.5 * s, 0.5 * s, x1 + 0.5 * s, y1 - 0.5 * s), lay.rows - 1)
    forth = np.vstack([sweep, sweep[::-1]] * 20)
    if lay.formation == "abreast":
        other = forth + np.array([0.0, 0.5 * s])
    else:
        other = np.vstack([sweep[::-1], sweep] * 20)  # from where robot 0's first sweep ends
    knots = [motion.timed_waypoints(way, lay.speed) for way in (forth, other)]
    return Scene(world, knots)


def build_scene(config: ScenarioConfig, rng: np.random.Generator) -> Scene:
    """The world and true paths of a scenario; same config and generator state, same scene."""
    lay = config.layout
    if isinstance(lay, IndoorReturnLayout):
        return _indoor_return(rng, lay, config.duration)
    if isinstance(lay, PathLayout):
        return _outdoor(rng, lay, config.duration)
    if isinstance(lay, RoomLayout):
        return _room(rng, lay, config.duration)
    assert isinstance(lay, GridLayout)
    return _grid(rng, lay, config.duration)
