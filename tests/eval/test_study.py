"""The study: every scenario produces every output; results survive interruption and failure;
the acceptance figures of the comparison hold on the shipped scenarios."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from failing_runs import fail_simulating
from tcaff_gtsam.eval.config import (
    MethodsConfig,
    StudyConfig,
    load_methods,
    load_scenario,
    load_study,
)
from tcaff_gtsam.eval.jobs import simulated_job
from tcaff_gtsam.eval.methods import estimate_names
from tcaff_gtsam.eval.metrics import step_errors
from tcaff_gtsam.eval.results import JobResult, score, thresholds_of
from tcaff_gtsam.eval.study import run_study

from tcaff_gtsam.geometry import se2_from_params

QUICK_METHODS = MethodsConfig(clipper_k=[3, 5], clipper_k_shown=5)


def short(name: str, duration: float = 25.0):
    return load_scenario(name).model_copy(update={"duration": duration})


def quick_study(tmp_path, scenarios, seeds=(0,), workers=1) -> StudyConfig:
    return StudyConfig(name="t", scenarios=list(scenarios), methods=QUICK_METHODS,
                       seeds=list(seeds), workers=workers, output=str(tmp_path / "results"))


@pytest.mark.parametrize("name", ["indoor_return", "same_direction", "opposite_directions",
                                  "four_robots", "ambiguous_grid", "indoor_rgbd"])
def test_each_scenario_produces_every_output(name):
    scenario = short(name)
    if scenario.camera is not None:  # ray-casting dominates: a quarter of the pixels suffices
        scenario = scenario.model_copy(update={
            "camera": scenario.camera.model_copy(update={"width": 160, "height": 120})})
    job = simulated_job(scenario, QUICK_METHODS, seed=1)
    n = 4 if name == "four_robots" else 2
    assert len(job.pairs) == n * (n - 1)
    names = estimate_names(QUICK_METHODS)
    assert set(job.metrics) == set(names)
    steps = len(job.arrays["times"])
    assert steps == 25
    for method in names:
        assert job.arrays[f"est_{method}"].shape == (len(job.pairs), steps, 3)
        assert set(job.metrics[method]) == {"all"} | {f"{i}->{j}" for i, j in job.pairs}
    truth = job.metrics["ground_truth"]["all"]
    assert truth["translation_error_m_mean"] < 1e-9 and truth["availability"] == 1.0
    assert job.arrays["overlap"].shape == (len(job.pairs), steps)


@pytest.fixture(scope="module")
def serial_study(tmp_path_factory):
    """A two-scenario study run in this process, with its figures, and its configuration:
    written once for the tests that read its folder or compare their own runs with its
    jobs."""
    cfg = quick_study(tmp_path_factory.mktemp("serial"),
                      [short("indoor_return", 20), short("ambiguous_grid", 20)])
    return cfg, run_study(cfg)


@pytest.mark.slow
def test_study_writes_tables_figures_runs_and_the_latest_link(serial_study):
    cfg, outcome = serial_study
    root = Path(cfg.output)
    folder = outcome.folder
    assert not outcome.interrupted and not outcome.failed
    assert (root / "latest").resolve() == folder.resolve()
    metrics = json.loads((folder / "metrics.json").read_text())
    assert set(metrics["summary"]) == {"indoor_return", "ambiguous_grid"}
    assert metrics["summary"]["indoor_return"]["ground_truth"]["false_accept"] == 0.0
    csv_lines = (folder / "metrics.csv").read_text().splitlines()
    assert csv_lines[0].startswith("scenario,seed,method,pair,translation_error_m_mean")
    # per pair and pooled rows for each method of each run, plus the summary rows
    n_methods = len(estimate_names(QUICK_METHODS))
    assert len(csv_lines) == 1 + 2 * n_methods * 3 + 2 * n_methods
    figures = sorted(p.name for p in (folder / "figures").glob("*.png"))
    assert figures == ["clipper_sweep.png", "errors_ambiguous_grid.png",
                       "errors_indoor_return.png", "leave_and_return.png", "scenarios.png"]
    assert all((folder / "figures" / f).stat().st_size > 10_000 for f in figures)
    assert sorted(p.name for p in (folder / "runs").iterdir()) == [
        "ambiguous_grid-seed0.json", "ambiguous_grid-seed0.npz",
        "indoor_return-seed0.json", "indoor_return-seed0.npz"]
    assert load_study(folder / "config.yaml") == cfg


def test_saved_run_reproduces_its_metrics(tmp_path):
    job = simulated_job(short("indoor_return", 30), QUICK_METHODS, seed=0)
    job.save(tmp_path)
    meta = json.loads((tmp_path / f"{job.stem}.json").read_text())
    with np.load(tmp_path / f"{job.stem}.npz") as data:
        arrays = dict(data)
    again = JobResult(meta["name"], meta["seed"], [tuple(p) for p in meta["pairs"]],
                      arrays, seconds=meta["seconds"])
    trace = again.traces("tcaff")[0]
    assert np.array_equal(trace.estimate, job.arrays["est_tcaff"][0], equal_nan=True)
    score(again, estimate_names(QUICK_METHODS), thresholds_of(QUICK_METHODS))
    assert json.loads(json.dumps(again.metrics)) == meta["metrics"]


def test_same_seed_same_results():
    a = simulated_job(short("ambiguous_grid", 20), QUICK_METHODS, seed=4)
    b = simulated_job(short("ambiguous_grid", 20), QUICK_METHODS, seed=4)
    for key, value in a.arrays.items():
        assert np.array_equal(value, b.arrays[key], equal_nan=True), key


def test_interrupted_study_keeps_the_finished_runs(tmp_path):
    cfg = quick_study(tmp_path, [short("indoor_return", 20), short("ambiguous_grid", 20)])
    finished = []

    def stop_after_first(job):
        finished.append(job.stem)
        raise KeyboardInterrupt

    outcome = run_study(cfg, on_job_done=stop_after_first)
    assert outcome.interrupted
    assert finished == ["indoor_return-seed0"]
    metrics = json.loads((outcome.folder / "metrics.json").read_text())
    assert metrics["interrupted"] is True
    assert list(metrics["summary"]) == ["indoor_return"]
    assert (outcome.folder / "runs" / "indoor_return-seed0.npz").is_file()
    assert not (outcome.folder / "runs" / "ambiguous_grid-seed0.npz").exists()
    assert (outcome.folder / "figures" / "leave_and_return.png").is_file()


def test_a_failing_run_does_not_lose_the_others(tmp_path, monkeypatch):
    fail_simulating(monkeypatch, "indoor_return")
    cfg = quick_study(tmp_path, [short("indoor_return", 20), short("ambiguous_grid", 20)])
    outcome = run_study(cfg, figures=False)
    assert [f["scenario"] for f in outcome.failed] == ["indoor_return"]
    assert "sensor exploded" in outcome.failed[0]["error"]
    assert [j.name for j in outcome.jobs] == ["ambiguous_grid"]
    metrics = json.loads((outcome.folder / "metrics.json").read_text())
    assert metrics["failed"][0]["error"] == "sensor exploded"


def test_a_study_of_the_ground_truth_alone_draws_its_figures_without_warnings(tmp_path):
    """The error figures then hold no method's line (the truth is not drawn), and no legend."""
    import warnings

    cfg = quick_study(tmp_path, [short("indoor_return", 6)]).model_copy(
        update={"methods": MethodsConfig(methods=["ground_truth"])})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        outcome = run_study(cfg)
    assert not outcome.failed
    assert (outcome.folder / "figures" / "errors_indoor_return.png").is_file()


