"""NEES of the alignment covariance: whether `AlignmentEstimate.P` describes the error.

Runs `PairwiseAligner` (the library's defaults with each data set's map span kappa and window
W, or with --methods dataset the method set the project's command runs there) over every
directed pair of:

- UTIAS MRCLAM data set 6 (`mrclam.load_run` with the shipped evaluation's nu, overlap and
  drift settings): VIO-like odometry (seeds 0 .. --seeds - 1) and raw dead reckoning, each
  with 20 s and with 150 s maps (--spans);
- the 7-Scenes kitchen as two robots (its two halves, as `tcaff rgbd` walks it): VIO-like
  odometry (--seeds) and exact odometry;
- the simulator's scenarios of `tcaff study paper` (--sim-seeds each);

for each covariance model of --models:

  today         the covariance the parameters give (the library's and the camera preset's:
                calibrated)
  constant      the original's R = diag(0.5 m, 0.5 m, 5 deg)^2 for every candidate
  residual      the registration's sandwich covariance (`frame_aligner.residual_covariance`)
  calibrated    `frame_aligner.calibrated_covariance` with FrameAlignerParams' settings
  calibrated+Q  the same with the filter's Q set to the run's own drift (an oracle: the mean
                square per-step change of the true T_oi_oj)
  calibrated+drift
                calibrated with R's `map_drift` set to that drift per square root of a second
                (an oracle of what the odometries' drift tells R; the filter as it is)
  calibrated+declared
                calibrated with `map_drift` from what the odometries declare (`declared_drift`:
                the simulator's random walks, the VIO-like heading walk, none for exact
                odometry), as a user who knows their odometry would set it
  calibrated+declared-max
                the same, each part the larger of the declared one and the default's: the
                declared drift only where it is more than `map_drift` assumes

and prints one row per data set (seeds pooled) and model:

  est       estimates: steps with an estimate, over pairs and seeds
  mean, median, <7.81
            NEES = e' P^-1 e of every estimate, e = estimate - truth (x [m], y [m], theta
            [rad], theta wrapped), and the share under 7.815 (chi-square, 3 dof, 95 %);
            honest: mean 3, 95 % under
  95 % of mean
            a bootstrap interval of the mean over the episodes (robot pairs of a run, both
            directions together; their count in `pairs`): an estimate's error persists from
            step to step, so a data set of few pairs (the kitchen: one per run) pins the
            mean down only loosely; "-" below 5 pairs
  ok mean   mean NEES of the correct estimates (within 1 m and 5 deg), which the false
            accepts' huge NEES do not swamp
  held      mean NEES of the correct estimates at steps whose best path took no measurement:
            whether P grows with the drift while nothing is measured
  meas      the same at the steps whose best path took one
  R         at those steps, the mean NEES of the measurement taken (the aligner's z against
            its own R): whether R describes one registration's error; meas above R means the
            filter's fusion shrinks P more than it shrinks the error (consecutive
            registrations share most of their error)
  R_s       the same against one registration's covariance R_s, R without the re-registration
            inflation (`one_registration`), which is what the filter's P settles at under a
            run of registrations: 3 where R_s is right (R's NEES is below it by design)
  wrong     share of the estimates off by more than 1 m or 5 deg (false accepts)
  outside   share of those with NEES > 14.16 (outside their 99.7 % ellipse)
  x, y, th  RMS of e_k / sigma_k over the correct estimates (sigma_k = sqrt(P_kk)); 1: honest
  sig m, sig deg
            RMS reported sigma: translation (x and y together) and heading
  avail, correct
            share of the overlap steps (the maps share enough objects) with an estimate, and
            with a correct one
  jitter    mean of d' (R_a + R_b)^-1 d / 3 over every two consecutive steps whose estimates
            took a measurement of the same hypothesis (d the difference of the two
            measurements): what `TCAFFParams.jitter_reference` compares

--lost P loses each robot's maps at random, with probability P (drawn from --lost-seed, the
robot and the exchange, as a team node's --drop-share draws them): a busy machine or a lossy
link, where a node steps its filter only for the maps that arrive (docs/team.md,
`--silence`). --every K exchanges maps every K seconds instead of every one. Lost or skipped
exchanges count neither as overlap nor as estimates.

Runs are built once and cached as pickles in --cache (delete it after changing the loaders or
the simulator); the kitchen's maps take the mapping front end about 7 s a run. The default
(all data sets, today's covariance) takes about 2 minutes on 2 cores, most of it MRCLAM with
150 s maps; each further model about as long again.

    python scripts/bench_nees.py [--data mrclam kitchen sim] [--models today]
        [--seeds 3] [--sim-seeds 2] [--spans 20 150] [--workers 2] [--methods library]
        [--lost 0.3] [--lost-seed 0] [--every 2]
"""

