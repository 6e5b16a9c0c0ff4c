"""Jobs: one run through every method of a set, scored; with people in a simulated run, also
tracked with every method's alignments and scored with MOTA."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from .config import MethodsConfig, ScenarioConfig
from .methods import estimate_names, run_methods
from .results import JobResult, score, thresholds_of
from .runs import AlignmentRun
from .sim.simulate import SimRun, simulate

__all__ = ["evaluate", "evaluate_simulated", "shared_maps", "simulated_job"]

SIMULATION_SHARE = 0.2  # of a simulated job's progress
TRACKING_SHARE = 0.7    # of the rest, when the run has people to track


def _span(progress: Callable[[float], None] | None, start: float, span: float
          ) -> Callable[[float], None] | None:
    """`progress` of a part of the work: its shares mapped onto [start, start + span]."""
    if progress is None:
        return None
    return lambda share: progress(start + span * share)


def shared_maps(run: AlignmentRun) -> dict[str, np.ndarray]:
    """What each robot shares at each exchange, the objects of its map seen within kappa, as
    ragged arrays for the recordings: map_xy_<r> (N, 2) m in robot r's odometry frame,
    map_widths_<r> (N,) m (float32: for drawing), map_counts_<r> (S,) objects per exchange."""
    arrays = {}
    for r, maps in enumerate(run.maps):
        recent = [m.recent(float(t), run.settings.kappa) for m, t in zip(maps, run.times,
                                                                          strict=True)]
        arrays[f"map_xy_{r}"] = np.concatenate(
            [m.centroids[:, :2] for m in recent]).astype(np.float32).reshape(-1, 2)
        arrays[f"map_widths_{r}"] = np.concatenate(
            [m.widths for m in recent]).astype(np.float32).reshape(-1)
        arrays[f"map_counts_{r}"] = np.array([len(m) for m in recent], dtype=np.int32)
    return arrays


def evaluate(run: AlignmentRun, methods: MethodsConfig, name: str, seed: int | None,
             arrays: dict[str, np.ndarray],
             progress: Callable[[float], None] | None = None) -> JobResult:
    """Every method over every directed pair of a run, scored where the truth is known.

    Args:
        name, seed: the job's (seed None for a recorded run).
        arrays: the run's own arrays to keep with the estimates: times (S,) and poses_true,
            poses_odom (n, S, 3) at least (see `JobResult.arrays`).
    Returns:
        The job; unscored (`metrics` empty) when the truth is unknown at some step.
    """
    people = getattr(run, "people", None)
    aligning = 1.0 if people is None else 1.0 - TRACKING_SHARE
    runs = run_methods(run, methods, _span(progress, 0.0, aligning))
    arrays = {**arrays, **shared_maps(run), "truth": runs.truth}
    overlap = [run.overlap(i, j) for i, j in runs.pairs]
    if all(o is not None for o in overlap):
        arrays["overlap"] = np.array(overlap, dtype=bool).reshape(len(runs.pairs), -1)
    for stream, est in runs.estimates.items():
        arrays[f"est_{stream}"] = est
    for stream, cov in runs.covariances.items():
        arrays[f"cov_{stream}"] = cov
    for p, (steps, z) in enumerate(runs.candidates):
        arrays[f"cand_steps_{p}"], arrays[f"cand_z_{p}"] = steps, z
    job = JobResult(name, seed, runs.pairs, arrays, seconds=runs.seconds)
    if np.all(np.isfinite(runs.truth)):
        score(job, estimate_names(methods), thresholds_of(methods))
    if people is not None:
        from .mot import collaborative_mot

        start = time.perf_counter()
        scores = collaborative_mot(people, run.times, runs.pairs, runs.estimates,
                                   run.scenario.pedestrians,
                                   _span(progress, aligning, TRACKING_SHARE))
        job.seconds["tracking"] = time.perf_counter() - start
        job.arrays["mot_times"] = people.times
        job.arrays["mot_window"] = np.float64(run.scenario.pedestrians.mota_window)
        for method, mot in scores.items():
            job.arrays[f"mot_counts_{method}"] = mot.counts
            job.mot[method] = {"mota": mot.mota, "robots": mot.robots}
    return job


def evaluate_simulated(run: SimRun, methods: MethodsConfig,
                       progress: Callable[[float], None] | None = None) -> JobResult:
    """`evaluate` of a simulated run, keeping its world for the figures."""
    return evaluate(run, methods, run.scenario.name, run.seed, {
        "times": run.times, "poses_true": run.poses_true, "poses_odom": run.poses_odom,
        "world_xy": run.world.xy, "world_widths": run.world.widths, "walls": run.world.walls,
    }, progress)


def simulated_job(scenario: ScenarioConfig, methods: MethodsConfig, seed: int,
                  progress: Callable[[float], None] | None = None) -> JobResult:
    """Simulate one scenario with one seed, run every method, score them."""
    run = simulate(scenario, seed, _span(progress, 0.0, SIMULATION_SHARE))
    return evaluate_simulated(run, methods, _span(progress, SIMULATION_SHARE,
                                                  1.0 - SIMULATION_SHARE))