@pytest.mark.slow
def test_parallel_workers_give_the_serial_results(tmp_path, serial_study):
    """The serial study's jobs again on two worker processes, one job each: every array and
    metric the same, in the serial order."""
    cfg, serial = serial_study
    parallel = run_study(quick_study(tmp_path, cfg.scenarios, workers=2), figures=False)
    assert not parallel.interrupted and not parallel.failed
    assert [j.stem for j in parallel.jobs] == [j.stem for j in serial.jobs]
    for a, b in zip(serial.jobs, parallel.jobs, strict=True):
        assert a.arrays.keys() == b.arrays.keys()
        for name, array in a.arrays.items():
            assert np.array_equal(array, b.arrays[name], equal_nan=True), (a.stem, name)
        assert a.metrics == b.metrics


# -- the acceptance figures of the comparison, on the shipped scenarios at full length ---------


@pytest.fixture(scope="module")
def indoor_run():
    """indoor_return at full length with TCAFF and its iSAM2 graph, run once for the tests
    that check it; holds of `drop_after` only, so that robot 1's absence leaves gaps."""
    return simulated_job(load_scenario("indoor_return"), MethodsConfig(
        methods=["tcaff", "tcaff_isam2"], tcaff={"hold_for": None}), seed=0)


@pytest.mark.slow
def test_indoor_tcaff_meets_the_papers_figures(indoor_run):
    job = indoor_run
    tcaff = job.metrics["tcaff"]["all"]
    assert tcaff["translation_error_m_mean"] <= 0.35
    assert tcaff["heading_error_deg_mean"] <= 1.1
    assert tcaff["availability"] >= 0.8
    assert tcaff["false_accept"] == 0.0
    # smoothing helps, compared on the steps both read-outs answer (the smoothed one also
    # answers steps before the causal one could, where errors are larger)
    causal, smoothed = (job.arrays[f"est_tcaff_isam2_{r}"] for r in ("causal", "smoothed"))
    both = ~np.isnan(causal[..., 0]) & ~np.isnan(smoothed[..., 0])
    truth = se2_from_params(job.arrays["truth"])
    error = {name: np.vstack([step_errors(truth[p], est[p])[both[p]] for p in range(len(est))])
             for name, est in (("causal", causal), ("smoothed", smoothed))}
    assert both.sum() > 100
    assert np.all(error["smoothed"].mean(axis=0) <= error["causal"].mean(axis=0))