from __future__ import annotations

import argparse
import math
import pickle
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tcaff_gtsam.eval.metrics import NEES_95, NEES_997, Thresholds, step_errors, step_nees
from tcaff_gtsam.eval.runs import directed_pairs

from tcaff_gtsam import FrameAlignerParams, PairwiseAligner, TCAFFParams
from tcaff_gtsam.aligner_params import MAX_MAP_DRIFT
from tcaff_gtsam.geometry import se2_to_params, wrap_angle

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MRCLAM = SHARED / "mrclam" / "MRCLAM_Dataset6"
KITCHEN = SHARED / "rgbd" / "7scenes_redkitchen"
#: the scenarios of `tcaff study paper`
SCENARIOS = ("indoor_return", "same_direction", "opposite_directions", "four_robots",
             "ambiguous_grid", "indoor_rgbd", "mot")


@dataclass(frozen=True)
class Source:
    """One run: `group` names its row of the table (seeds pooled), `kind` its loader."""

    group: str
    name: str
    kind: str  # "mrclam", "kitchen" or "sim"
    odometry: str = ""
    kappa: float = 0.0
    seed: int | None = None
    scenario: str = ""


def sources(data: list[str], seeds: int, sim_seeds: int, scenarios: list[str],
            spans: list[float]) -> list[Source]:
    """The runs of the data sets asked for, MRCLAM with each map span of `spans` (s)."""
    out = []
    if "mrclam" in data:
        for kappa in spans:
            out += [Source(f"mrclam vio {kappa:g} s", f"mrclam-vio{kappa:g}-s{s}", "mrclam",
                           "vio", kappa, s) for s in range(seeds)]
            out.append(Source(f"mrclam raw {kappa:g} s", f"mrclam-raw{kappa:g}", "mrclam", "raw",
                              kappa))
    if "kitchen" in data:
        out += [Source("kitchen vio", f"kitchen-vio-s{s}", "kitchen", "vio", seed=s)
                for s in range(seeds)]
        out.append(Source("kitchen exact", "kitchen-exact", "kitchen", "exact"))
    if "sim" in data:
        out += [Source(f"sim {sc}", f"sim-{sc}-s{s}", "sim", seed=s, scenario=sc)
                for sc in scenarios for s in range(sim_seeds)]
    return out


