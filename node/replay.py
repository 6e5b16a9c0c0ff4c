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

from tcaff_gtsam.aligner_params import _kappa
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.filter_params import MAX_WINDOW
from tcaff_gtsam.inputs import read_npz, shown
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.param_checks import MAX_SECONDS, _count
from tcaff_gtsam.params import _int_at_least, _require

from .link import check_name

__all__ = ["MAX_TEAM", "RobotReplay", "replay", "robot_names", "run_replay"]

#: the most robots a team run on one machine has (`TeamConsistency.MAX_ROBOTS`): each robot's
#: node holds a port of its own (`run.free_ports`)
MAX_TEAM = 1024
#: the arrays of a saved replay besides its objects', and its objects' (`ObjectMap`'s order)
_REPLAY_ARRAYS = ("robots", "robot", "times", "sizes", "kappa", "window")
_OBJECT_ARRAYS = ("centroids", "widths", "heights", "last_seen")


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
        """Write the replay to an npz archive at exactly `path`.

        Raises:
            DataError: a replay without exchanges (`load` refuses one: nothing to replay).
        """
        if not self.maps:
            raise DataError(f"{path}: a robot replay needs at least one exchange, got none")
        sizes = np.array([len(m) for m in self.maps], dtype=np.int64)
        fields = {name: np.concatenate([getattr(m, name) for m in self.maps])
                  for name in _OBJECT_ARRAYS}
        with open(Path(path), "wb") as file:
            np.savez(file, robots=np.array(self.robots), robot=self.robot, times=self.times,
                     sizes=sizes, kappa=self.kappa, window=-1 if self.window is None
                     else self.window, **fields)

    @classmethod
    def load(cls, path: str | Path) -> RobotReplay:
        """Read a replay written by `save`.

        Raises:
            DataError: the file is missing, corrupt or not a replay, naming the file and the
                field: robots not 2 to MAX_TEAM distinct robot names; robot not an int index
                of them; times not finite increasing numbers, at least one, one per map,
                spanning at most a year (`MAX_SECONDS`); sizes not ints >= 0 that share out
                the objects' arrays exactly; a map no ObjectMap holds; kappa or window outside
                what the node's aligner and TCAFF take (kappa > 0 s and at most a year, or
                inf; window an int in 1..MAX_WINDOW, or -1 for the preset's). Numbers stored
                as text are refused, not parsed.
        """
        data = read_npz(path, "robot replay")
        missing = [name for name in (*_REPLAY_ARRAYS, *_OBJECT_ARRAYS) if name not in data]
        if missing:
            raise DataError(f"{path}: not a robot replay (no {', '.join(missing)})")

        def refuse(name: str, rule: str) -> DataError:
            return DataError(f"{path}: not a robot replay: {name} = {shown(data[name])} {rule}")

        def field(check, name: str, *args, **kwargs):
            """The scalar `name`, checked as `check` (a parameter check) checks a setting."""
            value = data[name].item() if data[name].ndim == 0 else data[name]
            try:
                check("RobotReplay", name, value, *args, **kwargs)
            except ConfigError as exc:
                raise DataError(f"{path}: not a robot replay ({exc})") from None
            return value

        robots = data["robots"]
        if robots.dtype.kind != "U" or robots.ndim != 1 or not 2 <= len(robots) <= MAX_TEAM:
            raise refuse("robots", f"must be 2 to {MAX_TEAM} (MAX_TEAM) robot names")
        names = tuple(str(r) for r in robots)
        try:
            for name in names:
                check_name("robot name", name)
        except ConfigError as exc:
            raise DataError(f"{path}: not a robot replay: robots holds {exc}") from None
        if len(set(names)) != len(names):
            raise refuse("robots", "must be distinct names")
        robot = field(_count, "robot", 0, len(names) - 1)
        kappa = field(_kappa, "kappa")  # the node's aligner's
        stored = data["window"]
        preset = stored.shape == () and stored.dtype.kind in "iu" and stored == -1  # None
        window = None if preset else field(_count, "window", 1, MAX_WINDOW, "MAX_WINDOW")

        centroids = data["centroids"]
        if centroids.ndim != 2 or centroids.shape[1] != 3:
            raise refuse("centroids", "must have shape (n, 3), one row per object")
        n = len(centroids)
        for name in _OBJECT_ARRAYS[1:]:
            if data[name].shape != (n,):
                raise refuse(name, f"must have shape ({n},), one per object")
        sizes, times = data["sizes"], data["times"]
        # each size at most n: their sum cannot wrap around
        if sizes.dtype.kind not in "iu" or sizes.ndim != 1 or np.any((sizes < 0) | (sizes > n)) \
                or sizes.sum() != n:
            raise refuse("sizes", f"must be one int >= 0 per map, the objects of each, "
                                  f"summing to the {n} objects stored")
        # checked here, not when the first exchange is due after the team is awaited
        seconds = times.astype(float) if times.dtype.kind in "iuf" else times
        # as floats: a span of int64 times can wrap around
        if (times.dtype.kind not in "iuf" or times.shape != sizes.shape or not len(times)
                or not np.all(np.isfinite(seconds)) or np.any(np.diff(seconds) <= 0)
                or seconds[-1] - seconds[0] > MAX_SECONDS):  # a schedule the clock can wait for
            raise refuse("times", f"(its {times.size} times must be finite and increasing, "
                                  f"one per map ({len(sizes)}), at least one, spanning at "
                                  f"most a year, MAX_SECONDS)")
        cuts = np.cumsum(sizes)[:-1]
        parts = {name: np.split(data[name], cuts) for name in _OBJECT_ARRAYS}
        maps = []
        for k in range(len(sizes)):
            try:
                maps.append(ObjectMap(*(parts[name][k] for name in _OBJECT_ARRAYS)))
            except DataError as exc:
                raise DataError(f"{path}: not a robot replay: map {k}: {exc}") from None
        return cls(names, int(robot), seconds, maps,
                   float(kappa), None if window is None else int(window))


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