@pytest.mark.slow
def test_ambiguous_grid_fools_single_shot_clipper_but_not_tcaff():
    job = simulated_job(load_scenario("ambiguous_grid"), MethodsConfig(
        methods=["tcaff", "clipper"], clipper_k=[3, 6, 10]), seed=0)
    for k in (3, 6, 10):
        assert job.metrics[f"clipper_k{k}"]["all"]["false_accept"] > 0.02
    tcaff = job.metrics["tcaff"]["all"]
    assert tcaff["false_accept"] <= 0.01
    assert tcaff["availability"] >= 0.8
    assert not math.isnan(tcaff["translation_error_m_mean"] or math.nan)


@pytest.mark.slow
def test_interrupting_a_parallel_study_keeps_the_finished_runs(tmp_path):
    """Stopped when the first job is done: the long run (started first, longest first) is
    then mid-run on the other worker, a short one queued or just started; both are ended,
    and only the finished runs are kept. The long run is four robots over 600 s (half a
    minute of work on a quiet core), so that it cannot end before the other worker has
    started and finished a 10 s run even on a loaded machine."""
    cfg = quick_study(tmp_path, [short("indoor_return", 10), short("ambiguous_grid", 10),
                                 short("four_robots", 600)], workers=2)

    def stop(job):
        raise KeyboardInterrupt

    outcome = run_study(cfg, on_job_done=stop, figures=False)
    assert outcome.interrupted and outcome.jobs
    finished = {job.stem for job in outcome.jobs}
    assert "four_robots-seed0" not in finished and len(finished) < 3
    metrics = json.loads((outcome.folder / "metrics.json").read_text())
    assert metrics["interrupted"] is True
    assert sorted(p.name for p in (outcome.folder / "runs").glob("*.npz")) == sorted(
        f"{stem}.npz" for stem in finished)


@pytest.mark.slow
def test_graph_estimates_wait_for_the_first_factor_and_smoothed_fills_the_filters_span(
        indoor_run):
    """Causal graph estimates start only once the pair is linked by a factor (before, the
    graph holds only its gauge's guess); the smoothed read-out covers every step from a linked
    pair's first TCAFF estimate to its last, the gaps TCAFF had no estimate in included."""
    job = indoor_run
    tcaff = ~np.isnan(job.arrays["est_tcaff"][..., 0])
    causal = ~np.isnan(job.arrays["est_tcaff_isam2_causal"][..., 0])
    smoothed = ~np.isnan(job.arrays["est_tcaff_isam2_smoothed"][..., 0])
    assert np.all(causal <= tcaff)
    gaps = 0
    for p in range(len(job.pairs)):
        held = np.flatnonzero(tcaff[p])
        span = np.zeros_like(tcaff[p])
        span[held[0]:held[-1] + 1] = True
        assert np.array_equal(smoothed[p], span) or not smoothed[p].any()
        gaps += int(np.sum(span & ~tcaff[p]))
    assert gaps > 0  # the case the span fills: robot 1 away from the room
    truth = job.arrays["truth"]
    for name in ("causal", "smoothed"):
        err = np.linalg.norm(job.arrays[f"est_tcaff_isam2_{name}"][..., :2] - truth[..., :2],
                             axis=-1)
        assert np.nanmax(err) < 1.0  # no gauge guesses (identity, metres away) among them


