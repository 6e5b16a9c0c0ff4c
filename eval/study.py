"""The comparison study: scenarios x methods x seeds, in parallel processes.

Each job (one scenario, one seed) simulates the run, runs every method over every directed pair
and scores them. A finished job is written to `<output>/<timestamp>/runs/` at once, so an
interrupted or partly failed study keeps everything it finished. At the end the study writes
metrics.json, metrics.csv and the figures, and points `<output>/latest` at the folder.
"""

from __future__ import annotations

import csv
import json
import logging
import multiprocessing
import queue
import time
import traceback
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from tcaff_gtsam.geometry import se2_from_params

from .config import MethodsConfig, ScenarioConfig, StudyConfig, dump_study
from .methods import MethodRuns, method_names, run_methods
from .metrics import PairTrace, Thresholds, pair_metrics, pooled_metrics
from .mot import COUNTS, collaborative_mot
from .sim.simulate import SimRun, simulate

__all__ = ["JobResult", "StudyOutcome", "run_job", "run_study", "summarize_mot"]

log = logging.getLogger(__name__)

SIMULATION_SHARE = 0.2  # of a job's progress bar
TRACKING_SHARE = 0.7    # of the rest, when the scenario has people to track


@dataclass
class JobResult:
    """One scenario and seed, every method scored.

    Attributes:
        scenario, seed: what ran.
        pairs: directed pairs (i, j).
        arrays: everything the figures need, as saved in runs/<scenario>-seed<seed>.npz:
            times (S,), poses_true and poses_odom (n, S, 3), truth (P, S, 3), overlap (P, S),
            est_<method> (P, S, 3), cand_steps_<p> (M,), cand_z_<p> (M, 3), world_xy (n, 2),
            world_widths (n,), walls (m, 2, 2); with people to track also mot_times (F,),
            mot_window (the rolling MOTA window, s) and mot_counts_<method> (n, F, 4): per
            robot and frame the people to track, false positives, misses and identity
            switches.
        metrics: method -> {"all": report over the pairs, "i->j": report of one pair}.
        seconds: method -> compute time.
        mot: method -> {"mota": averaged over the robots, "robots": [per robot summary]};
            empty without people.
    """

    scenario: str
    seed: int
    pairs: list[tuple[int, int]]
    arrays: dict[str, np.ndarray]
    metrics: dict[str, dict[str, dict]]
    seconds: dict[str, float]
    mot: dict[str, dict] = field(default_factory=dict)

    @property
    def stem(self) -> str:
        return f"{self.scenario}-seed{self.seed}"

    def traces(self, method: str) -> list[PairTrace]:
        """The method's PairTrace of every pair."""
        a = self.arrays
        T_odom = se2_from_params(a["poses_odom"])
        return [PairTrace(a["times"], se2_from_params(a["truth"][p]), a[f"est_{method}"][p],
                          a["overlap"][p], T_odom[i], T_odom[j])
                for p, (i, j) in enumerate(self.pairs)]

    def save(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / f"{self.stem}.npz", "wb") as file:
            np.savez_compressed(file, **self.arrays)
        (folder / f"{self.stem}.json").write_text(json.dumps(
            {"scenario": self.scenario, "seed": self.seed, "pairs": self.pairs,
             "seconds": self.seconds, "metrics": self.metrics, "mot": self.mot}, indent=1))


def _report(job_traces: dict[str, list[PairTrace]], pairs, thresholds: Thresholds) -> dict:
    out = {}
    for method, traces in job_traces.items():
        out[method] = {"all": pooled_metrics(traces, thresholds).as_report()}
        for (i, j), trace in zip(pairs, traces, strict=True):
            out[method][f"{i}->{j}"] = pair_metrics(trace, thresholds).as_report()
    return out


def thresholds_of(methods: MethodsConfig) -> Thresholds:
    return Thresholds(methods.thresholds.translation,
                      np.radians(methods.thresholds.heading_deg))