def load(source: Source, cache: Path):
    """The source's run (an `AlignmentRun`), from the cache when it is there."""
    path = cache / f"{source.name}.pkl"
    if path.is_file():
        with path.open("rb") as f:
            return pickle.load(f)
    if source.kind == "mrclam":
        from tcaff_gtsam.eval.config import load_mrclam
        from tcaff_gtsam.eval.datasets import mrclam

        config = load_mrclam("default")
        data = mrclam.read_dataset(MRCLAM)
        run, _ = mrclam.load_run(data, source.odometry, source.seed, source.kappa, config.nu,
                                 config.min_shared, config.vio.heading_rw_deg_per_sqrt_min,
                                 config.vio.scale_std, name=source.name)
    elif source.kind == "kitchen":
        from tcaff_gtsam.eval.config import load_rgbd
        from tcaff_gtsam.eval.datasets.rgbd_robots import halves, load_run, walk
        from tcaff_gtsam.eval.datasets.rgbd_sequence import read_sequence
        from tcaff_gtsam.mapping.mapper import MapperParams

        config = load_rgbd("default")
        sequence = read_sequence(KITCHEN)
        walks = [walk(sequence, a, b) for a, b in halves(sequence.frame_ids)]
        run, _ = load_run(walks, source.odometry, source.seed, config.kappa,
                          MapperParams(nu=config.nu, kappa=config.kappa), config.min_shared,
                          config.match_radius, config.vio.heading_rw_deg_per_sqrt_min,
                          config.vio.scale_std, config.window, config.graph_drift, source.name)
    else:
        from tcaff_gtsam.eval.config import load_scenario
        from tcaff_gtsam.eval.sim.simulate import simulate

        run = simulate(load_scenario(source.scenario), source.seed)
    cache.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        pickle.dump(run, f)
    return run


def dataset_methods(source: Source):
    """The method set the project's own command runs on this source."""
    from tcaff_gtsam.eval.config import load_methods, load_mrclam, load_rgbd

    if source.kind == "mrclam":
        methods = load_mrclam("default").methods
    elif source.kind == "kitchen":
        methods = load_rgbd("default").methods
    else:
        methods = "default"
    return load_methods(methods) if isinstance(methods, str) else methods


# -- covariance models -------------------------------------------------------------------------
# Each takes the aligner's and the filter's parameters, the run and its source, and returns the
# parameters changed.

Model = Callable[[FrameAlignerParams, TCAFFParams, object, Source],
                 tuple[FrameAlignerParams, TCAFFParams]]


def library_params(run) -> tuple[FrameAlignerParams, TCAFFParams]:
    """The library's defaults with the run's map span kappa and window W."""
    settings = run.settings
    return (FrameAlignerParams(kappa=settings.kappa),
            TCAFFParams() if settings.window is None else TCAFFParams(window=settings.window))


def _mode(params: FrameAlignerParams, covariance: str) -> FrameAlignerParams:
    """`params` with covariance set to `covariance`."""
    return replace(params, covariance=covariance)


def truth_drift(run) -> np.ndarray:
    """(3, 3) Q of the run's own drift: the mean square per-step change of every pair's true
    T_oi_oj (x and y pooled; theta wrapped), an oracle of the odometries' relative drift."""
    steps = []
    for i, j in directed_pairs(run):
        truth = se2_to_params(run.T_true(i, j))
        d = np.diff(truth, axis=0)
        d[:, 2] = wrap_angle(d[:, 2])
        steps.append(d[np.all(np.isfinite(d), axis=1)])
    d = np.concatenate(steps)
    # floored at 5 mm and 0.05 deg: exact odometry does not drift at all
    translation = max(float(np.mean(d[:, :2] ** 2)), 0.005**2)
    return np.diag([translation, translation,
                    max(float(np.mean(d[:, 2] ** 2)), math.radians(0.05) ** 2)])


def truth_rates(run) -> tuple[float, float]:
    """`truth_drift` as `map_drift`'s (metres, radians) per square root of a second."""
    Q = truth_drift(run)
    step = float(np.median(np.diff(run.times)))
    return math.sqrt(Q[0, 0] / step), math.sqrt(Q[2, 2] / step)