def test_expected_seconds_grow_with_the_work_and_rank_the_demo_longest_first():
    """A parallel study starts its jobs longest first by `expected_seconds`: the guess grows
    with the duration, the robots, a camera and people to track, and puts the demo's rendered
    scenario, then its people tracking (both cut to 60 s there; 25 and 24 s alone with the
    start-up), before the object-level ones."""
    from tcaff_gtsam.eval.executor import JobSpec, expected_seconds

    demo = load_study("demo")

    def guess(scenario, **updates) -> float:
        return expected_seconds(JobSpec(scenario.model_copy(update=updates), demo.methods, 0))

    room = load_scenario("four_robots")
    assert guess(room, duration=200) > guess(room, duration=100)
    assert guess(room) > guess(room, layout=room.layout.model_copy(update={"robots": 2}))
    assert guess(load_scenario("mot")) > guess(load_scenario("mot"), pedestrians=None)
    rgbd = load_scenario("indoor_rgbd")
    assert guess(rgbd) > guess(rgbd, camera=None)
    ranked = sorted(demo.scenarios, key=lambda s: -guess(s))
    assert [s.name for s in ranked[:3]] == ["indoor_rgbd", "mot", "four_robots"]


def test_every_method_that_reports_a_covariance_keeps_it_and_a_reread_job_scores_the_same(
        tmp_path):
    """The TCAFF filters (the team's too), the graph's read-outs and single-shot CLIPPER keep a
    covariance beside each estimate (NaN exactly where there is none); ICP and the truth keep
    none and score no NEES. The judge rides on the TCAFF streams only. A job saved without
    covariances (before they were kept) still loads and scores, with NEES None."""
    from tcaff_gtsam.params import FrameAlignerParams, constant_alignment_covariance

    # the original's constant R, so that CLIPPER's covariance can be checked below
    methods = QUICK_METHODS.model_copy(
        update={"aligner": FrameAlignerParams(covariance="constant")})
    job = simulated_job(short("indoor_return", 40), methods, seed=0)
    kept = {k.removeprefix("cov_") for k in job.arrays if k.startswith("cov_")}
    assert kept == {"tcaff", "tcaff_reference", "tcaff_team", "tcaff_isam2_causal",
                    "tcaff_isam2_smoothed", "clipper_k3", "clipper_k5"}
    for stream in kept:
        est, cov = job.arrays[f"est_{stream}"], job.arrays[f"cov_{stream}"]
        assert cov.shape == (*est.shape, 3)
        has = ~np.isnan(est[..., 0])
        assert has.any(), stream
        assert np.all(np.isfinite(cov[has])) and np.all(np.isnan(cov[~has])), stream
        assert np.all(np.linalg.eigvalsh(cov[has]) > 0), stream
    # single-shot CLIPPER's covariance is the aligner's R of its solution: the constant one
    has = ~np.isnan(job.arrays["est_clipper_k3"][..., 0])
    np.testing.assert_array_equal(job.arrays["cov_clipper_k3"][has],
                                  np.broadcast_to(constant_alignment_covariance(),
                                                  (has.sum(), 3, 3)))
    for stream in ("icp", "ground_truth"):
        report = job.metrics[stream]["all"]
        assert report["nees_mean"] is None and report["confident_false_accept"] is None
    for stream in kept:
        report = job.metrics[stream]["all"]
        assert report["nees_mean"] is not None and 0 <= report["nees_under_95"] <= 1, stream
    judged = {s for s, by_pair in job.metrics.items() if by_pair["all"]["judge_availability"]
              is not None}
    assert judged == {"tcaff", "tcaff_team", "tcaff_isam2_causal", "tcaff_isam2_smoothed"}
    assert len({job.metrics[s]["all"]["judge_availability"] for s in judged}) == 1

    job.save(tmp_path / "new")
    again = JobResult.load(tmp_path / "new", job.stem)
    score(again, estimate_names(methods), thresholds_of(methods))
    assert again.metrics == json.loads(json.dumps(job.metrics))

    old = JobResult(job.name, job.seed, job.pairs,
                    {k: v for k, v in job.arrays.items() if not k.startswith("cov_")})
    old.save(tmp_path / "old")
    loaded = JobResult.load(tmp_path / "old", job.stem)
    score(loaded, estimate_names(QUICK_METHODS), thresholds_of(QUICK_METHODS))
    for stream, by_pair in loaded.metrics.items():
        for pair, report in by_pair.items():
            assert report["nees_mean"] is None and report["nees_under_95"] is None
            fresh = {k: v for k, v in job.metrics[stream][pair].items()
                     if k not in ("nees_mean", "nees_under_95", "confident_false_accept")}
            assert {k: v for k, v in report.items() if k in fresh} == pytest.approx(fresh)


