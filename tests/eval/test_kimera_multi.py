"""Tests for the Kimera-Multi reader's parts that need no bag: the ground-truth CSV, pose
interpolation, the configured extrinsics and the truth of a recorded run."""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from tcaff_gtsam.eval.cli import app
from tcaff_gtsam.eval.config import (
    ExtrinsicsConfig,
    TopicsConfig,
    load_kimera_multi,
    load_methods,
)
from tcaff_gtsam.eval.dataset_runs import run_kimera_multi
from tcaff_gtsam.eval.datasets.kimera_multi import (
    GT_HEADER,
    MAPS_VERSION,
    PoseTrack,
    RobotMapping,
    extrinsic,
    read_ground_truth,
)
from tcaff_gtsam.eval.methods import run_methods
from tcaff_gtsam.eval.runs import RecordedRun, RunSettings
from tcaff_gtsam.mapping.camera import T_body_camera
from test_text_tables import fifo_holding
from typer.testing import CliRunner

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.object_map import ObjectMap


def pose(x, y, z, yaw, pitch=0.0, roll=0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [yaw, pitch, roll]).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


def write_gt(path, stamps_ns, poses) -> None:
    rows = []
    for t, T in zip(stamps_ns, poses, strict=True):
        qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
        values = [T[0, 3], T[1, 3], T[2, 3], qw, qx, qy, qz]
        rows.append(f"{t}," + ",".join(repr(float(v)) for v in values))
    path.write_text(GT_HEADER + "\n" + "\n".join(rows) + "\n")


def test_ground_truth_round_trip_keeps_w_first_quaternions(tmp_path):
    stamps = 1_634_000_000_000_000_000 + np.arange(5) * 100_000_000
    poses = [pose(1.0 * k, -2.0, 0.1, 0.3 * k, 0.05, -0.02) for k in range(5)]
    write_gt(tmp_path / "a_gt_odom.csv", stamps, poses)
    times, T = read_ground_truth(tmp_path / "a_gt_odom.csv")
    np.testing.assert_allclose(times - times[0], 0.1 * np.arange(5), atol=1e-6)
    np.testing.assert_allclose(T, np.array(poses), atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("timestamp,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,0,1\n", "header"),
    (GT_HEADER + "\n1,0,0,0,1,0,0\n", "8 values|bad ground-truth row"),
    (GT_HEADER + "\n1,0,0,nan,1,0,0,0\n", "non-finite"),
    (GT_HEADER + "\n1,0,0,0,0,0,0,0\n", "zero quaternion"),
    (GT_HEADER + "\n2,0,0,0,1,0,0,0\n1,0,0,0,1,0,0,0\n", "increase"),
    (GT_HEADER + "\n1,a,0,0,1,0,0,0\n", "bad ground-truth row"),
])
def test_bad_ground_truth_raises_data_error(tmp_path, text, match):
    path = tmp_path / "r_gt_odom.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=match):
        read_ground_truth(path)


def test_missing_ground_truth_raises_data_error(tmp_path):
    with pytest.raises(DataError, match=r"none\.csv: no such ground-truth file"):
        read_ground_truth(tmp_path / "none.csv")


