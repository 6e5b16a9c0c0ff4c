"""Recorded RGB-D sequences as robots: each robot walks a range of frames of a sequence (or a
whole sequence), its frames go through the real mapping front end, and its object maps are
exchanged at 1 Hz. The truth comes from the sequence's poses.

- **Odometry frames.** A robot's odometry frame is gravity aligned (z up, from the sequence's
  gravity direction) with its origin at the robot's first camera position and its x axis
  along that camera's horizontal viewing direction, as a VIO system would set it up. The
  front end maps the camera's poses (`T_body_camera` = identity): a hand-held camera tilts
  and rolls, and the front end takes its gravity from each frame's pose.
- **The run's frames.** A sequence's world frame need not be level (7-Scenes' is not), so
  the run's world is the level world: the first robot's sequence world turned by
  `level_rotation` of its gravity (sequences of one place share their world frame). The
  run's body is the level body: at the camera, z up, x along the horizontal part of the
  optical axis, so a body's planar pose is the camera's position and viewing heading.
- **Odometry.** `exact`: the sequence's poses. `vio`: the poses with VIO-like drift, as the
  MRCLAM loader draws it: the heading takes a random walk (after t minutes its error's std
  is `heading_rw_deg_per_sqrt_min` * sqrt(t) degrees) and every distance moved is scaled by
  (1 + e), e drawn once per robot with std `scale_std`; pitch and roll stay exact (a VIO
  system observes gravity).
- **Walks.** A robot's frames are those of its range at a chosen rate (at most the rate the
  folder holds); `there_and_back` walks them forward, then backward to the start, the time
  running on. Each robot's clock starts at 0 at its first frame; exchanges are at 1, 2, ...
  seconds, while every robot still walks.
- **Overlap.** Two maps overlap at an exchange when at least `min_shared` of their objects
  match under the truth (mutual nearest neighbours in the plane within `match_radius`):
  an alignment is possible only then.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se3_to_se2
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.registration import mutual_inliers

from ..runs import RecordedRun, RunSettings
from .rgbd_sequence import RgbdSequence

__all__ = ["Walk", "halves", "level_body", "level_rotation", "load_run", "map_walk",
           "odometry", "walk"]

_DOWN = np.array([0.0, 0.0, -1.0])  # gravity in a level frame (z up)


@dataclass(frozen=True, eq=False)
class Walk:
    """The frames one robot sees, in order.

    Attributes:
        sequence: the recorded sequence.
        positions: (k,) int, the frames (positions in `sequence`, each with truth).
        times: (k,) s on the robot's clock (0 at its first frame), increasing.
        label: the robot's name, e.g. "redkitchen[0:500]".
        start, stop: the frame-id range [start, stop) asked for (None: open).
        rate: Hz asked for (None: every frame the folder holds).
        there_and_back: walked forward, then back to the start.
    """

    sequence: RgbdSequence
    positions: np.ndarray
    times: np.ndarray
    label: str
    start: int | None = None
    stop: int | None = None
    rate: float | None = None
    there_and_back: bool = False

    @property
    def duration(self) -> float:
        return float(self.times[-1]) if self.times.size else 0.0


def walk(sequence: RgbdSequence, start: int | None = None, stop: int | None = None,
         rate: float | None = None, there_and_back: bool = False) -> Walk:
    """The frames of a sequence whose frame ids lie in [start, stop), with truth, at most
    `rate` Hz (None: every frame the folder holds), walked forward (and back).

    Raises:
        DataError: no frame with truth in the range, fewer than two frames, or a rate the
            folder cannot give (higher than the rate of its frames).
    """
    ids = sequence.frame_ids
    in_range = np.ones(ids.size, dtype=bool)
    if start is not None:
        in_range &= ids >= start
    if stop is not None:
        in_range &= ids < stop
    span = f"[{'' if start is None else start}:{'' if stop is None else stop}]"
    label = f"{sequence.name}{span}"
    truth = np.all(np.isfinite(sequence.T_world_camera.reshape(len(ids), -1)), axis=1)
    positions = np.flatnonzero(in_range & truth)
    if positions.size < 2:
        raise DataError(f"{label}: {positions.size} frames with ground truth in the range; a "
                        f"robot needs two or more (the sequence's frame ids run from "
                        f"{ids.min()} to {ids.max()})")
    times = sequence.times[positions]
    held = 1.0 / float(np.median(np.diff(times)))
    if rate is not None:
        if not (math.isfinite(rate) and rate > 0):
            raise DataError(f"rate = {rate!r}: must be a finite number > 0 Hz")
        if rate > held * 1.01:
            raise DataError(f"rate = {rate:g} Hz: {sequence.folder} holds frames at "
                            f"{held:.3g} Hz in this range, not more")
        # the first frame, then each frame at least one period after the last one kept
        kept = [0]
        for k in range(1, times.size):
            if times[k] - times[kept[-1]] >= 1.0 / rate - 1e-9:
                kept.append(k)
        positions, times = positions[kept], times[kept]
    times = times - times[0]
    if there_and_back:
        back = positions[-2::-1]
        back_times = 2.0 * times[-1] - times[-2::-1]
        positions = np.concatenate([positions, back])
        times = np.concatenate([times, back_times])
        label += " there and back"
    return Walk(sequence, positions, times, label, start, stop, rate, there_and_back)


def halves(frame_ids: np.ndarray) -> list[tuple[int, int]]:
    """The frame-id ranges [start, stop) of the first and second half of a sequence's frame
    ids (k,) (increasing), as two robots' ranges: the default split of one sequence."""
    middle = int(frame_ids[len(frame_ids) // 2])
    return [(int(frame_ids[0]), middle), (middle, int(frame_ids[-1]) + 1)]


def level_rotation(gravity: np.ndarray) -> np.ndarray:
    """(3, 3) R_level_world: the smallest rotation taking the world's gravity direction
    (3,), of any nonzero finite length, to -z. Gravity along +z (a world upside down) has no
    smallest: a half turn about y.

    Raises:
        DataError: gravity not three finite numbers, not all zero.
    """
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or not np.any(g):
        raise DataError(f"level_rotation: gravity must be 3 finite numbers, not all zero, "
                        f"got {gravity!r}")
    g = g / np.max(np.abs(g))  # so that the norm cannot overflow
    if math.hypot(g[0], g[1]) < 1e-100:
        # along z to double precision: scipy's turn loses precision when the cross product
        # with -z underflows (a tilt of 1e-158 from +z moves -z by 3e-8)
        g = np.array([0.0, 0.0, g[2]])
    rotation, _ = Rotation.align_vectors(_DOWN[None], (g / np.linalg.norm(g))[None])
    return rotation.as_matrix()


def _yaw(R: np.ndarray) -> np.ndarray:
    """(...,) the heading of the horizontal part of a camera's optical axis (its z column)."""
    return np.arctan2(R[..., 1, 2], R[..., 0, 2])


def level_body(T_frame_camera: np.ndarray) -> np.ndarray:
    """(..., 4, 4) the level body of (..., 4, 4) camera poses (optical frame: x right, y down,
    z forward) in a gravity-aligned (z up) frame: at the camera, turned about z only, x along
    the horizontal part of the optical axis (heading 0 for a camera looking straight up or
    down, which has none)."""
    T = np.asarray(T_frame_camera, dtype=float)
    out = np.zeros_like(T)
    out[..., :3, :3] = _rz(_yaw(T[..., :3, :3]))
    out[..., :3, 3] = T[..., :3, 3]
    out[..., 3, 3] = 1.0
    return out


def _rz(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((*np.shape(angle), 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    return out


def odometry(T_world_camera: np.ndarray, times: np.ndarray, gravity: np.ndarray, kind: str,
             rng: np.random.Generator | None = None, heading_rw_deg_per_sqrt_min: float = 1.0,
             scale_std: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """A walking camera's odometry.

    Args:
        T_world_camera: (k, 4, 4) the true camera poses in the sequence's world frame.
        times: (k,) s, increasing.
        gravity: (3,) gravity's direction in the world frame.
        kind: "exact" or "vio" (see the module's notes; rng draws the drift).
    Returns:
        T_odom_camera (k, 4, 4), the camera in the robot's gravity-aligned odometry frame,
        and T_world_odom (k, 4, 4), that frame in the world as the truth places it at each
        frame (constant for exact odometry; drifting for vio).
    """
    T_level_world = np.eye(4)
    T_level_world[:3, :3] = level_rotation(gravity)
    T_level_camera = T_level_world @ T_world_camera
    first = T_level_camera[0]
    T_level_odom = np.eye(4)
    T_level_odom[:3, :3] = _rz(_yaw(first[:3, :3]))
    T_level_odom[:3, 3] = first[:3, 3]
    truth = invert(T_level_odom) @ T_level_camera
    if kind == "exact":
        T_odom_camera = truth
    elif kind == "vio":
        if rng is None:
            raise DataError("odometry: vio needs a random generator (seed)")
        dt = np.diff(times)
        sigma = math.radians(heading_rw_deg_per_sqrt_min) / math.sqrt(60.0)
        drift = np.r_[0.0, np.cumsum(sigma * np.sqrt(dt) * rng.standard_normal(dt.size))]
        scale = 1.0 + scale_std * rng.standard_normal()
        steps = np.diff(truth[:, :3, 3], axis=0)
        # each step is taken with the heading error of its start, and scaled
        moved = scale * np.einsum("kij,kj->ki", _rz(drift[:-1]), steps)
        T_odom_camera = truth.copy()
        T_odom_camera[:, :3, 3] = np.vstack([truth[:1, :3, 3],
                                             truth[0, :3, 3] + np.cumsum(moved, axis=0)])
        T_odom_camera[:, :3, :3] = _rz(drift) @ truth[:, :3, :3]
    else:
        raise DataError(f"odometry: expected 'exact' or 'vio', got {kind!r}")
    T_world_level = invert(T_level_world)
    T_world_odom = T_world_level @ T_level_camera @ invert(T_odom_camera)
    return T_odom_camera, T_world_odom


def map_walk(route: Walk, T_odom_camera: np.ndarray, exchanges: np.ndarray,
             mapper_params: MapperParams | None = None,
             progress: Callable[[float], None] | None = None
             ) -> tuple[list[ObjectMap], np.ndarray]:
    """A robot's maps: every frame of its walk through `RgbdFrontEnd`, the map taken at each
    exchange (s on the robot's clock) after the frames up to it.

    Returns:
        maps (one per exchange) and (k, 5) seconds per frame of the front end's stages
        (register, segment, filter, lift, track), for the k frames mapped (those up to the
        last exchange).
    """
    seq = route.sequence
    front = RgbdFrontEnd(seq.camera, np.eye(4), depth_scale=seq.depth_scale,
                         mapper_params=mapper_params)
    maps: list[ObjectMap] = []
    seconds = np.zeros((route.positions.size, 5))
    stages = ("register", "segment", "filter", "lift", "track")
    s = 0
    for k, (position, t) in enumerate(zip(route.positions, route.times, strict=True)):
        while s < exchanges.size and exchanges[s] < t:
            maps.append(front.object_map())
            s += 1
        if s == exchanges.size:
            break
        rgb, depth = seq.read(int(position))
        result = front.process(float(t), rgb, depth, T_odom_camera[k])
        seconds[k] = [result.seconds[name] for name in stages]
        if progress is not None:
            progress((k + 1) / route.positions.size)
    while s < exchanges.size:
        maps.append(front.object_map())
        s += 1
    mapped = int(np.count_nonzero(route.times <= exchanges[-1])) if exchanges.size else 0
    return maps, seconds[:mapped]


def overlap(maps_i: list[ObjectMap], maps_j: list[ObjectMap], T_oi_oj: np.ndarray,
            min_shared: int, match_radius: float) -> np.ndarray:
    """(S,) bool: the maps of an exchange share at least `min_shared` objects under the true
    T_oi_oj ((S, 3, 3) SE(2)): mutual nearest neighbours within `match_radius` in the plane."""
    out = np.zeros(len(maps_i), dtype=bool)
    for s, (a, b) in enumerate(zip(maps_i, maps_j, strict=True)):
        if min(len(a), len(b)) < min_shared:
            continue
        pairs = mutual_inliers(T_oi_oj[s], a.centroids[:, :2], b.centroids[:, :2],
                               np.ones((len(a), len(b)), dtype=bool), match_radius)
        out[s] = pairs.shape[0] >= min_shared
    return out


def load_run(walks: list[Walk], kind: str, seed: int | None, kappa: float,
             mapper_params: MapperParams | None = None, min_shared: int = 5,
             match_radius: float = 0.3, heading_rw_deg_per_sqrt_min: float = 1.0,
             scale_std: float = 0.01, window: int | None = None,
             graph_drift: tuple[float, float] | None = None, name: str = "rgbd",
             progress: Callable[[int, float], None] | None = None
             ) -> tuple[RecordedRun, list[np.ndarray]]:
    """The robots' maps at 1 Hz exchanges as a recorded run.

    Args:
        walks: one per robot (two or more).
        kind: "exact" or "vio"; seed draws the drift of vio (a generator per robot).
        kappa: s; the front end's maps hold objects seen this recently (`MapperParams.kappa`).
        progress: called with the robot's index and its share mapped.
    Returns:
        The run, in the level world with level bodies (see the module's notes): its
        T_world_odom (n, S, 4, 4) places each odometry frame in the level world, its
        T_odom_body (n, S, 4, 4) each level body in its odometry frame. And per robot the
        front end's seconds per frame and stage (k, 5).
    Raises:
        DataError: fewer than two robots, a walk shorter than one second, vio without a seed.
    """
    if len(walks) < 2:
        raise DataError(f"robots: need two or more, got {len(walks)}")
    if kind == "vio" and seed is None:
        raise DataError("seed: VIO-like odometry needs a seed")
    end = min(w.duration for w in walks)
    exchanges = np.arange(1.0, math.floor(end) + 1.0)
    if exchanges.size == 0:
        raise DataError(f"robots: the shortest walk lasts {end:.2f} s; maps are exchanged "
                        "once per second")
    mapper_params = MapperParams(kappa=kappa) if mapper_params is None else mapper_params
    maps, seconds, T_world_odom, T_odom_body = [], [], [], []
    # sequences of one place share their world frame, and so their gravity
    down = np.asarray(walks[0].sequence.gravity, float)
    for w in walks[1:]:
        other = np.asarray(w.sequence.gravity, float)
        angle = math.degrees(math.acos(np.clip(down @ other / np.linalg.norm(down)
                                               / np.linalg.norm(other), -1.0, 1.0)))
        if angle > 0.5:
            raise DataError(f"robots: {w.label}'s gravity {other.tolist()} is {angle:.1f} deg "
                            f"from {walks[0].label}'s {down.tolist()}; sequences of one "
                            "place share their world frame")
    T_level_world = np.eye(4)
    T_level_world[:3, :3] = level_rotation(down)
    for r, route in enumerate(walks):
        seq = route.sequence
        rng = None if seed is None else np.random.default_rng([seed, r])
        T_oc, T_wo = odometry(seq.T_world_camera[route.positions], route.times, seq.gravity,
                              kind, rng, heading_rw_deg_per_sqrt_min, scale_std)
        robot_maps, robot_seconds = map_walk(
            route, T_oc, exchanges, mapper_params,
            None if progress is None else (lambda share, r=r: progress(r, share)))
        maps.append(robot_maps)
        seconds.append(robot_seconds)
        # the poses at the exchanges: the last frame at or before each
        at = np.searchsorted(route.times, exchanges, side="right") - 1
        T_world_odom.append(T_level_world @ T_wo[at])
        T_odom_body.append(level_body(T_oc[at]))
    T_world_odom, T_odom_body = np.array(T_world_odom), np.array(T_odom_body)
    n = len(walks)
    shared = np.zeros((n, n, exchanges.size), dtype=bool)
    for i in range(n):
        for j in range(n):
            if i != j:
                T_true = se3_to_se2(invert(T_world_odom[i]) @ T_world_odom[j])
                shared[i, j] = overlap(maps[i], maps[j], T_true, min_shared, match_radius)
    run = RecordedRun(name, RunSettings(kappa, window, graph_drift), exchanges, maps,
                      T_world_odom, T_odom_body, shared, tuple(w.label for w in walks))
    return run, seconds
