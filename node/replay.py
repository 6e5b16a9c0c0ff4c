"""Replay sources: one robot's maps of a run, fed to its node on a wall-clock schedule.

Exchange k of a run is published at `start + (times[k] - times[0]) / speed` (wall seconds, the
epoch clock every process of this machine shares). A node started late or restarted mid-run
joins at the exchange the schedule has reached, as a robot switched on again would.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.object_map import ObjectMap

__all__ = ["RobotReplay", "replay", "robot_names", "run_replay"]


@dataclass(frozen=True, eq=False)
class RobotReplay:
    """One robot's maps of a run.

    Attributes:
        robots: the names of every robot of the run (the team); robot: this one's index.
        times: (S,) s, the exchanges on the run's clock.
        maps: (S,) this robot's map at each exchange, in its odometry frame.
        kappa: s, the run's mapping window.
        window: the run's TCAFF window W (None: the preset's).
    """

    robots: tuple[str, ...]
    robot: int
    times: np.ndarray
    maps: list[ObjectMap]
    kappa: float
    window: int | None = None


def run_replay(run, robot: int, names: tuple[str, ...] | None = None) -> RobotReplay:
    """Robot `robot` of an `AlignmentRun` (a simulated or recorded run).

    Raises:
        ConfigError: robot is not an index of the run's robots.
    """
    n = run.n_robots
    if not 0 <= robot < n:
        raise ConfigError(f"--robot {robot}: the run has robots 0..{n - 1}")
    names = names or robot_names(n)
    return RobotReplay(names, robot, np.asarray(run.times, dtype=float), list(run.maps[robot]),
                       run.settings.kappa, run.settings.window)


def robot_names(n: int) -> tuple[str, ...]:
    """The names robots of a run get in a team: r0, r1, ..."""
    return tuple(f"r{i}" for i in range(n))


def replay(source: RobotReplay, publish: Callable[[float, ObjectMap, int], None], start: float,
           speed: float, clock_offset: float = 0.0, stop: threading.Event | None = None,
           progress: Callable[[int, int], None] | None = None) -> int:
    """Publish each exchange of `source` at its time on the schedule; skip the ones past.

    Args:
        publish: called as publish(t, map, k) with t and the map's `last_seen` shifted by
            `clock_offset` (s: this robot's clock against the run's).
        start: wall time (epoch s) of the first exchange; speed: run seconds per wall second.
        stop: set to end early.
        progress: called with (exchanges published, exchanges in the run).
    Returns:
        The number of exchanges published.
    """
    stop = stop or threading.Event()
    offsets = (source.times - source.times[0]) / speed
    done = 0
    for k, (t, object_map) in enumerate(zip(source.times, source.maps, strict=True)):
        wait = start + offsets[k] - time.time()
        if wait < -0.5 / speed:
            continue  # this exchange is past: joined or restarted mid-run
        if wait > 0 and stop.wait(wait):
            break
        if clock_offset:
            object_map = ObjectMap(object_map.centroids, object_map.widths, object_map.heights,
                                   object_map.last_seen + clock_offset)
        publish(float(t) + clock_offset, object_map, k)
        done += 1
        if progress is not None:
            progress(k + 1, len(source.times))
    return done