def _map_drift(drift: tuple[float, float]) -> tuple[float, float]:
    """(d_t, d_theta) within `MAX_MAP_DRIFT`, the most `FrameAlignerParams.map_drift` takes: a
    scenario's odometry may drift faster (its own bounds allow 1.4 m and 0.25 rad per square
    root of a second between two robots), and the model then takes the bound, saying so."""
    bounded = (min(drift[0], MAX_MAP_DRIFT[0]), min(drift[1], MAX_MAP_DRIFT[1]))
    if bounded != tuple(drift):
        print(f"note: map_drift {tuple(drift)} taken as {bounded}, MAX_MAP_DRIFT: the rows of "
              f"this run's drift models hold less drift than the odometry's", flush=True)
    return bounded


def declared_drift(run, source: Source, default: tuple[float, float]) -> tuple[float, float]:
    """`map_drift` from the odometries' own specification, as a user who knows them would set
    it: two robots' random walks (d_t, d_theta) combine to (hypot(d_t_i, d_t_j),
    hypot(d_theta_i, d_theta_j)), per square root of a second.

    - simulator: each robot's `OdometryDrift` (the pair of the most drift);
    - VIO-like odometry: its heading random walk, per square root of a minute; its scale
      error is no random walk, so the default's translation stays;
    - exact odometry: none; MRCLAM's dead reckoning declares nothing: the default.
    """
    if source.kind == "sim":
        drifts = run.scenario.odometry
        if not isinstance(drifts, (list, tuple)):
            drifts = [drifts] * run.n_robots
        return max(((math.hypot(a.position_rw, b.position_rw),
                     math.radians(math.hypot(a.heading_rw_deg, b.heading_rw_deg)))
                    for k, a in enumerate(drifts) for b in drifts[k + 1:]),
                   key=lambda drift: drift[1])
    if source.odometry == "vio":
        from tcaff_gtsam.eval.config import load_mrclam, load_rgbd

        config = load_mrclam("default") if source.kind == "mrclam" else load_rgbd("default")
        per_second = config.vio.heading_rw_deg_per_sqrt_min / math.sqrt(60.0)
        return default[0], math.radians(math.sqrt(2.0) * per_second)
    if source.odometry == "exact":
        return 0.0, 0.0
    return default


MODELS: dict[str, Model] = {
    # the covariance the parameters give (the library's and the camera preset's: calibrated)
    "today": lambda a, f, run, source: (a, f),
    # the original's constant R = diag(0.5 m, 0.5 m, 5 deg)^2
    "constant": lambda a, f, run, source: (_mode(a, "constant"), f),
    # the registration's sandwich covariance, as `residual_covariance` computes it
    "residual": lambda a, f, run, source: (_mode(a, "residual"), f),
    # `calibrated_covariance` with the parameters' settings
    "calibrated": lambda a, f, run, source: (_mode(a, "calibrated"), f),
    # the same with the filter's Q (and the aligner's repeat_Q) set to the run's true drift
    "calibrated+Q": lambda a, f, run, source: _with_Q(a, f, truth_drift(run)),
    # the same R with the map drift set to the run's true drift; the filter's Q as it is
    "calibrated+drift": lambda a, f, run, source: (replace(
        _mode(a, "calibrated"), map_drift=_map_drift(truth_rates(run))), f),
    # R's map drift from what each robot's odometry declares (no truth)
    "calibrated+declared": lambda a, f, run, source: (replace(
        _mode(a, "calibrated"), map_drift=_map_drift(declared_drift(run, source, a.map_drift))),
        f),
    # ... only where it exceeds the default's, part by part
    "calibrated+declared-max": lambda a, f, run, source: (replace(
        _mode(a, "calibrated"), map_drift=_map_drift(tuple(np.maximum(
            declared_drift(run, source, a.map_drift), a.map_drift).tolist()))), f),
}


def _with_Q(aligner: FrameAlignerParams, tcaff: TCAFFParams, Q: np.ndarray
            ) -> tuple[FrameAlignerParams, TCAFFParams]:
    """The calibrated covariance inflated for a filter of drift Q (3, 3), and that filter."""
    return replace(_mode(aligner, "calibrated"), repeat_Q=Q), replace(tcaff, Q=Q)


