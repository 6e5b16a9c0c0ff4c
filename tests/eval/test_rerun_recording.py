"""Rerun recordings, read back with Rerun's chunk reader and its dataframe API: entities, times and
counts."""

from __future__ import annotations

import collections
import re
import sys

import numpy as np
import pytest
import rerun as rr
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval import cli
from tcaff_gtsam.eval.config import load_methods, load_scenario
from tcaff_gtsam.eval.jobs import evaluate_simulated
from tcaff_gtsam.eval.rerun_recording import check_rerun, record
from tcaff_gtsam.eval.results import JobResult
from tcaff_gtsam.eval.sim.simulate import SimRun, simulate
from tcaff_gtsam.eval.trajectories import export

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_error, se2_from_params


@pytest.fixture(scope="module")
def run() -> SimRun:
    """indoor_return, shortened."""
    return simulate(load_scenario("indoor_return").model_copy(update={"duration": 30.0}), 0)


@pytest.fixture(scope="module")
def job(run) -> JobResult:
    """The run through TCAFF, CLIPPER and the truth: a real simulated job."""
    methods = load_methods("default").model_copy(update={
        "methods": ["tcaff", "clipper", "ground_truth"]})
    return evaluate_simulated(run, methods)


def test_jobs_keep_what_each_robot_shared(run, job):
    kappa = run.settings.kappa
    for r in range(run.n_robots):
        recent = [m.recent(float(t), kappa) for m, t in zip(run.maps[r], run.times, strict=True)]
        counts = job.arrays[f"map_counts_{r}"]
        np.testing.assert_array_equal(counts, [len(m) for m in recent])
        assert 0 < counts.max() and counts.sum() < sum(len(m) for m in run.maps[r])
        np.testing.assert_allclose(job.arrays[f"map_xy_{r}"],
                                   np.concatenate([m.centroids[:, :2] for m in recent]),
                                   atol=1e-5)
        np.testing.assert_allclose(job.arrays[f"map_widths_{r}"],
                                   np.concatenate([m.widths for m in recent]), rtol=1e-6)


def read_back(path) -> dict[str, list]:
    """entity path -> the record batches of its chunks."""
    batches = collections.defaultdict(list)
    for chunk in rr.chunk.RrdReader(path).stream().collect().stream().to_chunks():
        batches[chunk.entity_path].append(chunk.to_record_batch())
    return batches


def column(batches: list, name: str) -> list:
    """A column over an entity's chunks, in time order."""
    rows = [row for b in batches for row in zip(b.column("time").to_pylist(),
                                                b.column(name).to_pylist(), strict=True)]
    return [value for _, value in sorted(rows, key=lambda r: r[0])]


def seconds(batches: list) -> np.ndarray:
    return np.sort([t.total_seconds() for b in batches for t in b.column("time").to_pylist()])


def test_recording_reads_back_with_every_entity_time_and_count(job, tmp_path):
    path = record(tmp_path / "run.rrd", [job])
    entities = read_back(path)
    root = f"/{job.stem}"
    S, times = job.n_steps, job.arrays["times"]
    assert {f"{root}/world/objects", f"{root}/world/walls", f"{root}/world/robots/0/path",
            f"{root}/world/robots/1/path", f"{root}/world/aligned/1/map",
            f"{root}/world/candidates/1"} <= set(entities)
    objects = entities[f"{root}/world/objects"][0]
    np.testing.assert_allclose(objects.column("Points2D:radii").to_pylist()[0],
                               0.5 * job.arrays["world_widths"], rtol=1e-6)
    for r in (0, 1):
        # the map over time: every exchange, as many objects as the robot shared, by width
        batches = entities[f"{root}/world/robots/{r}/map"]
        np.testing.assert_allclose(seconds(batches), times)
        sizes = [len(p) for p in column(batches, "Points2D:positions")]
        np.testing.assert_array_equal(sizes, job.arrays[f"map_counts_{r}"])
        radii = np.concatenate(column(batches, "Points2D:radii"))
        np.testing.assert_allclose(radii, 0.5 * job.arrays[f"map_widths_{r}"], rtol=1e-6)
        # the true pose: one point per exchange, where poses_true has it
        poses = column(entities[f"{root}/world/robots/{r}/pose"], "Points2D:positions")
        np.testing.assert_allclose(np.array(poses)[:, 0], job.arrays["poses_true"][r, :, :2],
                                   atol=1e-5)
    # the accepted alignment (TCAFF): logged at every exchange, empty where it has none
    has = np.all(np.isfinite(job.arrays["est_tcaff"][job.pairs.index((0, 1))]), axis=1)
    assert 0 < has.sum() < S
    aligned = column(entities[f"{root}/world/aligned/1/pose"], "Points2D:positions")
    np.testing.assert_array_equal([len(p) for p in aligned], has.astype(int))
    # the accepted alignment's pose of robot 1 is near its true pose in the world
    true_xy = job.arrays["poses_true"][1, has, :2]
    np.testing.assert_allclose([p[0] for p in aligned if p], true_xy, atol=1.0)
    # every candidate, at its step
    p = job.pairs.index((0, 1))
    candidates = column(entities[f"{root}/world/candidates/1"], "Points2D:positions")
    np.testing.assert_array_equal([len(c) for c in candidates],
                                  np.bincount(job.arrays[f"cand_steps_{p}"].astype(int),
                                              minlength=S))
    # errors over time: each method, each pair, only where it has an estimate
    for stream in ("tcaff", "ground_truth"):
        for q, (i, j) in enumerate(job.pairs):
            est = job.arrays[f"est_{stream}"][q]
            steps = np.flatnonzero(np.all(np.isfinite(est), axis=1))
            batches = entities[f"{root}/errors/{i}_to_{j}/translation/{stream}"]
            np.testing.assert_allclose(seconds(batches), times[steps])
            expected = se2_error(se2_from_params(job.arrays["truth"][q, steps]),
                                 se2_from_params(est[steps]))[:, 0]
            got = np.concatenate(column(batches, "Scalars:scalars"))
            np.testing.assert_allclose(got, expected, atol=1e-9)