def run_job(scenario: ScenarioConfig, methods: MethodsConfig, seed: int,
            progress: Callable[[float], None] | None = None) -> JobResult:
    """Simulate one scenario with one seed, run every method, score them."""
    def report(share: float, start: float, span: float) -> None:
        if progress is not None:
            progress(start + span * share)

    run = simulate(scenario, seed, lambda s: report(s, 0.0, SIMULATION_SHARE))
    return score_run(run, methods,
                     lambda s: report(s, SIMULATION_SHARE, 1.0 - SIMULATION_SHARE))


def score_run(run: SimRun, methods: MethodsConfig,
              progress: Callable[[float], None] | None = None) -> JobResult:
    """Run every method over a simulated run and score them; with people in the run, also
    track them with every method's alignments and score the tracking (MOTA)."""
    aligning = 1.0 if run.people is None else 1.0 - TRACKING_SHARE

    def report(share: float, start: float, span: float) -> None:
        if progress is not None:
            progress(start + span * share)

    runs = run_methods(run, methods, lambda s: report(s, 0.0, aligning))
    job = job_from_runs(run.scenario.name, run.seed, runs, {
        "times": run.times, "poses_true": run.poses_true, "poses_odom": run.poses_odom,
        "overlap": np.array([run.overlap(i, j) for i, j in runs.pairs]),
        "world_xy": run.world.xy, "world_widths": run.world.widths, "walls": run.world.walls,
    })
    score(job, methods)
    if run.people is not None:
        start = time.perf_counter()
        scores = collaborative_mot(run.people, run.times, runs.pairs, runs.estimates,
                                   run.scenario.pedestrians,
                                   lambda s: report(s, aligning, TRACKING_SHARE))
        job.seconds["tracking"] = time.perf_counter() - start
        job.arrays["mot_times"] = run.people.times
        job.arrays["mot_window"] = np.float64(run.scenario.pedestrians.mota_window)
        for method, mot in scores.items():
            job.arrays[f"mot_counts_{method}"] = mot.counts
            job.mot[method] = {"mota": mot.mota, "robots": mot.robots}
    return job


def job_from_runs(name: str, seed: int, runs: MethodRuns, arrays: dict[str, np.ndarray]
                  ) -> JobResult:
    """A `JobResult` (unscored) of the methods' runs; `arrays` holds the run's own arrays
    (times, poses, overlap, world), the truth, estimates and candidates are added."""
    arrays = {**arrays, "truth": runs.truth}
    for method, est in runs.estimates.items():
        arrays[f"est_{method}"] = est
    for p, (steps, z) in enumerate(runs.candidates):
        arrays[f"cand_steps_{p}"], arrays[f"cand_z_{p}"] = steps, z
    return JobResult(name, seed, runs.pairs, arrays, {}, runs.seconds)


def score(job: JobResult, methods: MethodsConfig) -> None:
    """Fill `job.metrics`: every method, pooled over the pairs and per pair."""
    job.metrics = _report({m: job.traces(m) for m in method_names(methods)}, job.pairs,
                          thresholds_of(methods))


@dataclass
class StudyOutcome:
    """What a study produced, including when it stopped early."""

    folder: Path
    jobs: list[JobResult]
    failed: list[dict]
    interrupted: bool
    summary: dict[str, dict[str, dict]]
    mot_summary: dict[str, dict[str, dict]] = field(default_factory=dict)


def _job_in_worker(scenario: ScenarioConfig, methods: MethodsConfig, seed: int, key: int,
                   updates) -> JobResult:
    return run_job(scenario, methods, seed, lambda share: updates.put((key, share)))


def _new_folder(root: Path) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    root.mkdir(parents=True, exist_ok=True)
    for n in range(1, 1000):
        folder = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir()  # atomic: two studies started in the same second get two folders
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{root}: no free results folder for {stamp}")


