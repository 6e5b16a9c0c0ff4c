"""The UTIAS MRCLAM loader, on small data sets the tests write in its format (robots driving
circles among known landmarks, sightings from known poses) and on the first minute of the real
data set 6 when it is there."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.cli import app
from tcaff_gtsam.eval.datasets import mrclam
from typer.testing import CliRunner

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, se3_to_se2

T0 = 1_248_444_000.0
REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "mrclam" / "MRCLAM_Dataset6"
HEADER = "# written by the tests\n# columns\n"
LANDMARKS = {6 + k: xy for k, xy in enumerate(
    [(0.0, 0.0), (0.3, 0.1), (2.0, 1.5), (-1.5, 2.0), (1.0, -2.0), (-2.0, -1.0),
     (2.5, -0.5), (-0.5, 3.0)])}


def circle(robot: int, t: np.ndarray) -> np.ndarray:
    """(k, 3) robot's true pose: a circle at its own speed, radius and centre."""
    v, w = 0.3 + 0.05 * robot, 0.15 + 0.02 * robot
    theta = 0.7 * robot + w * t
    centre = np.array([0.3 * robot - 0.5, 0.2 * robot])
    x = centre[0] + v / w * np.sin(theta)
    y = centre[1] - v / w * np.cos(theta)
    return np.column_stack([x, y, np.angle(np.exp(1j * theta))])


def write_dataset(folder: Path, seconds: float = 40.0, barcodes: dict | None = None,
                  landmarks: dict | None = None, noise: float = 0.0) -> Path:
    """A data set in MRCLAM format: five robots on circles, exact commanded odometry, Vicon at
    100 Hz, sightings at 5 Hz of the landmarks within 5 m and 60 deg."""
    folder.mkdir(parents=True, exist_ok=True)
    landmarks = landmarks or LANDMARKS
    barcodes = barcodes or {s: 10 + 3 * s for s in range(1, 21)}
    rng = np.random.default_rng(0)
    (folder / "Barcodes.dat").write_text(HEADER + "".join(
        f"{s}\t{b}\n" for s, b in barcodes.items()))
    (folder / "Landmark_Groundtruth.dat").write_text(HEADER + "".join(
        f"{s}\t{x:.6f}\t{y:.6f}\t0.0001\t0.0001\n" for s, (x, y) in landmarks.items()))
    for robot in range(1, 6):
        v, w = 0.3 + 0.05 * robot, 0.15 + 0.02 * robot
        t_odo = np.arange(0.0, seconds, 0.02)
        (folder / f"Robot{robot}_Odometry.dat").write_text(HEADER + "".join(
            f"{T0 + t:.3f}\t{v:.6f}\t{w:.6f}\n" for t in t_odo))
        t_gt = np.arange(0.0, seconds, 0.01)
        truth = circle(robot, t_gt)
        (folder / f"Robot{robot}_Groundtruth.dat").write_text(HEADER + "".join(
            f"{T0 + t:.3f}\t{x:.8f}\t{y:.8f}\t{th:.8f}\n" for t, (x, y, th) in
            zip(t_gt, truth, strict=True)))
        rows = []
        for t in np.arange(0.2, seconds, 0.2):
            x, y, th = circle(robot, np.array([t]))[0]
            for subject, (lx, ly) in landmarks.items():
                r = math.hypot(lx - x, ly - y) + noise * rng.standard_normal()
                b = float(np.angle(np.exp(1j * (math.atan2(ly - y, lx - x) - th))))
                if r < 5.0 and abs(b) < math.radians(60):
                    rows.append(f"{T0 + t:.3f}\t{barcodes[subject]}\t{r:.6f}\t{b:.6f}\n")
        (folder / f"Robot{robot}_Measurement.dat").write_text(HEADER + "".join(rows))
    return folder


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("mrclam") / "Synthetic")


def run_of(folder: Path, odometry: str = "vio", **kwargs):
    data = mrclam.read_dataset(folder)
    options = {"seed": 0, "kappa": 20.0, "nu": 1, "min_shared": 3,
               "heading_rw_deg_per_sqrt_min": 0.0, "scale_std": 0.0, **kwargs}
    return data, *mrclam.load_run(data, odometry, **options)


