"""The RGB-D sequence loaders (7-Scenes and TUM RGB-D layouts) and the single real frames'
(Redwood), on small folders the tests write in each format and on the real 7-Scenes sequence
in ../shared when it is there."""

from __future__ import annotations

import json
import math
import re
import struct
import tempfile
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from tcaff_gtsam.eval.datasets import rgbd_sequence as rs
from tcaff_gtsam.eval.datasets.rgbd_frames import load_redwood
from test_text_tables import fifo_holding

from tcaff_gtsam.errors import DataError

REAL = Path(__file__).resolve().parents[3] / "shared/data/rgbd/7scenes_redkitchen"
T0 = 1305031102.175304  # s; a TUM-like time stamp (float64 holds it to about 2e-7 s)
TUM_HEADER = "# written by the tests\n# file: 'test.bag'\n# timestamp columns\n"
HEADER_LINES = 3
GRAVITY = np.array([0.1, 0.9, 0.4]) / np.linalg.norm([0.1, 0.9, 0.4])
FAST = settings(max_examples=25, deadline=None)


def png(image: np.ndarray, ext: str = ".png") -> bytes:
    ok, data = cv2.imencode(ext, image)
    assert ok
    return data.tobytes()


#: uniform 640 x 480 images: tiny files that still carry a real header
COLOR_PNG = png(np.full((480, 640, 3), 90, np.uint8))
DEPTH_PNG = png(np.full((480, 640), 2000, np.uint16))


def rotations(draw_angle_max: float = math.pi):
    """Strategy: a rotation (3, 3) from a random unit quaternion."""
    return st.tuples(*[st.floats(-1, 1)] * 4).filter(
        lambda q: np.linalg.norm(q) > 0.2).map(
        lambda q: Rotation.from_quat(np.array(q) / np.linalg.norm(q)).as_matrix())


def pose_text(T: np.ndarray, fmt: str = "%.18e") -> str:
    return "".join(" ".join(fmt % v for v in row) + "\n" for row in T)


# -- 7-Scenes ----------------------------------------------------------------------------------