@settings(max_examples=50, deadline=None)
@given(st.integers(-320, 300), st.floats(0.5, 2.0), st.integers(0, 3))
@example(200, 1.0, 0)
def test_a_ground_truth_quaternion_of_another_norm_is_named(exponent, mantissa, row):
    """A quaternion of 1e200s overflowed its norm and became an all-zero rotation, which
    PoseTrack refused in a ValueError; quaternions are read as unit ones (rounding aside)."""
    stamps = 1_634_000_000_000_000_000 + np.arange(4) * 100_000_000
    q = Rotation.from_euler("z", 0.3).as_quat()  # x y z w
    scale = mantissa * 10.0**exponent
    rows = [f"{t},1,2,3," + ",".join(repr(float(v)) for v in
                                     (np.roll(q, 1) * (scale if k == row else 1.0)))
            for k, t in enumerate(stamps)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r_gt_odom.csv"
        path.write_text(GT_HEADER + "\n" + "\n".join(rows) + "\n")
        if abs(scale - 1.0) <= 1e-2:
            times, T = read_ground_truth(path)
            PoseTrack(times, T)(times[0])
        elif scale < 1e-6:
            with pytest.raises(DataError, match=f"row {row + 2} has a zero quaternion"):
                read_ground_truth(path)
        else:
            with pytest.raises(DataError, match=rf"row {row + 2}: the quaternion \(qw qx qy "
                                                r"qz\) has norm .*, not 1 \(within 0.01\)"):
                read_ground_truth(path)


def test_a_ground_truth_fifo_is_refused_before_it_is_opened(tmp_path):
    """It waited for ever for a writer; here the FIFO holds a whole ground truth."""
    with fifo_holding(tmp_path / "r_gt_odom.csv", GT_HEADER + "\n1,0,0,0,1,0,0,0\n") as fifo:
        with pytest.raises(DataError, match=f"{fifo}: cannot read .*not a regular file"):
            read_ground_truth(fifo)


@settings(max_examples=50, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi), st.floats(0.0, 1.0),
       st.floats(-10, 10), st.floats(-10, 10))
def test_interpolated_pose_lies_between_its_neighbours(yaw0, yaw1, share, x0, x1):
    times = np.array([10.0, 11.0])
    poses = np.array([pose(x0, 0.0, 0.0, yaw0), pose(x1, 1.0, 0.0, yaw1)])
    T, inside = PoseTrack(times, poses)([10.0 + share])
    assert inside[0]
    assert T[0, 0, 3] == pytest.approx(x0 + share * (x1 - x0), abs=1e-9)
    turn = math.remainder(yaw1 - yaw0, 2 * math.pi)  # slerp takes the short way round
    yaw = math.atan2(T[0, 1, 0], T[0, 0, 0])
    assert math.remainder(yaw - (yaw0 + share * turn), 2 * math.pi) == pytest.approx(0, abs=1e-6)


def test_interpolation_outside_the_span_is_flagged():
    times = np.array([1.0, 2.0, 3.0])
    poses = np.array([pose(k, 0, 0, 0) for k in range(3)])
    T, inside = PoseTrack(times, poses)([0.5, 1.0, 3.0, 3.5])
    np.testing.assert_array_equal(inside, [False, True, True, False])
    np.testing.assert_allclose(T[[0, 3], 0, 3], [0.0, 2.0])


@given(st.floats(0.0, 2.0), st.floats(-30, 30), st.floats(-1, 1))
def test_configured_extrinsics_match_the_camera_mount(height, pitch, forward):
    """xyz + rpy place a camera link; the optical frame is turned from it exactly as
    `T_body_camera` does (pitch positive = looking down)."""
    config = ExtrinsicsConfig(xyz=(forward, 0.0, height), rpy_deg=(0.0, pitch, 0.0))
    np.testing.assert_allclose(extrinsic(config, optical=True),
                               T_body_camera(height, pitch, forward), atol=1e-12)


def test_extrinsics_matrix_is_used_as_given_and_checked():
    T = T_body_camera(0.5, 10.0, 0.1)
    given_matrix = ExtrinsicsConfig(matrix=T.ravel().tolist())
    np.testing.assert_allclose(extrinsic(given_matrix, optical=True), T)
    bent = T.copy()
    bent[0, 0] = 2.0
    with pytest.raises(ConfigError, match="rigid"):
        extrinsic(ExtrinsicsConfig(matrix=bent.ravel().tolist()), optical=True)
    with pytest.raises(ValueError):
        ExtrinsicsConfig(matrix=[1.0] * 15)


EMPTY = ObjectMap(np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))


def recorded(S: int, T_world_odom: np.ndarray) -> RecordedRun:
    """A two-robot recorded run of S empty maps."""
    return RecordedRun("t", RunSettings(15.0), np.arange(S, dtype=float), [[EMPTY] * S] * 2,
                       T_world_odom, np.broadcast_to(np.eye(4), (2, S, 4, 4)))