def world_positions(run, robot: int, step: int) -> np.ndarray:
    """(k, 2) robot's map entries at a step, placed in the world by the true odometry frame."""
    T = se3_to_se2(run.T_world_odom[robot, step])
    xy = run.maps[robot][step].centroids[:, :2]
    return xy @ T[:2, :2].T + T[:2, 2]


@pytest.mark.parametrize("odometry", ["vio", "raw"])
def test_sightings_land_where_the_truth_puts_the_landmarks(dataset, odometry):
    _, run, labels = run_of(dataset, odometry)
    checked = 0
    for robot in range(run.n_robots):
        for step in range(0, len(run.times), 5):
            expected = np.array([LANDMARKS[s] for s in labels[robot][step]]).reshape(-1, 2)
            np.testing.assert_allclose(world_positions(run, robot, step), expected, atol=2e-3)
            checked += len(expected)
    assert checked > 100


def test_truth_transforms_compose(dataset):
    _, run, _ = run_of(dataset, "raw")
    T01, T12, T02 = run.T_true(0, 1), run.T_true(1, 2), run.T_true(0, 2)
    np.testing.assert_allclose(T01 @ T12, T02, atol=1e-9)
    np.testing.assert_allclose(T01 @ run.T_true(1, 0), np.broadcast_to(np.eye(3), T01.shape),
                               atol=1e-9)
    # the odometry frame is the robot's pose at the start, so T_true is the relative start pose
    start = run.times[0] - 1.0
    pose0, pose1 = circle(1, np.array([start]))[0], circle(2, np.array([start]))[0]
    T = np.linalg.inv(se2_from_params(pose0)) @ se2_from_params(pose1)
    np.testing.assert_allclose(se2_to_params(T01[0]), se2_to_params(T), atol=1e-6)