def test_a_run_without_truth_or_maps_is_drawn_in_the_reference_frame(job, tmp_path):
    arrays = {k: v for k, v in job.arrays.items() if not k.startswith("map_")}
    arrays["poses_true"] = np.full_like(arrays["poses_true"], np.nan)
    arrays["truth"] = np.full_like(arrays["truth"], np.nan)
    blind = JobResult("blind", None, job.pairs, arrays)
    entities = read_back(record(tmp_path / "blind.rrd", [blind, job], reference=1))
    assert not any(e.startswith("/blind/errors") or e.startswith("/blind/world/robots")
                   for e in entities)
    assert "/blind/world/aligned/0/pose" in entities  # robot 0 in robot 1's odometry frame
    assert f"/{job.stem}/world/aligned/0/map" in entities  # both runs, each under its root


def test_bad_input_is_refused_before_a_file_is_made(job, tmp_path):
    with pytest.raises(ConfigError, match="reference 2"):
        record(tmp_path / "a.rrd", [job], reference=2)
    with pytest.raises(ConfigError, match="method 'nope'"):
        record(tmp_path / "a.rrd", [job], method="nope")
    with pytest.raises(DataError, match="no runs"):
        record(tmp_path / "a.rrd", [])
    with pytest.raises(DataError, match="existing folder"):
        record(tmp_path / "missing" / "a.rrd", [job])
    assert not (tmp_path / "a.rrd").exists()


@settings(max_examples=20, deadline=None)
@given(robot=st.integers(0, 1), step=st.integers(0, 10**6), column=st.integers(0, 2),
       value=st.sampled_from([np.nan, np.inf, -np.inf]), truth=st.booleans())
def test_a_run_whose_odometry_is_not_finite_is_refused_as_export_refuses_it(
        job, tmp_path_factory, robot, step, column, value, truth):
    """view drew such a run when it had no truth; export refused it in a check of the
    geometry that named neither the run nor the array."""
    arrays = {k: v.copy() for k, v in job.arrays.items()}
    step %= arrays["poses_odom"].shape[1]
    arrays["poses_odom"][robot, step, column] = value
    if not truth:
        arrays["poses_true"][:], arrays["truth"][:] = np.nan, np.nan
    bad = JobResult(job.name, job.seed, job.pairs, arrays)
    folder = tmp_path_factory.mktemp("odometry")
    bad.save(folder)
    message = re.escape(f"{bad.stem}: poses_odom, the robots' odometry, is not finite for "
                        f"robot {robot} at step {step} (")
    with pytest.raises(DataError, match=message):
        record(folder / "run.rrd", [bad])
    with pytest.raises(DataError, match=message):
        export(folder)
    assert not (folder / "run.rrd").exists() and not (folder / "trajectories").exists()