def summarize(jobs: list[JobResult], methods: MethodsConfig) -> dict[str, dict[str, dict]]:
    """scenario -> method -> report pooled over every pair and seed."""
    summary: dict[str, dict[str, dict]] = {}
    thresholds = thresholds_of(methods)
    for name in dict.fromkeys(j.scenario for j in jobs):
        mine = [j for j in jobs if j.scenario == name]
        summary[name] = {m: pooled_metrics([t for j in mine for t in j.traces(m)],
                                           thresholds).as_report()
                         for m in method_names(methods)}
        pair_steps = sum(len(j.pairs) * len(j.arrays["times"]) for j in mine)
        for m, report in summary[name].items():
            report["ms_per_pair_step"] = 1e3 * sum(j.seconds.get(m, 0.0) for j in mine) / pair_steps
    return summary


def summarize_mot(jobs: list[JobResult]) -> dict[str, dict[str, dict]]:
    """scenario -> method -> tracking summary over its seeds: mota (mean of each seed's
    robot-averaged MOTA) and mota_std, and false_positives_share, misses_share and
    switches_share: shares of the people to track, pooled over robots and seeds. Scenarios
    without people are left out.
    """
    summary: dict[str, dict[str, dict]] = {}
    for name in dict.fromkeys(j.scenario for j in jobs if j.mot):
        mine = [j for j in jobs if j.scenario == name and j.mot]
        summary[name] = {}
        for method in mine[0].mot:
            motas = [j.mot[method]["mota"] for j in mine if j.mot[method]["mota"] is not None]
            totals = sum(j.arrays[f"mot_counts_{method}"].sum(axis=(0, 1)) for j in mine)
            objects = int(totals[0])
            shares = {f"{key}_share": float(total / objects) if objects else None
                      for key, total in zip(COUNTS[1:], totals[1:], strict=True)}
            summary[name][method] = {
                "mota": float(np.mean(motas)) if motas else None,
                "mota_std": float(np.std(motas)) if motas else None,
                "seeds": len(motas), "objects": objects, **shares}
    return summary