def test_identities_never_reach_the_aligner(dataset, tmp_path):
    """The same landmarks under other subject numbers and barcodes give the same maps: the
    maps hold geometry only, in an order that does not depend on identity."""
    subjects = list(LANDMARKS)
    shuffled = dict(zip(subjects, np.random.default_rng(3).permutation(subjects).tolist(),
                        strict=True))
    relabelled = {shuffled[s]: xy for s, xy in LANDMARKS.items()}
    codes = {s: 200 - 7 * s for s in range(1, 21)}
    other = write_dataset(tmp_path / "Other", landmarks=relabelled, barcodes=codes)
    _, run_a, labels_a = run_of(dataset)
    _, run_b, labels_b = run_of(other)
    differ = 0
    for r in range(run_a.n_robots):
        for a, b, la, lb in zip(run_a.maps[r], run_b.maps[r], labels_a[r], labels_b[r],
                                strict=True):
            for name in ("centroids", "widths", "heights", "last_seen"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            assert lb.tolist() == [shuffled[s] for s in la.tolist()]
            assert np.all(a.widths == mrclam.LANDMARK_SIZE[0])
            differ += int(len(la) > 1 and not np.all(np.diff(la) > 0))
    assert differ > 0  # entries are not in the order of the landmarks' numbers


def test_vio_drift_has_the_documented_size():
    """1 deg per sqrt(minute) and a 1 % scale error: after a minute of driving straight, the
    heading error's std is about 1 deg and the distance error's about 1 % (200 seeds)."""
    t = np.arange(0.0, 60.01, 0.01)
    truth = np.column_stack([t, 0.5 * t, np.zeros_like(t), np.zeros_like(t)])
    ends = np.array([mrclam.vio_like(np.random.default_rng(s), truth, 0.0, 60.0, 1.0, 0.0)[1][-1]
                     for s in range(200)])
    assert np.degrees(np.std(ends[:, 2])) == pytest.approx(1.0, rel=0.2)
    scaled = np.array([mrclam.vio_like(np.random.default_rng(s), truth, 0.0, 60.0, 0.0, 0.01)[1]
                       [-1] for s in range(200)])
    np.testing.assert_allclose(scaled[:, 1:], 0.0, atol=1e-9)
    assert np.std(scaled[:, 0] / 30.0 - 1.0) == pytest.approx(0.01, rel=0.2)


def test_map_drift_is_zero_without_drift_and_grows_with_it(dataset):
    """Odometry that is the truth misplaces nothing; VIO-like drift misplaces an old sighting
    more the older it is and more the stronger the drift; the circles' commanded odometry is
    exact, so dead reckoning drifts only by its sampling."""
    data = mrclam.read_dataset(dataset)
    kappas = np.array([2.0, 8.0, 30.0])
    np.testing.assert_allclose(mrclam.map_drift(data, "vio", 0, kappas, 0.0, 0.0), 0.0,
                               atol=1e-9)
    weak = mrclam.map_drift(data, "vio", 0, kappas, 1.0, 0.01)
    strong = mrclam.map_drift(data, "vio", 0, kappas, 10.0, 0.1)
    assert np.all(np.diff(strong) > 0) and np.all(strong > weak) and np.all(weak > 0)
    assert np.all(mrclam.map_drift(data, "raw", None, kappas, 0.0, 0.0) < 0.05)
    # longer than the data set: nothing to measure
    assert np.isnan(mrclam.map_drift(data, "vio", 0, np.array([1e4]), 1.0, 0.01)[0])
    # in any order, repeats included, each kappa gets its own figure
    shuffled = mrclam.map_drift(data, "vio", 0, np.array([30.0, 2.0, 30.0, 8.0]), 1.0, 0.01)
    np.testing.assert_allclose(shuffled, weak[[2, 0, 2, 1]])
    assert mrclam.map_drift(data, "vio", 0, np.zeros(0), 1.0, 0.01).shape == (0,)
    for bad in (np.array([0.0]), np.array([np.nan]), np.ones((2, 2))):
        with pytest.raises(DataError, match="kappas"):
            mrclam.map_drift(data, "vio", 0, bad, 1.0, 0.01)
    with pytest.raises(DataError, match="seed"):
        mrclam.map_drift(data, "vio", None, kappas, 1.0, 0.01)
    for every in (0.0, -1.0, float("nan"), "5"):
        with pytest.raises(DataError, match="every"):
            mrclam.map_drift(data, "vio", 0, kappas, 1.0, 0.01, every)


def test_kappa_is_set_per_odometry():
    """The shipped config holds VIO-like maps longer than dead-reckoned ones; one number sets
    both; a bad span or odometry is refused by name."""
    from tcaff_gtsam.eval.config import load_mrclam, override

    from tcaff_gtsam.errors import ConfigError

    config = load_mrclam("default")
    assert config.kappa_of("vio") > config.kappa_of("raw") == 20.0
    both = override(config, "test", kappa=10)
    assert both.kappa_of("raw") == both.kappa_of("vio") == 10.0
    one = override(config, "test", kappa={"raw": 5.0, "vio": 60.0})
    assert (one.kappa_of("raw"), one.kappa_of("vio")) == (5.0, 60.0)
    for bad in (-1, {"raw": 5.0, "vio": 0.0}, {"raw": 5.0, "gps": 1.0}, True):
        with pytest.raises(ConfigError, match="kappa"):
            override(config, "test", kappa=bad)
    with pytest.raises(ConfigError, match="gps"):
        config.kappa_of("gps")


@settings(max_examples=30, deadline=None)
@given(v=st.floats(0.0, 1.0), w=st.floats(-1.0, 1.0), seconds=st.floats(1.0, 20.0))
def test_dead_reckoning_follows_the_arc_of_constant_commands(v, w, seconds):
    t = np.arange(0.0, seconds, 0.015)
    odometry = np.column_stack([t, np.full_like(t, v), np.full_like(t, w)])
    times, poses = mrclam.dead_reckoning(odometry, 0.0)
    theta = w * times
    # the arc v/w (sin theta, 1 - cos theta) written so that it holds as w -> 0 too:
    # sin(theta)/w = t sinc(theta/pi) and (1 - cos theta)/w = t theta/2 sinc(theta/(2 pi))^2
    x = v * times * np.sinc(theta / np.pi)
    y = v * times * theta / 2 * np.sinc(theta / (2 * np.pi)) ** 2
    np.testing.assert_allclose(poses[:, 0], x, atol=1e-7)
    np.testing.assert_allclose(poses[:, 1], y, atol=1e-7)


def test_overlap_counts_shared_landmarks(dataset):
    _, run, labels = run_of(dataset, min_shared=2)
    for s in range(0, len(run.times), 7):
        shared = np.intersect1d(labels[0][s], labels[3][s]).size
        assert run.overlap(0, 3)[s] == (shared >= 2)


def test_pairs_choose_the_aligned_pairs_and_are_checked(dataset):
    _, run, _ = run_of(dataset, pairs=[(1, 2), (3, 1)])
    assert run.pairs == [(0, 1), (2, 0)]
    with pytest.raises(DataError, match="pairs"):
        run_of(dataset, pairs=[(1, 7)])
    with pytest.raises(DataError, match="pairs"):
        run_of(dataset, pairs=[(2, 2)])


# -- bad input ---------------------------------------------------------------------------------


def damaged(dataset: Path, tmp_path: Path, file: str, edit) -> Path:
    folder = tmp_path / "Damaged"
    folder.mkdir()
    for f in dataset.iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
    lines = (folder / file).read_text().splitlines(keepends=True)
    (folder / file).write_text("".join(edit(lines)))
    return folder


def replace_line(k: int, text: str):
    return lambda lines: [*lines[:k], text, *lines[k + 1:]]


@pytest.mark.parametrize(("file", "edit", "match"), [
    ("Robot2_Odometry.dat", replace_line(10, f"{T0 + 0.3:.3f}\t0.4\n"),
     r"Robot2_Odometry.dat:11: expected 3 columns, got 2"),
    ("Robot3_Measurement.dat", replace_line(5, f"{T0 + 0.4:.3f}\t31\tfar\t0.1\n"),
     r"Robot3_Measurement.dat:6: not a number"),
    ("Robot1_Groundtruth.dat", replace_line(20, f"{T0 + 0.18:.3f}\tnan\t0.0\t0.0\n"),
     r"Robot1_Groundtruth.dat:21: non-finite"),
    ("Robot4_Groundtruth.dat", replace_line(30, f"{T0 - 5:.3f}\t0.0\t0.0\t0.0\n"),
     r"Robot4_Groundtruth.dat:31: time goes backwards"),
    ("Robot5_Odometry.dat", lambda lines: lines[:2], r"Robot5_Odometry.dat: no rows"),
    ("Barcodes.dat", replace_line(4, "3\t16\n"), r"Barcodes.dat:5: expected a subject and a "
                                                 r"new barcode"),
    ("Landmark_Groundtruth.dat", lambda lines: lines[:2], r"Landmark_Groundtruth.dat: no "
                                                          r"landmark"),
])
def test_bad_files_name_the_file_and_line(dataset, tmp_path, file, edit, match):
    with pytest.raises(DataError, match=match):
        mrclam.read_dataset(damaged(dataset, tmp_path, file, edit))


def test_a_missing_file_or_folder_is_named(dataset, tmp_path):
    folder = damaged(dataset, tmp_path, "Barcodes.dat", lambda lines: lines)
    (folder / "Robot3_Measurement.dat").unlink()
    with pytest.raises(DataError, match=r"Robot3_Measurement.dat: no such file"):
        mrclam.read_dataset(folder)
    with pytest.raises(DataError, match="not a folder"):
        mrclam.read_dataset(tmp_path / "nowhere")
    empty = tmp_path / "Empty"
    empty.mkdir()
    with pytest.raises(DataError, match=r"Barcodes.dat: no such file"):
        mrclam.read_dataset(empty)


def test_sightings_of_unknown_barcodes_are_skipped_and_counted(dataset, tmp_path):
    folder = damaged(dataset, tmp_path, "Robot2_Measurement.dat",
                     lambda lines: [*lines, f"{T0 + 39.9:.3f}\t999\t1.0\t0.0\n",
                                    f"{T0 + 39.95:.3f}\t998\t1.0\t0.0\n"])
    data = mrclam.read_dataset(folder)
    assert data.skipped == {"sightings of unknown barcodes": 2}
    assert mrclam.read_dataset(dataset).skipped == {}


def test_robots_sightings_are_not_landmarks(dataset, tmp_path):
    barcode_of_robot_4 = 10 + 3 * 4
    folder = damaged(dataset, tmp_path, "Robot2_Measurement.dat",
                     lambda lines: [*lines, f"{T0 + 39.9:.3f}\t{barcode_of_robot_4}\t1.0\t0.0\n"])
    data = mrclam.read_dataset(folder)
    assert set(np.unique(data.robots[2].sightings[:, 1]).astype(int)) <= set(LANDMARKS)
    assert data.skipped == {}


# -- the command -------------------------------------------------------------------------------


@pytest.mark.slow
def test_command_scores_every_pair_and_resumes(dataset, tmp_path):
    vio = ["mrclam", "--data", str(dataset), "--methods", "tcaff_only", "--duration", "10",
           "--odometry", "vio"]
    run = [*vio, "--odometry", "raw"]
    args = [*run, "--output", str(tmp_path)]
    names = ("Synthetic-vio-seed0", "Synthetic-raw")
    first = CliRunner().invoke(app, [*args, "--no-figures"])
    assert first.exit_code == 0, first.output
    for name in names:
        folder = tmp_path / name
        for f in ("metrics.json", "metrics.csv", "table.md", f"{name}.npz"):
            assert (folder / f).is_file(), f
        assert not (folder / "figures").exists()
        metrics = json.loads((folder / "metrics.json").read_text())
        truth = metrics["summary"][name]["ground_truth"]
        assert truth["false_accept"] == 0.0 and truth["n_overlap"] > 0
        assert len(metrics["runs"][0]["metrics"]["tcaff"]) == 1 + 20
    assert "Per directed pair" in first.output
    again = CliRunner().invoke(app, [*args, "--no-figures"])
    assert again.exit_code == 0, again.output
    assert again.output.count("reused") == 2
    # a table spoilt since is written again, not reused with the spoilt file left in place
    (tmp_path / names[1] / "metrics.json").write_text("{not json")
    mended = CliRunner().invoke(app, [*args, "--no-figures"])
    assert mended.exit_code == 0 and mended.output.count("reused") == 1, mended.output
    json.loads((tmp_path / names[1] / "metrics.json").read_text())
    # ... the spoilt run's files are set aside, not deleted
    assert (tmp_path / "previous" / names[1] / "metrics.json").read_text() == "{not json"

    def fingerprint(folder, name):
        return json.loads((folder / f"{name}.json").read_text())["info"]["fingerprint"]

    before = {name: fingerprint(tmp_path / name, name) for name in names}
    other = CliRunner().invoke(app, [*args, "--kappa", "10", "--no-figures"])
    assert other.exit_code == 0 and "reused" not in other.output
    for name in names:  # a run of other settings moves the earlier results aside, whole
        aside = tmp_path / "previous" / name
        assert fingerprint(aside, name) == before[name] != fingerprint(tmp_path / name, name)
        assert {p.name for p in aside.iterdir()} == {p.name for p in (tmp_path / name).iterdir()}
    # the figures, of two pairs (drawing all 20 pairs' takes most of a run's time) and one
    # odometry (the other's results are drawn by the same code)
    drawn = CliRunner().invoke(app, [*vio, "--pairs", "1:2,5:4", "--output",
                                     str(tmp_path / "drawn")])
    assert drawn.exit_code == 0, drawn.output
    figures = {p.name for p in (tmp_path / "drawn" / names[0] / "figures").glob("*.png")}
    assert figures == {"arena.png", "errors_0_1.png", "errors_4_3.png", "candidates_0_1.png",
                       "candidates_4_3.png"}


def test_results_not_reused_are_set_aside_whole_and_a_failed_move_is_named(tmp_path):
    from tcaff_gtsam.eval.dataset_runs import _set_aside

    folder = tmp_path / "run"
    (folder / "figures").mkdir(parents=True)
    (folder / "figures" / "arena.png").write_bytes(b"png")
    for name in ("run.json", "run.npz", "metrics.json", "table.md", "recording.rrd"):
        (folder / name).write_text(name)
    (folder / "maps").mkdir()  # a Kimera run's maps stay: a run of the same settings reuses them
    _set_aside(folder, "run")
    aside = tmp_path / "previous" / "run"
    assert {p.name for p in aside.iterdir()} == {"run.json", "run.npz", "metrics.json",
                                                 "table.md", "recording.rrd", "figures"}
    assert [p.name for p in folder.iterdir()] == ["maps"]
    (folder / "run.json").write_text("second")
    _set_aside(folder, "run")  # a finished run replaces what an earlier move left
    assert [p.name for p in aside.iterdir()] == ["run.json"]
    assert (aside / "run.json").read_text() == "second"
    # an interrupted run (no job: it is written last) leaves partial results: they go, and
    # the finished run set aside before it stays
    (folder / "figures").mkdir()
    (folder / "metrics.json").write_text("partial")
    _set_aside(folder, "run")
    assert [p.name for p in folder.iterdir()] == ["maps"]
    assert (aside / "run.json").read_text() == "second"
    _set_aside(folder, "run")  # nothing left: nothing changes
    assert (aside / "run.json").read_text() == "second"
    blocked = tmp_path / "blocked"
    (blocked / "run").mkdir(parents=True)
    (blocked / "run" / "run.json").write_text("kept")
    (blocked / "previous").write_text("a file where the folder goes")
    with pytest.raises(DataError, match=r"run: .*previous is no folder; an earlier run's "
                                        r"results are moved there"):
        _set_aside(blocked / "run", "run")
    assert (blocked / "run" / "run.json").read_text() == "kept"
    (blocked / "previous").unlink()
    (blocked / "previous").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    with pytest.raises(DataError, match="previous is no folder"):
        _set_aside(blocked / "run", "run")  # a link is not followed to remove its contents
    assert (blocked / "run" / "run.json").read_text() == "kept"


def test_command_rejects_bad_options(dataset, tmp_path):
    for extra, message in ((["--pairs", "1-2"], "--pairs"), (["--odometry", "gps"], "gps"),
                           (["--kappa", "-1"], "kappa")):
        result = CliRunner().invoke(app, ["mrclam", "--data", str(dataset), "--output",
                                          str(tmp_path), *extra])
        assert result.exit_code != 0
        assert message in str(result.exception), result.output


# -- the real data set -------------------------------------------------------------------------


@pytest.mark.skipif(not REAL.is_dir(), reason="MRCLAM data set 6 is not beside the project")
def test_first_minute_of_data_set_6_places_sightings_on_the_landmarks():
    data = mrclam.read_dataset(REAL)
    assert data.skipped == {"sightings of unknown barcodes": 6}
    assert len(data.landmarks) == 15 and sorted(data.robots) == [1, 2, 3, 4, 5]
    run, labels = mrclam.load_run(data, "vio", 0, 20.0, 1, 3, 0.0, 0.0, duration=60.0)
    errors = np.concatenate([
        np.linalg.norm(world_positions(run, r, s) - np.array(
            [data.landmarks[k] for k in labels[r][s]]).reshape(-1, 2), axis=1)
        for r in range(run.n_robots) for s in range(len(run.times))])
    assert errors.size > 200
    # monocular range and bearing: a few tenths of a metre at several metres
    assert np.median(errors) < 0.15 and np.percentile(errors, 95) < 0.6
    T = run.T_true(0, 1)
    np.testing.assert_allclose(T @ run.T_true(1, 0), np.broadcast_to(np.eye(3), T.shape),
                               atol=1e-9)


def test_a_shorter_look_is_a_prefix_of_the_whole_run(dataset):
    """Each robot's drift has its own generator: using less data, or seeing fewer robots'
    results, changes nothing of what remains."""
    options = {"heading_rw_deg_per_sqrt_min": 5.0, "scale_std": 0.05, "seed": 4}
    _, whole, _ = run_of(dataset, **options)
    _, short, _ = run_of(dataset, duration=15.0, **options)
    S = len(short.times)
    np.testing.assert_allclose(short.T_odom_body, whole.T_odom_body[:, :S], atol=1e-9)
    for r in range(whole.n_robots):
        for a, b in zip(short.maps[r], whole.maps[r][:S], strict=True):
            np.testing.assert_allclose(a.centroids, b.centroids, atol=1e-9)


def test_sightings_before_the_run_starts_are_left_out(dataset, tmp_path):
    early = damaged(dataset, tmp_path, "Robot2_Measurement.dat",
                    lambda lines: [*lines[:2], f"{T0 - 2.0:.3f}\t{10 + 3 * 13}\t9.0\t0.0\n",
                                   *lines[2:]])
    _, run, _ = run_of(dataset)
    _, run_early, _ = run_of(early)
    for a, b in zip(run.maps[1], run_early.maps[1], strict=True):
        np.testing.assert_array_equal(a.centroids, b.centroids)


def test_the_graph_links_a_pair_run_in_one_direction_only(dataset):
    """With only (j, i) chosen, its TCAFF output still feeds the iSAM2 graph."""
    from tcaff_gtsam.eval.config import load_methods
    from tcaff_gtsam.eval.methods import run_methods

    _, run, _ = run_of(dataset, pairs=[(5, 4)])
    runs = run_methods(run, load_methods("tcaff_only"))
    tcaff = ~np.isnan(runs.estimates["tcaff"][0, :, 0])
    causal = ~np.isnan(runs.estimates["tcaff_isam2_causal"][0, :, 0])
    assert tcaff.sum() >= 5 and causal.sum() >= tcaff.sum() - 2
    err = runs.estimates["tcaff_isam2_smoothed"][0, tcaff, :2] - runs.truth[0, tcaff, :2]
    assert np.abs(err).max() < 0.1


@settings(max_examples=30, deadline=None)
@given(st.one_of(st.floats(allow_nan=False, allow_infinity=False).filter(
    lambda s: s not in range(1, 21)), st.integers(21, 10**30), st.integers(-10**30, 0)))
def test_a_subject_outside_the_twenty_is_named(dataset, tmp_path_factory, subject):
    """A subject of 1e20 was an OverflowError making the subjects of the sightings."""
    folder = damaged(dataset, tmp_path_factory.mktemp("subject"),
                     "Barcodes.dat", replace_line(7, f"{subject!r}\t28\n"))
    with pytest.raises(DataError, match=r"Barcodes.dat:8: expected a subject and a new barcode"
                                        r", got .* 28 \(subjects are 1-20\)"):
        mrclam.read_dataset(folder)


@pytest.mark.parametrize("later", [86_400.0, 1e9, 1e300])
def test_a_stray_row_a_day_later_in_every_file_is_named(dataset, tmp_path, later):
    """Every robot's odometry and truth ending in a row a day (or 1e9 s) on was read, and the
    run then asked for 7 GiB at once (MemoryError; 1e300 s: ValueError, maximum size)."""
    folder = damaged(dataset, tmp_path, "Barcodes.dat", lambda lines: lines)
    for robot in range(1, 6):
        for kind, row in (("Odometry", "\t0.0\t0.0\n"), ("Groundtruth", "\t0.0\t0.0\t0.0\n")):
            path = folder / f"Robot{robot}_{kind}.dat"
            lines = path.read_text().splitlines(keepends=True)
            last = float(lines[-1].split()[0])
            path.write_text("".join(lines) + f"{last + later!r}{row}")
    with pytest.raises(DataError, match=r"odometry and truth share .* s, more than a day "
                                        r"\(86400 s\), from Robot\d_\w+\.dat:\d+ \(.* s\) to "
                                        r"Robot\d_\w+\.dat:\d+ \(.* s\): a time stamp is wrong"):
        mrclam.read_dataset(folder)