def test_recorded_run_truth_is_the_planar_alignment():
    rng = np.random.default_rng(0)
    S = 4
    T_map_odom = np.array([[pose(*rng.uniform(-5, 5, 3), rng.uniform(-3, 3), 0.01, 0.02)
                            for _ in range(S)] for _ in range(2)])
    run = recorded(S, T_map_odom)
    T = run.T_true(0, 1)
    for s in range(S):
        rel = np.linalg.inv(T_map_odom[0, s]) @ T_map_odom[1, s]
        x, y, yaw = se2_to_params(T[s])
        assert (x, y) == pytest.approx((rel[0, 3], rel[1, 3]))
        assert yaw == pytest.approx(math.atan2(rel[1, 0], rel[0, 0]))
    np.testing.assert_allclose(T[0], se2_from_params(se2_to_params(T[0])))
    missing = T_map_odom.copy()
    missing[1] = np.nan
    assert np.all(np.isnan(recorded(S, missing).T_true(0, 1)))


def test_methods_that_need_the_truth_refuse_a_run_without_it():
    run = recorded(3, np.full((2, 3, 4, 4), np.nan))
    methods = load_methods("default")
    with pytest.raises(ConfigError, match=r"icp.*true alignment"):
        run_methods(run, methods)
    tcaff_only = methods.model_copy(update={"methods": ["tcaff", "tcaff_isam2"]})
    runs = run_methods(run, tcaff_only)
    assert np.isnan(runs.truth).all() and np.isnan(runs.estimates["tcaff"]).all()


def random_map(rng: np.random.Generator, n: int, d: int | None) -> ObjectMap:
    """n objects, with d-wide descriptors (None: without)."""
    descriptors = None
    if d is not None:
        descriptors = rng.uniform(0.0, 1.0, (n, d)) + 1e-3
        descriptors /= np.linalg.norm(descriptors, axis=1, keepdims=True)
    return ObjectMap(rng.uniform(-5, 5, (n, 3)), rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n),
                     rng.uniform(0, 30, n), descriptors)


def test_saved_maps_keep_their_descriptors(tmp_path):
    rng = np.random.default_rng(4)
    maps = [random_map(rng, 3, 8), EMPTY, random_map(rng, 0, 8), random_map(rng, 4, None),
            random_map(rng, 5, 8), random_map(rng, 2, 5)]
    S = len(maps)
    T = np.broadcast_to(pose(1.0, 2.0, 0.3, 0.4), (S, 4, 4))
    mapping = RobotMapping("sparkal1", np.arange(S) + 10.0, np.arange(S) + 9.9, T, T, maps,
                           120, 3.5, "abc", {"segment": 1.0})
    mapping.save(tmp_path)
    assert json.loads((tmp_path / "sparkal1.json").read_text())["version"] == MAPS_VERSION
    loaded = RobotMapping.load(tmp_path, "sparkal1")
    assert loaded is not None and len(loaded.maps) == S
    for saved, back in zip(maps, loaded.maps, strict=True):
        for key in ("centroids", "widths", "heights", "last_seen"):
            np.testing.assert_array_equal(getattr(back, key), getattr(saved, key))
        if saved.descriptors is None:
            assert back.descriptors is None
        else:
            np.testing.assert_array_equal(back.descriptors, saved.descriptors)


def test_maps_saved_by_another_version_are_mapped_again(tmp_path, caplog):
    """Maps of version 1 came from another front end (one view per object, no descriptors)."""
    rng = np.random.default_rng(5)
    T = np.broadcast_to(np.eye(4), (1, 4, 4))
    RobotMapping("sparkal1", np.array([1.0]), np.array([1.0]), T, T,
                 [random_map(rng, 3, 4)], 10, 1.0, "abc").save(tmp_path)
    meta = json.loads((tmp_path / "sparkal1.json").read_text())
    (tmp_path / "sparkal1.json").write_text(json.dumps({**meta, "version": 1}))
    assert MAPS_VERSION != 1
    assert RobotMapping.load(tmp_path, "sparkal1") is None
    assert "another version" in caplog.text


def test_topics_follow_the_robot_name():
    topics = TopicsConfig().of("sparkal1")
    assert topics["color"] == "/sparkal1/forward/color/image_raw/compressed"
    assert topics["odometry"] == "/sparkal1/jackal_velocity_controller/odom"


