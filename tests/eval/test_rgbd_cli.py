"""`tcaff rgbd`: recorded RGB-D sequences as robots, end to end on a small 7-Scenes folder the
tests render (a room of boxes, a camera walking loops in it, in a world frame that is not
gravity aligned), its bad input refused in one line, and the pieces it is made of
(`_parse_ranges`, `_halves`, `dataset_runs.walk_report`)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from tcaff_gtsam.eval import cli
from tcaff_gtsam.eval.config import load_methods, load_rgbd
from tcaff_gtsam.eval.dataset_runs import run_rgbd, walk_report
from tcaff_gtsam.eval.datasets import rgbd_robots
from tcaff_gtsam.eval.datasets.rgbd_sequence import read_sequence
from tcaff_gtsam.eval.metrics import Thresholds
from tcaff_gtsam.eval.sim.render import RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera

from tcaff_gtsam import FrameAligner, FrameAlignerParams, TCAFFParams
from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.geometry import (
    invert,
    se2_error,
    se2_from_params,
    se2_to_params,
    se3_from_xyz_yaw,
    se3_to_se2,
)

FAST = settings(max_examples=30, deadline=None)

#: (x, y, width, height) of the boxes along the walls of a 6 x 6 m room
BOXES = np.array([[0.6, 1.0, 0.6, 1.2], [0.6, 3.0, 0.5, 0.8], [0.7, 5.0, 0.45, 1.0],
                  [2.5, 5.4, 0.7, 0.7], [4.2, 5.4, 0.5, 1.4], [5.4, 4.6, 0.55, 0.9],
                  [5.3, 2.8, 0.6, 1.1], [5.4, 1.0, 0.4, 0.6], [3.6, 0.6, 0.65, 1.0],
                  [1.9, 0.6, 0.5, 1.3]])
FRAMES = 160  # at 4 Hz: two robots of 20 s each (the default halves)
LOOP = 24  # frames per turn of the camera round the room's middle
#: the data set's world frame: turned away from gravity and shifted
T_DATA_LEVEL = np.eye(4)
T_DATA_LEVEL[:3, :3] = Rotation.from_rotvec([0.35, -0.2, 0.1]).as_matrix()
T_DATA_LEVEL[:3, 3] = [1.0, -2.0, 0.5]


def matrix_text(M: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.12g}" for v in row) + "\n" for row in M)


def write_camera(folder: Path, camera: PinholeCamera, gravity: np.ndarray) -> None:
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    (folder / "camera-intrinsics.txt").write_text(matrix_text(K))
    (folder / "gravity-direction.txt").write_text(" ".join(f"{v:.12g}" for v in gravity))


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """A 7-Scenes folder of FRAMES rendered frames (240 x 180): a hand-held camera 1.2 m up,
    15 deg down, walking a 1 m circle in the room's middle and looking out at the boxes."""
    folder = tmp_path_factory.mktemp("rgbd") / "room"
    folder.mkdir()
    camera = PinholeCamera.from_fov(240, 180, 87)
    scene = RgbdScene(BOXES[:, :2], BOXES[:, 2], BOXES[:, 3], walls=room_walls(0, 0, 6, 6))
    for k in range(FRAMES):
        a = 2 * math.pi * k / LOOP
        T = (se3_from_xyz_yaw(3.0 + math.cos(a), 3.0 + math.sin(a), 0.0, a + 0.3)
             @ T_body_camera(1.2, 15.0))
        frame = render(scene, T, camera)
        stem = folder / f"frame-{k:06d}"
        cv2.imwrite(f"{stem}.color.png", frame.rgb[..., ::-1])  # OpenCV writes BGR
        cv2.imwrite(f"{stem}.depth.png", np.round(frame.depth * 1000).astype(np.uint16))
        Path(f"{stem}.pose.txt").write_text(matrix_text(T_DATA_LEVEL @ T))
    write_camera(folder, camera, T_DATA_LEVEL[:3, :3] @ np.array([0.0, 0.0, -1.0]))
    return folder