def test_missing_rerun_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` then fails
    with pytest.raises(ConfigError, match=r"extra viz: pip install 'tcaff-gtsam\[viz\]'"):
        check_rerun()


def test_view_command_writes_the_recording_of_saved_runs(job, tmp_path, monkeypatch, capsys):
    job.save(tmp_path / "runs")

    def tcaff(*args: str) -> tuple[int, str]:
        monkeypatch.setattr(sys, "argv", ["tcaff", *args])
        try:
            cli.main()
            code = 0
        except SystemExit as exited:
            code = exited.code or 0
        out = capsys.readouterr()
        return code, out.out + out.err

    code, out = tcaff("view", str(tmp_path))
    assert code == 0, out
    assert (tmp_path / "recording.rrd").is_file() and "rerun " in out
    assert f"/{job.stem}/world/robots/0/map" in read_back(tmp_path / "recording.rrd")
    empty = tmp_path / "empty"
    empty.mkdir()
    code, out = tcaff("view", str(empty))
    assert code == 2
    assert out.strip() == (f"error: {empty}: no saved runs (<name>.npz and .json, or runs/ of "
                           "a study)")
    code, out = tcaff("study", "--rerun", str(tmp_path), "--duration", "5")
    assert code == 2 and "--rerun" in out and "is a folder" in out


def test_the_dataframe_api_reads_every_error_series_at_its_times(job, tmp_path):
    """Rerun's dataframe reader (a DataFusion table indexed by the timeline) sees each
    method's error of each pair at the exchanges where the method has an estimate."""
    path = record(tmp_path / "run.rrd", [job])
    store = rr.chunk.ChunkStore.from_chunks(rr.chunk.RrdReader(path).stream().to_chunks())
    table = store.reader(index="time").to_arrow_table()
    seconds_at = np.array([t.total_seconds() for t in table.column("time").to_pylist()])
    np.testing.assert_allclose(np.sort(seconds_at), job.arrays["times"])
    root, times = f"/{job.stem}", job.arrays["times"]
    for stream in ("tcaff", "ground_truth"):
        for q, (i, j) in enumerate(job.pairs):
            est = job.arrays[f"est_{stream}"][q]
            steps = np.flatnonzero(np.all(np.isfinite(est), axis=1))
            name = f"{root}/errors/{i}_to_{j}/translation/{stream}:Scalars:scalars"
            cells = table.column(name).to_pylist()
            logged = [k for k, cell in enumerate(cells) if cell is not None]
            np.testing.assert_allclose(np.sort(seconds_at[logged]), times[steps])
            expected = se2_error(se2_from_params(job.arrays["truth"][q, steps]),
                                 se2_from_params(est[steps]))[:, 0]
            order = np.argsort(seconds_at[logged])
            got = np.concatenate([cells[k] for k in np.array(logged)[order]])
            np.testing.assert_allclose(got, expected, atol=1e-9)


def test_nees_series_where_the_job_kept_covariances(job, tmp_path):
    """Each pair's NEES over time for the methods whose covariances the job kept (TCAFF), at
    their estimate steps; none for the truth, which reports no covariance, nor for a job saved
    before covariances were kept."""
    entities = read_back(record(tmp_path / "run.rrd", [job]))
    root = f"/{job.stem}"
    for q, (i, j) in enumerate(job.pairs):
        est, cov = job.arrays["est_tcaff"][q], job.arrays["cov_tcaff"][q]
        steps = np.flatnonzero(np.all(np.isfinite(est), axis=1))
        batches = entities[f"{root}/errors/{i}_to_{j}/nees/tcaff"]
        np.testing.assert_allclose(seconds(batches), job.arrays["times"][steps])
        # e' P^-1 e of the parameters' error, heading wrapped
        e = est[steps] - job.arrays["truth"][q, steps]
        e[:, 2] = np.angle(np.exp(1j * e[:, 2]))
        expected = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov[steps]), e)
        np.testing.assert_allclose(np.concatenate(column(batches, "Scalars:scalars")), expected,
                                   rtol=1e-6)
        assert f"{root}/errors/{i}_to_{j}/nees/ground_truth" not in entities
    old = JobResult("old", None, job.pairs,
                    {k: v for k, v in job.arrays.items() if not k.startswith("cov_")})
    assert not any("/nees/" in e for e in read_back(record(tmp_path / "old.rrd", [old])))


def test_a_run_whose_saved_arrays_disagree_is_a_data_error(job, tmp_path):
    """A run file edited or written by something else: the candidates' steps and values of
    one pair of different lengths. It used to end in an IndexError deep in the drawing."""
    arrays = dict(job.arrays)
    key = next(k for k in arrays if k.startswith("cand_z_"))
    arrays[key] = arrays[key][:0]
    odd = JobResult("odd", None, job.pairs, arrays)
    with pytest.raises(DataError, match="odd: its saved arrays disagree"):
        record(tmp_path / "odd.rrd", [odd])
