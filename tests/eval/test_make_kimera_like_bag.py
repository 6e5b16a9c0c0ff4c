"""scripts/make_kimera_like_bag.py: the bags and CSVs it writes, read back with rosbags' AnyReader.

One short sequence (2 s, 160 x 120, exact depth) is written once; every check reads the files
and compares them with the layout of the Kimera-Multi data set and with the returned truth.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from tcaff_gtsam.eval.sim import kimera_bags
from tcaff_gtsam.eval.sim.render import RgbdScene, render

from tcaff_gtsam.errors import ConfigError

ROBOTS = ("acl_jackal2", "sparkal2")
SECONDS, RATE, WIDTH, HEIGHT = 2.0, 10.0, 160, 120
T0_NS = 1_634_000_000 * 10**9


script = kimera_bags
SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "make_kimera_like_bag.py"


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """(out folder, truth, {robot: {topic: [(record stamp ns, message), ...]}})."""
    out = tmp_path_factory.mktemp("kimera_like")
    truth = script.write_sequence(out, ROBOTS, SECONDS, RATE, WIDTH, HEIGHT, seed=3,
                                  depth_noise=0.0)
    bags = {}
    for robot in ROBOTS:
        with AnyReader([out / f"{robot}.bag"]) as reader:
            topics: dict[str, list] = {}
            for conn, stamp, raw in reader.messages():
                topics.setdefault(conn.topic, []).append(
                    (stamp, reader.deserialize(raw, conn.msgtype), conn.msgtype))
        bags[robot] = topics
    return out, truth, bags


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def _yaw(T: np.ndarray) -> float:
    return math.atan2(T[1, 0], T[0, 0])


def _angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


def test_files_topics_types_and_counts(written):
    out, _, bags = written
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{r}.bag" for r in ROBOTS] + [f"{r}_gt_odom.csv" for r in ROBOTS])
    frames, odom = round(SECONDS * RATE), round(SECONDS * 50)
    for r in ROBOTS:
        expected = {
            f"/{r}/forward/color/image_raw/compressed": ("sensor_msgs/msg/CompressedImage",
                                                         frames),
            f"/{r}/forward/color/camera_info": ("sensor_msgs/msg/CameraInfo", frames),
            f"/{r}/forward/depth/image_rect_raw": ("sensor_msgs/msg/Image", frames),
            f"/{r}/forward/depth/camera_info": ("sensor_msgs/msg/CameraInfo", frames),
            f"/{r}/jackal_velocity_controller/odom": ("nav_msgs/msg/Odometry", odom),
        }
        assert set(bags[r]) == set(expected)
        for topic, (msgtype, count) in expected.items():
            assert len(bags[r][topic]) == count, topic
            assert all(t == msgtype for _, _, t in bags[r][topic]), topic


def test_stamps(written):
    _, truth, bags = written
    assert truth.t0_ns == T0_NS
    for r in ROBOTS:
        for topic, items in bags[r].items():
            stamps = np.array([_stamp(m) for _, m, _ in items], dtype=np.int64)
            assert [s for s, _, _ in items] == stamps.tolist(), topic  # record == header
            assert np.all(np.diff(stamps) > 0), topic
        color = np.array([_stamp(m) for _, m, _ in bags[r][f"/{r}/forward/color/camera_info"]])
        assert color.tolist() == [T0_NS + k * 100_000_000 for k in range(len(color))]
        assert np.allclose(truth.times[r], np.arange(len(color)) / RATE)
        depth = np.array([_stamp(m) for _, m, _ in bags[r][f"/{r}/forward/depth/image_rect_raw"]])
        assert (depth - color).tolist() == [4_000_000] * len(color)
        odom = [_stamp(m) for _, m, _ in bags[r][f"/{r}/jackal_velocity_controller/odom"]]
        assert odom == [T0_NS + k * 20_000_000 for k in range(len(odom))]


def test_colour_images_decode_and_match_the_render(written):
    _, truth, bags = written
    scene = RgbdScene.from_world(truth.world)
    for r in ROBOTS:
        items = bags[r][f"/{r}/forward/color/image_raw/compressed"]
        for f, (_, msg, _) in enumerate(items):
            assert msg.format == "rgb8; jpeg compressed bgr8"
            assert msg.header.frame_id == f"{r}/forward_color_optical_frame"
            assert msg.header.seq == f
            bgr = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
            assert bgr.shape == (HEIGHT, WIDTH, 3)
            if f % 5 == 0:
                rgb = render(scene, truth.T_world_body[r][f] @ truth.T_body_color,
                             truth.color_camera).rgb
                err = np.abs(bgr[..., ::-1].astype(float) - rgb)
                assert err.mean() < 2.0 and np.count_nonzero(rgb) > 0


def test_depth_is_millimetres_of_the_depth_camera(written):
    _, truth, bags = written
    scene = RgbdScene.from_world(truth.world)
    for r in ROBOTS:
        for f, (_, msg, _) in enumerate(bags[r][f"/{r}/forward/depth/image_rect_raw"]):
            assert (msg.encoding, msg.is_bigendian, msg.height, msg.width, msg.step) == (
                "16UC1", 0, HEIGHT, WIDTH, 2 * WIDTH)
            assert msg.header.frame_id == f"{r}/forward_depth_optical_frame"
            mm = np.frombuffer(msg.data, "<u2").reshape(HEIGHT, WIDTH)
            T_world_depth = truth.T_world_body[r][f] @ truth.T_body_color @ truth.T_color_depth
            depth = render(scene, T_world_depth, truth.depth_camera,
                           depth_max=truth.depth_max).depth
            assert np.count_nonzero(mm) > 0.5 * mm.size
            assert np.array_equal(mm == 0, depth == 0)
            assert np.max(np.abs(mm - 1000.0 * depth)) <= 0.5 + 1e-3


def test_camera_info_and_mounts(written):
    _, truth, bags = written
    # hfov 80 deg (colour) and 87 deg (depth), principal point at the image centre
    for name, hfov in (("color", 80.0), ("depth", 87.0)):
        f = (WIDTH / 2) / math.tan(math.radians(hfov / 2))
        K = np.array([[f, 0, (WIDTH - 1) / 2], [0, f, (HEIGHT - 1) / 2], [0, 0, 1]])
        assert np.allclose(getattr(truth, f"{name}_camera").K, K)
        for r in ROBOTS:
            images = bags[r][f"/{r}/forward/{name}/" + (
                "image_raw/compressed" if name == "color" else "image_rect_raw")]
            infos = bags[r][f"/{r}/forward/{name}/camera_info"]
            for (_, info, _), (_, image, _) in zip(infos, images, strict=True):
                assert _stamp(info) == _stamp(image)
                assert info.header.frame_id == f"{r}/forward_{name}_optical_frame"
                assert (info.height, info.width) == (HEIGHT, WIDTH)
                assert info.distortion_model == "plumb_bob"
                assert np.array_equal(info.D, np.zeros(5))
                assert np.allclose(info.K, K.ravel())
                assert np.array_equal(info.R, np.eye(3).ravel())
                assert np.allclose(info.P, np.hstack([K, np.zeros((3, 1))]).ravel())
                assert (info.binning_x, info.binning_y) == (0, 0)
                assert (info.roi.x_offset, info.roi.y_offset, info.roi.width,
                        info.roi.height) == (0, 0, 0, 0)
    # colour camera 0.6 m up, 0.2 m forward, looking 5 deg down; depth camera 5.9 cm to its left
    T = truth.T_body_color
    assert np.allclose(T[:3, 3], [0.2, 0.0, 0.6])
    p = math.radians(5.0)
    assert np.allclose(T[:3, 2], [math.cos(p), 0.0, -math.sin(p)])  # optical z: forward, down
    assert np.allclose(T[:3, 0], [0.0, -1.0, 0.0])  # optical x: right
    assert np.allclose(truth.T_color_depth, np.r_[np.c_[np.eye(3), [-0.059, 0, 0]],
                                                  [[0, 0, 0, 1]]])


def test_ground_truth_csv(written):
    out, truth, _ = written
    for r in ROBOTS:
        lines = (out / f"{r}_gt_odom.csv").read_text().splitlines()
        assert lines[0] == "#timestamp_kf,x,y,z,qw,qx,qy,qz"
        rows = [line.split(",") for line in lines[1:]]
        assert len(rows) == round(SECONDS * 10)
        assert [int(row[0]) for row in rows] == [T0_NS + k * 100_000_000
                                                 for k in range(len(rows))]
        values = np.array([[float(v) for v in row[1:]] for row in rows])
        assert np.allclose(np.linalg.norm(values[:, 3:], axis=1), 1.0)
        assert np.allclose(values[:, [2, 4, 5]], 0.0)
        # the colour frames are at 10 Hz too, so row k is frame k
        T = truth.T_world_body[r]
        assert np.allclose(values[:, :2], T[:, :2, 3], atol=1e-5)
        for (qw, qz), T_k in zip(values[:, [3, 6]], T, strict=True):
            assert _angle_diff(2 * math.atan2(qz, qw), _yaw(T_k)) < 1e-6
    a, b = (np.loadtxt(out / f"{r}_gt_odom.csv", delimiter=",", comments="#") for r in ROBOTS)
    assert np.linalg.norm(a[0, 1:3] - b[0, 1:3]) > 1.0  # one world frame, robots apart


def test_odometry_is_the_drifting_odometry(written):
    _, truth, bags = written
    for r in ROBOTS:
        items = bags[r][f"/{r}/jackal_velocity_controller/odom"]
        for _, msg, _ in items:
            assert (msg.header.frame_id, msg.child_frame_id) == (f"{r}/odom", f"{r}/base")
            q, pos = msg.pose.pose.orientation, msg.pose.pose.position
            assert pos.z == 0.0 and q.x == 0.0 and q.y == 0.0
            assert math.isclose(q.w**2 + q.z**2, 1.0)
            assert not np.any(msg.pose.covariance) and not np.any(msg.twist.covariance)
        first = items[0][1].pose.pose
        assert (first.position.x, first.position.y, first.orientation.z) == (0.0, 0.0, 0.0)
        by_stamp = {_stamp(m): m.pose.pose for _, m, _ in items}
        T_wb, T_ob = truth.T_world_body[r], truth.T_odom_body[r]
        for t, T_o, T_w in zip(truth.times[r], T_ob, T_wb, strict=True):
            pose = by_stamp[T0_NS + round(t * 1e9)]
            assert np.allclose([pose.position.x, pose.position.y], T_o[:2, 3], atol=1e-12)
            yaw = 2 * math.atan2(pose.orientation.z, pose.orientation.w)
            assert _angle_diff(yaw, _yaw(T_o)) < 1e-9
            # the odometry frame is the first true pose, and drifts only a little in 2 s
            T_w_from_odom = T_wb[0] @ T_o
            assert np.linalg.norm(T_w_from_odom[:2, 3] - T_w[:2, 3]) < 0.1
            assert _angle_diff(_yaw(T_w_from_odom), _yaw(T_w)) < math.radians(2)
        drift = np.linalg.norm((T_wb[0] @ T_ob[-1])[:2, 3] - T_wb[-1][:2, 3])
        assert drift > 1e-6  # it really drifts


@pytest.mark.parametrize(("kwargs", "names"), [
    ({"robots": ("a",)}, "robots"),
    ({"robots": ("a", "a")}, "robots"),
    ({"robots": ("a", "b/c")}, "robots"),
    ({"rate": 15.0}, "rate"),
    ({"seconds": 0.0}, "seconds"),
    ({"width": 4}, "width"),
    ({"seconds": 7200.02}, r"seconds = 7200.02: .* at most 7200 s \(MAX_DURATION\)"),
    ({"width": 4097}, r"width = 4097: must be an int in \[8, 4096\] pixels \(MAX_IMAGE_SIDE\)"),
    ({"height": 10**12}, r"height = 1000000000000: .*\(MAX_IMAGE_SIDE\)"),
    ({"depth_noise": -1.0}, "depth_noise"),
    ({"camera_pitch_deg": math.nan}, "camera_pitch_deg"),
])
def test_bad_arguments_raise_config_error(tmp_path, kwargs, names):
    with pytest.raises(ConfigError, match=names):
        script.write_sequence(tmp_path / "out", **kwargs)
    assert not (tmp_path / "out").exists()


def test_refuses_to_overwrite(written):
    out, _, _ = written
    with pytest.raises(ConfigError, match="exists already"):
        script.write_sequence(out, seconds=0.1)


def test_help(capsys, monkeypatch):
    """The script's --help, run in this process (its imports are this module's)."""
    spec = importlib.util.spec_from_file_location("make_kimera_like_bag", SCRIPT)
    command = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(command)
    monkeypatch.setattr(sys, "argv", [str(SCRIPT), "--help"])
    with pytest.raises(SystemExit) as done:
        command.main()
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert "Kimera-Multi" in out and "--seconds" in out