def write_7scenes(folder: Path, poses: dict[int, np.ndarray], color_ext: str = "png",
                  gravity: str | None = "0\n0\n-2\n", small: bool = False,
                  seed: int = 0) -> Path:
    """Frames `poses` {number: T_world_camera}; small: random 64 x 48 images and a
    camera-intrinsics.txt for them, else uniform 640 x 480 images (default intrinsics)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for n, T in poses.items():
        stem = folder / f"frame-{n:06d}"
        if small:
            color = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
            depth = rng.integers(0, 4000, (48, 64), dtype=np.uint16)
            depth[0, :5] = 65535
            depth[1, :5] = 0
            (Path(f"{stem}.color.{color_ext}")).write_bytes(png(color, f".{color_ext}"))
            Path(f"{stem}.depth.png").write_bytes(png(depth))
        else:
            Path(f"{stem}.color.{color_ext}").write_bytes(
                COLOR_PNG if color_ext == "png" else png(np.zeros((480, 640, 3), np.uint8),
                                                         ".jpg"))
            Path(f"{stem}.depth.png").write_bytes(DEPTH_PNG)
        Path(f"{stem}.pose.txt").write_text(pose_text(T))
    if small:
        (folder / "camera-intrinsics.txt").write_text("58.5 0 32\n0 58.5 24\n0 0 1\n")
    if gravity is not None:
        (folder / "gravity-direction.txt").write_text(gravity)
    return folder


def some_poses(ids, seed: int = 1) -> dict[int, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {}
    for n in ids:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        out[n] = T
    return out


def test_7scenes_frames_times_poses_and_gravity(tmp_path):
    poses = some_poses([0, 5, 10, 15])
    folder = write_7scenes(tmp_path / "chess", poses, color_ext="jpg")
    seq = rs.read_7scenes(folder)
    assert seq.layout == "7scenes" and seq.name == "chess" and len(seq) == 4
    assert seq.frame_ids.dtype == np.int64 and seq.frame_ids.tolist() == [0, 5, 10, 15]
    np.testing.assert_array_equal(seq.times, np.array([0, 5, 10, 15]) / 30.0)
    np.testing.assert_allclose(seq.T_world_camera, np.stack(list(poses.values())), atol=1e-12)
    np.testing.assert_array_equal(seq.gravity, [0.0, 0.0, -1.0])  # normalised from 0 0 -2
    assert seq.depth_scale == 1000.0
    assert (seq.camera.width, seq.camera.height, seq.camera.fx, seq.camera.fy, seq.camera.cx,
            seq.camera.cy) == (640, 480, 585.0, 585.0, 320.0, 240.0)
    assert [p.name for p in seq.color_paths] == [f"frame-{n:06d}.color.jpg" for n in poses]
    assert [p.name for p in seq.depth_paths] == [f"frame-{n:06d}.depth.png" for n in poses]
    np.testing.assert_array_equal(rs.read_sequence(folder, fps=15.0).times,
                                  np.array([0, 5, 10, 15]) / 15.0)
    with pytest.raises(ValueError):  # the loaded arrays are read-only: the sequence is frozen
        seq.T_world_camera[0, 0, 0] = 2.0


def test_7scenes_read_gives_rgb_and_depth_with_65535_as_none(tmp_path):
    folder = write_7scenes(tmp_path / "small", some_poses([3, 7]), small=True)
    seq = rs.read_sequence(folder)
    assert (seq.camera.width, seq.camera.height, seq.camera.fx, seq.camera.cx) == (
        64, 48, 58.5, 32.0)
    for k in range(2):
        rgb, depth = seq.read(k)
        bgr = cv2.imread(str(seq.color_paths[k]))
        raw = cv2.imread(str(seq.depth_paths[k]), cv2.IMREAD_UNCHANGED)
        assert rgb.dtype == np.uint8 and rgb.shape == (48, 64, 3)
        np.testing.assert_array_equal(rgb, bgr[..., ::-1])
        assert depth.dtype == np.uint16 and depth.shape == (48, 64)
        assert (raw == 65535).sum() >= 5 and not (depth == 65535).any()
        np.testing.assert_array_equal(depth, np.where(raw == 65535, 0, raw))
    with pytest.raises(DataError, match="k = 2"):
        seq.read(2)


def test_7scenes_missing_files_name_the_file(tmp_path):
    for gone, what in (("depth.png", "depth.png"), ("pose.txt", "pose.txt"),
                       ("color.png", "color.png")):
        folder = write_7scenes(tmp_path / gone, some_poses([0, 5, 10]))
        (folder / f"frame-000005.{gone}").unlink()
        with pytest.raises(DataError, match=rf"frame-000005\.{what}.*no such file; frame 5"):
            rs.read_7scenes(folder)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DataError, match=f"{empty}: no 7-Scenes frames"):
        rs.read_7scenes(empty)
    with pytest.raises(DataError, match=f"{empty}: neither a 7-Scenes .* nor a TUM"):
        rs.read_sequence(empty)
    with pytest.raises(DataError, match="no such folder"):
        rs.read_sequence(tmp_path / "nowhere")


def test_7scenes_frame_numbers_must_be_unique(tmp_path):
    folder = write_7scenes(tmp_path / "twice", some_poses([0, 5]))
    (folder / "frame-000005.color.jpg").write_bytes(png(np.zeros((480, 640, 3), np.uint8),
                                                        ".jpg"))
    with pytest.raises(DataError, match=r"frame 5 again.*unique"):
        rs.read_7scenes(folder)
    folder = write_7scenes(tmp_path / "widths", some_poses([0, 5]))
    (folder / "frame-5.pose.txt").write_text(pose_text(np.eye(4)))
    with pytest.raises(DataError, match="frame 5 again"):
        rs.read_7scenes(folder)
    folder = write_7scenes(tmp_path / "letters", some_poses([0]))
    (folder / "frame-00x1.pose.txt").write_text(pose_text(np.eye(4)))
    with pytest.raises(DataError, match=r"frame-00x1\.pose\.txt: expected a frame number"):
        rs.read_7scenes(folder)


@pytest.mark.parametrize(("text", "message"), [
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", r"4 x 4 matrix .*\[4, 4, 4\]"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1 7\n", r"4 x 4 matrix"),
    ("1 0 0 0\n0 one 0 0\n0 0 1 0\n0 0 0 1\n", "not a number: 'one'"),
    ("1 0 0 0\n0 1 0 nan\n0 0 1 0\n0 0 0 1\n", "non-finite"),
    ("1.1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"not a rigid transform: max \|R R' - I\| = 0.21"),
    ("-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"det R = -1"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", r"last row"),
])
def test_7scenes_bad_pose_files_name_the_file(tmp_path, text, message):
    folder = write_7scenes(tmp_path / "bad", some_poses([0, 5]))
    path = folder / "frame-000005.pose.txt"
    path.write_text(text)
    with pytest.raises(DataError, match=message) as info:
        rs.read_7scenes(folder)
    assert str(info.value).startswith(f"{path}: ")


@FAST
@given(R=rotations(), t=st.tuples(*[st.floats(-50, 50)] * 3), digits=st.sampled_from([4, 6, 17]))
def test_7scenes_poses_round_trip_and_come_back_orthonormal(R, t, digits):
    """Poses stored to a few digits come back as the nearest exact rotation."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_7scenes(Path(tmp) / "s", {0: T})
        (folder / "frame-000000.pose.txt").write_text(pose_text(T, f"%.{digits}f"))
        got = rs.read_7scenes(folder).T_world_camera[0]
    R_got = got[:3, :3]
    np.testing.assert_allclose(R_got @ R_got.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R_got) > 0
    np.testing.assert_allclose(got, T, atol=3 * 10.0 ** -digits)
    np.testing.assert_array_equal(got[3], [0, 0, 0, 1])


def test_7scenes_camera_intrinsics_file_and_image_size(tmp_path):
    folder = write_7scenes(tmp_path / "k", some_poses([0]))
    (folder / "camera-intrinsics.txt").write_text("500 0 319\n0 501 241\n0 0 1\n")
    cam = rs.read_7scenes(folder).camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (500, 501, 319, 241, 640,
                                                                        480)
    (folder / "camera-intrinsics.txt").write_text("500 0 319\n0 501 241\n")
    with pytest.raises(DataError, match=r"camera-intrinsics.txt: expected a 3 x 3 matrix"):
        rs.read_7scenes(folder)
    (folder / "camera-intrinsics.txt").write_text("500 0 319\n0 501 241\n0 0 x\n")
    with pytest.raises(DataError, match=r"camera-intrinsics.txt:3: not a number: 'x'"):
        rs.read_7scenes(folder)
    (folder / "camera-intrinsics.txt").write_text("500 0 1319\n0 501 241\n0 0 1\n")
    with pytest.raises(DataError, match=r"principal point \(1319, 241\) lies outside"):
        rs.read_7scenes(folder)
    (folder / "camera-intrinsics.txt").unlink()
    (folder / "frame-000000.color.png").write_bytes(png(np.zeros((240, 320, 3), np.uint8)))
    with pytest.raises(DataError, match=r"depth.png: the depth image is 640 x 480 pixels but "
                                        r"the colour image .*color.png is 320 x 240"):
        rs.read_7scenes(folder)
    (folder / "frame-000000.depth.png").write_bytes(png(np.zeros((240, 320), np.uint16)))
    with pytest.raises(DataError, match=r"frame-000000.color.png: the image is 320 x 240 pixels "
                                        r"but the 7-Scenes intrinsics are for 640 x 480"):
        rs.read_7scenes(folder)


