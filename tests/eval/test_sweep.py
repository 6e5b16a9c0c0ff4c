"""Sweeps and the Dask executor: the same results as local processes, a killed worker's job run
again, resume without redoing finished jobs, failures recorded, bad sweep files refused."""

from __future__ import annotations

import json
import os
import re
import signal
from pathlib import Path

import numpy as np
import pytest
import yaml
from failing_runs import fail_simulating
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval import executor as executor_module
from tcaff_gtsam.eval import jobs as jobs_module
from tcaff_gtsam.eval.config import (
    MethodsConfig,
    StudyConfig,
    SweepConfig,
    load_methods,
    load_scenario,
    load_sweep,
)
from tcaff_gtsam.eval.executor import FREE_HTTP_PORT, Executor, JobSpec, Progress, job_runner
from tcaff_gtsam.eval.methods import estimate_names
from tcaff_gtsam.eval.sweep import job_hash, plan_sweep, run_sweep

from tcaff_gtsam.errors import ConfigError

distributed = pytest.importorskip("distributed")

METHODS = MethodsConfig(methods=["tcaff", "ground_truth"])


def short(name: str, duration: float = 15.0):
    return load_scenario(name).model_copy(update={"duration": duration})


def base_study(seeds=(0, 1), workers=1) -> StudyConfig:
    return StudyConfig(name="base", scenarios=[short("indoor_return"), short("ambiguous_grid")],
                       methods=METHODS, seeds=list(seeds), workers=workers)


def tau_sweep(tmp_path: Path, taus=(4.0, 12.0)) -> SweepConfig:
    return SweepConfig(name="taus", study="unused", grid={"methods.tcaff.tau": list(taus)},
                       output=str(tmp_path / "sweeps"))


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes on 127.0.0.1, one thread each."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", scheduler_port=0, dashboard_address=None,
                                  scheduler_kwargs=FREE_HTTP_PORT) as local:
        yield local


def run_all(executor: Executor, specs: list[JobSpec], progress: Progress | None = None):
    done, failed = {}, {}
    with job_runner(executor) as run:
        run(specs, progress or Progress(), done.__setitem__, failed.__setitem__)
    return done, failed


def test_dask_gives_the_local_arrays_bit_for_bit(cluster):
    specs = [JobSpec(short("indoor_return"), METHODS, 3),
             JobSpec(short("opposite_directions"), METHODS, 1)]
    local, _ = run_all(Executor(workers=1), specs)
    remote, failed = run_all(Executor(scheduler=cluster.scheduler_address), specs)
    assert not failed and sorted(remote) == [0, 1]
    for key in local:
        assert local[key].arrays.keys() == remote[key].arrays.keys()
        for name, array in local[key].arrays.items():
            assert array.dtype == remote[key].arrays[name].dtype, name
            assert np.array_equal(array, remote[key].arrays[name], equal_nan=True), name
        assert local[key].metrics == remote[key].metrics


def test_a_killed_worker_has_its_job_run_again(cluster):
    """... and the run says so: the worker lost, with the jobs it held."""
    specs = [JobSpec(short("indoor_return", 20.0), METHODS, seed) for seed in range(4)]
    killed: list[str] = []
    lost: list[tuple[str, list[int]]] = []

    class KillOnce(Progress):
        def advance(self, key: int, share: float) -> None:
            if killed:
                return
            with distributed.Client(cluster.scheduler_address, timeout=10) as client:
                busy = [w for w, keys in client.processing().items() if keys]
                if not busy:
                    return
                pid = client.run(os.getpid, workers=busy[:1])[busy[0]]
            os.kill(pid, signal.SIGKILL)
            killed.append(busy[0])

        def lost(self, worker: str, keys: list[int]) -> None:
            lost.append((worker, keys))

    done, failed = run_all(Executor(scheduler=cluster.scheduler_address), specs, KillOnce())
    assert killed, "no worker was busy when the jobs reported progress"
    assert not failed
    assert sorted(done) == [0, 1, 2, 3]
    assert [done[k].seed for k in range(4)] == [0, 1, 2, 3]
    assert [worker for worker, _ in lost] == killed
    assert lost[0][1] and set(lost[0][1]) <= {0, 1, 2, 3}  # running or waiting there


