"""Write small ROS1 bags laid out like the Kimera-Multi data set, from the rendered RGB-D simulator.

For every robot R the output folder gets:

  R.bag            /R/forward/color/image_raw/compressed  sensor_msgs/CompressedImage (JPEG)
                   /R/forward/color/camera_info           sensor_msgs/CameraInfo
                   /R/forward/depth/image_rect_raw        sensor_msgs/Image (16UC1, mm, 0 = none)
                   /R/forward/depth/camera_info           sensor_msgs/CameraInfo
                   /R/jackal_velocity_controller/odom     nav_msgs/Odometry (50 Hz, drifting)
  R_gt_odom.csv    #timestamp_kf,x,y,z,qw,qx,qy,qz: the true body pose in the shared world frame
                   at 10 Hz (ns stamps, quaternion w first)

Depth comes from a second camera 5.9 cm left of the colour camera with a wider field of view
(87 vs 80 deg), stamped 4 ms after the colour frame, so readers must register and synchronise.
Stamps start at 1634000000 s.

    python scripts/make_kimera_like_bag.py --out data/kimera_like --seconds 30

is its command line; `write_sequence` is the entry point for code and tests.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.geometry import se3_from_xyz_yaw
from tcaff_gtsam.params import _int_at_least, _real

from ..config import CameraConfig, load_scenario
from ..config_scenario import MAX_DURATION, MAX_IMAGE_SIDE
from .motion import drifting_odometry, poses_along
from .render import RgbdScene, render
from .rgbd import clear_paths
from .scenarios import build_scene
from .world import World

T0_NS = 1_634_000_000 * 10**9
ODOM_RATE, GT_RATE = 50, 10  # Hz
DEPTH_DELAY_NS = 4_000_000
COLOR_HFOV, DEPTH_HFOV = 80.0, 87.0  # degrees
#: (4, 4) the depth optical frame in the colour optical frame: 5.9 cm to its left.
T_COLOR_DEPTH = np.array([[1.0, 0, 0, -0.059], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
#: key: (topic below /R/, message type)
TOPICS = {"odom": ("jackal_velocity_controller/odom", "nav_msgs/msg/Odometry"),
          "color": ("forward/color/image_raw/compressed", "sensor_msgs/msg/CompressedImage"),
          "color_info": ("forward/color/camera_info", "sensor_msgs/msg/CameraInfo"),
          "depth": ("forward/depth/image_rect_raw", "sensor_msgs/msg/Image"),
          "depth_info": ("forward/depth/camera_info", "sensor_msgs/msg/CameraInfo")}
TYPES = get_typestore(Stores.ROS1_NOETIC)
MSG = TYPES.types


@dataclass(frozen=True, eq=False)
class SequenceTruth:
    """What `write_sequence` wrote, for checking readers and mappers against.

    Attributes:
        robots: the robot names, in the scenario's robot order.
        times: times[R] (F,) seconds since t0_ns of robot R's colour frames.
        T_world_body: T_world_body[R] (F, 4, 4) the true body pose at each colour frame in the
            world (map) frame shared by all robots.
        T_odom_body: T_odom_body[R] (F, 4, 4) the same poses in R's drifting odometry frame
            (its first true pose), as in the bag's odometry messages.
        t0_ns: stamp of sequence time 0, ns.
        T_body_color: (4, 4) colour optical frame in the body frame.
        T_color_depth: (4, 4) depth optical frame in the colour optical frame.
        color_camera, depth_camera: the intrinsics.
        depth_max: metres; farther surfaces give no depth.
        world: the rendered objects (world frame), e.g. to render the truth again.
    """

    robots: tuple[str, ...]
    times: dict[str, np.ndarray]
    T_world_body: dict[str, np.ndarray]
    T_odom_body: dict[str, np.ndarray]
    t0_ns: int
    T_body_color: np.ndarray
    T_color_depth: np.ndarray
    color_camera: PinholeCamera
    depth_camera: PinholeCamera
    depth_max: float
    world: World


def _header(seq: int, stamp_ns: int, frame_id: str):
    stamp = MSG["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return MSG["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)


def _camera_info(header, camera: PinholeCamera):
    K = camera.K
    return MSG["sensor_msgs/msg/CameraInfo"](
        header=header, height=camera.height, width=camera.width, distortion_model="plumb_bob",
        D=np.zeros(5), K=K.ravel(), R=np.eye(3).ravel(), P=np.hstack([K, np.zeros((3, 1))]).ravel(),
        binning_x=0, binning_y=0, roi=MSG["sensor_msgs/msg/RegionOfInterest"](0, 0, 0, 0, False))


def _odometry(header, child: str, pose: np.ndarray):
    """pose: (x, y, theta) of the body in the odometry frame; the twist is left zero."""
    vec, theta = MSG["geometry_msgs/msg/Vector3"], float(pose[2])
    return MSG["nav_msgs/msg/Odometry"](
        header=header, child_frame_id=child,
        pose=MSG["geometry_msgs/msg/PoseWithCovariance"](MSG["geometry_msgs/msg/Pose"](
            MSG["geometry_msgs/msg/Point"](float(pose[0]), float(pose[1]), 0.0),
            MSG["geometry_msgs/msg/Quaternion"](0.0, 0.0, math.sin(theta / 2),
                                                math.cos(theta / 2))), np.zeros(36)),
        twist=MSG["geometry_msgs/msg/TwistWithCovariance"](MSG["geometry_msgs/msg/Twist"](
            vec(0.0, 0.0, 0.0), vec(0.0, 0.0, 0.0)), np.zeros(36)))


def _number(v) -> bool:
    return _real(v) and math.isfinite(v)


def _check(robots: tuple, seconds, rate, width, height, depth_noise, mount: tuple) -> None:
    pixels = f"must be an int in [8, {MAX_IMAGE_SIDE}] pixels (MAX_IMAGE_SIDE)"
    checks = [
        (len(robots) > 0 and len(set(robots)) == len(robots) and all(
            isinstance(r, str) and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", r) for r in robots),
         "robots", robots, "need distinct ROS names ([A-Za-z][A-Za-z0-9_]*)"),
        (_number(rate) and rate > 0 and abs(ODOM_RATE / rate - round(ODOM_RATE / rate)) < 1e-9,
         "rate", rate, f"must divide the {ODOM_RATE} Hz odometry rate (1, 2, 5, 10, 25, 50 Hz)"),
        (_number(seconds) and _number(rate) and seconds * rate >= 1
         and seconds <= MAX_DURATION, "seconds", seconds,
         f"must be finite, hold a frame (>= 1 / rate) and be at most {MAX_DURATION:g} s "
         f"(MAX_DURATION)"),
        (_int_at_least(width, 8) and width <= MAX_IMAGE_SIDE, "width", width, pixels),
        (_int_at_least(height, 8) and height <= MAX_IMAGE_SIDE, "height", height, pixels),
        (_number(depth_noise) and 0 <= depth_noise <= 0.1, "depth_noise", depth_noise,
         "must be in [0, 0.1] m at 1 m"),
        *((_number(v), name, v, "must be a finite number") for name, v in zip(
            ("camera_height", "camera_pitch_deg", "camera_forward"), mount, strict=True))]
    for ok, name, value, rule in checks:
        if not ok:
            raise ConfigError(f"{name} = {value!r}: {rule}")


def write_sequence(out_dir, robots=("acl_jackal2", "sparkal2"), seconds: float = 30.0,
                   rate: float = 10.0, width: int = 640, height: int = 480, seed: int = 0,
                   scenario: str = "indoor_rgbd", depth_noise: float = 0.0025,
                   progress: Callable[[str, int, int], None] | None = None, *,
                   camera_height: float = 0.6, camera_pitch_deg: float = 5.0,
                   camera_forward: float = 0.2) -> SequenceTruth:
    """Simulate `scenario` for `seconds` and write one bag and one GT CSV per robot.

    Args:
        out_dir: folder to write into (created); existing files are never overwritten.
        robots: one name per robot of the scenario.
        rate: colour (and depth) frame rate in Hz; must divide 50 Hz.
        seconds: at most `config_scenario.MAX_DURATION` (two hours).
        width, height: pixels of both images, ints in [8, `config_scenario.MAX_IMAGE_SIDE`].
        depth_noise: metres of depth std at 1 m range, growing with range squared.
        progress: called as progress(robot, frames_done, frames_total) after every frame.
        camera_height, camera_pitch_deg, camera_forward: the colour camera's mount: metres up,
            degrees looking down, metres forward of the body origin (see `T_body_camera`).
    """
    robots = tuple(robots)
    mount = (camera_height, camera_pitch_deg, camera_forward)
    _check(robots, seconds, rate, width, height, depth_noise, mount)
    config = load_scenario(scenario)
    if len(robots) != config.n_robots:
        raise ConfigError(f"robots = {robots!r}: scenario {scenario!r} has {config.n_robots} "
                          f"robots, got {len(robots)} names")
    out = Path(out_dir)
    for path in [out / f"{r}{suffix}" for r in robots for suffix in (".bag", "_gt_odom.csv")]:
        if path.exists():
            raise ConfigError(f"out_dir = {str(out)!r}: {path.name} exists already; remove it "
                              "or choose another folder")
    out.mkdir(parents=True, exist_ok=True)
    config = config.model_copy(update={"duration": float(seconds)})
    cam = config.camera or CameraConfig()
    rng = np.random.default_rng(seed)
    scene = build_scene(config, rng)
    # Everything lives on the 50 Hz odometry grid (integer ns stamps); colour frames and GT rows
    # are every k-th sample of it, so odometry and frames agree exactly.
    n = round(seconds * ODOM_RATE)
    stamps = [T0_NS + j * (10**9 // ODOM_RATE) for j in range(n)]
    frame_every, gt_every = round(ODOM_RATE / rate), ODOM_RATE // GT_RATE
    frames = np.arange(0, n, frame_every)
    true = [poses_along(*knots, np.arange(n) / ODOM_RATE) for knots in scene.knots]
    world = clear_paths(rng, scene.world, true, cam.clearance)
    rendered = RgbdScene.from_world(world)
    color_cam = PinholeCamera.from_fov(width, height, COLOR_HFOV)
    depth_cam = PinholeCamera.from_fov(width, height, DEPTH_HFOV)
    T_body_color = T_body_camera(*mount)
    truth = SequenceTruth(robots, {}, {}, {}, T0_NS, T_body_color, T_COLOR_DEPTH.copy(),
                          color_cam, depth_cam, cam.depth_max, world)
    for k, r in enumerate(robots):
        drift = config.drift(k)
        odom = drifting_odometry(rng, true[k], 1 / ODOM_RATE, math.radians(drift.heading_rw_deg),
                                 drift.position_rw)
        truth.times[r] = frames / ODOM_RATE
        truth.T_world_body[r] = np.array([se3_from_xyz_yaw(x, y, 0.0, th)
                                          for x, y, th in true[k][frames]])
        truth.T_odom_body[r] = np.array([se3_from_xyz_yaw(x, y, 0.0, th)
                                         for x, y, th in odom[frames]])
        with (out / f"{r}_gt_odom.csv").open("w") as csv:
            csv.write("#timestamp_kf,x,y,z,qw,qx,qy,qz\n")
            for j in range(0, n, gt_every):
                x, y, th = true[k][j]
                csv.write(f"{stamps[j]},{x:.6f},{y:.6f},0.0,{math.cos(th / 2):.9f},0.0,0.0,"
                          f"{math.sin(th / 2):.9f}\n")
        with Writer(out / f"{r}.bag") as bag:
            conn = {key: bag.add_connection(f"/{r}/{topic}", msgtype, typestore=TYPES)
                    for key, (topic, msgtype) in TOPICS.items()}
            for j in range(n):
                # written in stamp order: odometry, colour (t), depth (t + 4 ms), next odometry
                messages = [("odom", _odometry(_header(j, stamps[j], f"{r}/odom"), f"{r}/base",
                                               odom[j]))]
                if j % frame_every == 0:
                    f = j // frame_every
                    T_world_color = truth.T_world_body[r][f] @ T_body_color
                    rgb = render(rendered, T_world_color, color_cam).rgb
                    jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                                        [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
                    # Both images show the scene at the colour frame's pose; the depth stamp is
                    # offset only so that readers have to pair frames by nearest stamp.
                    depth = render(rendered, T_world_color @ T_COLOR_DEPTH, depth_cam,
                                   depth_noise, rng, cam.depth_max).depth
                    mm = np.round(np.nan_to_num(depth) * 1000).clip(0, 65535).astype("<u2")
                    color_head = _header(f, stamps[j], f"{r}/forward_color_optical_frame")
                    depth_head = _header(f, stamps[j] + DEPTH_DELAY_NS,
                                         f"{r}/forward_depth_optical_frame")
                    messages += [
                        ("color", MSG["sensor_msgs/msg/CompressedImage"](
                            color_head, "rgb8; jpeg compressed bgr8", jpeg.ravel())),
                        ("color_info", _camera_info(color_head, color_cam)),
                        ("depth", MSG["sensor_msgs/msg/Image"](
                            depth_head, height, width, "16UC1", 0, 2 * width,
                            mm.view(np.uint8).ravel())),
                        ("depth_info", _camera_info(depth_head, depth_cam))]
                for key, msg in messages:
                    stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                    bag.write(conn[key], stamp, TYPES.serialize_ros1(msg, TOPICS[key][1]))
                if j % frame_every == 0 and progress is not None:
                    progress(r, j // frame_every + 1, len(frames))
    return truth