@pytest.mark.parametrize("gravity", [[0, 0, 0], [1, float("nan"), 0], [1, 2], "up",
                                     [1, 2, 3, 4], [[1, 2, 3]], None])
def test_gravity_argument_is_checked(tmp_path, gravity):
    folder = write_7scenes(tmp_path / "g", some_poses([0]), gravity=None)
    want = "gravity is unknown.*gravity-direction.txt" if gravity is None else "gravity = "
    with pytest.raises(DataError, match=want):
        rs.read_7scenes(folder, gravity=gravity)


def test_gravity_argument_wins_over_the_file_and_is_normalised(tmp_path):
    folder = write_7scenes(tmp_path / "g", some_poses([0]), gravity="broken\n")
    np.testing.assert_allclose(rs.read_7scenes(folder, gravity=(0, 3e-300, 4e-300)).gravity,
                               [0, 0.6, 0.8], atol=1e-15)
    with pytest.raises(DataError, match=r"gravity-direction.txt:1: not a number: 'broken'"):
        rs.read_7scenes(folder)
    (folder / "gravity-direction.txt").write_text("0 0\n")
    with pytest.raises(DataError, match=r"gravity-direction\.txt: expected 3 numbers.*got 2"):
        rs.read_7scenes(folder)
    (folder / "gravity-direction.txt").write_text("0 0 1\n")
    np.testing.assert_array_equal(rs.read_7scenes(folder).gravity, [0, 0, 1])


@pytest.mark.parametrize("fps", [0, -30, float("nan"), float("inf"), "30", True])
def test_fps_must_be_finite_and_positive(tmp_path, fps):
    folder = write_7scenes(tmp_path / "f", some_poses([0]))
    with pytest.raises(DataError, match="fps = "):
        rs.read_7scenes(folder, fps=fps)


def test_read_refuses_missing_unreadable_and_wrong_images(tmp_path):
    folder = write_7scenes(tmp_path / "r", some_poses([0, 1, 2, 3, 4]), small=True)
    seq = rs.read_7scenes(folder)
    seq.color_paths[0].unlink()
    seq.depth_paths[1].write_bytes(b"not a png")
    seq.depth_paths[2].write_bytes(png(np.zeros((48, 64), np.uint8)))
    seq.color_paths[3].write_bytes(png(np.zeros((24, 32, 3), np.uint8)))
    seq.color_paths[4].write_bytes(png(np.zeros((48, 64, 3), np.uint16)))
    for k, message in enumerate(["no such colour image", "cannot read the depth image",
                                 "depth image is uint8", "colour image is 32 x 24 pixels; the "
                                 "sequence's camera is 64 x 48", "colour image has dtype uint16"]):
        path = seq.color_paths[k] if k in (0, 3, 4) else seq.depth_paths[k]
        with pytest.raises(DataError, match=message) as info:
            seq.read(k)
        assert str(info.value).startswith(f"{path}: ")


@FAST
@given(kind=st.sampled_from(["color.jpg", "color.png", "depth.png"]),
       share=st.floats(0.0, 1.0, exclude_max=True))
@example(kind="color.jpg", share=0.5)
def test_read_refuses_an_image_cut_short_at_any_byte(kind, share):
    """cv2.imread decodes a JPEG cut short with its missing rows grey (libjpeg only warns);
    an image cut anywhere is refused, naming the file and the frame."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_7scenes(Path(tmp) / "cut", some_poses([0, 5]), small=True,
                               color_ext="jpg" if kind == "color.jpg" else "png")
        seq = rs.read_7scenes(folder)
        path = folder / f"frame-000005.{kind}"
        data = path.read_bytes()
        path.write_bytes(data[:int(share * len(data))])
        with pytest.raises(DataError) as info:
            seq.read(1)
        seq.read(0)  # the frame whole
    assert str(info.value).startswith(f"{path}: ") and str(info.value).endswith("(frame 5)")


def test_redwood_frames_refuse_a_jpeg_cut_short(tmp_path):
    for kind in ("color", "depth"):
        (tmp_path / kind).mkdir()
    K = [58.5, 0.0, 0.0, 0.0, 58.5, 0.0, 32.0, 24.0, 1.0]  # by column
    (tmp_path / "camera_primesense.json").write_text(
        json.dumps({"width": 64, "height": 48, "intrinsic_matrix": K}))
    (tmp_path / "odometry.log").write_text("0 0 1\n" + pose_text(np.eye(4), "%g") + "\n")
    colour = png(np.random.default_rng(0).integers(0, 256, (48, 64, 3), np.uint8), ".jpg")
    (tmp_path / "color" / "00000.jpg").write_bytes(colour)
    (tmp_path / "depth" / "00000.png").write_bytes(png(np.full((48, 64), 1500, np.uint16)))
    assert load_redwood(tmp_path)[0].rgb.shape == (48, 64, 3)
    (tmp_path / "color" / "00000.jpg").write_bytes(colour + bytes(16))  # padded: whole
    assert load_redwood(tmp_path)[0].rgb.shape == (48, 64, 3)
    (tmp_path / "color" / "00000.jpg").write_bytes(colour[:-100])
    with pytest.raises(DataError, match=r"00000\.jpg: the image is cut short"):
        load_redwood(tmp_path)


# -- TUM RGB-D ---------------------------------------------------------------------------------


def stamp(t: float) -> float:
    """The time as the files hold it (6 decimals)."""
    return float(f"{t:.6f}")


def truth_pose(t: float) -> np.ndarray:
    """(4, 4) a camera turning at a constant rate about a fixed axis and moving at constant
    velocity: what linear interpolation and slerp reproduce exactly."""
    T = np.eye(4)
    s = t - T0
    base = Rotation.from_rotvec([0.3, -0.2, 0.5])
    T[:3, :3] = (base * Rotation.from_rotvec(s * np.array([0.4, 1.1, -0.3]))).as_matrix()
    T[:3, 3] = np.array([1.0, -2.0, 0.5]) + s * np.array([0.3, 0.1, -0.2])
    return T


def truth_rows(times, pose=truth_pose) -> list[str]:
    rows = []
    for t in map(stamp, times):
        T = pose(t)
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        rows.append(f"{t:.6f} " + " ".join(f"{v:.17g}" for v in (*T[:3, 3], *q)))
    return rows


def write_tum(folder: Path, color: list[float], depth: list[float], truth: list[str],
              accelerometer: list[str] | None = None, gravity: str | None = None) -> Path:
    """A TUM RGB-D folder; images named by their row (rgb/0003.png), so that time stamps can
    be changed without renaming them."""
    (folder / "rgb").mkdir(parents=True, exist_ok=True)
    (folder / "depth").mkdir(exist_ok=True)
    for kind, times, data in (("rgb", color, COLOR_PNG), ("depth", depth, DEPTH_PNG)):
        rows = []
        for k, t in enumerate(times):
            (folder / kind / f"{k:04d}.png").write_bytes(data)
            rows.append(f"{t:.6f} {kind}/{k:04d}.png")
        (folder / f"{kind}.txt").write_text(TUM_HEADER + "\n".join(rows) + "\n")
    (folder / "groundtruth.txt").write_text(TUM_HEADER + "\n".join(truth) + "\n")
    if accelerometer is not None:
        (folder / "accelerometer.txt").write_text(TUM_HEADER + "\n".join(accelerometer) + "\n")
    if gravity is not None:
        (folder / "gravity-direction.txt").write_text(gravity)
    return folder


def accel_rows(times, pose=truth_pose, down=GRAVITY, axes=None) -> list[str]:
    """Readings at rest: the reaction to gravity (up) in the camera's axes (`axes` turns them
    into another sensor's)."""
    axes = np.eye(3) if axes is None else axes
    rows = []
    for t in times:
        a = axes @ pose(t)[:3, :3].T @ (-9.81 * down)
        rows.append(f"{t:.6f} {a[0]:.9f} {a[1]:.9f} {a[2]:.9f}")
    return rows


