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
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.inputs import read_npz
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import _int_at_least, _require

__all__ = ["MAX_TEAM", "RobotReplay", "replay", "robot_names", "run_replay"]

#: the most robots a team run on one machine has (`TeamConsistency.MAX_ROBOTS`): each robot's
#: node holds a port of its own (`run.free_ports`)
MAX_TEAM = 1024


@dataclass(frozen=True, eq=False)
class RobotReplay:
    """One robot's maps of a run (a simulated one, or a recorded data set's).

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

    def save(self, path: str | Path) -> None:
        """Write the replay to an npz archive at exactly `path`."""
        sizes = np.array([len(m) for m in self.maps], dtype=np.int64)
        fields = {name: np.concatenate([getattr(m, name) for m in self.maps]) if self.maps
                  else np.zeros(0) for name in ("centroids", "widths", "heights", "last_seen")}
        with open(Path(path), "wb") as file:
            np.savez(file, robots=np.array(self.robots), robot=self.robot, times=self.times,
                     sizes=sizes, kappa=self.kappa, window=-1 if self.window is None
                     else self.window, **fields)

    @classmethod
    def load(cls, path: str | Path) -> RobotReplay:
        """Read a replay written by `save`.

        Raises:
            DataError: the file is missing, corrupt or not a replay.
        """
        data = read_npz(path, "robot replay")
        try:
            sizes = data["sizes"].astype(np.int64)
            cuts = np.cumsum(sizes)[:-1]
            parts = {name: np.split(data[name].reshape(-1, 3) if name == "centroids"
                                    else data[name], cuts)
                     for name in ("centroids", "widths", "heights", "last_seen")}
            maps = [ObjectMap(*(parts[name][k] for name in
                                ("centroids", "widths", "heights", "last_seen")))
                    for k in range(len(sizes))]
            window = int(data["window"])
            times = data["times"].astype(float)
            # checked here, not when the first exchange is due after the team is awaited
            if (times.shape != (len(maps),) or not np.all(np.isfinite(times))
                    or np.any(np.diff(times) <= 0)):
                raise ValueError(f"its {times.size} times must be finite and increasing, one "
                                 f"per map ({len(maps)})")
            return cls(tuple(str(r) for r in data["robots"]), int(data["robot"]), times, maps,
                       float(data["kappa"]), None if window < 0 else window)
        except (KeyError, ValueError, TypeError) as exc:
            raise DataError(f"{path}: not a robot replay ({exc})") from None


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
    """The names robots of a run get in a team: r0, r1, ..., r(n - 1).

    Raises:
        ConfigError: n not an int in [0, MAX_TEAM].
    """
    _require(_int_at_least(n, 0) and n <= MAX_TEAM, "robot_names", "n", n,
             f"must be an int in [0, {MAX_TEAM}] (MAX_TEAM)")
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
    due = start + (source.times - source.times[0]) / speed
    # joined or restarted mid-run: begin at the exchange due now; later ones are never skipped
    first = int(np.searchsorted(due, time.time() - 0.5 / speed))
    done = 0
    for k in range(first, len(due)):
        t, object_map = source.times[k], source.maps[k]
        wait = due[k] - time.time()
        # asked also when behind the schedule (a publish that waited on a full queue):
        # otherwise a stopped replay would publish every exchange left
        if stop.is_set() or (wait > 0 and stop.wait(wait)):
            break
        if clock_offset:
            object_map = ObjectMap(object_map.centroids, object_map.widths, object_map.heights,
                                   object_map.last_seen + clock_offset)
        publish(float(t) + clock_offset, object_map, k)
        done += 1
        if progress is not None:
            progress(k + 1, len(source.times))
    return done