@pytest.mark.slow
def test_rgbd_maps_aligns_scores_and_reuses(room, tmp_path, tcaff_main, monkeypatch):
    from tcaff_gtsam.eval import plots

    runs = []  # the runs the command maps, seen on their way to the evaluation
    real_load_run = rgbd_robots.load_run

    def spy(*args, **kwargs):
        run, seconds = real_load_run(*args, **kwargs)
        runs.append(run)
        return run, seconds

    monkeypatch.setattr(rgbd_robots, "load_run", spy)
    # the top views are this command's own figures; the errors and candidates figures every
    # recorded run draws (a third of the run's time) are checked by the Kimera-Multi and
    # MRCLAM command tests
    monkeypatch.setattr(plots, "draw_recorded", lambda folder, job, shown: [])
    out = tmp_path / "out"
    args = ("rgbd", "--data", str(room), "--fps", "4", "--output", str(out))
    done = tcaff_main(*args)
    assert done.returncode == 0, done.stderr + done.stdout
    check_run(runs)
    assert "Mapping: ms per frame" in done.stdout and "false accepts" in done.stdout
    folder = out / "room-vio-seed0"  # the default config: VIO-like odometry, seed 0
    for name in ("metrics.json", "metrics.csv", "table.md", "walk_report.json",
                 "figures/top_view_0_1.png", "figures/top_view_1_0.png"):
        assert (folder / name).is_file(), name
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["robots"] == ["room[0:80]", "room[80:160]"]  # the two halves
    assert (metrics["odometry"], metrics["seed"]) == ("vio", 0)
    with np.load(folder / "room-vio-seed0.npz") as saved:
        check_paths(saved["poses_true"])
    report = json.loads((folder / "walk_report.json").read_text())
    assert "ground_truth" not in report and "tcaff" in report and "icp" in report
    assert {r["first_exchange"] for r in report.values()} == {9}  # W + 1
    # the maps are right under the truth (gravity taken from the file, the world tilted):
    # single-shot CLIPPER aligns them, and nothing is a false accept
    assert report["clipper_k5"]["estimates"] > 0
    assert report["clipper_k5"]["false_accept"] == 0.0
    assert report["clipper_k5"]["median_translation_m"] < 0.2
    for stream in ("tcaff", "tcaff_isam2_causal"):
        assert report[stream]["estimates"] > 0, stream
        assert report[stream]["false_accept"] == 0.0, stream

    saved = (folder / "room-vio-seed0.npz").stat().st_mtime_ns
    (folder / "figures/top_view_0_1.png").unlink()
    again = tcaff_main(*args)
    assert again.returncode == 0, again.stderr
    assert "saved results of an earlier run reused" in again.stdout
    assert "Mapping: ms per frame" not in again.stdout and len(runs) == 1  # nothing mapped
    assert (folder / "room-vio-seed0.npz").stat().st_mtime_ns == saved
    assert (folder / "figures/top_view_0_1.png").is_file()  # a missing figure is drawn
    assert json.loads((folder / "walk_report.json").read_text()) == report

    def walk_table(text: str) -> str:
        return text[text.index("false accepts"):text.index("results:")]

    assert walk_table(again.stdout) == walk_table(done.stdout)  # the same report, reprinted


def level_of_run_world() -> np.ndarray:
    """(4, 4) the run's world (the data's world turned level by `rgbd_robots.level_rotation`)
    in the level frame the room was rendered in."""
    T_data_world = np.eye(4)
    T_data_world[:3, :3] = rgbd_robots.level_rotation(T_DATA_LEVEL[:3, :3] @ [0, 0, -1]).T
    return invert(T_DATA_LEVEL) @ T_data_world