def standard_tum(folder: Path, **kwargs) -> tuple[Path, np.ndarray]:
    """30 colour frames at 30 Hz; depth 4 ms after each but the 6th; truth at 100 Hz on
    offsets -0.045..0.605 s with a gap from 0.295 to 0.455 s."""
    offsets = np.arange(30) / 30.0
    color = [stamp(T0 + o) for o in offsets]
    depth = [stamp(T0 + o + 0.004) for k, o in enumerate(offsets) if k != 5]
    grid = -0.045 + 0.01 * np.arange(66)
    grid = grid[(grid < 0.3) | (grid > 0.45)]
    truth = [stamp(T0 + o) for o in grid]
    write_tum(folder, color, depth, truth_rows(truth), **kwargs)
    return folder, offsets


def test_tum_pairs_interpolates_and_leaves_no_truth_as_nan(tmp_path):
    folder, offsets = standard_tum(tmp_path / "rgbd_dataset_freiburg1_xyz")
    seq = rs.read_sequence(folder, gravity=GRAVITY)
    kept = [k for k in range(30) if k != 5]
    assert seq.layout == "tum" and seq.name == "rgbd_dataset_freiburg1_xyz"
    assert seq.frame_ids.tolist() == kept and seq.frame_ids.dtype == np.int64
    assert seq.skipped == {"colour frames without depth within 0.02 s": 1}
    np.testing.assert_array_equal(seq.times, [stamp(T0 + offsets[k]) for k in kept])
    assert [p.name for p in seq.color_paths] == [f"{k:04d}.png" for k in kept]
    # depth.txt lacks the 6th frame: rows after it are one lower
    assert [p.name for p in seq.depth_paths] == [f"{k - (k > 5):04d}.png" for k in kept]
    no_truth = np.array([(0.295 < offsets[k] < 0.455) or offsets[k] > 0.605 for k in kept])
    assert 0 < no_truth.sum() < len(kept)
    assert np.isnan(seq.T_world_camera[no_truth]).all()
    want = np.stack([truth_pose(t) for t in seq.times[~no_truth]])
    np.testing.assert_allclose(seq.T_world_camera[~no_truth], want, atol=2e-6)
    assert seq.depth_scale == 5000.0
    cam = seq.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (517.3, 516.5, 318.6,
                                                                        255.3, 640, 480)
    rgb, depth = seq.read(0)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8 and (rgb == 90).all()
    assert depth.shape == (480, 640) and depth.dtype == np.uint16 and (depth == 2000).all()
    # TUM keeps 65535 as a depth value (only 7-Scenes uses it for none)
    seq.depth_paths[0].write_bytes(png(np.full((480, 640), 65535, np.uint16)))
    assert (seq.read(0)[1] == 65535).all()
    assert len(rs.read_tum(folder, GRAVITY, max_difference=0.05).skipped) == 0


@pytest.mark.parametrize(("name", "K"), [
    ("rgbd_dataset_freiburg2_desk", (520.9, 521.0, 325.1, 249.7)),
    ("rgbd_dataset_freiburg3_long_office", (535.4, 539.2, 320.1, 247.6)),
    ("my_kinect", (525.0, 525.0, 319.5, 239.5)),
])
def test_tum_intrinsics_by_folder_name(tmp_path, name, K):
    folder = write_tum(tmp_path / name, [T0], [T0], truth_rows([T0]))
    cam = rs.read_tum(folder, GRAVITY).camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == K
    (folder / "camera-intrinsics.txt").write_text("600 0 300\n0 601 200\n0 0 1\n")
    cam = rs.read_tum(folder, GRAVITY).camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (600, 601, 300, 200)


