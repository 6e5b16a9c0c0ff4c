"""Run every compared method over a simulated run, for every directed robot pair.

All methods advance together, one 1 Hz step at a time, on the same maps:

- tcaff: the paper's filter (default preset) on MNO-CLIPPER candidates.
- tcaff_reference: the authors' released settings on the same candidates, without this project's
  residual check and with the original's constant R.
- tcaff_isam2_causal / tcaff_isam2_smoothed: the TCAFF output of every pair (i, j) with i < j in
  one iSAM2 graph ((j, i) aligns the same two maps), read for every directed pair at each step
  (causal) and once more at the end (smoothed), at the steps that pair's TCAFF has an estimate
  and the graph links the two robots (causal: by then; smoothed: by the end).
- clipper_k<k>: single-shot CLIPPER accepting a solution of at least k associations.
- icp: ICP on centroids from the true initial alignment.
- ground_truth: the true alignment (a check on the evaluation itself).

The candidates are computed once per pair and step and shared by the TCAFF methods.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.frame_aligner import FrameAligner
from tcaff_gtsam.geometry import se2_to_params
from tcaff_gtsam.graph import InterRobotGraph
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import (
    FrameAlignerParams,
    constant_alignment_covariance,
)
from tcaff_gtsam.tcaff import TCAFF

from .baselines import CentroidICP, single_shot
from .config import MethodsConfig

__all__ = ["AlignmentRun", "MethodRuns", "RunSettings", "method_names", "run_methods"]


@dataclass
class MethodRuns:
    """What every method estimated over one run.

    Attributes:
        pairs: the directed pairs (i, j), i the ego robot.
        truth: (n_pairs, S, 3) the true (x, y, theta) of T_oi_oj.
        estimates: method name -> (n_pairs, S, 3) (x, y, theta) of T_oi_oj; NaN rows where the
            method had no estimate.
        candidates: per pair, (steps (M,), z (M, 3)): every candidate the TCAFF filter saw.
        seconds: method name -> compute time over the whole run (the shared candidates are
            counted under "candidates").
    """

    pairs: list[tuple[int, int]]
    truth: np.ndarray
    estimates: dict[str, np.ndarray]
    candidates: list[tuple[np.ndarray, np.ndarray]]
    seconds: dict[str, float] = field(default_factory=dict)


def method_names(methods: MethodsConfig) -> list[str]:
    """The estimate names a method set produces, in table order."""
    names = []
    for m in methods.methods:
        if m == "tcaff_isam2":
            names += ["tcaff_isam2_causal", "tcaff_isam2_smoothed"]
        elif m == "clipper":
            names += [f"clipper_k{k}" for k in methods.clipper_k]
        else:
            names.append(m)
    return names


@dataclass(frozen=True)
class RunSettings:
    """What the methods take from a run's configuration.

    Attributes:
        kappa: s, objects of a map seen longer ago are not aligned.
        window: the TCAFF window W of this run (None: the preset's).
        graph_drift: iSAM2 between-step drift (m, deg) per step (None: the default).
    """

    kappa: float
    window: int | None = None
    graph_drift: tuple[float, float] | None = None


class AlignmentRun(Protocol):
    """The robots' maps at the 1 Hz exchanges, and the truth to score against.

    Attributes:
        settings: `RunSettings`. times: (S,) seconds of the exchanges, on the maps' clock.
        maps: maps[r][s], robot r's map at exchange s, in its odometry frame.
    """

    settings: RunSettings
    times: np.ndarray
    maps: list[list[ObjectMap]]

    @property
    def n_robots(self) -> int: ...

    def T_true(self, i: int, j: int) -> np.ndarray:
        """(S, 3, 3) the true T_oi_oj at each exchange (NaN where unknown)."""
        ...


def run_methods(run: AlignmentRun, methods: MethodsConfig,
                progress: Callable[[float], None] | None = None) -> MethodRuns:
    """Every method of the set over every directed pair of the run.

    Args:
        run: a simulated (`SimRun`) or recorded run.
        progress: called after each step with the share of steps done.
    Raises:
        ConfigError: ICP or ground truth is asked for but the truth is unknown.
    """
    settings = run.settings
    kappa = settings.kappa
    n_steps, chosen = len(run.times), set(methods.methods)
    pairs = [(i, j) for i in range(run.n_robots) for j in range(run.n_robots) if i != j]
    names = method_names(methods)
    estimates = {name: np.full((len(pairs), n_steps, 3), np.nan) for name in names}
    seconds = dict.fromkeys(["candidates", *names], 0.0)
    cfg = methods.aligner_params(kappa)
    # max_rmse is applied below, so that the reference preset sees the unfiltered candidates
    aligner = FrameAligner(replace(cfg, max_rmse=None))
    single = FrameAligner(FrameAlignerParams(
        kappa=kappa, n_solutions=1, min_associations=min(methods.clipper_k), max_rmse=None,
        clipper=cfg.clipper))
    filters = {name: [TCAFF(methods.tcaff_params(name == "tcaff_reference", settings.window))
                      for _ in pairs]
               for name in ("tcaff", "tcaff_reference") if name in chosen or (
                   name == "tcaff" and "tcaff_isam2" in chosen)}
    graph = (InterRobotGraph(run.n_robots, methods.graph_params(settings.graph_drift))
             if "tcaff_isam2" in chosen else None)
    filtered = np.zeros((len(pairs), n_steps), dtype=bool)  # TCAFF had an estimate
    T_true = np.array([run.T_true(i, j) for i, j in pairs]).reshape(len(pairs), n_steps, 3, 3)
    known = np.all(np.isfinite(T_true), axis=(2, 3))
    truths = np.full((len(pairs), n_steps, 3), np.nan)
    if known.any():
        truths[known] = se2_to_params(T_true[known])
    needs_truth = chosen & {"icp", "ground_truth"}
    if needs_truth and not known.all():
        raise ConfigError(f"methods {sorted(needs_truth)} need the true alignment at every "
                          f"step, which this run does not have")
    icps = ([CentroidICP(T_true[p][0], kappa,
                         methods.icp.max_correspondence_distance,
                         methods.icp.min_correspondences, methods.icp.max_iterations)
             for p in range(len(pairs))] if "icp" in chosen else [])
    R_constant = constant_alignment_covariance()
    candidate_steps: list[list[int]] = [[] for _ in pairs]
    candidate_z: list[list[np.ndarray]] = [[] for _ in pairs]
    for s, t in enumerate(run.times):
        tcaff_out = {}
        for p, (i, j) in enumerate(pairs):
            ego, other = run.maps[i][s], run.maps[j][s]
            start = time.perf_counter()
            if filters:
                found = aligner.measurements(ego, other, t)
                kept = [m for m in found if cfg.max_rmse is None or m.rmse <= cfg.max_rmse]
            seconds["candidates"] += time.perf_counter() - start
            for name, per_pair in filters.items():
                use = kept if name == "tcaff" else found
                zs = np.array([m.z for m in use]).reshape(-1, 3)
                Rs = (np.array([m.R for m in use]).reshape(-1, 3, 3) if name == "tcaff"
                      else np.broadcast_to(R_constant, (len(use), 3, 3)))
                start = time.perf_counter()
                est = per_pair[p].update(zs, Rs)
                seconds[name] += time.perf_counter() - start
                if est is not None and name in estimates:
                    estimates[name][p, s] = est.x
                if name == "tcaff":
                    tcaff_out[p] = (est, zs, Rs)
                    candidate_steps[p] += [s] * len(zs)
                    candidate_z[p] += list(zs)
            if "clipper" in chosen:
                start = time.perf_counter()
                found_single = single.measurements(ego, other, t)
                best = found_single[0] if found_single else None
                for k in methods.clipper_k:
                    estimates[f"clipper_k{k}"][p, s] = single_shot(best, k)
                elapsed = time.perf_counter() - start
                for k in methods.clipper_k:  # one CLIPPER run serves every threshold
                    seconds[f"clipper_k{k}"] += elapsed
            if icps:
                start = time.perf_counter()
                estimates["icp"][p, s] = icps[p].update(t, ego, other)
                seconds["icp"] += time.perf_counter() - start
            if "ground_truth" in chosen:
                estimates["ground_truth"][p, s] = truths[p][s]
        if graph is not None:
            start = time.perf_counter()
            for p, (est, zs, Rs) in tcaff_out.items():
                i, j = pairs[p]
                if i < j:  # (j, i) aligns the same two maps: its factors would count them twice
                    graph.add_tcaff_estimate(s, i, j, est, zs, Rs)
            graph.update(s)
            for p, (est, _, _) in tcaff_out.items():
                filtered[p, s] = est is not None
                # Before its first factor a pair's graph alignment is only the gauge's guess.
                if est is not None and graph.connected(*pairs[p]):
                    estimates["tcaff_isam2_causal"][p, s] = graph.alignment_params(*pairs[p], s)
            seconds["tcaff_isam2_causal"] += time.perf_counter() - start
        if progress is not None:
            progress((s + 1) / n_steps)
    if graph is not None:
        start = time.perf_counter()
        for p, pair in enumerate(pairs):
            if not graph.connected(*pair):
                continue
            steps, T = graph.alignment_history(*pair)
            held = filtered[p, steps]
            estimates["tcaff_isam2_smoothed"][p, steps[held]] = se2_to_params(T[held])
        seconds["tcaff_isam2_smoothed"] += time.perf_counter() - start
    candidates = [(np.array(candidate_steps[p], dtype=np.int64),
                   np.array(candidate_z[p]).reshape(-1, 3)) for p in range(len(pairs))]
    return MethodRuns(pairs, truths, estimates, candidates, seconds)