def test_an_interrupted_sweep_resumes_without_redoing_finished_jobs(tmp_path):
    sweep, study = tau_sweep(tmp_path), base_study(seeds=(0,))
    plan = plan_sweep(sweep, study)
    assert len(plan.points) == 3 and plan.points[0].default  # tau 8 is the default
    assert len(plan.jobs) == 6
    finished = []

    def stop_after_two(job):
        finished.append(job.stem)
        if len(finished) == 2:
            raise KeyboardInterrupt

    first = run_sweep(sweep, study, figures=False, on_job_done=stop_after_two)
    assert first.interrupted and first.ran == 2 and first.reused == 0
    report = json.loads((first.folder / "sweep.json").read_text())
    assert report["interrupted"] is True
    assert [p["jobs_done"] for p in report["points"]] == [2, 0, 0]
    again = []
    second = run_sweep(sweep, study, figures=False, on_job_done=lambda j: again.append(j.stem))
    assert not second.interrupted and second.reused == 2 and second.ran == 4
    assert len(again) == 4
    # one more value: only its jobs run; the report covers every point
    third = run_sweep(tau_sweep(tmp_path, (4.0, 12.0, 16.0)), study, figures=False)
    assert third.reused == 6 and third.ran == 2
    rows = [r for r in third.rows if r["method"] == "tcaff"]
    assert [r["methods.tcaff.tau"] for r in rows] == ["8.0", "4.0", "12.0", "16.0"]
    assert all(r["jobs_done"] == r["jobs"] == 2 for r in rows)
    assert all(r["availability"] is not None for r in rows)
    # all done: the report is written again without reaching the (here unreachable) scheduler
    fourth = run_sweep(tau_sweep(tmp_path, (4.0, 12.0, 16.0)), study,
                       Executor(scheduler="tcp://127.0.0.1:9"), figures=False)
    assert fourth.reused == 8 and fourth.ran == 0 and fourth.rows == third.rows
    # a job whose arrays were cut short is run again now, not left out of the report (it used
    # to count as reused, be left out, and run only at the next call)
    job = next((fourth.folder / "jobs").iterdir())
    npz = next(job.glob("*.npz"))
    npz.write_bytes(npz.read_bytes()[:100])
    fifth = run_sweep(tau_sweep(tmp_path, (4.0, 12.0, 16.0)), study, figures=False)
    assert fifth.reused == 7 and fifth.ran == 1

    def scores(rows):  # the job's run time is its own
        return [{k: v for k, v in r.items() if k != "ms_per_pair_step"} for r in rows]

    assert scores(fifth.rows) == scores(third.rows)


def test_a_failing_job_is_recorded_the_others_finish_and_a_rerun_retries_it(tmp_path,
                                                                            monkeypatch):
    real = fail_simulating(monkeypatch, "ambiguous_grid", seed=1)
    sweep, study = tau_sweep(tmp_path, (8.0,)), base_study()
    outcome = run_sweep(sweep, study)
    assert [(f["scenario"], f["seed"]) for f in outcome.failed] == [("ambiguous_grid", 1)]
    assert outcome.ran == 3
    failed = outcome.folder / "jobs" / outcome.failed[0]["hash"] / "failed.json"
    assert "sensor exploded" in json.loads(failed.read_text())["traceback"]
    report = json.loads((outcome.folder / "sweep.json").read_text())
    assert report["failed"][0]["error"] == "RuntimeError: sensor exploded"
    assert report["points"][0]["jobs_done"] == 3
    assert report["points"][0]["default"]  # tau 8 is the default: no extra point
    assert sorted(p.name for p in (outcome.folder / "figures").iterdir()) == [
        "response_tau.png", "tradeoff.png"]
    monkeypatch.setattr(jobs_module, "simulate", real)
    rerun = run_sweep(sweep, study, figures=False)
    assert rerun.reused == 3 and rerun.ran == 1 and not rerun.failed
    assert not failed.exists()
    assert json.loads((outcome.folder / "sweep.json").read_text())["failed"] == []