def check_paths(poses_true: np.ndarray) -> None:
    """The true paths (2, 19, 3) of the saved job are the camera's position and viewing
    heading in a level world: the rendered poses at the last frame of each whole second."""
    assert poses_true.shape == (2, 19, 3)
    T_level_world = se3_to_se2(level_of_run_world())
    for r in range(2):
        for s in range(poses_true.shape[1]):
            k = (FRAMES // 2) * r + 4 * (s + 1)  # 4 Hz, each robot's clock from its first
            a = 2 * math.pi * k / LOOP
            got = se2_to_params(T_level_world @ se2_from_params(poses_true[r, s]))
            assert got[:2] == pytest.approx((3.0 + math.cos(a), 3.0 + math.sin(a)), abs=1e-6)
            assert math.remainder(got[2] - a - 0.3, 2 * math.pi) == pytest.approx(0.0,
                                                                                  abs=1e-6)


def check_run(runs: list) -> None:
    """The robots' maps of the room: every object where a box stands, with descriptors, in
    gravity-aligned odometry frames; the last exchange's maps align to the truth."""
    assert len(runs) == 1
    run = runs[0]
    assert len(run.maps) == 2
    np.testing.assert_array_equal(run.times, np.arange(1.0, 20.0))  # walks of 19.75 s
    # the run's world is the data's world turned level (gravity from the file): odometry
    # frames turn about z only in it
    down = np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(run.T_world_odom[..., :3, :3] @ down,
                               np.broadcast_to(down, (*run.T_world_odom.shape[:2], 3)),
                               atol=1e-9)
    T_level_world = level_of_run_world()
    for r in range(2):
        for s, objects in enumerate(run.maps[r]):
            if len(objects) == 0:
                continue
            assert objects.descriptors is not None, (r, s)
            c = np.column_stack([objects.centroids, np.ones(len(objects))])
            level = (T_level_world @ run.T_world_odom[r, s] @ c.T).T[:, :3]
            nearest = np.linalg.norm(level[:, None, :2] - BOXES[None, :, :2], axis=-1)
            assert nearest.min(axis=1).max() < 0.35, (r, s, level.round(2))
            box = nearest.argmin(axis=1)
            np.testing.assert_allclose(level[:, 2], BOXES[box, 3] / 2, atol=0.25)
    assert run.shared[0, 1, -1] and run.shared[1, 0, -1]
    assert min(len(run.maps[0][-1]), len(run.maps[1][-1])) >= 5
    T_true = se3_to_se2(invert(run.T_world_odom[0, -1]) @ run.T_world_odom[1, -1])
    found = FrameAligner(FrameAlignerParams.camera()).measurements(
        run.maps[0][-1], run.maps[1][-1], float(run.times[-1]))
    assert found
    dt, dtheta = se2_error(T_true, found[0].T)
    assert dt < 0.2 and math.degrees(dtheta) < 2.0


@pytest.fixture
def tiny(tmp_path) -> Path:
    """A 7-Scenes folder of 10 uniform 64 x 48 frames at 30 Hz (nothing to map)."""
    folder = tmp_path / "tiny"
    folder.mkdir()
    camera = PinholeCamera(64, 48, 58.5, 58.5, 32.0, 24.0)
    color = cv2.imencode(".png", np.full((48, 64, 3), 90, np.uint8))[1].tobytes()
    depth = cv2.imencode(".png", np.full((48, 64), 2000, np.uint16))[1].tobytes()
    for k in range(10):
        stem = folder / f"frame-{k:06d}"
        Path(f"{stem}.color.png").write_bytes(color)
        Path(f"{stem}.depth.png").write_bytes(depth)
        Path(f"{stem}.pose.txt").write_text(matrix_text(np.eye(4)))
    write_camera(folder, camera, np.array([0.0, 0.0, -1.0]))
    return folder


@pytest.mark.parametrize(("args", "named"), [
    (["--robots", "5:1"], ["--robots '5:1'", "empty"]),
    (["--robots", "0:10"], ["--robots '0:10'", "two ranges"]),
    (["--robots", "0:5,x:9"], ["--robots '0:5,x:9'", "'x:9'"]),
    (["--robots", "0:5:7,5:9"], ["--robots"]),
    (["--rate", "1000"], ["rate = 1000 Hz", "30 Hz"]),
    (["--rate", "0"], ["--rate 0"]),
    (["--rate", "nan"], ["--rate nan"]),
    (["--gravity", "1,2"], ["--gravity '1,2'", "three numbers"]),
    (["--gravity", "a,b,c"], ["--gravity 'a,b,c'"]),
    (["--gravity", "0,0,0"], ["gravity", "not all zero"]),
    (["--odometry", "foo"], ["--odometry 'foo'", "exact or vio"]),
    (["--odometry", "exact", "--odometry", "wheel"], ["--odometry 'wheel'"]),
    (["--fps", "0"], ["fps"]),
    (["--config", "missing.yaml"], ["missing.yaml"]),
])
def test_bad_input_is_one_line_naming_the_option(tiny, tmp_path, tcaff_main, args, named):
    out = tmp_path / "out"
    done = tcaff_main("rgbd", "--data", str(tiny), "--output", str(out), *args)
    line = one_line_error(done, *named)
    assert "Traceback" not in done.stderr, line
    assert not out.exists()  # refused before anything was written


def test_an_unknown_shipped_config_is_one_line(tiny, tmp_path, tcaff_main):
    done = tcaff_main("rgbd", "--data", str(tiny), "--config", "no_such_config", "--output",
                      str(tmp_path / "out"))
    one_line_error(done, "no_such_config", "default")


def test_folders_that_are_no_sequence_are_refused(tmp_path, tiny, tcaff_main):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "out"
    one_line_error(tcaff_main("rgbd", "--data", str(empty), "--output", str(out)),
                   str(empty), "neither a 7-Scenes")
    one_line_error(tcaff_main("rgbd", "--data", str(tmp_path / "nowhere"), "--output",
                              str(out)), "no such folder")
    # two folders take one range each
    one_line_error(tcaff_main("rgbd", "--data", str(tiny), "--data", str(tiny), "--robots",
                              "0:5", "--output", str(out)), "--robots '0:5'", "one range per")
    # a robot of a single frame
    one_line_error(tcaff_main("rgbd", "--data", str(tiny), "--robots", "0:1,1:10",
                              "--output", str(out)), "1 frames")
    assert not out.exists()


def one_line_error(done, *named: str) -> str:
    """The single stderr line of a refused command (exit 2), which names each of `named`."""
    assert done.returncode == 2, done.stderr + done.stdout
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for name in named:
        assert name in lines[0], (name, lines[0])
    return lines[0]


# -- the command's pieces ---------------------------------------------------------------------


bounds = st.none() | st.integers(0, 10**6)
ranges = st.lists(st.tuples(bounds, bounds).filter(
    lambda r: r[0] is None or r[1] is None or r[1] > r[0]), min_size=1, max_size=6)


def range_text(rs) -> str:
    return ",".join(f"{'' if a is None else a}:{'' if b is None else b}" for a, b in rs)


@FAST
@given(rs=ranges, spaces=st.booleans())
def test_robot_ranges_parse_back(rs, spaces):
    text = range_text(rs).replace(",", " , " if spaces else ",")
    if len(rs) >= 2:  # one sequence, a robot per range; or a folder per range
        assert cli._parse_ranges(text, 1) == rs
        assert cli._parse_ranges(text, len(rs)) == rs
    else:
        with pytest.raises(ConfigError, match="two ranges or more"):
            cli._parse_ranges(text, 1)
    with pytest.raises(ConfigError, match="one range per folder"):
        cli._parse_ranges(text, len(rs) + 1)


@FAST
@given(rs=ranges, k=st.integers(0, 5), start=st.integers(0, 1000), length=st.integers(0, 5))
def test_an_empty_range_is_refused(rs, k, start, length):
    bad = (start + length, start)  # stop <= start
    rs = [*rs[:k], bad, *rs[k:]]
    with pytest.raises(ConfigError, match=rf"the range '{bad[0]}:{bad[1]}' is empty"):
        cli._parse_ranges(range_text(rs), 1)


def test_no_ranges_default_by_the_number_of_folders():
    assert cli._parse_ranges(None, 1) == []  # the halves of the one sequence
    assert cli._parse_ranges(None, 3) == [(None, None)] * 3
    assert cli._parse_ranges(":,:", 2) == [(None, None)] * 2


@FAST
@given(ids=st.lists(st.integers(0, 10**6), min_size=2, max_size=80, unique=True).map(sorted))
def test_the_halves_split_the_frames_in_two(ids):
    (a, b), (c, d) = rgbd_robots.halves(np.array(ids))
    first = [i for i in ids if a <= i < b]
    second = [i for i in ids if c <= i < d]
    assert first + second == ids
    assert len(first) == len(ids) // 2 and len(second) == len(ids) - len(ids) // 2


def estimates(T_true: np.ndarray, deltas: dict[int, tuple[float, float]], S: int) -> np.ndarray:
    """(S, 3) estimates off the truth by (metres along the truth's x, degrees) at the given
    steps, NaN elsewhere."""
    out = np.full((S, 3), np.nan)
    for s, (dx, deg) in deltas.items():
        out[s] = se2_to_params(T_true @ se2_from_params([dx, 0.0, math.radians(deg)]))
    return out


def test_walk_report_counts_false_accepts_at_both_thresholds():
    S, first = 12, 8  # the first TCAFF can answer at is exchange W + 1 = 9
    truth = np.array([[1.0, 2.0, 0.5], [-1.0, 0.0, -0.5]])
    T = [se2_from_params(z) for z in truth]
    a = np.stack([
        estimates(T[0], {3: (2.0, 0.0), 8: (0.1, 0.0), 9: (0.5, 0.0), 11: (0.0, 4.0)}, S),
        estimates(T[1], {9: (0.0, 6.0), 11: (0.05, 0.0)}, S)])
    job = SimpleNamespace(pairs=[(0, 1), (1, 0)], arrays={
        "truth": np.stack([np.tile(z, (S, 1)) for z in truth]), "est_a": a,
        "est_none": np.full((2, S, 3), np.nan)})
    report = walk_report(job, ["a", "none"], Thresholds(1.0, math.radians(5.0)),
                         Thresholds(0.3, math.radians(3.0)), first)
    r = report["a"]
    assert r["estimates"] == 6
    assert r["false_accept"] == pytest.approx(2 / 6)  # 2 m; 6 deg
    assert r["false_accept_tight"] == pytest.approx(4 / 6)  # and 0.5 m; 4 deg
    assert r["availability_from_first"] == pytest.approx(5 / 8)  # exchanges 9-12, both pairs
    assert r["first_exchange"] == 9
    assert r["median_translation_m"] == pytest.approx(0.075)
    assert r["median_heading_deg"] == pytest.approx(0.0, abs=1e-9)
    assert report["none"] == {
        "estimates": 0, "false_accept": None, "false_accept_tight": None,
        "availability_from_first": 0.0, "first_exchange": 9, "median_translation_m": None,
        "median_heading_deg": None, "nees_mean": None, "nees_under_95": None,
        "confident_false_accept": None}
    assert r["nees_mean"] is None  # no covariance kept: undefined, not 0
    # with a covariance of 0.1 m and 1 deg sigmas: the estimates 2 m (NEES 400) and 6 deg
    # (NEES 36) off are confident false accepts; 0.5 m (25) is beyond 95 % but right
    sigmas = np.array([0.1, 0.1, math.radians(1.0)])
    job.arrays["cov_a"] = np.where(np.isnan(a[..., :1, None]), np.nan, np.diag(sigmas**2))
    r = walk_report(job, ["a"], Thresholds(1.0, math.radians(5.0)),
                    Thresholds(0.3, math.radians(3.0)), first)["a"]
    nees = [400.0, 1.0, 25.0, 16.0, 36.0, 0.25]  # steps 3, 8, 9, 11 of pair 0; 9, 11 of pair 1
    assert r["nees_mean"] == pytest.approx(np.mean(nees))
    assert r["nees_under_95"] == pytest.approx(2 / 6)
    assert r["confident_false_accept"] == pytest.approx(2 / 6)
    late = walk_report(job, ["a"], Thresholds(), Thresholds(0.3, math.radians(3.0)), S)
    assert late["a"]["availability_from_first"] is None  # no exchange from W + 1 on
    assert late["a"]["estimates"] == 6


def test_the_report_counts_from_the_method_sets_tcaff_window(tiny, tmp_path):
    """The first exchange TCAFF can answer at is W + 1 with the W TCAFF runs with: the method
    set's, unless the config sets the run's."""
    seq = read_sequence(tiny, None, 2.0)  # 10 frames at 2 Hz: two robots of 2 s
    walks = [rgbd_robots.walk(seq, a, b) for a, b in rgbd_robots.halves(seq.frame_ids)]
    methods = load_methods("tcaff_only").model_copy(
        update={"methods": ["tcaff"], "tcaff": replace(TCAFFParams(), window=3)})
    assert TCAFFParams().window != 3
    for window, first in ((None, 4), (6, 7)):
        config = load_rgbd("default").model_copy(update={"methods": methods, "window": window})
        (outcome,) = run_rgbd(config, walks, tmp_path / f"w{window}", ["exact"], [0],
                              figures=False)
        assert outcome.report["tcaff"]["first_exchange"] == first, window