def test_shipped_tests_are_the_papers():
    same, opposite = load_kimera_multi("same_direction"), load_kimera_multi("opposite_directions")
    assert same.robots == ["acl_jackal2", "sparkal2"]
    assert opposite.robots == ["sparkal2", "sparkal1"]
    for test in (same, opposite):
        assert test.mapping.kappa == 15.0 and test.window == 5
    with pytest.raises(ConfigError, match="Kimera-Multi test"):
        load_kimera_multi("nope")


# ---------------------------------------------------------------------------------------------
# end to end: Kimera-like bags written from the simulator -> `tcaff kimera-multi`

ROBOTS = ("acl_jackal2", "sparkal2")


@pytest.fixture(scope="module")
def sequence(kimera_like_sequence):
    """30 s of two robots at 240 x 180, 5 Hz, and the simulation's truth."""
    return kimera_like_sequence


@pytest.fixture(scope="module")
def command(sequence, tmp_path_factory):
    """`tcaff kimera-multi` run once on the sequence with the tcaff_only methods and figures:
    the output folder and the runner's result."""
    data, _ = sequence
    output = tmp_path_factory.mktemp("command")
    result = CliRunner().invoke(app, ["kimera-multi", "--data", str(data), "--output",
                                      str(output), "--methods", "tcaff_only"])
    return output, result


def copy_of(data: Path, target: Path, skip: tuple[str, ...] = ()) -> Path:
    """The data folder again, files linked, without `skip`."""
    target.mkdir()
    for path in data.iterdir():
        if path.name not in skip:
            (target / path.name).symlink_to(path)
    return target


def true_alignment(truth, i: int, j: int, t: np.ndarray) -> np.ndarray:
    """(S, 3) the simulation's planar T_oi_oj at seconds since T0 (frames on the 5 Hz grid)."""
    out = []
    for s in t:
        T = []
        for robot in (ROBOTS[i], ROBOTS[j]):
            k = int(np.argmin(np.abs(truth.times[robot] - s)))
            T.append(truth.T_world_body[robot][k] @ np.linalg.inv(truth.T_odom_body[robot][k]))
        rel = np.linalg.inv(T[0]) @ T[1]
        out.append((rel[0, 3], rel[1, 3], math.atan2(rel[1, 0], rel[0, 0])))
    return np.array(out)


@pytest.mark.slow
def test_command_aligns_the_robots_as_the_simulation_did(sequence, command):
    data, truth = sequence
    output, result = command
    assert result.exit_code == 0, result.output
    assert "Mapping" in result.output and "TCAFF" in result.output
    folder = output / "same_direction"
    for name in ("maps/acl_jackal2.npz", "maps/sparkal2.json", "metrics.json", "metrics.csv",
                 "table.md", "figures/errors_0_1.png", "same_direction.npz"):
        assert (folder / name).is_file(), name
    metrics = json.loads((folder / "metrics.json").read_text())
    assert all(fps > 0 for fps in metrics["frames_per_second"].values())
    with np.load(folder / "same_direction.npz") as a:
        first = a["est_tcaff"]
        exchanges = a["t0"] + a["times"] - 1_634_000_000  # seconds since the sequence began
        for p, (i, j) in enumerate([(0, 1), (1, 0)]):
            # the truth read from the bags and CSVs is the simulation's (frames, axes, stamps)
            sim = true_alignment(truth, i, j, exchanges)
            np.testing.assert_allclose(a["truth"][p][:, :2], sim[:, :2], atol=0.02)
            np.testing.assert_allclose(np.cos(a["truth"][p][:, 2] - sim[:, 2]), 1.0, atol=1e-4)
            est = a["est_tcaff"][p]
            has = ~np.isnan(est[:, 0])
            assert has.sum() >= 5, f"TCAFF estimated only {has.sum()} steps of pair {i}->{j}"
            err = np.linalg.norm(est[has, :2] - sim[has, :2], axis=1)
            assert err.max() < 0.3
            heading = np.abs(np.angle(np.exp(1j * (est[has, 2] - sim[has, 2]))))
            assert np.degrees(heading).max() < 3.0
    table = (folder / "table.md").read_text()
    assert "translation error [m]" in table and "TCAFF" in table

    # a second run reuses both robots' maps and gives the same estimates
    again = CliRunner().invoke(app, ["kimera-multi", "--data", str(data), "--output",
                                     str(output), "--methods", "tcaff_only", "--no-figures"])
    assert again.exit_code == 0, again.output
    assert again.output.count("reused") == 2
    with np.load(folder / "same_direction.npz") as b:
        np.testing.assert_array_equal(b["est_tcaff"], first)