# -- one run -----------------------------------------------------------------------------------


def one_registration(R: np.ndarray, Q: np.ndarray, rho: float) -> np.ndarray:
    """R_s (n, 3, 3) of calibrated covariances R (n, 3, 3) inflated for a filter of drift Q
    (3, 3): the solution of R = R_s + rho R_s Q^-1 R_s (`calibrated_covariance`, part 3).
    In Q's whitened frame (Q = L L') B = L^-1 R L^-T and A = L^-1 R_s L^-T share their
    eigenvectors and B = A + rho A^2, so A's eigenvalues are (sqrt(1 + 4 rho b) - 1) / (2 rho).
    """
    if rho == 0:
        return R
    L = np.linalg.cholesky(Q)
    L_inv = np.linalg.inv(L)
    B = L_inv @ R @ L_inv.T
    b, v = np.linalg.eigh(0.5 * (B + np.swapaxes(B, -1, -2)))
    a = (np.sqrt(1.0 + 4.0 * rho * np.clip(b, 0.0, None)) - 1.0) / (2.0 * rho)
    return L @ ((v * a[..., None, :]) @ np.swapaxes(v, -1, -2)) @ L.T


def run_source(source: Source, model: str, methods: str, cache: Path, lost: float = 0.0,
               lost_seed: int = 0, every: int = 1) -> dict:
    """Every directed pair of one run under one model: per estimate the error (n, 3), its P
    (n, 3, 3), its NEES and whether it is correct (as the evaluation scores them,
    `metrics.step_nees` and `step_errors` within `Thresholds`), and the NEES of the measurement
    it took against that measurement's own R and against its R_s (NaN for a held estimate);
    counts of overlap steps, of those with an estimate and with a correct one. With `lost` >
    0 the other robot's maps are lost at random at that rate (`lost_exchanges`, drawn with
    `lost_seed`), and with `every` > 1 only every `every`-th is made (a slower exchange
    rate): the pair skips the others, which count neither as overlap nor as estimates."""
    from tcaff_gtsam.precompile import compile_kernels

    compile_kernels()
    run = load(source, cache)
    settings = run.settings
    if methods == "dataset":
        m = dataset_methods(source)
        aligner, tcaff = m.aligner_params(settings.kappa), m.tcaff_params(False,
                                                                          settings.window)
    else:
        aligner, tcaff = library_params(run)
    aligner, tcaff = MODELS[model](aligner, tcaff, run, source)
    pairs = directed_pairs(run)
    limits = Thresholds()
    parts = []
    overlap = available = correct = 0
    start = time.perf_counter()
    steps = len(run.times)
    for i, j in pairs:
        pair = PairwiseAligner(aligner, tcaff)
        T_true = run.T_true(i, j)
        truth = se2_to_params(T_true)
        shared = run.overlap(i, j)
        on = np.ones(steps, bool) if shared is None else np.asarray(shared, bool)
        arrived = ~lost_exchanges(steps, lost, lost_seed, j)
        arrived[np.arange(steps) % every != 0] = False
        on = on & arrived
        x, z = np.full((steps, 3), np.nan), np.full((steps, 3), np.nan)
        P, R = np.full((steps, 3, 3), np.nan), np.full((steps, 3, 3), np.nan)
        hypothesis = np.full(steps, -1)
        for s, t in enumerate(run.times):
            if not arrived[s]:
                continue
            est = pair.update(float(t), run.maps[i][s], run.maps[j][s])
            if est is None or not np.all(np.isfinite(truth[s])):
                continue
            x[s], P[s], hypothesis[s] = est.x, est.P, est.hypothesis
            if est.measurement >= 0:
                z[s], R[s] = pair.taken[est.measurement].z, pair.taken[est.measurement].R
        # the jitter of measurements of one hypothesis at consecutive steps of the filter
        # (the exchanges made: `jitter_reference`)
        made = np.flatnonzero(arrived)
        z_m, R_m, h_m = z[made], R[made], hypothesis[made]
        pairs_on = np.flatnonzero(~np.isnan(z_m[1:, 0]) & ~np.isnan(z_m[:-1, 0])
                                  & (h_m[1:] == h_m[:-1])) + 1
        d = z_m[pairs_on] - z_m[pairs_on - 1]
        d[:, 2] = wrap_angle(d[:, 2])
        jitter = np.einsum("ni,ni->n", d, np.linalg.solve(R_m[pairs_on] + R_m[pairs_on - 1],
                                                          d[..., None])[..., 0]) / 3
        has = ~np.isnan(x[:, 0])
        ok = limits.correct(step_errors(T_true[has], x[has]))
        measured = ~np.isnan(z[has, 0])
        taken, taken_s = np.full(measured.shape, np.nan), np.full(measured.shape, np.nan)
        taken[measured] = step_nees(T_true[has][measured], z[has][measured], R[has][measured])
        fed = pair.aligner.params
        rho = fed.repeat_inflation if fed.covariance == "calibrated" else 0.0
        Q = pair.filter.params.Q if fed.repeat_Q is None else fed.repeat_Q
        taken_s[measured] = step_nees(T_true[has][measured], z[has][measured],
                                      one_registration(R[has][measured], Q, rho))
        e = x[has] - truth[has]
        e[:, 2] = wrap_angle(e[:, 2])
        parts.append({"errors": e, "P": P[has], "nees": step_nees(T_true[has], x[has], P[has]),
                      "ok": ok, "held": ~measured, "taken": taken, "taken_s": taken_s,
                      "episode": np.full(len(e), f"{source.name} {min(i, j)}-{max(i, j)}"),
                      "jitter": jitter})
        overlap += int(on.sum())
        available += int((on & has).sum())
        correct += int((on[has] & ok).sum())
    joined = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
    return {"group": source.group, "model": model, **joined,
            "overlap": overlap, "available": available, "correct": correct,
            "seconds": time.perf_counter() - start}