def test_tum_refuses_an_image_size_its_camera_does_not_have(tmp_path):
    folder = write_tum(tmp_path / "rgbd_dataset_freiburg1_small", [T0], [T0], truth_rows([T0]))
    (folder / "rgb/0000.png").write_bytes(png(np.zeros((240, 320, 3), np.uint8)))
    (folder / "depth/0000.png").write_bytes(png(np.zeros((240, 320), np.uint16)))
    with pytest.raises(DataError, match=r"rgb/0000.png: the image is 320 x 240 pixels but the "
                                        r"TUM freiburg1 intrinsics are for 640 x 480"):
        rs.read_tum(folder, GRAVITY)


def test_tum_missing_files_are_named(tmp_path):
    folder = write_tum(tmp_path / "t", [T0], [T0], truth_rows([T0]))
    (folder / "groundtruth.txt").unlink()
    (folder / "depth.txt").unlink()
    with pytest.raises(DataError, match=r"missing .*depth.txt, .*groundtruth.txt \(a TUM"):
        rs.read_tum(folder, GRAVITY)
    folder = write_tum(tmp_path / "u", [T0, T0 + 0.1], [T0], truth_rows([T0]))
    (folder / "rgb/0001.png").unlink()
    with pytest.raises(DataError, match=rf"{folder / 'rgb.txt'}:{HEADER_LINES + 2}: no such "
                                        r"image .*rgb/0001.png"):
        rs.read_tum(folder, GRAVITY)
    folder = write_tum(tmp_path / "v", [T0], [T0 + 1.0], truth_rows([T0]))
    with pytest.raises(DataError, match=r"no colour frame of rgb\.txt has a depth frame"):
        rs.read_tum(folder, GRAVITY)
    (folder / "groundtruth.txt").write_text(TUM_HEADER)
    with pytest.raises(DataError, match=r"groundtruth\.txt: no rows"):
        rs.read_tum(folder, GRAVITY, max_difference=2.0)


CORRUPTIONS = ["x1", "nan", "inf", "-inf", "1,5", "DROP", "EXTRA"]


@FAST
@given(table=st.sampled_from(["rgb.txt", "depth.txt", "groundtruth.txt", "accelerometer.txt"]),
       row=st.integers(0, 9), column=st.integers(0, 7), corruption=st.sampled_from(CORRUPTIONS))
def test_tum_corrupted_field_names_file_and_line(table, row, column, corruption):
    times = [stamp(T0 + 0.01 * k) for k in range(10)]
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_tum(Path(tmp) / "rgbd_dataset_freiburg1_t", times, times,
                           truth_rows(times), accel_rows(times))
        path = folder / table
        lines = path.read_text().splitlines()
        fields = lines[HEADER_LINES + row].split()
        k = column % len(fields)
        if corruption == "DROP":
            del fields[k]
        elif corruption == "EXTRA":
            fields.append("0.5")
        else:
            fields[k] = corruption
        lines[HEADER_LINES + row] = " ".join(fields)
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(DataError) as info:
            rs.read_sequence(folder)
    assert f"{path}:{HEADER_LINES + row + 1}: " in str(info.value)


@FAST
@given(table=st.sampled_from(["rgb.txt", "depth.txt", "groundtruth.txt", "accelerometer.txt"]),
       row=st.integers(1, 9), repeat=st.booleans())
def test_tum_time_stamps_must_increase(table, row, repeat):
    times = [stamp(T0 + 0.01 * k) for k in range(10)]
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_tum(Path(tmp) / "t", times, times, truth_rows(times), accel_rows(times))
        path = folder / table
        lines = path.read_text().splitlines()
        fields = lines[HEADER_LINES + row].split()
        fields[0] = f"{times[row - 1] - (0.0 if repeat else 0.005):.6f}"
        lines[HEADER_LINES + row] = " ".join(fields)
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(DataError, match="repeats" if repeat else "goes backwards") as info:
            rs.read_tum(folder)
    assert f"{path}:{HEADER_LINES + row + 1}: time stamp" in str(info.value)


@FAST
@given(R=rotations(), t=st.tuples(*[st.floats(-50, 50)] * 3), scale=st.floats(0.991, 1.009),
       flip=st.booleans())
