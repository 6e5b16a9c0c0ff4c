"""Trajectories for evo and g2o: every robot's path in one robot's frame, the export command,
and evo's own command line reproducing the table's APE."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core import sync
from evo.tools.file_interface import read_tum_trajectory_file
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from tcaff_gtsam.eval import cli
from tcaff_gtsam.eval.metrics import Thresholds
from tcaff_gtsam.eval.results import JobResult, score, write_tables
from tcaff_gtsam.eval.trajectories import TRUTH, export, robot_paths, write_g2o, write_tum
from test_text_tables import fifo_holding

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se2_from_params, se2_to_params

BIN = Path(sys.executable).parent
PAIRS = [(0, 1), (1, 0), (2, 0), (1, 2)]  # robot 2 reaches robot 0's frame only inversely


def make_job(seed: int = 0, S: int = 25, t0: float = 1000.0) -> JobResult:
    """Three robots whose odometry drifts from their true paths, the true alignments of the
    pairs, and an estimate `noisy` off by a few cm and degrees with gaps."""
    rng = np.random.default_rng(seed)
    steps = np.arange(S, dtype=float)
    true = np.stack([np.column_stack([rng.uniform(-5, 5) + 0.5 * steps,
                                      rng.uniform(-5, 5) + np.sin(0.2 * steps),
                                      rng.uniform(-3, 3) + 0.05 * steps]) for _ in range(3)])
    drift = np.cumsum(rng.normal(0, [0.02, 0.02, 0.003], (3, S, 3)), axis=1)
    odom = se2_to_params(se2_from_params(true) @ se2_from_params(drift))
    T_w_o = se2_from_params(true) @ invert(se2_from_params(odom))
    truth = np.stack([se2_to_params(invert(T_w_o[i]) @ T_w_o[j]) for i, j in PAIRS])
    noisy = se2_to_params(se2_from_params(truth)
                          @ se2_from_params(rng.normal(0, [0.05, 0.05, 0.02], (len(PAIRS), S, 3))))
    noisy[:, rng.random(S) < 0.3] = np.nan
    # its covariance: sigmas of a few cm and degrees, x and y correlated, NaN without estimate
    cov = np.einsum("psi,psj->psij", *[rng.normal(0, 0.05, (len(PAIRS), S, 3))] * 2)
    cov += np.diag([0.05**2, 0.05**2, 0.02**2])
    cov[np.isnan(noisy[..., 0])] = np.nan
    arrays = {"times": steps, "t0": np.array(t0), "poses_true": true, "poses_odom": odom,
              "truth": truth, "est_noisy": noisy, "cov_noisy": cov,
              "est_ground_truth": truth.copy()}
    job = JobResult("walk", seed, PAIRS, arrays)
    score(job, ["noisy", "ground_truth"], Thresholds())
    return job


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 2))
def test_paths_through_the_true_alignment_are_the_true_paths(seed, reference):
    job = make_job(seed)
    T_w_b = se2_from_params(job.arrays["poses_true"])
    T_w_oref = T_w_b[reference] @ invert(se2_from_params(job.arrays["poses_odom"][reference]))
    truth = robot_paths(job, TRUTH, reference)
    through_truth = robot_paths(job, "ground_truth", reference)
    assert set(truth) == {0, 1, 2} and set(through_truth) == {0, 1, 2} - {reference}
    for robot, (steps, T) in truth.items():
        np.testing.assert_array_equal(steps, np.arange(job.n_steps))
        # each robot's true pose in the reference robot's odometry frame of that step
        np.testing.assert_allclose(T, invert(T_w_oref) @ T_w_b[robot], atol=1e-9)
        if robot != reference:
            np.testing.assert_allclose(through_truth[robot][1], T, atol=1e-9)


def test_estimate_paths_skip_the_steps_without_an_estimate():
    job = make_job(1)
    paths = robot_paths(job, "noisy", 0)
    has = ~np.isnan(job.arrays["est_noisy"][0, :, 0])
    np.testing.assert_array_equal(paths[1][0], np.flatnonzero(has))
    assert set(paths) == {1, 2}  # robot 2 through the inverse of the pair (2, 0)


def test_bad_reference_or_method_is_named():
    job = make_job()
    with pytest.raises(ConfigError, match=r"reference 3: .*0\.\.2"):
        robot_paths(job, TRUTH, 3)
    with pytest.raises(ConfigError, match=r"method 'clipper'.*noisy"):
        robot_paths(job, "clipper", 0)


def test_tum_files_read_back_by_evo_give_the_table_ape(tmp_path):
    job = make_job(2)
    folder = write_tum(tmp_path, job, 0)
    assert folder == tmp_path / "trajectories" / "walk-seed2" / "frame_0"
    assert {p.name for p in folder.iterdir()} == {TRUTH, "noisy", "ground_truth"}
    assert sorted(p.name for p in (folder / TRUTH).iterdir()) == ["0.tum", "1.tum", "2.tum"]
    only = write_tum(tmp_path / "only", job, 0, streams=["noisy"])
    assert {p.name for p in only.iterdir()} == {TRUTH, "noisy"}
    for robot, pair in ((1, "0->1"), (2, None)):
        ref = read_tum_trajectory_file(str(folder / TRUTH / f"{robot}.tum"))
        est = read_tum_trajectory_file(str(folder / "noisy" / f"{robot}.tum"))
        assert ref.timestamps[0] == pytest.approx(1000.0)  # the run's clock
        ref, est = sync.associate_trajectories(ref, est)
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((ref, est))
        if pair is not None:
            assert ape.get_statistic(evo_metrics.StatisticsType.rmse) == pytest.approx(
                job.metrics["noisy"][pair]["ape_m"], rel=1e-6)
        assert ape.get_statistic(evo_metrics.StatisticsType.rmse) > 0.01


def test_evo_ape_command_reproduces_the_table(tmp_path):
    job = make_job(3)
    job.save(tmp_path / "runs")
    write_tables(tmp_path, {}, [job], {})
    export(tmp_path, "tum", 0)
    frame = tmp_path / "trajectories" / "walk-seed3" / "frame_0"
    done = subprocess.run([str(BIN / "evo_ape"), "tum", str(frame / TRUTH / "1.tum"),
                           str(frame / "noisy" / "1.tum")], capture_output=True, text=True,
                          timeout=120, env={"HOME": str(tmp_path), "PATH": str(BIN)})
    assert done.returncode == 0, done.stderr
    rmse = float(next(line.split()[1] for line in done.stdout.splitlines()
                      if line.split()[:1] == ["rmse"]))
    with open(tmp_path / "metrics.csv") as file:
        row = next(r for r in csv.DictReader(file) if r["method"] == "noisy"
                   and r["pair"] == "0->1")
    assert rmse == pytest.approx(float(row["ape_m"]), abs=5e-7)  # evo prints 6 decimals


def test_g2o_pose_graph_reads_back_in_gtsam(tmp_path):
    job = make_job(4)
    folder = write_g2o(tmp_path, job, 1)
    assert folder.name == "frame_1"
    graph, values = gtsam.readG2o(str(folder / "noisy.g2o"))
    paths = robot_paths(job, "noisy", 1)
    n_poses = job.n_steps + sum(len(steps) for steps, _ in paths.values())
    assert values.size() == n_poses
    # each robot's chain of odometry, and one alignment edge per estimate
    n_chain = (job.n_steps - 1) + sum(len(steps) - 1 for steps, _ in paths.values())
    n_align = sum(len(steps) for steps, _ in paths.values())
    assert graph.size() == n_chain + n_align
    steps, T = paths[0]
    key = 0 * job.n_steps + int(steps[-1])  # robot 0's last estimated pose
    # g2o files keep 6 significant digits
    np.testing.assert_allclose(values.atPose2(key).matrix(), T[-1], rtol=1e-5, atol=1e-5)
    # the file's solution is its own: every edge agrees with the vertices it joins
    assert graph.error(values) < 1e-6 * graph.size()


def test_rosbag2_export_holds_every_pairs_alignments_for_mcap_readers(tmp_path):
    """Read back with mcap's reader and mcap-ros2-support's decoder (not the writer's
    library): one topic per pair and stream, a message per step with a value, on the run's
    clock; a second export replaces the bag."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    job = make_job(6)
    job.save(tmp_path / "runs")
    for _ in range(2):
        (folder,) = export(tmp_path, "rosbag2")
    assert folder == tmp_path / "trajectories" / "walk-seed6" / "rosbag2"
    with open(next(folder.glob("*.mcap")), "rb") as file:
        decoded = [(c.topic, m) for _, c, _, m in make_reader(
            file, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    for stream, key in (("truth", "truth"), ("noisy/alignment", "est_noisy")):
        for p, (i, j) in enumerate(PAIRS):
            got = [m for topic, m in decoded if topic == f"/r{i}/tcaff/{stream}/r{j}"]
            values = job.arrays[key][p]
            steps = np.flatnonzero(np.all(np.isfinite(values), axis=1))
            assert len(got) == len(steps)
            for m, s in zip(got, steps, strict=True):
                assert m.header.frame_id == f"r{i}/odom"
                stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                assert stamp == pytest.approx(1000.0 + s, abs=1e-6)
                pose = m.pose.pose
                assert (pose.position.x, pose.position.y) == tuple(values[s, :2])
                assert 2 * np.arctan2(pose.orientation.z, pose.orientation.w) == \
                    pytest.approx(values[s, 2], abs=1e-12)
                # the method's covariance of (x, y, yaw) in ROS's (x, y, z, roll, pitch, yaw)
                covariance = np.reshape(m.pose.covariance, (6, 6))[np.ix_([0, 1, 5], [0, 1, 5])]
                expected = (job.arrays["cov_noisy"][p, s] if stream.startswith("noisy")
                            else np.zeros((3, 3)))
                np.testing.assert_array_equal(covariance, expected)


def test_export_of_a_recorded_folder_and_bad_input(tmp_path):
    job = make_job(5)
    job.seed = None  # a recorded run is saved as <name>.npz beside its tables
    job.save(tmp_path)
    (written,) = export(tmp_path, "g2o", 2)
    assert {p.name for p in written.iterdir()} == {"truth.g2o", "noisy.g2o",
                                                   "ground_truth.g2o"}
    with pytest.raises(ConfigError, match="format 'kml'"):
        export(tmp_path, "kml")
    with pytest.raises(DataError, match="no saved runs"):
        export(tmp_path / "trajectories")
    (tmp_path / "broken.npz").write_bytes(b"not a zip")
    (tmp_path / "broken.json").write_text("{}")
    with pytest.raises(DataError, match="not a saved job"):
        export(tmp_path)


def test_export_command_one_line_errors(tmp_path, monkeypatch, capsys):
    for args, named in ((["export", str(tmp_path)], "no saved runs"),
                        (["export", str(tmp_path / "missing")], "not a results folder")):
        monkeypatch.setattr(sys, "argv", ["tcaff", *args])
        with pytest.raises(SystemExit) as exited:
            cli.main()
        assert exited.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err, err


@pytest.mark.parametrize("fmt", ["tum", "g2o", "rosbag2"])
def test_export_refuses_a_reference_no_job_has_before_writing(tmp_path, fmt):
    """It used to end in an IndexError after making the folder (tum, g2o), or be ignored
    (rosbag2)."""
    make_job(5).save(tmp_path / "runs")
    with pytest.raises(ConfigError, match="reference 9"):
        export(tmp_path, fmt, 9)
    assert not (tmp_path / "trajectories").exists()


def test_export_skips_the_runs_without_the_reference_robot(tmp_path, caplog):
    """A study's runs have two to four robots: a reference of the four-robot run's was
    refused for every run."""
    three = make_job(5)
    two = make_job(6)
    two.name, two.pairs = "pair", [(0, 1), (1, 0)]
    two.arrays = {name: (value[:2] if name in ("poses_true", "poses_odom", "truth")
                         or name.startswith(("est_", "cov_")) else value)
                  for name, value in two.arrays.items()}
    score(two, ["noisy", "ground_truth"], Thresholds())
    for job in (three, two):
        job.save(tmp_path / "runs")
    (written,) = export(tmp_path, "tum", 2)
    assert written.parent.name == three.stem
    assert f"{two.stem}: no robot 2, whose frame the paths are put in: skipped" in caplog.text
    caplog.clear()
    assert len(export(tmp_path, "rosbag2", 2)) == 2  # every pair: no reference needed
    assert "skipped" not in caplog.text


@pytest.mark.parametrize("fmt", ["tum", "rosbag2"])
def test_export_into_a_file_where_its_folder_goes_is_a_data_error(tmp_path, fmt):
    job = make_job(5)
    job.save(tmp_path / "runs")
    taken = tmp_path / "trajectories" / job.stem
    taken.parent.mkdir()
    taken.write_text("keep me")
    with pytest.raises(DataError, match=f"its {fmt} files could not be written"):
        export(tmp_path, fmt)
    assert taken.read_text() == "keep me"


# -- saved jobs that are not what `JobResult.save` writes ------------------------------------------


def _save_altered(folder: Path, meta=None, arrays=None, text: str | None = None) -> JobResult:
    """make_job(5) saved into `folder`, its JSON entries updated by `meta` (a key mapped to
    DROP is removed) or replaced by `text`, its arrays updated by `arrays` (DROP removes)."""
    job = make_job(5)
    job.save(folder)
    json_path, npz_path = folder / f"{job.stem}.json", folder / f"{job.stem}.npz"
    saved = json.loads(json_path.read_text())
    for key, value in (meta or {}).items():
        saved.pop(key) if value is DROP else saved.__setitem__(key, value)
    json_path.write_text(json.dumps(saved) if text is None else text)
    if arrays:
        with np.load(npz_path) as data:
            kept = dict(data)
        for key, value in arrays.items():
            kept.pop(key) if value is DROP else kept.__setitem__(key, value)
        np.savez(npz_path, **kept)
    return job


DROP = object()
S, P = 25, len(PAIRS)  # make_job's steps and pairs (3 robots)


@pytest.mark.parametrize(("meta", "arrays", "text", "file", "words"), [
    (None, None, "[" * 100_000 + "]" * 100_000, "json", "not JSON (RecursionError"),
    (None, None, '{"name": "walk", "seed": 0, "pa', "json", "not JSON (JSONDecodeError"),
    (None, None, "[]", "json", "not a saved job (a JSON object), got []"),
    ({"pairs": [[0, 5]]}, None, None, "json", "pairs must be [i, j] of two of the 3 robots"),
    ({"pairs": [[0, 1], [0, 1]]}, None, None, "json", "each pair once"),
    ({"pairs": [[1, 1]]}, None, None, "json", "pairs must be [i, j] of two"),
    ({"pairs": "ab"}, None, None, "json", "pairs must be a JSON list, got 'ab'"),
    ({"pairs": [[0, 1, 2]]}, None, None, "json", "pairs must be an (m, 2) array"),
    ({"pairs": [[0, "1"]]}, None, None, "json", "pairs must be an (m, 2) array of integer"),
    ({"info": []}, None, None, "json", "info must be a JSON dict, got []"),
    ({"info": {"robots": ["a"]}}, None, None, "json", "info.robots must name the 3 robots"),
    ({"name": 5}, None, None, "json", "name must be a JSON str, got 5"),
    ({"name": "../up"}, None, None, "json", "name must be a file name, got '../up'"),
    ({"seed": 1.5}, None, None, "json", "seed must be a JSON int >= 0 or null, got 1.5"),
    ({"seed": True}, None, None, "json", "seed must be a JSON int >= 0 or null, got True"),
    ({"seed": -1}, None, None, "json", "seed must be an int >= 0 or null, got -1"),
    ({"metrics": DROP}, None, None, "json", "no 'metrics', not a saved job"),
    ({"seconds": {"noisy": "fast"}}, None, None, "json", "seconds.noisy must be seconds"),
    ({"metrics": {"noisy": [1]}}, None, None, "json", "metrics.noisy must map pairs to"),
    ({"mot": {"noisy": {"mota": 1}}}, None, None, "json", "mot.noisy must hold a mota"),
    (None, {"times": DROP}, None, "npz", "no array 'times', not a saved job"),
    (None, {"truth": DROP}, None, "npz", "no array 'truth', not a saved job"),
    (None, {"poses_odom": DROP}, None, "npz", "no array 'poses_odom', not a saved job"),
    (None, {"times": np.array(3.0)}, None, "npz", "array 'times' has shape (), expected (S,)"),
    (None, {"times": np.zeros(S)}, None, "npz", "array 'times' must be finite seconds that "
                                                "increase"),
    (None, {"times": 1e300 + np.arange(S) * 1e290}, None, "npz", "times[0] = 1e+300 is beyond"),
    (None, {"t0": np.array(9e9 - 10)}, None, "npz", "array 't0' = 8999999990.0 puts the times "
                                                    "beyond"),
    (None, {"poses_odom": np.zeros(3 * S * 3)}, None, "npz",
     f"array 'poses_odom' has shape ({3 * S * 3},), expected (n, S, 3) = (*, {S}, 3)"),
    (None, {"truth": np.zeros((S, P, 3))}, None, "npz",
     f"array 'truth' has shape ({S}, {P}, 3), expected (P, S, 3) = ({P}, {S}, 3)"),
    (None, {"truth": np.full((P, S, 3), "x")}, None, "npz", "array 'truth' must be real "
                                                           "numbers"),
    (None, {"truth": np.full((P, S, 3), np.inf)}, None, "npz", "truth[0, 0, 0] = inf is not "
                                                              "finite"),
    (None, {"est_noisy": np.zeros((P, S))}, None, "npz", "array 'est_noisy' has shape"),
    (None, {"cov_noisy": np.zeros((P, S, 3))}, None, "npz", "array 'cov_noisy' has shape"),
    (None, {"cov_other": np.zeros((P, S, 3, 3))}, None, "npz", "'cov_other' without "
                                                              "'est_other'"),
    (None, {"poses_true": np.ones((3, S, 3), dtype=bool)}, None, "npz",
     "array 'poses_true' must hold numbers, got bool"),
    (None, {"overlap": np.ones((P, S))}, None, "npz", "array 'overlap' must be (P, S)"),
    (None, {"cand_steps_0": np.array([0, S])}, None, "npz", "the candidates of a pair"),
    (None, {"cand_steps_0": np.array([0, S]), "cand_z_0": np.zeros((2, 3))}, None, "npz",
     f"array 'cand_steps_0' holds a step beyond the {S} steps"),
    (None, {"map_counts_0": np.ones(S, dtype=np.int32), "map_xy_0": np.zeros((S, 2)),
            "map_widths_0": np.zeros(S - 1)}, None, "npz", "array 'map_widths_0' has shape"),
])
def test_a_saved_job_that_is_not_one_is_a_data_error_naming_file_and_entry(
        tmp_path, meta, arrays, text, file, words):
    """Each used to load, and fail later deep in an export (RecursionError, IndexError,
    AttributeError, KeyError, AxisError, OverflowError in a bag's time stamps, gtsam's
    RuntimeError) or be taken as it was (pairs 'ab', a name that is no file name, a seed
    1.5)."""
    job = _save_altered(tmp_path, meta, arrays, text)
    with pytest.raises(DataError) as info:
        JobResult.load(tmp_path, job.stem)
    assert str(info.value).startswith(f"{tmp_path / job.stem}.{file}: ")
    assert words in str(info.value)
    for fmt in ("tum", "rosbag2"):
        with pytest.raises(DataError, match=re.escape(words)):
            export(tmp_path, fmt)
    assert not (tmp_path / "trajectories").exists()


#: JSON values of any shape, for the entries of a job's JSON
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                                max_size=3),
    max_leaves=8)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_any_altered_saved_job_exports_or_is_a_data_error(tmp_path_factory, data):
    """One JSON entry replaced by any JSON value, or one array by any array (shape, dtype,
    values): the job loads and exports in every format, or loading it is a DataError naming
    the file."""
    folder = tmp_path_factory.mktemp("altered")
    if data.draw(st.booleans(), "alter the JSON"):
        key = data.draw(st.sampled_from(["name", "seed", "pairs", "metrics", "seconds", "mot",
                                         "info"]), "key")
        change = {"meta": {key: data.draw(JSON_VALUES, "value")}}
    else:
        key = data.draw(st.sampled_from(["times", "t0", "poses_true", "poses_odom", "truth",
                                         "est_noisy", "cov_noisy", "overlap"]), "array")
        shape = data.draw(st.sampled_from([(), (S,), (P, S), (3, S, 3), (P, S, 3), (S, P, 3),
                                           (P, S, 3, 3), (2, S, 3)]), "shape")
        dtype = data.draw(st.sampled_from([np.float64, np.float32, np.int64, np.bool_, "U2"]))
        value = data.draw(arrays(dtype, shape, elements=None if dtype == "U2" else
                                 st.floats(-1e300, 1e300) if dtype in (np.float64,)
                                 else None), "values")
        change = {"arrays": {key: value}}
    job = _save_altered(folder, **change)
    try:
        JobResult.load(folder, job.stem)
    except DataError as exc:
        assert str(exc).startswith(f"{folder / job.stem}.")
        return
    for fmt in ("tum", "g2o", "rosbag2"):
        try:
            export(folder, fmt)
        except DataError as exc:  # a stream of non-finite odometry, a name ROS 2 cannot take
            assert job.stem in str(exc) or str(folder) in str(exc)


def test_a_saved_job_whose_json_is_a_fifo_is_refused_before_it_is_opened(tmp_path):
    job = make_job(5)
    job.save(tmp_path)
    text = (tmp_path / f"{job.stem}.json").read_text()
    (tmp_path / f"{job.stem}.json").unlink()
    with fifo_holding(tmp_path / f"{job.stem}.json", text):
        with pytest.raises(DataError, match="not a regular file"):
            JobResult.load(tmp_path, job.stem)


def test_a_recorded_run_whose_saved_job_is_not_one_is_run_again(tmp_path, caplog):
    """A data set's run is reused when its saved job has the same fingerprint: `"info": []`
    (or anything not a saved job) was an AttributeError reading the fingerprint; it is run
    again."""
    from tcaff_gtsam.eval.config import MethodsConfig
    from tcaff_gtsam.eval.dataset_runs import _saved

    job = _save_altered(tmp_path, {"info": []})
    assert _saved(tmp_path, job.stem, "fingerprint", MethodsConfig(), figures=False) is None
    # refused for what it holds, not for a fingerprint no saved job would match
    assert "results not reusable" in caplog.text and "info must be a JSON dict" in caplog.text
