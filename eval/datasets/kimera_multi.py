"""Kimera-Multi rosbags: one robot's synchronised RGB-D frames with odometry poses, its camera
calibration, and the ground-truth CSVs.

Each robot's data set is one or more ROS1 bags (the raw bag with the cameras and wheel odometry,
and optionally the bag Kimera-VIO wrote with its odometry), read with `rosbags`' AnyReader as one
stream in time order, so memory stays bounded whatever the length. Topics (per robot, `{robot}`
replaced by its name; all configurable):

- colour: `/{robot}/forward/color/image_raw/compressed`, sensor_msgs/CompressedImage (JPEG or PNG);
- depth: `/{robot}/forward/depth/image_rect_raw`, sensor_msgs/Image, 16UC1 millimetres;
- both `camera_info` topics, sensor_msgs/CameraInfo (ROS1 fields `K`, `D`, `R`, `P`);
- odometry: nav_msgs/Odometry, the body pose in the robot's odometry frame.

Ground truth is `<robot>_gt_odom.csv` with the header `#timestamp_kf,x,y,z,qw,qx,qy,qz`:
nanosecond stamps, the body pose in a map frame shared by the robots of a sequence, quaternions
w first. All times here are float seconds of ROS time.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation, Slerp
from tcaff_gtsam.mapping.camera import PinholeCamera

from tcaff_gtsam.errors import DataError

from ..config import TopicsConfig

__all__ = [
    "CameraCalibration",
    "PoseTrack",
    "RgbdFrame",
    "RobotBags",
    "read_ground_truth",
]

log = logging.getLogger(__name__)

GT_HEADER = "#timestamp_kf,x,y,z,qw,qx,qy,qz"


@dataclass(frozen=True)
class CameraCalibration:
    """Intrinsics of the colour and the depth camera, from their camera_info topics."""

    color: PinholeCamera
    depth: PinholeCamera


@dataclass(frozen=True)
class RgbdFrame:
    """One synchronised frame.

    Attributes:
        t: seconds, the colour image's stamp.
        rgb: (H, W, 3) uint8, in the colour camera.
        depth: (Hd, Wd) uint16 millimetres (0 = no return), in the depth camera.
        T_odom_body: (4, 4) the body pose in the odometry frame at t (interpolated).
    """

    t: float
    rgb: np.ndarray
    depth: np.ndarray
    T_odom_body: np.ndarray


def _stamp(msg) -> float:
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def _poses(xyz: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """(n, 4, 4) from (n, 3) positions and (n, 4) quaternions x, y, z, w."""
    T = np.tile(np.eye(4), (xyz.shape[0], 1, 1))
    T[:, :3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    T[:, :3, 3] = xyz
    return T


def read_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A Kimera-Multi ground-truth CSV.

    Returns:
        times (n,) seconds, strictly increasing, and T_map_body (n, 4, 4).
    Raises:
        DataError: missing file, wrong header, bad rows, non-finite values, zero quaternions
        or stamps that do not increase.
    """
    path = Path(path)
    try:
        with open(path) as file:
            header = file.readline().strip()
            if header.replace(" ", "") != GT_HEADER:
                raise DataError(f"{path}: header is {header!r}, expected {GT_HEADER!r}")
            rows = np.loadtxt(file, delimiter=",", dtype=np.float64, ndmin=2)
    except OSError as err:
        raise DataError(f"{path}: cannot read the ground truth: {err}") from err
    except ValueError as err:
        raise DataError(f"{path}: bad ground-truth row: {err}") from err
    if rows.shape[0] == 0 or rows.shape[1] != 8:
        raise DataError(f"{path}: expected rows of 8 values, got shape {rows.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(rows), axis=1))
    if bad.size:
        raise DataError(f"{path}: row {bad[0] + 2} has non-finite values: {rows[bad[0]]}")
    norms = np.linalg.norm(rows[:, 4:8], axis=1)
    if np.any(norms < 1e-6):
        k = int(np.argmin(norms))
        raise DataError(f"{path}: row {k + 2} has a zero quaternion")
    times = rows[:, 0] * 1e-9
    if np.any(np.diff(times) <= 0):
        k = int(np.flatnonzero(np.diff(times) <= 0)[0])
        raise DataError(f"{path}: timestamp_kf must increase, but row {k + 3} has "
                        f"{rows[k + 1, 0]:.0f} after {rows[k, 0]:.0f}")
    return times, _poses(rows[:, 1:4], rows[:, [5, 6, 7, 4]])  # w first in the file


class PoseTrack:
    """Poses over time, interpolated: positions linearly, rotations by slerp. Built once per
    trajectory, so that each query costs only the lookup.

    Args:
        times: (n,) strictly increasing seconds; poses: (n, 4, 4).
    """

    def __init__(self, times: np.ndarray, poses: np.ndarray) -> None:
        self.times, self.poses = times, poses
        self._slerp = (Slerp(times, Rotation.from_matrix(poses[:, :3, :3])) if times.size > 1
                       else None)

    def __call__(self, query) -> tuple[np.ndarray, np.ndarray]:
        """(m, 4, 4) poses at the (m,) `query` seconds and (m,) bool, which queries lie within
        [times[0], times[-1]] (the others hold the nearest end's pose)."""
        times = self.times
        query = np.atleast_1d(np.asarray(query, dtype=float))
        inside = (query >= times[0]) & (query <= times[-1])
        q = np.clip(query, times[0], times[-1])
        if self._slerp is None:
            return np.repeat(self.poses[:1], q.size, axis=0), inside
        out = np.tile(np.eye(4), (q.size, 1, 1))
        out[:, :3, :3] = self._slerp(q).as_matrix()
        for axis in range(3):
            out[:, axis, 3] = np.interp(q, times, self.poses[:, axis, 3])
        return out, inside


def _camera(msg, topic: str) -> PinholeCamera:
    # ROS1 bags name the fields K and D; ROS2 bags k and d
    K = np.asarray(msg.K if hasattr(msg, "K") else msg.k, dtype=float)
    if K.shape != (9,) or not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
        raise DataError(f"{topic}: camera_info K = {K.tolist()} is not a valid 3 x 3 matrix")
    D = np.asarray(msg.D if hasattr(msg, "D") else msg.d, dtype=float)
    if D.size and np.any(np.abs(D) > 1e-9):
        log.warning("%s: distortion %s is ignored (the images are taken as rectified)", topic,
                    D.tolist())
    return PinholeCamera.from_K(K.reshape(3, 3), int(msg.width), int(msg.height))


def _decode_color(msg, topic: str, t: float) -> np.ndarray:
    bgr = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataError(f"{topic} at t = {t:.3f} s: cannot decode the {msg.format!r} image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _decode_depth(msg, topic: str, t: float) -> np.ndarray:
    if msg.encoding not in ("16UC1", "mono16"):
        raise DataError(f"{topic} at t = {t:.3f} s: encoding {msg.encoding!r}, expected 16UC1 "
                        f"(millimetres)")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < 2 * w or data.size != h * step:
        raise DataError(f"{topic} at t = {t:.3f} s: {data.size} bytes do not hold {h} rows of "
                        f"step {step} for width {w}")
    rows = data.reshape(h, step)[:, :2 * w]
    return rows.copy().view(">u2" if msg.is_bigendian else "<u2").astype(np.uint16)


class RobotBags:
    """One robot's bags, opened for reading; use as a context manager.

    Args:
        paths: the robot's ROS1 bag files (read together, in time order).
        robot: its name, for the topics and messages.
        topics: topic names (default: Kimera-Multi's).
    Raises:
        DataError: a missing, truncated or corrupt bag, or a topic the bags do not hold (the
        message lists the topics they do hold).
    """

    def __init__(self, paths: Sequence[Path], robot: str,
                 topics: TopicsConfig | None = None) -> None:
        self.paths = [Path(p) for p in paths]
        if not self.paths:
            raise DataError(f"robot {robot}: no bag files given")
        missing = [str(p) for p in self.paths if not p.is_file()]
        if missing:
            raise DataError(f"robot {robot}: bag files not found: {missing}")
        self.robot = robot
        self.topics = (topics or TopicsConfig()).of(robot)
        self._reader = AnyReader(self.paths)
        try:
            self._reader.open()
        except Exception as err:  # rosbags raises several kinds for damaged files
            raise DataError(f"robot {robot}: cannot open {[str(p) for p in self.paths]}: "
                            f"{type(err).__name__}: {err}") from err
        present = self._reader.topics
        absent = [t for t in self.topics.values() if t not in present]
        if absent:
            self._reader.close()
            raise DataError(f"robot {robot}: topics {absent} are not in "
                            f"{[p.name for p in self.paths]}; topics present: {sorted(present)}")
        self._connections = {role: [c for c in self._reader.connections if c.topic == topic]
                             for role, topic in self.topics.items()}

    def __enter__(self) -> RobotBags:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._reader.stack is not None:
            self._reader.close()

    def _messages(self, *roles: str) -> Iterator[tuple[str, object]]:
        """(role, message) in the bags' time order; damage is a DataError naming the robot."""
        connections = [c for role in roles for c in self._connections[role]]
        role_of = {id(c): role for role in roles for c in self._connections[role]}
        try:
            for connection, _, raw in self._reader.messages(connections=connections):
                yield role_of[id(connection)], self._reader.deserialize(raw, connection.msgtype)
        except DataError:
            raise
        except Exception as err:
            raise DataError(f"robot {self.robot}: the bags {[p.name for p in self.paths]} are "
                            f"damaged: {type(err).__name__}: {err}") from err

    def time_span(self) -> tuple[float, float]:
        """Seconds of the bags' first and last message."""
        return self._reader.start_time * 1e-9, self._reader.end_time * 1e-9

    def calibration(self) -> CameraCalibration:
        """The first camera_info message of each camera."""
        found = {}
        for role, msg in self._messages("color_info", "depth_info"):
            found.setdefault(role, _camera(msg, self.topics[role]))
            if len(found) == 2:
                break
        absent = [self.topics[r] for r in ("color_info", "depth_info") if r not in found]
        if absent:
            raise DataError(f"robot {self.robot}: no message on {absent}")
        return CameraCalibration(found["color_info"], found["depth_info"])

    def odometry(self) -> tuple[np.ndarray, np.ndarray]:
        """Every odometry message: times (n,) seconds, strictly increasing, and T_odom_body
        (n, 4, 4). Repeated stamps keep the first message."""
        times, xyz, quat = [], [], []
        for _, msg in self._messages("odometry"):
            pose = msg.pose.pose
            times.append(_stamp(msg))
            xyz.append((pose.position.x, pose.position.y, pose.position.z))
            quat.append((pose.orientation.x, pose.orientation.y, pose.orientation.z,
                         pose.orientation.w))
        if not times:
            raise DataError(f"robot {self.robot}: no message on {self.topics['odometry']}")
        times, xyz, quat = np.array(times), np.array(xyz), np.array(quat)
        order = np.argsort(times, kind="stable")
        times, xyz, quat = times[order], xyz[order], quat[order]
        first = np.r_[True, np.diff(times) > 0]
        times, xyz, quat = times[first], xyz[first], quat[first]
        bad = ~np.all(np.isfinite(np.hstack([xyz, quat])), axis=1) | (
            np.linalg.norm(quat, axis=1) < 1e-6)
        if bad.any():
            raise DataError(f"robot {self.robot}: odometry at t = {times[bad][0]:.3f} s has a "
                            f"non-finite pose or a zero quaternion")
        return times, _poses(xyz, quat)

    def frames(self, rate: float | None = 10.0, stride: int = 1, tolerance: float = 0.02,
               start: float | None = None, stop: float | None = None) -> Iterator[RgbdFrame]:
        """Colour frames paired with the depth image nearest in time, with interpolated poses.

        Args:
            rate: Hz, at most this many frames per second are kept (None: all).
            stride: then every stride-th of those.
            tolerance: seconds; colour frames with no depth image this close are skipped.
            start, stop: seconds, only frames in [start, stop).
        Frames outside the odometry's time span are skipped. Only kept frames are decoded.
        """
        if stride < 1 or tolerance < 0 or (rate is not None and rate <= 0):
            raise DataError(f"frames: stride = {stride} must be >= 1, tolerance = {tolerance} "
                            f">= 0 and rate = {rate} > 0 or None")
        odometry = PoseTrack(*self.odometry())
        odom_times = odometry.times
        # (t, msg): colour images waiting for a depth image after them, and recent depth
        # images; bounded, so that a topic that stops cannot fill the memory
        colors: deque = deque(maxlen=64)
        depths: deque = deque(maxlen=64)
        next_due, counted = -np.inf, 0
        skipped = {"no depth": 0, "no odometry": 0}

        def pair(t: float, color) -> RgbdFrame | None:
            nonlocal next_due, counted
            best = min(depths, key=lambda d: abs(d[0] - t), default=None)
            if best is None or abs(best[0] - t) > tolerance:
                skipped["no depth"] += 1
                return None
            if not odom_times[0] <= t <= odom_times[-1]:
                skipped["no odometry"] += 1
                return None
            if t < next_due:
                return None
            next_due = t + (1.0 / rate if rate else 0.0) - 1e-3
            counted += 1
            if (counted - 1) % stride:
                return None
            T, _ = odometry([t])
            return RgbdFrame(t, _decode_color(color, self.topics["color"], t),
                             _decode_depth(best[1], self.topics["depth"], best[0]), T[0])

        def ready(latest_depth: float) -> Iterator[RgbdFrame]:
            while colors and (latest_depth - colors[0][0] > tolerance):
                t, color = colors.popleft()
                frame = pair(t, color)
                if frame is not None:
                    yield frame
                # depth images too old for the next colour frame are no longer needed
                while colors and depths and depths[0][0] < colors[0][0] - tolerance:
                    depths.popleft()

        for role, msg in self._messages("color", "depth"):
            t = _stamp(msg)
            if (start is not None and t < start) or (stop is not None and t >= stop):
                continue
            if role == "color":
                colors.append((t, msg))
            else:
                depths.append((t, msg))
                yield from ready(t)
        yield from ready(np.inf)
        if any(skipped.values()):
            log.info("robot %s: skipped colour frames: %s", self.robot, skipped)
