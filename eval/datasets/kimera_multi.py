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

import hashlib
import io
import json
import logging
import math
import time
import zipfile
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation, Slerp
from tcaff_gtsam.mapping.camera import R_BODY_OPTICAL, PinholeCamera, rigid_transform
from tcaff_gtsam.mapping.frontend import DepthRegistration, RgbdFrontEnd
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se3_from_rt
from tcaff_gtsam.object_map import ObjectMap

from ..config import ExtrinsicsConfig, KimeraMultiConfig, TopicsConfig
from ..runs import RecordedRun, RunSettings
from .image_files import jpeg_defect
from .rgbd_sequence import QUATERNION_TOL, quaternion_norms
from .text_tables import read_text

__all__ = [
    "CameraCalibration",
    "KimeraProgress",
    "PoseTrack",
    "RgbdFrame",
    "RobotBags",
    "RobotMapping",
    "extrinsic",
    "load_run",
    "map_robot",
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
        DataError: missing file (or a folder, FIFO or device), wrong header, bad rows,
        non-finite values, quaternions that are zero or not of unit norm (off by more than
        `QUATERNION_TOL`: a pose file holds unit quaternions, rounding aside), or stamps that
        do not increase.
    """
    path = Path(path)
    text = read_text(path, "ground-truth file")
    header, _, body = text.partition("\n")
    if header.strip().replace(" ", "") != GT_HEADER:
        raise DataError(f"{path}: header is {header.strip()!r}, expected {GT_HEADER!r}")
    try:
        rows = np.loadtxt(io.StringIO(body), delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as err:
        raise DataError(f"{path}: bad ground-truth row: {err}") from err
    if rows.shape[0] == 0 or rows.shape[1] != 8:
        raise DataError(f"{path}: expected rows of 8 values, got shape {rows.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(rows), axis=1))
    if bad.size:
        raise DataError(f"{path}: row {bad[0] + 2} has non-finite values: {rows[bad[0]]}")
    norms = quaternion_norms(rows[:, 4:8])
    if np.any(norms < 1e-6):
        k = int(np.argmin(norms))
        raise DataError(f"{path}: row {k + 2} has a zero quaternion")
    off = np.flatnonzero(~(np.abs(norms - 1.0) <= QUATERNION_TOL))
    if off.size:
        k = int(off[0])
        raise DataError(f"{path}: row {k + 2}: the quaternion (qw qx qy qz) has norm "
                        f"{norms[k]:.6g}, not 1 (within {QUATERNION_TOL:g}): "
                        f"{rows[k].tolist()}")
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


def _decode_color(msg, topic: str, t: float, index: int) -> np.ndarray:
    """The (H, W, 3) RGB image of a CompressedImage message, the topic's `index`-th (from 0,
    in the bags' time order). OpenCV's imdecode refuses a JPEG whose bytes simply end, but
    decodes one cut short and padded (with zeros, as a driver's fixed-size buffer can be) and
    makes up the rest of its rows, so a JPEG is walked to its end-of-image marker first
    (`jpeg_defect`); other formats (PNG) fail to decode when cut short."""
    data = np.asarray(msg.data, dtype=np.uint8)
    if (defect := jpeg_defect(data.tobytes())) is not None:
        raise DataError(f"{topic} message {index} at t = {t:.3f} s: the colour image {defect}")
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataError(f"{topic} message {index} at t = {t:.3f} s: cannot decode the "
                        f"{msg.format!r} image")
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
        Raises:
            DataError: a kept colour image that is a JPEG cut short (`image_files.jpeg_defect`)
                or that OpenCV cannot decode, naming its topic, its index on the topic (from 0,
                in the bags' time order) and its time; depth that is not 16UC1 or whose bytes do
                not hold its rows.
        """
        if stride < 1 or tolerance < 0 or (rate is not None and rate <= 0):
            raise DataError(f"frames: stride = {stride} must be >= 1, tolerance = {tolerance} "
                            f">= 0 and rate = {rate} > 0 or None")
        odometry = PoseTrack(*self.odometry())
        odom_times = odometry.times
        # (t, index on the colour topic, msg): colour images waiting for a depth image after
        # them, and (t, msg): recent depth images; bounded, so that a topic that stops cannot
        # fill the memory
        colors: deque = deque(maxlen=64)
        depths: deque = deque(maxlen=64)
        next_due, counted, color_index = -np.inf, 0, -1
        skipped = {"no depth": 0, "no odometry": 0}

        def pair(t: float, index: int, color) -> RgbdFrame | None:
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
            return RgbdFrame(t, _decode_color(color, self.topics["color"], t, index),
                             _decode_depth(best[1], self.topics["depth"], best[0]), T[0])

        def ready(latest_depth: float) -> Iterator[RgbdFrame]:
            while colors and (latest_depth - colors[0][0] > tolerance):
                t, index, color = colors.popleft()
                frame = pair(t, index, color)
                if frame is not None:
                    yield frame
                # depth images too old for the next colour frame are no longer needed
                while colors and depths and depths[0][0] < colors[0][0] - tolerance:
                    depths.popleft()

        for role, msg in self._messages("color", "depth"):
            t = _stamp(msg)
            color_index += role == "color"
            if (start is not None and t < start) or (stop is not None and t >= stop):
                continue
            if role == "color":
                colors.append((t, color_index, msg))
            else:
                depths.append((t, msg))
                yield from ready(t)
        yield from ready(np.inf)
        if any(skipped.values()):
            log.info("robot %s: skipped colour frames: %s", self.robot, skipped)


# -- mapping a robot's bags ---------------------------------------------------------------------

MAPS_VERSION = 2  # bump when the saved maps' meaning changes (2: merged object clouds, half-
# resolution segmentation, descriptors)


def extrinsic(config: ExtrinsicsConfig, optical: bool) -> np.ndarray:
    """(4, 4) the configured frame in its parent. With `optical`, xyz/rpy place a camera link
    (x forward) and the optical frame (x right, y down, z forward) is turned from it."""
    if config.matrix is not None:
        return rigid_transform("extrinsics matrix", np.reshape(config.matrix, (4, 4)),
                               ConfigError)
    R = Rotation.from_euler("xyz", config.rpy_deg, degrees=True).as_matrix()
    return se3_from_rt(R @ R_BODY_OPTICAL if optical else R, config.xyz)


@dataclass
class RobotMapping:
    """One robot's maps at the 1 Hz exchanges.

    Attributes:
        robot: its name.
        times: (S,) s, whole seconds of ROS time at which maps are exchanged.
        frame_times: (S,) s, the last mapped frame at or before each exchange.
        T_odom_body: (S, 4, 4) the body pose in the odometry frame at those frames.
        T_map_body: (S, 4, 4) the true body pose in the shared map frame (NaN: no ground truth).
        maps: the map at each exchange, in the odometry frame.
        frames: frames mapped; seconds: wall time of reading and mapping them.
        fingerprint: of the settings and files the maps came from (see `_fingerprint`).
        stage_seconds: the front end's time per stage, summed over the frames.
    """

    robot: str
    times: np.ndarray
    frame_times: np.ndarray
    T_odom_body: np.ndarray
    T_map_body: np.ndarray
    maps: list[ObjectMap]
    frames: int
    seconds: float
    fingerprint: str = ""
    stage_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def frames_per_second(self) -> float | None:
        return self.frames / self.seconds if self.seconds > 0 else None

    @property
    def has_truth(self) -> bool:
        return bool(np.all(np.isfinite(self.T_map_body)))

    def save(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        sizes = np.array([len(m) for m in self.maps], dtype=np.int64)
        entries = {key: np.concatenate([getattr(m, key) for m in self.maps])
                   for key in ("centroids", "widths", "heights", "last_seen")}
        # per map its descriptors' width d (-1: none), the values of all maps in one array
        entries["descriptor_dims"] = np.array(
            [-1 if m.descriptors is None else m.descriptors.shape[1] for m in self.maps],
            dtype=np.int64)
        entries["descriptors"] = np.concatenate(
            [np.zeros(0), *(m.descriptors.ravel() for m in self.maps
                            if m.descriptors is not None)])
        with open(folder / f"{self.robot}.npz", "wb") as file:
            np.savez_compressed(
                file, times=self.times, frame_times=self.frame_times,
                T_odom_body=self.T_odom_body, T_map_body=self.T_map_body, map_sizes=sizes,
                **entries)
        (folder / f"{self.robot}.json").write_text(json.dumps({
            "robot": self.robot, "version": MAPS_VERSION, "fingerprint": self.fingerprint,
            "frames": self.frames, "seconds": self.seconds,
            "frames_per_second": self.frames_per_second,
            "stage_seconds": self.stage_seconds, "exchanges": len(self.times)}, indent=1))

    @classmethod
    def load(cls, folder: Path, robot: str) -> RobotMapping | None:
        """The saved mapping of `robot`, or None when there is none or it cannot be read
        (missing, truncated, of another version or lacking a key: then with a warning, and
        the robot is mapped again)."""
        if not (folder / f"{robot}.json").exists():
            return None
        try:
            meta = json.loads((folder / f"{robot}.json").read_text())
            if meta.get("version") != MAPS_VERSION:
                log.warning("the saved maps of %s in %s are of another version (%s, not %d); "
                            "mapping it again", robot, folder, meta.get("version"),
                            MAPS_VERSION)
                return None
            with np.load(folder / f"{robot}.npz") as a:
                arrays = {k: a[k] for k in a.files}
            ends = np.cumsum(arrays["map_sizes"])
            values, used, maps = arrays["descriptors"], 0, []
            for n, e, d in zip(arrays["map_sizes"], ends, arrays["descriptor_dims"],
                               strict=True):
                descriptors = None
                if d >= 0:
                    descriptors = values[used:used + n * d].reshape(n, d)
                    used += n * d
                maps.append(ObjectMap(arrays["centroids"][e - n:e], arrays["widths"][e - n:e],
                                      arrays["heights"][e - n:e], arrays["last_seen"][e - n:e],
                                      descriptors))
            if used != values.size:
                raise ValueError(f"{values.size} descriptor values for {used}")
            return cls(robot, arrays["times"], arrays["frame_times"], arrays["T_odom_body"],
                       arrays["T_map_body"], maps, int(meta["frames"]),
                       float(meta["seconds"]), meta["fingerprint"],
                       meta.get("stage_seconds", {}))
        except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError,
                zipfile.BadZipFile) as err:
            log.warning("no reusable maps of %s in %s (%s: %s); mapping it again", robot,
                        folder, type(err).__name__, err)
            return None


def _bag_paths(config: KimeraMultiConfig, robot: str, data: Path) -> list[Path]:
    pattern = config.bags.replace("{robot}", robot)
    paths = sorted(data.glob(pattern))
    if not paths:
        present = sorted(p.name for p in data.glob("*.bag"))
        raise DataError(f"robot {robot}: no bag matches {pattern!r} in {data}; bags there: "
                        f"{present}")
    return paths


def _ground_truth_path(config: KimeraMultiConfig, robot: str, data: Path) -> Path:
    """Where `robot`'s ground-truth CSV is in `data` (a robot without one is not scored).

    Raises:
        DataError: something other than a file is there (a folder, a FIFO).
    """
    path = data / config.ground_truth.replace("{robot}", robot)
    if path.exists() and not path.is_file():
        kind = "a folder" if path.is_dir() else "not a regular file"
        raise DataError(f"{path}: {kind}, not the ground-truth CSV of robot {robot} "
                        f"(ground_truth {config.ground_truth!r} of the config)")
    return path


def _fingerprint(config: KimeraMultiConfig, robot: str, paths: list[Path], gt: Path) -> str:
    """Changes when anything that shapes the robot's maps changes."""
    files = [(p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in paths]
    if gt.is_file():
        files.append((gt.name, gt.stat().st_size, gt.stat().st_mtime_ns))
    keys = ("topics", "rig", "stride", "sync_tolerance", "start", "duration", "mapping")
    settings = config.model_dump(mode="json", include=set(keys))
    blob = json.dumps({"robot": robot, "files": files, "settings": settings}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def map_robot(config: KimeraMultiConfig, robot: str, data: Path,
              progress: Callable[[float], None] | None = None) -> RobotMapping:
    """Map one robot's bags and record its map at every whole second of ROS time.

    Raises:
        DataError: missing or damaged bags, missing topics, bad messages, a ground truth that
            is not a file or not a valid CSV (a missing one is warned about).
    """
    paths = _bag_paths(config, robot, data)
    gt_path = _ground_truth_path(config, robot, data)
    truth = read_ground_truth(gt_path) if gt_path.is_file() else None
    if truth is None:
        log.warning("robot %s: no ground truth at %s; its alignments are not scored", robot,
                    gt_path)
    with RobotBags(paths, robot, config.topics) as bags:
        calibration = bags.calibration()
        T_color_depth = extrinsic(config.rig.color_depth, optical=False)
        registration = DepthRegistration(calibration.depth, T_color_depth)
        front_end = RgbdFrontEnd(
            calibration.color, extrinsic(config.rig.body_color, optical=True),
            config.rig.depth_scale, registration=registration,
            mapper_params=MapperParams(nu=config.mapping.nu, kappa=config.mapping.kappa))
        first, last = bags.time_span()
        begin = first + (config.start or 0.0)
        end = last if config.duration is None else min(last, begin + config.duration)
        times, frame_times, poses, maps = [], [], [], []
        stage_seconds: dict[str, float] = {}
        frames, clock = 0, time.perf_counter()
        exchange, previous = None, None
        for frame in bags.frames(config.mapping.frame_rate, config.stride,
                                 config.sync_tolerance, begin, end + 1e-9):
            if exchange is None:
                exchange = math.ceil(frame.t)
            while frame.t > exchange and previous is not None:
                times.append(exchange)
                frame_times.append(previous.t)
                poses.append(previous.T_odom_body)
                maps.append(front_end.object_map())
                exchange += 1
            result = front_end.process(frame.t, frame.rgb, frame.depth, frame.T_odom_body)
            for stage, s in result.seconds.items():
                stage_seconds[stage] = stage_seconds.get(stage, 0.0) + s
            previous, frames = frame, frames + 1
            if progress is not None and end > begin:
                progress(min(1.0, (frame.t - begin) / (end - begin)))
        seconds = time.perf_counter() - clock
    if not times:
        raise DataError(f"robot {robot}: {frames} frames mapped, not enough for one 1 Hz map "
                        f"exchange (check the topics' stamps and sync_tolerance)")
    frame_times = np.array(frame_times)
    T_map_body = np.full((len(times), 4, 4), np.nan)
    if truth is not None:
        T, inside = PoseTrack(*truth)(frame_times)
        T_map_body[inside] = T[inside]
        if not inside.all():
            log.warning("robot %s: ground truth covers %d of %d exchanges", robot,
                        inside.sum(), inside.size)
    return RobotMapping(robot, np.array(times, dtype=float), frame_times, np.array(poses),
                        T_map_body, maps, frames, seconds,
                        _fingerprint(config, robot, paths, gt_path), stage_seconds)


class KimeraProgress:
    """Hooks for the loader's progress reports; the default reports nothing."""

    def robot(self, robot: str, reused: bool) -> None: ...
    def mapping(self, robot: str, share: float) -> None: ...


def load_run(config: KimeraMultiConfig, data: Path, maps_folder: Path, resume: bool = True,
             progress: KimeraProgress | None = None
             ) -> tuple[RecordedRun, list[RobotMapping], list[str]]:
    """Map every robot's bags (reusing maps saved in `maps_folder` by an earlier run with the
    same settings and files when `resume`), and the run at the exchanges all robots share.

    Each robot's maps are saved as soon as it is mapped, so a failure in one robot's bags
    never loses the robots already mapped.

    Returns:
        The run, every robot's mapping, and the robots whose saved maps were reused.
    Raises:
        DataError: `data` is not a folder, a robot's ground truth is not a file (checked
            before any robot is mapped), a robot's data cannot be read, or the robots'
            recordings share no exchange.
    """
    progress = progress or KimeraProgress()
    data = Path(data)
    if not data.is_dir():
        raise DataError(f"--data {data}: not a folder")
    # all checked before the first robot's bags are mapped, which takes minutes
    truths = {robot: _ground_truth_path(config, robot, data) for robot in config.robots}
    mappings, reused = [], []
    for robot in config.robots:
        saved = RobotMapping.load(maps_folder, robot) if resume else None
        if saved is not None:
            paths = _bag_paths(config, robot, data)
            if saved.fingerprint == _fingerprint(config, robot, paths, truths[robot]):
                progress.robot(robot, True)
                mappings.append(saved)
                reused.append(robot)
                continue
        progress.robot(robot, False)
        mapping = map_robot(config, robot, data, lambda s, r=robot: progress.mapping(r, s))
        mapping.save(maps_folder)
        mappings.append(mapping)
    return _common_run(config, mappings), mappings, reused


def _common_run(config: KimeraMultiConfig, mappings: list[RobotMapping]) -> RecordedRun:
    """The robots' maps at the whole seconds of ROS time every robot has a map for."""
    common = mappings[0].times
    for m in mappings[1:]:
        common = np.intersect1d(common, m.times)
    if common.size == 0:
        spans = {m.robot: (m.times[0], m.times[-1]) for m in mappings}
        raise DataError(f"the robots' recordings share no whole second of ROS time: {spans}")
    index = [np.searchsorted(m.times, common) for m in mappings]
    maps = [[m.maps[k] for k in idx] for m, idx in zip(mappings, index, strict=True)]
    T_odom_body = np.array([m.T_odom_body[idx] for m, idx in zip(mappings, index, strict=True)])
    T_map_body = np.array([m.T_map_body[idx] for m, idx in zip(mappings, index, strict=True)])
    settings = RunSettings(config.mapping.kappa, config.window, config.graph_drift)
    return RecordedRun(config.name, settings, common, maps, T_map_body @ invert(T_odom_body),
                       T_odom_body, robot_names=tuple(config.robots))