def test_job_hash_is_the_configuration():
    a = JobSpec(short("indoor_return"), METHODS, 0)
    assert job_hash(a) == job_hash(JobSpec(short("indoor_return"), MethodsConfig(
        methods=["tcaff", "ground_truth"]), 0))
    assert job_hash(a) != job_hash(JobSpec(short("indoor_return"), METHODS, 1))
    assert job_hash(a) != job_hash(JobSpec(short("indoor_return", 16.0), METHODS, 0))
    # same values in another order of the grid: the same jobs, shared by both points
    plan = plan_sweep(SweepConfig(name="s", study="x", points=[
        {"methods.tcaff.tau": 8.0}, {"methods.tcaff.tau": 4.0}]), base_study())
    assert plan.points[0].default and len(plan.points) == 2 and len(plan.jobs) == 8


def write_sweep(tmp_path: Path, body: dict) -> Path:
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({"name": "s", "study": {
        "scenarios": ["indoor_return"], "methods": "tcaff_only"}, **body}))
    return path


@pytest.mark.parametrize(("body", "named"), [
    ({"grid": {"methods.tcaff.taux": [1.0]}}, "tcaff.taux"),
    ({"grid": {"scenario.layout.nope": [1.0]}}, "layout.nope"),
    ({"grid": {"scenario.pedestrians.count": [3]}}, "scenario.pedestrians.count"),
    ({"grid": {"tcaff.tau": [1.0]}}, "grid: tcaff.tau"),
    ({"grid": {}}, "grid"),
    ({"grid": {"methods.tcaff.tau": []}}, "methods.tcaff.tau: needs at least one value"),
    ({"grid": {"methods.tcaff.tau": ["high"]}}, "methods.tcaff.tau = 'high'"),
    ({"grid": {"scenario.window": [0]}}, "scenario.window = 0"),
    ({"grid": {"methods.tcaff.tau": 8.0}}, "grid.methods.tcaff.tau"),
    ({"points": []}, "points"),
    ({"points": [{"methods.tcaff.tau": 1.0}, {"scenario.window": 4}]}, "point 1"),
    ({}, "give either grid"),
    ({"grid": {"methods.tcaff.tau": [1.0]}, "method": "clipper_k3"}, "method 'clipper_k3'"),
    ({"grid": {"methods.tcaff.tau": [1.0]}, "seeds": [1, 1]}, "seeds"),
])
def test_a_bad_sweep_file_is_a_config_error_naming_the_key(tmp_path, body, named):
    with pytest.raises(ConfigError, match=r"sweep\.yaml") as error:
        sweep, study = load_sweep(write_sweep(tmp_path, body))
        plan_sweep(sweep, study, "sweep.yaml")
    assert named in str(error.value)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.text(st.sampled_from("abcxyz_"), min_size=1, max_size=8), min_size=1,
                max_size=3), st.sampled_from(["methods", "scenario"]))
def test_any_unknown_path_is_named(keys, root):
    path = ".".join([root, "zz_" + keys[0], *keys[1:]])  # no config has a key starting zz_
    sweep = SweepConfig(name="s", study="x", grid={path: [1]})
    study = base_study(seeds=(0,))
    with pytest.raises(ConfigError) as error:
        plan_sweep(sweep, study, "f.yaml")
    message = str(error.value)
    assert message.startswith("f.yaml: ") and "zz_" + keys[0] in message


def test_executor_refuses_two_places_and_bad_counts():
    with pytest.raises(ConfigError, match="one or the other"):
        Executor(scheduler="tcp://127.0.0.1:1", local_cluster=2)
    with pytest.raises(ConfigError, match="local_cluster 0"):
        Executor(local_cluster=0)
    with pytest.raises(ConfigError, match="workers 0"):
        Executor(workers=0)


def test_an_unreachable_scheduler_is_a_config_error(tmp_path, monkeypatch):
    monkeypatch.setattr(executor_module, "_CONNECT_TIMEOUT", 0.5)  # s; nothing will answer
    expected = re.escape("scheduler 'tcp://127.0.0.1:9': no Dask scheduler")
    with pytest.raises(ConfigError, match=expected), \
            job_runner(Executor(scheduler="tcp://127.0.0.1:9")):
        pass