def lost_exchanges(steps: int, share: float, seed: int, j: int) -> np.ndarray:
    """(steps,) bool: the exchanges at which robot j's map is lost on a busy machine or a
    lossy link, each with probability `share`, drawn as a team node draws its losses
    (`NodeParams.drop_share`: fixed by the seed, the sender and the exchange, so every model
    and every robot receiving j's maps sees the same losses)."""
    from tcaff_gtsam.node.node import _draw

    if share == 0:
        return np.zeros(steps, bool)
    return np.array([_draw(seed, str(j), s) < share for s in range(steps)])


# -- the table ---------------------------------------------------------------------------------


#: fewer episodes than this give no interval: resampling two or three pairs bounds nothing
MIN_EPISODES = 5


def mean_interval(values: np.ndarray, episode: np.ndarray, draws: int = 2000
                  ) -> tuple[float, float]:
    """95 % interval of the mean of `values` (n,) by a bootstrap over their episodes (n,)
    labels: consecutive estimates of one robot pair share their error, so the pair (both
    directions) is the unit that is drawn again, not the estimate. A data set of few
    episodes gives a wide interval: its mean says little about the covariance."""
    labels, index = np.unique(episode, return_inverse=True)
    if labels.size < MIN_EPISODES:
        return math.nan, math.nan
    sums = np.bincount(index, values, minlength=labels.size)
    counts = np.bincount(index, minlength=labels.size)
    rng = np.random.default_rng(0)
    draw = rng.integers(0, labels.size, (draws, labels.size))
    means = sums[draw].sum(axis=1) / counts[draw].sum(axis=1)
    lo, hi = np.quantile(means, [0.025, 0.975])
    return float(lo), float(hi)


