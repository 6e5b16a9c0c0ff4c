"""Which part of one registration's covariance R_s is off, per data set.

`calibrated_covariance` builds R_s from three parts: the point noise s~^2 G, the map drift's
translation (kappa / 2 d_t^2 on x and y) and its heading (kappa / 2 d_theta^2 J J', a turn
about the registered objects). For every measurement TCAFF's best path takes (library
defaults, the runs of `bench_nees.py`), this records the three parts of its R_s and its error
e = z - truth, keeps the correct ones (within 1 m and 5 deg: where many are wrong the errors'
tail is cut off and the scales come out low), and fits one scale per part,
a, b_t, b_theta, maximising the Gaussian likelihood of the errors under
a point + b_t translation + b_theta heading. 1 for each says the part is right; a scale of
the drift parts says how much more (or less) drift the errors show than `map_drift` gives,
to compare with what the data set's odometry declares (the variance ratio of
`bench_nees.declared_drift` to `map_drift`, printed beside it).

    python scripts/fit_covariance_parts.py [--data sim kitchen mrclam] [--seeds 3]
                                           [--sim-seeds 2] [--cache results/bench_nees]

Columns: n (measurements), the NEES of z against R_s itself (3 when R_s is right), the three
fitted scales, the declared ones (translation, heading; "-" where the odometry declares
nothing), the mean association count k, and two measures of how much of a registration's
error the next one repeats (what `repeat_inflation` assumes all of):

  step      over consecutive correct measurements of one hypothesis at consecutive steps, the
            mean of d' (R_s,k-1 + R_s,k)^-1 d / 3, d the change of z less the true change: the
            fresh share of the error times R_s's scale (0 when every registration repeats the
            last one's error, the NEES of R_s / 3 when none does). This one a filter could
            measure without the truth.
  fresh     step divided by the NEES of R_s / 3: the fresh share itself (needs the truth).

With --by-objects a second table splits each data set's measurements by the number of
associations k they register (buckets of `K_BUCKETS`): the NEES of z against R_s (mean,
median, 90th percentile, share under 7.815; chi-square with 3 dof: 3, 2.37, 6.25, 0.95) and
the mean of e_k^2 / R_s,kk for x, y and theta, whether R_s follows the count of objects.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from bench_nees import (
    SCENARIOS,
    declared_drift,
    library_params,
    load,
    run_arguments,
    sources,
)
from scipy.optimize import minimize
from tcaff_gtsam.eval.metrics import Thresholds, step_errors
from tcaff_gtsam.eval.runs import directed_pairs

from tcaff_gtsam import frame_aligner
from tcaff_gtsam.covariance import _single_registration_parts
from tcaff_gtsam.geometry import se2_to_params, wrap_angle
from tcaff_gtsam.pairwise import PairwiseAligner
from tcaff_gtsam.params import FrameAlignerParams

#: R (the aligner's output, as bytes) -> the parts of its R_s, filled while a run goes
_PARTS: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, int]] = {}


def _recording(covariance):
    """`frame_aligner._calibrated_covariance` that also records each R's parts."""
    def calibrated(T, p, q, w, kappa, noise_prior, prior_dof, drift, rho, Q_inv):
        R = covariance(T, p, q, w, kappa, noise_prior, prior_dof, drift, rho, Q_inv)
        _PARTS[R.tobytes()] = (*_single_registration_parts(T, p, q, w, kappa, noise_prior,
                                                           prior_dof, drift), len(w))
        return R
    return calibrated


def measurements(source, cache: Path) -> list[tuple]:
    """(error (3,), point, translation, heading parts (3, 3), k, step) of every correct
    measurement the best paths of the run's pairs took; step: d' (R_s,k-1 + R_s,k)^-1 d / 3 of
    its change d from the previous step's correct measurement of the same hypothesis, less
    the true change (NaN without one). Needs `_recording` in place (`main` puts it)."""
    run = load(source, cache)
    aligner, tcaff = library_params(run)
    limits = Thresholds()
    rows = []
    for i, j in directed_pairs(run):
        _PARTS.clear()
        pair = PairwiseAligner(aligner, tcaff)
        T_true = run.T_true(i, j)
        truth = se2_to_params(T_true)
        last = None  # (step, hypothesis, z, R_s) of the previous correct measurement
        for s, t in enumerate(run.times):
            est = pair.update(float(t), run.maps[i][s], run.maps[j][s])
            if est is None or est.measurement < 0 or not np.all(np.isfinite(truth[s])):
                continue
            taken = pair.taken[est.measurement]
            parts = _PARTS.get(taken.R.tobytes())
            if parts is None:
                raise RuntimeError(f"{source.name}: a measurement's R was not recorded (is "
                                   "frame_aligner._calibrated_covariance recording?)")
            if not limits.correct(step_errors(T_true[s:s + 1],
                                                               taken.z[None]))[0]:
                continue
            e = taken.z - truth[s]
            e[2] = wrap_angle(e[2])
            R_s = parts[0] + parts[1] + parts[2]
            step = math.nan
            if last is not None and last[0] == s - 1 and last[1] == est.hypothesis:
                d = taken.z - last[2] - (truth[s] - truth[s - 1])
                d[2] = wrap_angle(d[2])
                step = float(d @ np.linalg.solve(last[3] + R_s, d)) / 3
            last = (s, est.hypothesis, taken.z, R_s)
            rows.append((e, *parts, step))
    return rows