@pytest.mark.slow
def test_cli_sweep_on_a_local_cluster_writes_the_report(tmp_path, tcaff_main):
    """... and leaves port 8787 (Dask's dashboard port) to whoever holds it, quietly."""
    import socket
    import warnings

    path = write_sweep(tmp_path, {"grid": {"scenario.window": [4, 12]},
                                  "output": str(tmp_path / "out")})
    # one worker process: the cluster fixture's two workers cover the spreading of jobs
    command = ["sweep", str(path), "--local-cluster", "1", "--duration", "12", "--seeds", "1"]
    with socket.socket() as held, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            held.bind(("", 8787))
            held.listen()
        except OSError:  # held already (by another process's cluster)
            pass
        done = tcaff_main(*command)
    assert [str(w.message) for w in caught if "8787" in str(w.message)] == []
    assert done.returncode == 0, done.stderr
    assert "3 points (scenario.window) x 1 scenarios x 1 seeds = 3 jobs" in done.stdout
    folder = tmp_path / "out" / "s"
    lines = (folder / "sweep.csv").read_text().splitlines()
    assert lines[0].startswith("point,scenario.window,default,jobs,jobs_done,method,")
    assert len(lines) == 1 + 3 * len(estimate_names(load_methods("tcaff_only")))
    assert sorted(p.name for p in (folder / "figures").iterdir()) == [
        "response_window.png", "tradeoff.png"]
    again = tcaff_main(*command)
    assert again.returncode == 0 and "3 of 3 jobs done by an earlier run" in again.stdout


def test_cli_bad_sweep_is_one_line_and_status_2(tmp_path, tcaff_main):
    path = write_sweep(tmp_path, {"grid": {"methods.tcaff.tau": []}})
    done = tcaff_main("sweep", str(path))
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "methods.tcaff.tau" in done.stderr


def test_sweep_figures_of_points_without_figures_draw_without_warnings(tmp_path):
    """Points whose reports hold no availability or false accepts (no estimate anywhere) draw
    empty figures quietly: no legend warning, no empty-slice warning."""
    import warnings
    from types import SimpleNamespace

    from tcaff_gtsam.eval.plots import draw_sweep

    points = [SimpleNamespace(default=k == 0, settings=k > 0,
                              values={"methods.tcaff.tau": float(4 * k)}) for k in range(3)]
    reports = [dict.fromkeys(("false_accept", "availability", "translation_error_m_mean",
                              "time_to_first_correct_s")) for _ in points]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        written = draw_sweep(tmp_path, points, reports, ["methods.tcaff.tau"], "TCAFF")
    assert [p.name for p in written] == ["tradeoff.png", "response_tau.png"]
    assert all(p.stat().st_size > 0 for p in written)


def test_the_command_line_reports_lost_workers_and_the_jobs_run_again(capsys, monkeypatch):
    from tcaff_gtsam.eval import cli
    from tcaff_gtsam.eval.cli.common import _bars
    from tcaff_gtsam.eval.cli.studies import _study_bars

    monkeypatch.setattr(cli, "_consoles", {})  # consoles on this test's captured stdout
    with _bars() as bars:
        progress = _study_bars(bars, 3)
        for key, seed in enumerate((0, 1, 2)):
            progress.start(key, f"indoor_return seed {seed}")
        assert progress.summary() is None
        progress.lost("tcp://127.0.0.1:40001", [0, 2])
        progress.lost("tcp://127.0.0.1:40002", [])
    out = " ".join(capsys.readouterr().out.split())
    assert ("worker lost: tcp://127.0.0.1:40001 (held indoor_return seed 0, indoor_return "
            "seed 2)") in out
    assert "worker lost: tcp://127.0.0.1:40002 (held no job)" in out
    assert progress.summary() == ("2 Dask worker(s) lost during the run; 2 job(s) run again "
                                  "on other workers")