def _write_tables(folder: Path, study: StudyConfig, outcome: StudyOutcome) -> None:
    (folder / "metrics.json").write_text(json.dumps({
        "study": study.name, "interrupted": outcome.interrupted, "failed": outcome.failed,
        "summary": outcome.summary, "mot_summary": outcome.mot_summary,
        "runs": [{"scenario": j.scenario, "seed": j.seed, "metrics": j.metrics, "mot": j.mot}
                 for j in outcome.jobs]}, indent=1))
    rows = []
    for j in outcome.jobs:
        for method, by_pair in j.metrics.items():
            for pair, report in by_pair.items():
                rows.append({"scenario": j.scenario, "seed": j.seed, "method": method,
                             "pair": pair, **report})
    for scenario, by_method in outcome.summary.items():
        for method, report in by_method.items():
            rows.append({"scenario": scenario, "seed": "all", "method": method, "pair": "all",
                         **report})
    if rows:
        write_csv(folder / "metrics.csv", rows)
    mot_rows = []
    for j in outcome.jobs:
        for method, mot in j.mot.items():
            mot_rows.append({"scenario": j.scenario, "seed": j.seed, "method": method,
                             "robot": "mean", "mota": mot["mota"]})
            mot_rows += [{"scenario": j.scenario, "seed": j.seed, "method": method,
                          "robot": r, **report} for r, report in enumerate(mot["robots"])]
    for scenario, by_method in outcome.mot_summary.items():
        for method, report in by_method.items():
            mot_rows.append({"scenario": scenario, "seed": "all", "method": method,
                             "robot": "all", **report})
    if mot_rows:
        write_csv(folder / "mot.csv", mot_rows)


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows of dictionaries as CSV, the columns in order of first appearance."""
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)


def _link_latest(root: Path, folder: Path) -> None:
    latest = root / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(folder.name, target_is_directory=True)
    except OSError as exc:  # some file systems have no symbolic links; results are still there
        log.warning("could not link %s: %s", latest, exc)


class Progress:
    """What the study reports while it runs; the CLI draws it as progress bars."""

    def start(self, key: int, label: str) -> None: ...
    def advance(self, key: int, share: float) -> None: ...
    def finish(self, key: int, ok: bool) -> None: ...


def run_study(study: StudyConfig, progress: Progress | None = None,
              on_job_done: Callable[[JobResult], None] | None = None,
              figures: bool = True) -> StudyOutcome:
    """Run a resolved study (see `config.resolve_study`) and write its results.

    Jobs run in `study.workers` processes (in this process when 1). Ctrl-C stops the study: the
    jobs already finished are summarised and written, and `interrupted` is set.

    Args:
        on_job_done: called in this process with each finished job, after it is saved.
        figures: draw the PNG figures.
    """
    from . import plots

    progress = progress or Progress()
    root = Path(study.output)
    folder = _new_folder(root)
    (folder / "config.yaml").write_text(dump_study(study))
    methods: MethodsConfig = study.methods  # type: ignore[assignment]
    todo = [(s, seed) for s in study.scenarios for seed in study.seeds]
    jobs: list[JobResult] = []
    failed: list[dict] = []
    interrupted = False

    def done(key: int, job: JobResult) -> None:
        job.save(folder / "runs")
        jobs.append(job)
        progress.finish(key, True)
        if on_job_done is not None:
            on_job_done(job)

    def fail(key: int, scenario: ScenarioConfig, seed: int, exc: BaseException) -> None:
        log.error("%s seed %d failed: %s", scenario.name, seed, exc)
        failed.append({"scenario": scenario.name, "seed": seed, "error": str(exc),
                       "traceback": "".join(traceback.format_exception(exc))})
        progress.finish(key, False)

    for key, (scenario, seed) in enumerate(todo):
        progress.start(key, f"{scenario.name} seed {seed}")
    try:
        if study.workers == 1 or len(todo) == 1:
            for key, (scenario, seed) in enumerate(todo):
                try:
                    job = run_job(scenario, methods, seed,
                                  lambda share, key=key: progress.advance(key, share))
                except Exception as exc:
                    fail(key, scenario, seed, exc)
                    continue
                done(key, job)
        else:
            _run_parallel(todo, methods, min(study.workers, len(todo)), progress, done, fail)
    except KeyboardInterrupt:
        interrupted = True
        log.warning("interrupted: writing the %d finished jobs", len(jobs))
    order = {(s.name, seed): k for k, (s, seed) in enumerate(todo)}
    jobs.sort(key=lambda j: order[(j.scenario, j.seed)])
    outcome = StudyOutcome(folder, jobs, failed, interrupted,
                           summarize(jobs, methods) if jobs else {}, summarize_mot(jobs))
    _write_tables(folder, study, outcome)
    if figures and jobs:
        plots.draw_all(folder / "figures", jobs, outcome.summary, methods, outcome.mot_summary)
    if jobs:
        _link_latest(root, folder)
    return outcome


def _run_parallel(todo, methods: MethodsConfig, workers: int, progress: Progress,
                  done, fail) -> None:
    context = multiprocessing.get_context("spawn")  # fork would copy numba and gtsam state
    with context.Manager() as manager:
        updates = manager.Queue()
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context)
        futures: dict[Future, int] = {
            pool.submit(_job_in_worker, scenario, methods, seed, key, updates): key
            for key, (scenario, seed) in enumerate(todo)}
        handled: set[Future] = set()

        def collect(future: Future) -> None:
            handled.add(future)
            key = futures[future]
            scenario, seed = todo[key]
            try:
                job = future.result()
            except Exception as exc:
                fail(key, scenario, seed, exc)
                return
            done(key, job)

        try:
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                _drain(updates, progress)
                for future in finished:
                    collect(future)
        except BaseException:
            processes = list((pool._processes or {}).values())  # gone after shutdown()
            pool.shutdown(wait=False, cancel_futures=True)
            for process in processes:
                process.terminate()
            # jobs that finished meanwhile are kept like the others
            for future in futures:
                if future not in handled and future.done() and not future.cancelled():
                    try:
                        collect(future)
                    except BaseException:
                        continue
            raise
        pool.shutdown()


def _drain(updates, progress: Progress) -> None:
    while True:
        try:
            key, share = updates.get_nowait()
        except queue.Empty:
            return
        progress.advance(key, share)
