"""Run a scenario: robots drive, detect objects, map them, and publish their maps at 1 Hz.

Each robot detects objects at the mapping frame rate in its drifting odometry frame and tracks
them with the real `ObjectMapper` (confirmed after nu sightings, dropped after kappa s unseen).
Detections come from the object-level sensor model, or, when the scenario has a camera, from
rendered RGB-D frames mapped by the real front end (segmentation, lifting, tracking).
Once per second every robot's map is recorded, along with which world object each map entry
really is, so that the truth of every alignment and of every map overlap is known.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tcaff_gtsam.mapping.mapper import MapperParams, ObjectMapper

from tcaff_gtsam.geometry import invert
from tcaff_gtsam.object_map import ObjectMap

from ..config import ScenarioConfig
from ..runs import RunSettings
from .motion import drifting_odometry, odometry_frame, poses_along
from .people import PeopleRun, simulate_people
from .scenarios import build_scene
from .sensor import observe
from .world import World

__all__ = ["SimRun", "simulate"]


@dataclass(frozen=True, eq=False)
class SimRun:
    """A simulated run, sampled at the 1 Hz map exchanges.

    Attributes:
        scenario: the configuration that made it; seed: its random seed.
        times: (S,) seconds of the exchanges.
        poses_true: (n_robots, S, 3) true body poses (x, y, theta) in the world frame.
        poses_odom: (n_robots, S, 3) body poses in each robot's own odometry frame.
        maps: maps[r][s], robot r's map at exchange s, in its odometry frame.
        labels: labels[r][s] (len(maps[r][s]),) int, the world object of each map entry
            (-1: built from false segments).
        world: the objects.
        people: the walking people and every robot's detections of them (None: the scenario
            has no pedestrians).
    """

    scenario: ScenarioConfig
    seed: int
    times: np.ndarray
    poses_true: np.ndarray
    poses_odom: np.ndarray
    maps: list[list[ObjectMap]]
    labels: list[list[np.ndarray]]
    world: World
    people: PeopleRun | None = None

    #: every directed pair of robots is aligned
    pairs = None

    @property
    def n_robots(self) -> int:
        return self.poses_true.shape[0]

    @property
    def settings(self) -> RunSettings:
        s = self.scenario
        return RunSettings(s.mapping.kappa, s.window, s.graph_drift)

    def T_w_o(self, robot: int) -> np.ndarray:
        """(S, 3, 3) robot's odometry frame in the world frame: T_w_b T_o_b^-1."""
        return odometry_frame(self.poses_true[robot], self.poses_odom[robot])

    def T_true(self, i: int, j: int) -> np.ndarray:
        """(S, 3, 3) the true T_oi_oj at each exchange."""
        return invert(self.T_w_o(i)) @ self.T_w_o(j)

    def overlap(self, i: int, j: int) -> np.ndarray:
        """(S,) bool: the two maps' objects seen within kappa share at least `min_shared` world
        objects, so a correct alignment can be found."""
        kappa, need = self.scenario.mapping.kappa, self.scenario.min_shared
        out = np.zeros(len(self.times), dtype=bool)
        for s, t in enumerate(self.times):
            a = self.labels[i][s][self.maps[i][s].recent_indices(t, kappa)]
            b = self.labels[j][s][self.maps[j][s].recent_indices(t, kappa)]
            out[s] = np.intersect1d(a[a >= 0], b[b >= 0]).size >= need
        return out


def simulate(config: ScenarioConfig, seed: int,
             progress: Callable[[float], None] | None = None) -> SimRun:
    """Simulate a scenario; the same config and seed give the same run.

    Args:
        progress: called with the share of robots done, in (0, 1].
    """
    rng = np.random.default_rng(seed)
    scene = build_scene(config, rng)
    dt = 1.0 / config.mapping.frame_rate
    frame_times = dt * np.arange(1, round(config.duration / dt) + 1)
    exchange_times = np.arange(1.0, np.floor(config.duration) + 1.0)
    # the last frame at or before each exchange
    exchange_frames = np.searchsorted(frame_times, exchange_times + 1e-9) - 1
    mapper_params = MapperParams(nu=config.mapping.nu, kappa=config.mapping.kappa)
    n = config.n_robots
    world = scene.world
    rendered = None
    if config.camera is not None:
        # Open3D, the renderer and the front end: 0.8 s of a worker's start that renders none
        from .render import RgbdScene
        from .rgbd import RenderedCamera, clear_paths

        paths = [poses_along(*knots, frame_times) for knots in scene.knots]
        world = clear_paths(rng, world, paths, config.camera.clearance)
        rendered = RgbdScene.from_world(world)
    poses_true = np.zeros((n, len(exchange_times), 3))
    poses_odom = np.zeros_like(poses_true)
    maps: list[list[ObjectMap]] = []
    labels: list[list[np.ndarray]] = []
    walkers = config.pedestrians
    people_frames = np.zeros(0, dtype=np.int64)  # the frames people are detected at
    if walkers is not None:
        every = round(config.mapping.frame_rate / walkers.rate)
        people_frames = np.arange(every - 1, len(frame_times), every)
    driven, people_true, people_odom = [], [], []
    for robot in range(n):
        drift = config.drift(robot)
        true = poses_along(*scene.knots[robot], np.r_[0.0, frame_times])
        odom = drifting_odometry(rng, true, dt, np.radians(drift.heading_rw_deg),
                                 drift.position_rw)[1:]
        true = true[1:]
        driven.append(true[:, :2])
        people_true.append(true[people_frames])
        people_odom.append(odom[people_frames])
        if rendered is None:
            mapper = ObjectMapper(mapper_params)
        else:
            camera = RenderedCamera(rendered, config.camera, mapper_params)
            mapper = camera.front_end.mapper
        votes: dict[int, Counter] = {}
        robot_maps, robot_labels = [], []
        next_exchange = 0
        for f, t in enumerate(frame_times):
            if rendered is None:
                centroids, widths, heights, seen = observe(rng, world, true[f], odom[f],
                                                           config.sensor)
                tracks = mapper.update(t, centroids, widths, heights)
            else:
                tracks, seen = camera.step(rng, t, true[f], odom[f])
            for track, label in zip(tracks.tolist(), seen.tolist(), strict=True):
                votes.setdefault(track, Counter())[label] += 1
            while next_exchange < len(exchange_frames) and exchange_frames[next_exchange] == f:
                robot_maps.append(mapper.object_map())
                robot_labels.append(np.array([votes[k].most_common(1)[0][0]
                                              for k in mapper.confirmed_ids().tolist()],
                                             dtype=np.int64))
                next_exchange += 1
        poses_true[robot] = true[exchange_frames]
        poses_odom[robot] = odom[exchange_frames]
        maps.append(robot_maps)
        labels.append(robot_labels)
        if progress is not None:
            progress((robot + 1) / n)
    people = None
    if walkers is not None:
        # a generator of its own, so that adding people leaves the robots' maps unchanged
        people = simulate_people(np.random.default_rng([seed, 1]), walkers,
                                 frame_times[people_frames], driven, np.array(people_true),
                                 np.array(people_odom))
    return SimRun(config, seed, exchange_times, poses_true, poses_odom, maps, labels, world,
                  people)