@pytest.mark.slow
def test_missing_topic_lists_the_topics_present(sequence, tmp_path):
    data, _ = sequence
    config = load_kimera_multi("same_direction")
    config = config.model_copy(update={"topics": config.topics.model_copy(
        update={"odometry": "/{robot}/kimera_vio_ros/odometry"})})
    with pytest.raises(DataError, match=r"kimera_vio_ros/odometry.*topics present.*"
                                        r"jackal_velocity_controller/odom"):
        run_kimera_multi(config, data, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "overwritten"])
def test_damaged_bag_keeps_the_robots_already_mapped(sequence, tmp_path, damage):
    data, _ = sequence
    broken = copy_of(data, tmp_path / "data", skip=("sparkal2.bag",))
    raw = (data / "sparkal2.bag").read_bytes()
    if damage == "truncated":
        raw = raw[:len(raw) // 2]
    else:
        middle = len(raw) // 2
        raw = raw[:middle] + bytes(100_000) + raw[middle + 100_000:]
    (broken / "sparkal2.bag").write_bytes(raw)
    # 8 s of acl_jackal2 are mapped (and kept) before sparkal2's bag is opened and read
    result = CliRunner().invoke(app, ["kimera-multi", "--data", str(broken), "--output",
                                      str(tmp_path / "out"), "--methods", "tcaff_only",
                                      "--duration", "8"])
    assert result.exit_code != 0
    assert isinstance(result.exception, DataError)
    assert "sparkal2" in str(result.exception)
    assert "damaged" in str(result.exception)
    maps = tmp_path / "out" / "same_direction" / "maps"
    assert (maps / "acl_jackal2.npz").is_file()
    assert not (maps / "sparkal2.npz").exists()


@pytest.fixture(scope="module")
def mapped(sequence, command, tmp_path_factory):
    """The sequence aligned once with the tcaff_only methods, no figures, from the maps the
    command saved: the config and the outcome, whose saved maps later runs start from."""
    data, _ = sequence
    config = load_kimera_multi("same_direction").model_copy(
        update={"methods": load_methods("tcaff_only")})
    output = tmp_path_factory.mktemp("mapped")
    shutil.copytree(command[0] / config.name / "maps", output / config.name / "maps")
    outcome = run_kimera_multi(config, data, output, figures=False)
    assert outcome.reused == list(ROBOTS)  # the same settings and bags as the command's
    return config, outcome


def copy_saved_maps(mapped, output: Path, robots: tuple[str, ...]) -> None:
    """`robots`' saved maps of `mapped` copied where a run into `output` looks for them."""
    _, outcome = mapped
    maps = output / outcome.folder.name / "maps"
    maps.mkdir(parents=True)
    for robot in robots:
        for path in outcome.folder.glob(f"maps/{robot}.*"):
            shutil.copy2(path, maps / path.name)


@pytest.mark.slow
def test_without_ground_truth_alignments_are_still_saved(sequence, mapped, tmp_path):
    """The robot without ground truth is mapped (the other's map, which has it, is reused)."""
    data, _ = sequence
    bare = copy_of(data, tmp_path / "data", skip=("sparkal2_gt_odom.csv",))
    config = load_kimera_multi("same_direction")
    copy_saved_maps(mapped, tmp_path / "out", ("acl_jackal2",))
    outcome = run_kimera_multi(config, bare, tmp_path / "out", figures=False)
    assert outcome.reused == ["acl_jackal2"]
    assert outcome.recorded.summary == {}
    methods = outcome.recorded.methods.methods
    assert "icp" not in methods and "ground_truth" not in methods
    with np.load(outcome.folder / "same_direction.npz") as a:
        assert np.isnan(a["truth"]).all()
        assert (~np.isnan(a["est_tcaff"][:, :, 0])).sum() >= 5
    assert not (outcome.folder / "metrics.json").exists()
    assert not (outcome.folder / "figures").exists()


def test_missing_bags_and_data_folder_raise(tmp_path):
    config = load_kimera_multi("same_direction")
    with pytest.raises(DataError, match="not a folder"):
        run_kimera_multi(config, tmp_path / "nowhere", tmp_path)
    with pytest.raises(DataError, match="no bag matches"):
        run_kimera_multi(config, tmp_path, tmp_path / "out")


@pytest.mark.parametrize("make", [Path.mkdir, os.mkfifo], ids=["folder", "fifo"])
def test_a_ground_truth_that_is_not_a_file_is_named_before_any_robot_is_mapped(tmp_path, make):
    """It was taken for a missing ground truth: a warning, and the run went on unscored."""
    config = load_kimera_multi("same_direction")
    gt = tmp_path / f"{config.robots[1]}_gt_odom.csv"
    make(gt)
    kind = "a folder" if gt.is_dir() else "not a regular file"
    with pytest.raises(DataError, match=f"^{gt}: {kind}, not the ground-truth CSV of robot "
                                        f"{config.robots[1]} "):
        run_kimera_multi(config, tmp_path, tmp_path / "out")  # no robot has bags here


def test_recorded_run_checks_its_shapes():
    with pytest.raises(DataError, match="one map per exchange"):
        RecordedRun("t", RunSettings(15.0), np.arange(3.0), [[EMPTY] * 3, [EMPTY] * 2],
                    np.zeros((2, 3, 4, 4)), np.zeros((2, 3, 4, 4)))
    with pytest.raises(DataError, match=r"T_odom_body.*\(2, 3, 4, 4\)"):
        RecordedRun("t", RunSettings(15.0), np.arange(3.0), [[EMPTY] * 3] * 2,
                    np.zeros((2, 3, 4, 4)), np.zeros((2, 3, 4)))
    with pytest.raises(DataError, match="two robots"):
        RecordedRun("t", RunSettings(15.0), np.arange(3.0), [[EMPTY] * 3],
                    np.zeros((1, 3, 4, 4)), np.zeros((1, 3, 4, 4)))


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncated", "keyless"])
def test_a_damaged_saved_map_is_mapped_again_with_a_warning(sequence, mapped, tmp_path, damage,
                                                             caplog):
    """--resume (the default) treats an unreadable map file as no reusable map."""
    data, _ = sequence
    config, first = mapped
    copy_saved_maps(mapped, tmp_path, ROBOTS)
    saved = tmp_path / first.folder.name / "maps" / "sparkal2.npz"
    if damage == "truncated":
        saved.write_bytes(saved.read_bytes()[:200])
    else:
        with np.load(saved) as a:
            arrays = {k: a[k] for k in a.files if k != "map_sizes"}
        np.savez_compressed(saved, **arrays)
    again = run_kimera_multi(config, data, tmp_path, figures=False)
    assert again.reused == ["acl_jackal2"]
    assert "no reusable maps of sparkal2" in caplog.text
    np.testing.assert_array_equal(again.recorded.job.arrays["est_tcaff"],
                                  first.recorded.job.arrays["est_tcaff"])


def test_a_failed_run_does_not_claim_maps_an_earlier_run_left(tmp_path, tcaff_main):
    """The note that a rerun reuses the maps is for maps this run made, not older ones."""
    maps = tmp_path / "out" / "same_direction" / "maps"
    maps.mkdir(parents=True)
    old = maps / "acl_jackal2.npz"
    old.write_bytes(b"an earlier run's")
    os.utime(old, (0, 0))
    done = tcaff_main("kimera-multi", "--data", str(tmp_path / "missing"), "--output",
                      str(tmp_path / "out"))
    assert done.returncode == 2
    assert "a rerun reuses them" not in done.stderr, done.stderr