def summary(parts: list[dict]) -> dict:
    """The table's numbers of one data set and model from its runs' `run_source` results."""
    e, P, values, ok, held, episode, taken, taken_s = (
        np.concatenate([p[key] for p in parts])
        for key in ("errors", "P", "nees", "ok", "held", "episode", "taken", "taken_s"))
    overlap = sum(p["overlap"] for p in parts)
    jitter = np.concatenate([p["jitter"] for p in parts])
    out = {"est": len(e), "available": sum(p["available"] for p in parts) / max(overlap, 1),
           "correct": sum(p["correct"] for p in parts) / max(overlap, 1),
           "jitter": float(jitter.mean()) if jitter.size else math.nan}
    if not len(e):
        return out
    bad = ~ok
    sigma = np.sqrt(np.diagonal(P, axis1=1, axis2=2))
    out.update(
        nees_mean=float(values.mean()), nees_median=float(np.median(values)),
        episodes=len(np.unique(episode)), nees_interval=mean_interval(values, episode),
        under=float(np.mean(values < NEES_95)),
        nees_ok=mean_where(values, ~bad), nees_held=mean_where(values, held & ~bad),
        nees_measured=mean_where(values, ~held & ~bad), nees_R=mean_where(taken, ~held & ~bad),
        nees_Rs=mean_where(taken_s, ~held & ~bad),
        wrong=float(bad.mean()), outside=mean_where(values > NEES_997, bad),
        ratio=(np.sqrt(np.mean((e[~bad] / sigma[~bad]) ** 2, axis=0)) if (~bad).any()
               else np.full(3, math.nan)),
        sigma=np.sqrt(np.mean(sigma**2, axis=0)))
    return out


def mean_where(values: np.ndarray, mask: np.ndarray) -> float:
    """Mean of values (n,) where mask (n,) bool holds; NaN where it holds nowhere."""
    return float(values[mask].mean()) if mask.any() else math.nan


def print_table(results: list[dict], models: list[str]) -> None:
    """One row per data set and model (see the module's notes for the columns)."""
    groups = list(dict.fromkeys(r["group"] for r in results))
    print(f"{'data set':26} {'model':19} {'est':>6} {'pairs':>5} {'mean':>7} "
          f"{'95 % of mean':>15} "
          f"{'median':>6} {'<7.81':>6} "
          f"{'ok mean':>7} {'held':>6} {'meas':>6} {'R':>6} {'R_s':>6} {'wrong':>6} "
          f"{'outside':>7} "
          f"{'x':>5} {'y':>5} {'th':>5} "
          f"{'sig m':>6} {'sig deg':>7} {'avail':>6} {'correct':>7} {'jitter':>6}")
    for group in groups:
        for model in models:
            parts = [r for r in results if r["group"] == group and r["model"] == model]
            if not parts:
                continue
            r = summary(parts)
            head = f"{group:26} {model:19} {r['est']:6d}"
            tail = f"{r['available']:6.3f} {r['correct']:7.3f} {r['jitter']:6.2f}"
            if not r["est"]:
                blank = " ".join(f"{'':>{w}}" for w in (15, 6, 6, 7, 6, 6, 6, 6, 6, 7, 5, 5, 5, 6,
                                                        7))
                print(f"{head} {'':>5} {'-':>7} {blank} {tail}")
                continue
            outside = "-" if math.isnan(r["outside"]) else f"{r['outside']:.2f}"
            held, measured, R, R_s = ("-" if math.isnan(r[key]) else f"{r[key]:.2f}"
                                      for key in ("nees_held", "nees_measured", "nees_R",
                                                  "nees_Rs"))
            x, y, th = r["ratio"]
            lo, hi = r["nees_interval"]
            interval = "-" if math.isnan(lo) else f"{lo:.2f}-{hi:.2f}"
            print(f"{head} {r['episodes']:5d} {r['nees_mean']:7.2f} {interval:>15} "
                  f"{r['nees_median']:6.2f} {r['under']:6.3f} "
                  f"{r['nees_ok']:7.2f} {held:>6} {measured:>6} {R:>6} {R_s:>6} "
                  f"{r['wrong']:6.3f} "
                  f"{outside:>7} {x:5.2f} {y:5.2f} "
                  f"{th:5.2f} {math.hypot(*r['sigma'][:2]):6.3f} "
                  f"{math.degrees(r['sigma'][2]):7.2f} {tail}")