def test_a_done_job_whose_files_cannot_be_read_is_reported_and_run_again(tmp_path):
    """A job file nested too deep for the parser (or otherwise not a saved job) used to end the
    sweep in a RecursionError before its report; now the report is written with the other
    jobs' results, names the job as failed, and the next run runs it again."""
    sweep, study = tau_sweep(tmp_path, (8.0,)), base_study(seeds=(0,))
    first = run_sweep(sweep, study, figures=False)
    assert first.ran == 2 and not first.failed
    spoilt, kept = sorted((first.folder / "jobs").iterdir())
    stem = json.loads((spoilt / "job.json").read_text())["stem"]
    (spoilt / f"{stem}.json").write_text("[" * 100_000 + "]" * 100_000)
    second = run_sweep(sweep, study, figures=False)
    assert second.ran == 0 and second.reused == 2
    assert [f["hash"] for f in second.failed] == [spoilt.name]
    error = second.failed[0]["error"]
    assert error.startswith(f"DataError: {spoilt / stem}.json: not a saved job: not JSON "
                            "(RecursionError")
    report = json.loads((second.folder / "sweep.json").read_text())
    assert [f["error"] for f in report["failed"]] == [error]
    assert [p["jobs_done"] for p in report["points"]] == [1]  # the other job's results stay
    assert (kept / "job.json").is_file() and not (spoilt / "job.json").exists()
    third = run_sweep(sweep, study, figures=False)
    assert third.ran == 1 and third.reused == 1 and not third.failed
    assert json.loads((third.folder / "sweep.json").read_text())["failed"] == []


def test_a_job_record_nested_too_deep_is_run_again_now(tmp_path):
    """job.json, the mark of a done job: unreadable, the job is not done (it was a
    RecursionError that ended the sweep)."""
    sweep, study = tau_sweep(tmp_path, (8.0,)), base_study(seeds=(0,))
    first = run_sweep(sweep, study, figures=False)
    marker = sorted((first.folder / "jobs").iterdir())[0] / "job.json"
    marker.write_text("[" * 100_000 + "]" * 100_000)
    again = run_sweep(sweep, study, figures=False)
    assert again.ran == 1 and again.reused == 1 and not again.failed
    assert json.loads(marker.read_text())["hash"] == marker.parent.name


def test_a_failure_record_cut_short_still_names_its_job(tmp_path, monkeypatch):
    """A failed.json cut short by hand ended the report in a JSONDecodeError."""
    fail_simulating(monkeypatch, "ambiguous_grid")
    sweep, study = tau_sweep(tmp_path, (8.0,)), base_study(seeds=(0,))
    first = run_sweep(sweep, study, figures=False)
    (failed,) = first.failed
    record = first.folder / "jobs" / failed["hash"] / "failed.json"
    record.write_text(record.read_text()[:12])

    def interrupted(scenario, seed, progress=None):  # Ctrl-C before the job runs again
        raise KeyboardInterrupt

    monkeypatch.setattr(jobs_module, "simulate", interrupted)
    second = run_sweep(sweep, study, figures=False)
    assert second.interrupted
    (listed,) = json.loads((second.folder / "sweep.json").read_text())["failed"]
    assert listed["hash"] == failed["hash"]
    assert (listed["scenario"], listed["seed"]) == ("ambiguous_grid", 0)
    assert listed["error"].startswith(f"its failure record is unreadable: {record}: not a job "
                                      "failure record: not JSON")


def test_the_default_window_is_shown_and_its_point_shares_the_base_jobs():
    """A scenario that leaves `window` unset runs the presets' W = 8: the point window 8 is the
    base study (one row, the same jobs); it was a separate 'window None' row running the
    same configuration again under another hash."""
    sweep = SweepConfig(name="w", study="unused", grid={"scenario.window": [4, 8]},
                        output="unused")
    plan = plan_sweep(sweep, base_study(seeds=(0,)))
    assert [(p.values, p.default) for p in plan.points] == [
        ({"scenario.window": 4}, False), ({"scenario.window": 8}, True)]
    assert len(plan.jobs) == 4  # 2 points x 2 scenarios
    tau = plan_sweep(tau_sweep(Path("unused"), (4.0,)), base_study(seeds=(0,)))
    assert tau.points[0].default
    assert {spec.scenario.window for spec in tau.jobs.values()} == {8}
    # where the presets' window is not every scenario's, the default row says so
    paths = StudyConfig(name="base", scenarios=[short("indoor_return"),
                                                short("same_direction")],
                        methods=METHODS, seeds=[0], workers=1)
    mixed = plan_sweep(sweep, paths)
    assert mixed.points[0].default and mixed.points[0].values == {
        "scenario.window": "per scenario"}
    assert len(mixed.points) == 3