def test_tum_quaternions_round_trip(R, t, scale, flip):
    """Quaternions off unit length by less than 1e-2 are normalised; -q is the same rotation."""
    q = Rotation.from_matrix(R).as_quat() * scale * (-1 if flip else 1)
    row = f"{T0:.6f} " + " ".join(f"{v:.17g}" for v in (*t, *q))
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_tum(Path(tmp) / "t", [T0], [T0], [row])
        got = rs.read_tum(folder, GRAVITY).T_world_camera[0]
    np.testing.assert_allclose(got[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(got[:3, 3], t, atol=1e-12)
    np.testing.assert_array_equal(got[3], [0, 0, 0, 1])


def test_tum_quaternion_far_from_unit_is_refused(tmp_path):
    rows = [f"{T0:.6f} 0 0 0 0 0 0 1", f"{T0 + 0.01:.6f} 0 0 0 0 0 0 1.05"]
    folder = write_tum(tmp_path / "t", [T0], [T0], rows)
    with pytest.raises(DataError, match=rf"groundtruth.txt:{HEADER_LINES + 2}: the quaternion .*"
                                        r"norm 1.05, off 1 by 0.05"):
        rs.read_tum(folder, GRAVITY)


@FAST
@given(R0=rotations(), axis=st.tuples(*[st.floats(-1, 1)] * 3).filter(
    lambda a: np.linalg.norm(a) > 0.1), angle=st.floats(0.01, 0.95 * math.pi),
    flip=st.booleans())
def test_tum_slerp_midpoint_is_the_half_angle_rotation(R0, axis, angle, flip):
    axis = np.array(axis) / np.linalg.norm(axis)
    R1 = R0 @ Rotation.from_rotvec(angle * axis).as_matrix()
    rows = []
    for t, R, p in ((100.0, R0, (0.0, 1.0, 2.0)), (100.05, R1, (1.0, 3.0, -2.0))):
        q = Rotation.from_matrix(R).as_quat() * (-1 if flip and t > 100 else 1)
        rows.append(f"{t:.6f} " + " ".join(f"{v:.17g}" for v in (*p, *q)))
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_tum(Path(tmp) / "t", [100.025], [100.025], rows)
        got = rs.read_tum(folder, GRAVITY).T_world_camera[0]
    np.testing.assert_allclose(got[:3, :3], R0 @ Rotation.from_rotvec(angle / 2 * axis)
                               .as_matrix(), atol=1e-9)
    np.testing.assert_allclose(got[:3, 3], (0.5, 2.0, 0.0), atol=1e-9)


def test_tum_truth_gap_over_a_tenth_of_a_second_gives_nan(tmp_path):
    truth = truth_rows([T0, T0 + 0.1, T0 + 0.25])
    folder = write_tum(tmp_path / "t", [T0 - 0.01, T0 + 0.05, T0 + 0.1, T0 + 0.2, T0 + 0.3],
                       [T0 - 0.01, T0 + 0.05, T0 + 0.1, T0 + 0.2, T0 + 0.3], truth)
    T = rs.read_tum(folder, GRAVITY).T_world_camera
    assert np.isnan(T[[0, 3, 4]]).all()  # before, in a 0.15 s gap, after
    np.testing.assert_allclose(T[1], truth_pose(T0 + 0.05), atol=1e-6)
    np.testing.assert_allclose(T[2], truth_pose(stamp(T0 + 0.1)), atol=1e-9)


@FAST
@given(color=st.lists(st.integers(0, 120), min_size=1, max_size=15, unique=True),
       depth=st.lists(st.integers(0, 120), min_size=1, max_size=15, unique=True),
       max_difference=st.sampled_from([0.0, 1 / 64, 0.02, 0.3]))
def test_tum_pairs_each_colour_frame_with_the_nearest_depth_frame(color, depth,
                                                                   max_difference):
    """On a grid of 1/64 s (exact in float64 and in six decimals) ties are frequent: a colour
    frame halfway between two depth frames takes the earlier one."""
    base = math.floor(T0)
    color_t = [base + k / 64 for k in sorted(color)]
    depth_t = [base + k / 64 for k in sorted(depth)]
    d = np.array(depth_t)
    nearest = [int(np.argmin(np.abs(d - t))) for t in color_t]  # first of equals: earlier
    want = [(k, j) for k, (t, j) in enumerate(zip(color_t, nearest, strict=True))
            if abs(d[j] - t) <= max_difference]
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_tum(Path(tmp) / "t", color_t, depth_t, truth_rows([base, base + 2]))
        if not want:
            with pytest.raises(DataError, match="no colour frame"):
                rs.read_tum(folder, GRAVITY, max_difference)
            return
        seq = rs.read_tum(folder, GRAVITY, max_difference)
    assert seq.frame_ids.tolist() == [k for k, _ in want]
    assert [p.name for p in seq.depth_paths] == [f"{j:04d}.png" for _, j in want]
    assert sum(seq.skipped.values()) == len(color_t) - len(want)
    assert np.all(np.diff(seq.times) > 0)


def test_tum_gravity_from_accelerometer_in_the_camera_axes(tmp_path):
    folder, _ = standard_tum(tmp_path / "t")
    times = [stamp(T0 + o) for o in np.arange(-0.2, 1.0, 0.01)]  # some outside the truth
    (folder / "accelerometer.txt").write_text(TUM_HEADER + "\n".join(accel_rows(times)) + "\n")
    np.testing.assert_allclose(rs.read_tum(folder).gravity, GRAVITY, atol=1e-6)
    # a gravity file comes first, even with an accelerometer there
    (folder / "gravity-direction.txt").write_text("0\n0\n-1\n")
    np.testing.assert_array_equal(rs.read_sequence(folder).gravity, [0, 0, -1])


def test_tum_accelerometer_in_other_axes_is_refused(tmp_path):
    def tumbling(t: float) -> np.ndarray:  # turns enough to tell frames apart
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec((t - T0) * np.array([2.0, 1.0, 0.5])).as_matrix()
        return T

    times = [stamp(T0 + 0.01 * k) for k in range(100)]
    body = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # x fwd, y left
    folder = write_tum(tmp_path / "t", times[:1], times[:1], truth_rows(times, tumbling),
                       accel_rows(times, tumbling, axes=body))
    with pytest.raises(DataError, match=r"accelerometer.txt: the accelerometer readings do not "
                                        r"agree in the world frame .*not the colour camera's "
                                        r"optical axes; give .* `gravity` argument"):
        rs.read_tum(folder)
    (folder / "accelerometer.txt").write_text(
        TUM_HEADER + "\n".join(accel_rows(times, tumbling)) + "\n")
    np.testing.assert_allclose(rs.read_tum(folder).gravity, GRAVITY, atol=1e-6)
    (folder / "accelerometer.txt").write_text(
        TUM_HEADER + "\n".join(accel_rows([t + 5 for t in times], tumbling)) + "\n")
    with pytest.raises(DataError, match="no reading lies within the ground truth's span"):
        rs.read_tum(folder)
    (folder / "accelerometer.txt").unlink()
    with pytest.raises(DataError, match=r"gravity is unknown .*gravity-direction.txt.*`gravity`"):
        rs.read_tum(folder)


def test_tum_max_difference_is_checked(tmp_path):
    folder = write_tum(tmp_path / "t", [T0], [T0], truth_rows([T0]))
    for bad in (-0.01, float("nan"), float("inf"), "0.02"):
        with pytest.raises(DataError, match="max_difference = "):
            rs.read_tum(folder, GRAVITY, bad)


def test_read_sequence_refuses_a_folder_of_both_layouts(tmp_path):
    folder = write_tum(tmp_path / "t", [T0], [T0], truth_rows([T0]))
    (folder / "frame-000000.pose.txt").write_text(pose_text(np.eye(4)))
    with pytest.raises(DataError, match="holds both"):
        rs.read_sequence(folder, GRAVITY)


# -- the real 7-Scenes sequence ----------------------------------------------------------------


@pytest.mark.skipif(not REAL.is_dir(), reason="the 7-Scenes redkitchen frames are not there")
def test_real_7scenes_redkitchen():
    start = time.perf_counter()
    seq = rs.read_sequence(REAL)
    assert time.perf_counter() - start < 1.0
    assert seq.layout == "7scenes" and len(seq) == 200
    np.testing.assert_array_equal(seq.frame_ids, np.arange(0, 1000, 5))
    np.testing.assert_allclose(seq.times, seq.frame_ids / 30.0, rtol=0, atol=1e-12)
    g = np.loadtxt(REAL / "gravity-direction.txt")
    np.testing.assert_allclose(seq.gravity, g / np.linalg.norm(g), atol=1e-12)
    np.testing.assert_allclose(seq.T_world_camera[0], np.loadtxt(REAL / "frame-000000.pose.txt"),
                               atol=1e-3)
    assert not np.isnan(seq.T_world_camera).any()
    rgb, depth = seq.read(0)
    assert rgb.shape == (480, 640, 3) and rgb.dtype == np.uint8
    assert depth.shape == (480, 640) and depth.dtype == np.uint16
    assert 0.5 < np.mean(depth > 0) < 1.0 and depth.max() < 65535


# -- files that are not what the layouts hold ------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(st.one_of(st.integers(1_000_000_000, 10**40),
                 st.integers(19, 60).map(lambda n: int("9" * n))),
       st.integers(0, 3))