def run_arguments(parser: argparse.ArgumentParser, data: list[str]) -> None:
    """The arguments that pick this script's runs (--data, default `data`; --seeds;
    --sim-seeds; --cache), for it and the scripts that read the same runs."""
    parser.add_argument("--data", nargs="+", default=data, choices=["mrclam", "kitchen", "sim"],
                        help="data sets to run")
    parser.add_argument("--seeds", type=int, default=3,
                        help="seeds of the VIO-like odometry (MRCLAM and kitchen)")
    parser.add_argument("--sim-seeds", type=int, default=2, help="seeds per sim scenario")
    parser.add_argument("--cache", type=Path, default=Path("results/bench_nees"),
                        help="folder of the cached runs (shared by bench_nees.py, "
                        "fit_covariance_parts.py and twin_nees.py)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    run_arguments(parser, ["mrclam", "kitchen", "sim"])
    parser.add_argument("--models", nargs="+", default=["today"],
                        choices=list(MODELS), help="covariance models to compare")
    parser.add_argument("--methods", default="library", choices=["library", "dataset"],
                        help="library: PairwiseAligner's defaults (with the run's kappa and "
                        "W); dataset: the method set the project's command runs (mrclam: "
                        "repetitive, kitchen: camera, sim: default)")
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS,
                        help="simulator scenarios")
    parser.add_argument("--spans", nargs="+", type=float, default=[20.0, 150.0],
                        help="MRCLAM map spans kappa, s")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    parser.add_argument("--lost", type=float, default=0.0,
                        help="share of each robot's maps lost at random (a busy machine, a "
                        "lossy link, as a team node's --drop-share): a pair's filter skips "
                        "the steps whose other map is lost, which count neither as overlap "
                        "nor as estimates")
    parser.add_argument("--lost-seed", type=int, default=0,
                        help="seed of the exchanges --lost loses")
    parser.add_argument("--every", type=int, default=1,
                        help="exchange maps every this many of the data's steps (1 s each): "
                        "2 is an exchange every 2 s")
    args = parser.parse_args()
    if not 0.0 <= args.lost < 1.0:
        parser.error(f"--lost must be in [0, 1), got {args.lost}")
    if args.every < 1:
        parser.error(f"--every must be at least 1, got {args.every}")
    todo = [(s, m) for s in sources(args.data, args.seeds, args.sim_seeds, args.scenarios,
                                    args.spans)
            for m in args.models]
    # build each run once before the pool races to cache it
    for s in dict.fromkeys(s for s, _ in todo):
        load(s, args.cache)
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(run_source, *zip(*todo, strict=True),
                                [args.methods] * len(todo), [args.cache] * len(todo),
                                [args.lost] * len(todo), [args.lost_seed] * len(todo),
                                [args.every] * len(todo)))
    lost = (f", {args.lost:.0%} of the exchanges lost (seed {args.lost_seed})" if args.lost
            else "") + (f", an exchange every {args.every} s" if args.every > 1 else "")
    print(f"{len(todo)} runs in {time.perf_counter() - start:.0f} s ({args.methods} methods"
          f"{lost})")
    print_table(results, args.models)
    seconds: dict[str, float] = {}
    for r in results:
        seconds[r["group"]] = seconds.get(r["group"], 0.0) + r["seconds"]
    print("seconds per data set (all models): " + ", ".join(f"{g} {s:.0f}"
                                                         for g, s in seconds.items()))


if __name__ == "__main__":
    main()