def fit(rows: list[tuple]) -> tuple[float, np.ndarray]:
    """The NEES of the errors against R_s, and the scales (3,) of its parts that best
    explain them."""
    e = np.array([r[0] for r in rows])
    parts = np.array([[r[1], r[2], r[3]] for r in rows])  # (n, 3, 3, 3)

    def whitened(S):
        return np.einsum("ni,ni->n", e, np.linalg.solve(S, e[..., None])[..., 0])

    def nll(log_scale):
        S = np.einsum("k,nkij->nij", np.exp(log_scale), parts) + 1e-12 * np.eye(3)
        return float(np.sum(np.linalg.slogdet(S)[1] + whitened(S)))

    best = minimize(nll, np.zeros(3), method="Nelder-Mead",
                    options={"maxiter": 2000, "xatol": 1e-3, "fatol": 1e-3})
    return float(whitened(parts.sum(axis=1)).mean()), np.exp(best.x)


#: the buckets [low, high) of association counts k that --by-objects splits by
K_BUCKETS = ((0, 6), (6, 8), (8, 12), (12, 10_000))


def by_objects(group: str, rows: list[tuple]) -> None:
    """Print the --by-objects rows of one data set (see the module's notes)."""
    e = np.array([r[0] for r in rows])
    R_s = np.array([r[1] + r[2] + r[3] for r in rows])
    k = np.array([r[4] for r in rows])
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(R_s, e[..., None])[..., 0])
    parts = e**2 / np.diagonal(R_s, axis1=1, axis2=2)
    for low, high in K_BUCKETS:
        m = (k >= low) & (k < high)
        if m.sum() < 8:
            continue
        v = nees[m]
        span = f"{low}-{high - 1}" if high < K_BUCKETS[-1][1] else f">= {low}"
        x, y, th = parts[m].mean(axis=0)
        print(f"{group:24} {span:>6} {m.sum():>6} {v.mean():>6.2f} {np.median(v):>6.2f} "
              f"{np.quantile(v, 0.9):>6.2f} {np.mean(v < 7.815):>6.3f} {x:>5.2f} {y:>5.2f} "
              f"{th:>5.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    run_arguments(parser, ["sim", "kitchen", "mrclam"])
    parser.add_argument("--by-objects", action="store_true",
                        help="also split each data set's NEES by the association count k")
    args = parser.parse_args()
    frame_aligner._calibrated_covariance = _recording(frame_aligner._calibrated_covariance)
    default = FrameAlignerParams().map_drift
    groups: dict[str, list] = {}
    declared: dict[str, tuple[float, float]] = {}
    for source in sources(args.data, args.seeds, args.sim_seeds, list(SCENARIOS),
                          [20.0, 150.0]):
        groups.setdefault(source.group, []).extend(measurements(source, args.cache))
        drift = declared_drift(load(source, args.cache), source, default)
        declared[source.group] = (drift if drift is not default
                                  else (math.nan, math.nan))
    print(f"{'data set':24} {'n':>6} {'NEES R_s':>8} {'point':>6} {'drift t':>7} "
          f"{'drift th':>8} {'declared t, th':>15} {'k':>5} {'step':>5} {'fresh':>5}")
    for group, rows in groups.items():
        if len(rows) < 10:
            print(f"{group:24} {len(rows):>6}  too few correct measurements to fit")
            continue
        nees, (a, b_t, b_theta) = fit(rows)
        d_t, d_theta = declared[group]
        ratio = "-" if math.isnan(d_t) else (f"{(d_t / default[0]) ** 2:.2f}, "
                                              f"{(d_theta / default[1]) ** 2:.2f}")
        k = np.mean([r[4] for r in rows])
        step = np.nanmean([r[5] for r in rows]) if any(np.isfinite(r[5]) for r in rows) \
            else math.nan
        print(f"{group:24} {len(rows):>6} {nees:>8.2f} {a:>6.2f} {b_t:>7.2f} {b_theta:>8.2f} "
              f"{ratio:>15} {k:>5.1f} {step:>5.2f} {step / (nees / 3):>5.2f}", flush=True)
    if args.by_objects:
        print(f"\n{'data set':24} {'k':>6} {'n':>6} {'mean':>6} {'median':>6} {'p90':>6} "
              f"{'<7.81':>6} {'x':>5} {'y':>5} {'th':>5}")
        for group, rows in groups.items():
            by_objects(group, rows)


if __name__ == "__main__":
    main()
