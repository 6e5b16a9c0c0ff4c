"""A team run as a ROS 2 bag (rosbag2, MCAP storage) with the standard messages of `node.ros2`,
so that `ros2 bag play`, Foxglove and RViz show it: each robot's shared maps, its node's
accepted alignments and team alignments, and the true alignments where the run knows them.

Topics (names as in `node.ros2`; every message stamped, and logged, at its exchange's time):
    /<robot>/tcaff/map                        visualization_msgs/msg/MarkerArray
    /<robot>/tcaff/alignment/<neighbour>      geometry_msgs/msg/PoseWithCovarianceStamped
    /<robot>/tcaff/team_alignment/<other>     the same type (a team run with team consistency)
    /<robot>/tcaff/truth/<neighbour>          the same type, covariance zero
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError

from .results import COLUMNS, TEAM_COLUMNS, read_alignments, row_covariance
from .ros2 import (
    ALIGNMENT_TYPE,
    MAP_TYPE,
    _store,
    alignment_topic,
    check_ros_name,
    map_message,
    map_topic,
    pose_message,
    serialize,
    team_topic,
)

__all__ = ["truth_topic", "write_bag", "write_team_bag"]

log = logging.getLogger(__name__)


def truth_topic(robot: str, neighbour: str) -> str:
    return f"/{robot}/tcaff/truth/{neighbour}"


def ns(t: float) -> int:
    """A bag's time stamp (ns) of `t` s.

    Raises:
        DataError: t not finite or before 0 s (the epoch).
    """
    if not np.isfinite(t) or t < 0:
        raise DataError(f"a bag's time stamps are ns >= 0 since the epoch; got {t!r} s")
    return round(float(t) * 1e9)


def write_team_bag(bag: str | Path, run, names: tuple[str, ...], results: str | Path | None = None
                   ) -> dict[str, int]:
    """Write `run`'s maps, the alignments its nodes wrote under `results` (<robot>.csv and,
    with team consistency, <robot>.team.csv) and its true alignments to a new rosbag2 folder
    `bag` (MCAP storage).

    Args:
        run: an `AlignmentRun` (maps at the exchanges, `T_true`, `settings.kappa`).
        names: the robots' names, in the run's order (ROS 2 name tokens).
        results: the team's output folder; None: maps and truth only.
    Returns:
        messages written per topic.
    Raises:
        ConfigError: `bag` exists, or a name that is not a ROS 2 name token.
        DataError: an alignments file that cannot be read, or negative times.
    """
    bag = Path(bag)
    if bag.exists():
        raise ConfigError(f"--bag {str(bag)!r}: exists; a bag is written to a new folder")
    for name in names:
        check_ros_name("--robot", name)
    times = np.asarray(run.times, dtype=float)
    # gather first: a file that cannot be read leaves no half-written bag
    messages: list[tuple[int, str, str, object]] = []
    for i, robot in enumerate(names):
        frame = f"{robot}/odom"
        for k, t in enumerate(times):
            recent = run.maps[i][k].recent(float(t), run.settings.kappa)
            messages.append((ns(t), map_topic(robot), MAP_TYPE, map_message(t, frame, recent)))
        for j, other in enumerate(names):
            if j == i:
                continue
            truth = run.T_true(i, j)
            for k, t in enumerate(times):
                T = truth[k]
                if np.all(np.isfinite(T)):
                    x = np.array([T[0, 2], T[1, 2], np.arctan2(T[1, 0], T[0, 0])])
                    messages.append((ns(t), truth_topic(robot, other), ALIGNMENT_TYPE,
                                     pose_message(t, frame, x, np.zeros((3, 3)))))
        if results is None:
            continue
        for suffix, columns, topic in ((".csv", COLUMNS, alignment_topic),
                                       (".team.csv", TEAM_COLUMNS, team_topic)):
            path = Path(results) / f"{robot}{suffix}"
            if not path.exists():  # a node that failed early, or no team consistency
                if suffix == ".csv":
                    log.warning("%s: no alignments of %s for the bag", path, robot)
                continue
            rows = read_alignments(path, columns)
            for k in np.flatnonzero(rows["accepted"] == 1):
                t = float(rows["stamp"][k])
                x = np.array([rows["x"][k], rows["y"][k], rows["theta"][k]])
                try:
                    neighbour = check_ros_name("neighbour", rows["neighbour"][k])
                except ConfigError as exc:
                    raise DataError(f"{path}: {exc}") from None
                messages.append((ns(t), topic(robot, neighbour), ALIGNMENT_TYPE,
                                 pose_message(t, frame, x, row_covariance(rows, k))))
    return write_bag(bag, messages)


def write_bag(bag: str | Path, messages: list[tuple[int, str, str, object]]) -> dict[str, int]:
    """Write (ns, topic, msgtype, message) rows, in time order, to a new rosbag2 folder `bag`
    (MCAP storage); returns the messages written per topic.

    Raises:
        ConfigError: the bag cannot be written there (it exists, or its folder is not
            writable).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.errors import WriterError

    counts: dict[str, int] = {}
    try:
        with Writer(Path(bag), version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            connections = {}
            for stamp, topic, msgtype, message in sorted(messages, key=lambda m: m[0]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype,
                                                               typestore=_store())
                writer.write(connections[topic], stamp, serialize(message, msgtype))
                counts[topic] = counts.get(topic, 0) + 1
    except (WriterError, OSError) as exc:
        raise ConfigError(f"bag {str(bag)!r}: cannot be written ({exc})") from None
    return counts