@example(int("9" * 19), 0)
def test_7scenes_a_frame_number_past_the_largest_is_named(number, zeros):
    """A frame renamed frame-99...9 (19 nines or more) was an OverflowError making the frame
    ids; a smaller number past MAX_FRAME_NUMBER made times past a year of frames. The largest
    is read."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_7scenes(Path(tmp) / "s", some_poses([0, 5]))
        digits = "0" * zeros + str(number)
        for kind in ("color.png", "depth.png", "pose.txt"):
            (folder / f"frame-000005.{kind}").rename(folder / f"frame-{digits}.{kind}")
        with pytest.raises(DataError, match=rf"frame-{digits}\.\w+\.\w+: frame number {digits} "
                                            r"is beyond 999999999"):
            rs.read_7scenes(folder)
        for kind in ("color.png", "depth.png", "pose.txt"):
            (folder / f"frame-{digits}.{kind}").rename(folder / f"frame-999999999.{kind}")
        assert rs.read_7scenes(folder).frame_ids.tolist() == [0, 999_999_999]


def png_header(width: int, height: int) -> bytes:
    """A PNG claiming width x height RGB pixels in its header, its data empty."""
    def chunk(kind: bytes, body: bytes = b"") -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body)))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT") + chunk(b"IEND")


@pytest.mark.parametrize("kind", ["color.png", "depth.png"])
@pytest.mark.parametrize("side", [100_000, 2**31 - 1])
def test_an_image_header_claiming_billions_of_pixels_is_named(tmp_path, kind, side):
    """Pillow refuses to open it (DecompressionBombError), which the loader let through."""
    folder = write_7scenes(tmp_path / "s", some_poses([0, 5]))
    (folder / f"frame-000000.{kind}").write_bytes(png_header(side, side))
    with pytest.raises(DataError, match=rf"frame-000000\.{kind}: cannot read the image"):
        rs.read_7scenes(folder)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 29), st.integers(0, 12), st.sampled_from(["rgb.txt", "depth.txt"]))
def test_tum_an_image_name_holding_a_nul_is_no_such_image(row, at, listing):
    """'rg\\x00b/0.png' in a list was a ValueError (embedded null byte) out of the listing of
    its folder."""
    with tempfile.TemporaryDirectory() as tmp:
        folder, _ = standard_tum(Path(tmp) / "t")
        path = folder / listing
        lines = path.read_text().split("\n")
        number = HEADER_LINES + row % (len(lines) - HEADER_LINES - 1)
        stamp_text, name = lines[number].split()
        name = name[:at % len(name)] + "\x00" + name[at % len(name):]
        lines[number] = f"{stamp_text} {name}"
        path.write_text("\n".join(lines))
        with pytest.raises(DataError, match=rf"{listing}:{number + 1}: no such image"):
            rs.read_tum(folder)


@settings(max_examples=25, deadline=None)
@given(st.integers(-300, 306))
@example(306)
def test_tum_gravity_from_readings_of_any_size(exponent):
    """Readings near the float limit overflowed rotated and summed, and gravity came out
    [nan nan nan] without a word; readings of any size point the same way."""
    with tempfile.TemporaryDirectory() as tmp:
        folder, _ = standard_tum(Path(tmp) / "t")
        rows = []
        for t in (stamp(T0 + o) for o in np.arange(-0.2, 1.0, 0.01)):
            a = truth_pose(t)[:3, :3].T @ (-GRAVITY) * 10.0**exponent
            rows.append(f"{t:.6f} " + " ".join(repr(float(v)) for v in a))
        (folder / "accelerometer.txt").write_text(TUM_HEADER + "\n".join(rows) + "\n")
        np.testing.assert_allclose(rs.read_tum(folder).gravity, GRAVITY, atol=1e-6)


def test_tum_readings_at_the_float_limit_give_the_direction_of_small_ones(tmp_path):
    """'0 -1e308 1e308' gave gravity [nan nan nan]: it is the direction '0 -1 1' gives."""
    folder, _ = standard_tum(tmp_path / "t")
    times = [stamp(T0 + o) for o in np.arange(-0.2, 1.0, 0.01)]
    gravity = []
    for reading in ("0 -1 1", "0 -1e308 1e308"):
        (folder / "accelerometer.txt").write_text(
            TUM_HEADER + "\n".join(f"{t:.6f} {reading}" for t in times) + "\n")
        gravity.append(rs.read_tum(folder).gravity)
    np.testing.assert_allclose(gravity[1], gravity[0], atol=1e-12)


@pytest.mark.parametrize("name", ["gravity-direction.txt", "frame-000005.pose.txt",
                                  "camera-intrinsics.txt"])
def test_7scenes_a_fifo_for_a_text_file_is_refused_before_it_is_opened(tmp_path, name):
    """It waited for ever for a writer; here the FIFO holds what the file would."""
    folder = write_7scenes(tmp_path / "s", some_poses([0, 5]))
    text = (folder / name).read_text() if (folder / name).exists() else (
        "585 0 320\n0 585 240\n0 0 1\n")
    (folder / name).unlink(missing_ok=True)
    with fifo_holding(folder / name, text):
        with pytest.raises(DataError, match=f"{folder / name}: cannot read .*not a regular "
                                            "file"):
            rs.read_7scenes(folder)


# -- Redwood -----------------------------------------------------------------------------------


def write_redwood(folder: Path) -> Path:
    """One 64 x 48 frame with its camera file and log (the identity pose)."""
    for kind in ("color", "depth"):
        (folder / kind).mkdir(parents=True)
    K = [58.5, 0.0, 0.0, 0.0, 58.5, 0.0, 32.0, 24.0, 1.0]  # by column
    (folder / "camera_primesense.json").write_text(
        json.dumps({"width": 64, "height": 48, "intrinsic_matrix": K}))
    (folder / "odometry.log").write_text("0 0 1\n" + pose_text(np.eye(4), "%g") + "\n")
    (folder / "color" / "00000.jpg").write_bytes(png(np.zeros((48, 64, 3), np.uint8), ".jpg"))
    (folder / "depth" / "00000.png").write_bytes(png(np.full((48, 64), 1500, np.uint16)))
    return folder


@pytest.mark.parametrize(("file", "text", "words"), [
    ("camera_primesense.json", None, "no such camera file"),
    ("camera_primesense.json", '{"width": 64, "height": 4', "not a camera file: not JSON"),
    ("camera_primesense.json", "[]", "expected a JSON object of width, height, "
                                     "intrinsic_matrix, got []"),
    ("camera_primesense.json", '{"width": 64, "height": 48}', "expected a JSON object"),
    ("camera_primesense.json", '{"width": 64, "height": 48, "intrinsic_matrix": '
                               '[58.5, 0, 0, 0, 58.5, 0, 32, 24]}', "must be 9 finite numbers"),
    ("camera_primesense.json", '{"width": 64, "height": 48, "intrinsic_matrix": '
                               '[58.5, 0, 0, 0, 58.5, 0, 32, 24, "a"]}', "must be real numbers"),
    ("camera_primesense.json", '{"width": "x", "height": 48, "intrinsic_matrix": '
                               '[58.5, 0, 0, 0, 58.5, 0, 32, 24, 1]}', "not a camera"),
    ("camera_primesense.json", '{"width": 64, "height": 48, "intrinsic_matrix": '
                               '[-1, 0, 0, 0, 58.5, 0, 32, 24, 1]}', "not a camera"),
    ("odometry.log", None, "no such file"),
    ("odometry.log", "0 0 1\n1 0 0 0\n0 1 0\n0 0 1 0\n0 0 0 1\n",
     "odometry.log:3: expected a row of 4 numbers"),
    ("odometry.log", "0 0 1\n1 0 0 0\n0 1 0 x\n0 0 1 0\n0 0 0 1\n",
     "odometry.log:3: not a number: 'x'"),
    ("odometry.log", "0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 0\n", "blocks of 5 lines"),
    ("odometry.log", "0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "odometry.log:1: expected 3 "
                                                                  "ids"),
    ("odometry.log", "0 0 1\n2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not a rigid transform"),
])
def test_redwood_files_that_are_not_its_files_are_named(tmp_path, file, text, words):
    """Each was an exception of Python's or numpy's (FileNotFoundError, JSONDecodeError,
    TypeError, KeyError, ValueError) naming neither the file nor what it lacks."""
    folder = write_redwood(tmp_path / "r")
    if text is None:
        (folder / file).unlink()
    else:
        (folder / file).write_text(text)
    with pytest.raises(DataError, match=re.escape(words)) as info:
        load_redwood(folder)
    assert str(info.value).startswith(str(folder / file))


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(["camera_primesense.json", "odometry.log"]), st.integers(0, 10**6))
def test_redwood_files_cut_anywhere_load_or_name_the_file(file, cut):
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_redwood(Path(tmp) / "r")
        raw = (folder / file).read_bytes()
        (folder / file).write_bytes(raw[:cut % (len(raw) + 1)])
        try:
            frames = load_redwood(folder)
        except DataError as exc:
            assert str(exc).startswith(str(folder / file))
        else:
            assert len(frames) == 1 and np.isfinite(frames[0].T_body_camera).all()