def test_the_graphs_covariances_are_its_marginals_at_each_step():
    """The causal read-out's covariance at a step is the graph's marginal of the pair's
    alignment then (checked by replaying the graph through that step), the smoothed one the
    marginal from the final graph."""
    from tcaff_gtsam.eval.methods import run_methods
    from tcaff_gtsam.eval.methods.stages import RunSetup, SharedStages
    from tcaff_gtsam.eval.methods.tcaff import GraphRunner
    from tcaff_gtsam.eval.sim.simulate import simulate

    methods = QUICK_METHODS.model_copy(update={"methods": ["tcaff_isam2"]})
    run = simulate(short("indoor_return", 30), 0)
    runs = run_methods(run, methods)
    causal = runs.covariances["tcaff_isam2_causal"]
    has = ~np.isnan(runs.estimates["tcaff_isam2_causal"][..., 0])
    p, s = np.argwhere(has)[len(np.argwhere(has)) // 2]
    setup = RunSetup.of(run)
    stages = SharedStages(setup, methods)
    graph = GraphRunner(setup, stages, methods)
    for k in range(s + 1):
        stages.begin(k, float(run.times[k]))
        graph.step(k, float(run.times[k]))
    np.testing.assert_allclose(causal[p, s], graph.graph.alignment(*setup.pairs[p], s)[1],
                               rtol=1e-9, atol=1e-15)
    for k in range(s + 1, len(run.times)):
        stages.begin(k, float(run.times[k]))
        graph.step(k, float(run.times[k]))
    graph.finish()
    smoothed = runs.covariances["tcaff_isam2_smoothed"]
    steps = np.flatnonzero(~np.isnan(runs.estimates["tcaff_isam2_smoothed"][p, :, 0]))
    for k in steps[:: max(1, len(steps) // 5)]:
        np.testing.assert_allclose(smoothed[p, k], graph.graph.alignment(*setup.pairs[p], k)[1],
                                   rtol=1e-9, atol=1e-15)


def stages_beside_pair_aligners(scenario: str, seed: int = 0) -> tuple:
    """(run, setup, stages, aligners): `seed` of `scenario`, the study's shared stages for the
    tcaff_only set, and a `PairwiseAligner` per pair with the stages' own parameters."""
    from tcaff_gtsam.eval.methods.stages import RunSetup, SharedStages
    from tcaff_gtsam.eval.sim.simulate import simulate

    from tcaff_gtsam import PairwiseAligner

    run = simulate(load_scenario(scenario), seed)
    setup = RunSetup.of(run)
    stages = SharedStages(setup, load_methods("tcaff_only"))
    return run, setup, stages, [PairwiseAligner(stages.checked, stages.tcaff_params)
                                for _ in setup.pairs]


def estimates_side_by_side(run, setup, stages, aligners, steps: int):
    """Over the first `steps` steps, per pair: (p, the stage's estimate, the pair aligner's,
    that aligner), having checked that both have one or neither, and the same x."""
    for s, t in enumerate(run.times[:steps]):
        stages.begin(s, float(t))
        for p, (i, j) in enumerate(setup.pairs):
            staged = stages.tcaff(p)[0]
            paired = aligners[p].update(float(t), run.maps[i][s], run.maps[j][s])
            assert (staged is None) == (paired is None), (s, p)
            if paired is not None:
                np.testing.assert_array_equal(staged.x, paired.x)
            yield p, staged, paired, aligners[p]


def test_the_studys_tcaff_stage_estimates_what_a_pair_aligner_does():
    """The study's shared stages repeat `PairwiseAligner.update` (search, admit, count,
    evidence, filter): at every step and pair both give the same estimate. The grid's seed 6
    holds an early acceptance that stays provisional while ambiguous candidates near it are
    found, which only a plain candidate may settle (`TCAFF.confirmable`)."""
    run, setup, stages, aligners = stages_beside_pair_aligners("ambiguous_grid", 6)
    reported = provisional = 0
    for _, _, paired, aligner in estimates_side_by_side(run, setup, stages, aligners, 30):
        reported += paired is not None
        provisional += any(m.ambiguous for m in aligner.measurements) and \
            aligner.filter.provisional
    assert reported > 0 and provisional > 0


def test_the_studys_tcaff_stage_holds_as_a_pair_aligner_does():
    """Where a pair's alignment is held past W steps without a registration (indoor_return's
    seed 0 from step 93), the stage grows it as `PairwiseAligner` does, about where the robots
    are (`pairwise.HeldDrift`): the same estimates and covariances at every step, and held
    steps that grew by more than the map drift's diagonal."""
    run, setup, stages, aligners = stages_beside_pair_aligners("indoor_return")
    diagonal = stages.tcaff_params.held_Q
    lever = 0
    for s, t in enumerate(run.times[:110]):
        stages.begin(s, float(t))
        for p, (i, j) in enumerate(setup.pairs):
            before = aligners[p].filter.held
            stages.tcaff(p)
            staged = stages._filters[p].held
            aligners[p].update(float(t), run.maps[i][s], run.maps[j][s])
            paired = aligners[p].filter.held
            assert (staged is None) == (paired is None), (s, p)
            if staged is None:
                continue
            np.testing.assert_array_equal(staged.x, paired.x)
            np.testing.assert_array_equal(staged.P, paired.P)
            if before is not None and before.n_measurements == 0 == paired.n_measurements:
                grown = paired.P - before.P
                lever += not np.allclose(grown, diagonal, rtol=1e-3, atol=0.0)
    assert lever > 0


def test_the_studys_tcaff_stage_covers_twins_as_a_pair_aligner_does():
    """Where a map has fitted itself over the window (ambiguous_grid's seed 0 from step 34),
    the stage and `PairwiseAligner` report the same estimates and covariances, widened beyond
    the filter's own to cover the twins (`twins.Twins`), never narrower; the stage keeps the
    filter's own for the graph (`SharedStages.filtered`)."""
    run, setup, stages, aligners = stages_beside_pair_aligners("ambiguous_grid")
    widened = 0
    for p, staged, paired, aligner in estimates_side_by_side(run, setup, stages, aligners, 40):
        if paired is None:
            continue
        np.testing.assert_array_equal(staged.P, paired.P)
        own = aligner.filter.estimate.P
        np.testing.assert_array_equal(stages.filtered(p).P, own)  # the graph's input
        assert np.linalg.eigvalsh(paired.P - own).min() > -1e-12
        widened += not np.array_equal(paired.P, own)
    assert widened > 0


def test_the_studys_tcaff_runs_as_a_pair_aligner_does():
    """The study's TCAFF stage gives each pair's filter what `PairwiseAligner` gives its own:
    the aligner's jitter reference, so the covariances it scores are the library's."""
    from tcaff_gtsam.eval.methods.stages import RunSetup, SharedStages
    from tcaff_gtsam.eval.sim.simulate import simulate

    from tcaff_gtsam import PairwiseAligner

    run = simulate(short("indoor_return", 10), 0)
    stages = SharedStages(RunSetup.of(run), QUICK_METHODS)
    pair = PairwiseAligner(stages.checked, QUICK_METHODS.tcaff_params(False, None))
    assert stages.tcaff_params.jitter_reference is not None
    assert stages.tcaff_params == pair.filter.params
