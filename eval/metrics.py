"""Evaluation metrics of frame alignment for directed robot pairs.

For a directed pair (i, j) the estimator outputs, at each step of a run, either nothing or an
estimate of T_oi_oj, the transform mapping robot j's odometry frame into robot i's. The error of an
estimate is the SE(2) transform T_gt^-1 T_est, expressed in the frame of the truth (the oj frame):
its translation norm [m] and the absolute value of its heading [rad]. From the per-step errors this
module derives

* the mean and standard deviation of the translation and heading errors over the steps that have
  an estimate,
* availability: the share of the steps at which the maps overlap (an alignment is possible) that
  have an estimate,
* correct availability: the share of the overlap steps that have an estimate within both
  thresholds, so a method that answers often but wrongly does not look available,
* false accept rate: the share of estimates off by more than a translation or heading threshold,
* time to first correct: seconds from the first overlap step to the first estimate within both
  thresholds,
* the relative pose error (RPE): the error of robot j's body pose seen from robot i's body,
  T_bi_bj = T_oi_bi^-1 T_oi_oj T_oj_bj, which is what a robot acting on the alignment experiences.
  Its translation is evo's APE (translation part) of robot j's path in robot i's odometry frame,
  T_oi_oj T_oj_bj, against the true path (the rotation T_bi_oi keeps norms);
* the APE and RPE of that path as evo defines them (`PairTrace.path_errors`): the RMSE that
  `evo_ape tum` and `evo_rpe tum` print on the exported trajectories (see `trajectories`).

`pooled_metrics` pools several pairs (or seeds) into one summary by concatenating their per-step
errors. SI units throughout (metres, radians, seconds); only `Metrics.as_report` gives degrees.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from numbers import Real

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import compose, invert, se2_error, se2_from_params

__all__ = [
    "Metrics",
    "PairTrace",
    "Thresholds",
    "pair_metrics",
    "pooled_metrics",
    "relative_pose_errors",
    "step_errors",
]

# Tolerance on R^T R = I, det R = 1 and the bottom row (0, 0, 1) of an SE(2) matrix; loose enough
# for transforms that went through float32 files or long chains of products.
_SE2_TOL = 1e-6


@dataclass(frozen=True)
class Thresholds:
    """Limits beyond which an estimate counts as wrong (a false accept).

    translation: metres; heading: radians. An estimate is correct when both errors are <= their
    threshold and a false accept when either exceeds it.
    """

    translation: float = 1.0
    heading: float = math.radians(5.0)

    def __post_init__(self) -> None:
        for name in ("translation", "heading"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, Real)
                    or not math.isfinite(value) or value <= 0):
                raise ConfigError(f"Thresholds.{name}: expected a finite number > 0, "
                                  f"got {value!r}")


def _as_se2_stack(T, name: str, n: int | None = None) -> np.ndarray:
    """Check that T is a finite (n, 3, 3) stack of SE(2) matrices; return it as a float array."""
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (3, 3) or (n is not None and T.shape[0] != n):
        expected = f"({'S' if n is None else n}, 3, 3)"
        raise DataError(f"{name}: expected shape {expected}, got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise DataError(f"{name}: contains non-finite values")
    R = T[:, :2, :2]
    ortho = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(2)).max(axis=(1, 2), initial=0.0)
    det = np.linalg.det(R) if len(T) else np.zeros(0)
    bottom = np.abs(T[:, 2, :] - [0.0, 0.0, 1.0]).max(axis=1, initial=0.0)
    bad = np.flatnonzero((ortho > _SE2_TOL) | (np.abs(det - 1.0) > _SE2_TOL)
                         | (bottom > _SE2_TOL))
    if bad.size:
        raise DataError(f"{name}: not an SE(2) matrix at step(s) {bad[:5].tolist()}")
    return T


def _as_estimate(estimate, name: str, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Check an (n, 3) estimate array; return it and the (n,) mask of steps with an estimate."""
    estimate = np.asarray(estimate, dtype=float)
    if estimate.ndim != 2 or estimate.shape[1] != 3 or (n is not None and estimate.shape[0] != n):
        expected = f"({'S' if n is None else n}, 3)"
        raise DataError(f"{name}: expected shape {expected}, got {estimate.shape}")
    missing = np.all(np.isnan(estimate), axis=1)
    bad = np.flatnonzero(~missing & ~np.all(np.isfinite(estimate), axis=1))
    if bad.size:
        raise DataError(f"{name}: rows must be all finite or all NaN (no estimate); "
                        f"partly non-finite at step(s) {bad[:5].tolist()}")
    return estimate, ~missing


def _errors(T_true: np.ndarray, estimate: np.ndarray, has: np.ndarray) -> np.ndarray:
    """(S, 2) errors of validated inputs, NaN rows where `has` is False."""
    # se2_error rejects NaN, so the missing rows are scored against a placeholder and blanked after
    filled = np.where(has[:, None], estimate, 0.0)
    err = se2_error(T_true, se2_from_params(filled))
    err[~has] = np.nan
    return err


def step_errors(T_true, estimate) -> np.ndarray:
    """Per-step error of an alignment estimate against the truth.

    T_true: (S, 3, 3) true T_oi_oj. estimate: (S, 3) estimated (x [m], y [m], theta [rad]) of
    T_oi_oj, a row of NaN meaning no estimate at that step.
    Returns (S, 2): translation norm [m] and |heading| [rad] of T_true^-1 T_est (the error in the
    truth's oj frame); NaN rows where there is no estimate.
    """
    estimate, has = _as_estimate(estimate, "estimate")
    T_true = _as_se2_stack(T_true, "T_true", estimate.shape[0])
    return _errors(T_true, estimate, has)


@dataclass(frozen=True)
class PairTrace:
    """Everything needed to score one directed pair (i, j) over a run of S steps.

    times: (S,) seconds, strictly increasing.
    T_true: (S, 3, 3) true T_oi_oj at each step.
    estimate: (S, 3) estimated (x [m], y [m], theta [rad]) of T_oi_oj; a row of NaN = no estimate.
    overlap: (S,) bool, steps at which the two maps share enough objects for an alignment.
    T_oi_bi: (S, 3, 3) robot i's odometry pose (its body bi in its odometry frame oi).
    T_oj_bj: (S, 3, 3) robot j's odometry pose.

    The arrays are stored as read-only float (bool for overlap) copies.
    """

    times: np.ndarray
    T_true: np.ndarray
    estimate: np.ndarray
    overlap: np.ndarray
    T_oi_bi: np.ndarray
    T_oj_bj: np.ndarray

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        if times.ndim != 1 or times.shape[0] == 0:
            raise DataError(f"PairTrace.times: expected shape (S,) with S >= 1, got {times.shape}")
        if not np.all(np.isfinite(times)):
            raise DataError("PairTrace.times: contains non-finite values")
        if np.any(np.diff(times) <= 0):
            k = int(np.flatnonzero(np.diff(times) <= 0)[0])
            raise DataError(f"PairTrace.times: must be strictly increasing, but times[{k + 1}] = "
                            f"{times[k + 1]} <= times[{k}] = {times[k]}")
        n = times.shape[0]
        estimate, _ = _as_estimate(self.estimate, "PairTrace.estimate", n)
        overlap = np.asarray(self.overlap)
        if overlap.shape != (n,):
            raise DataError(f"PairTrace.overlap: expected shape ({n},), got {overlap.shape}")
        if overlap.dtype != bool:
            # 0/1 integers are accepted; anything else is more likely a mistake than a flag
            if not (np.issubdtype(overlap.dtype, np.number) and np.all(np.isin(overlap, (0, 1)))):
                raise DataError(f"PairTrace.overlap: expected booleans, got dtype {overlap.dtype}")
            overlap = overlap.astype(bool)
        fields = {
            "times": times,
            "T_true": _as_se2_stack(self.T_true, "PairTrace.T_true", n),
            "estimate": estimate,
            "overlap": overlap,
            "T_oi_bi": _as_se2_stack(self.T_oi_bi, "PairTrace.T_oi_bi", n),
            "T_oj_bj": _as_se2_stack(self.T_oj_bj, "PairTrace.T_oj_bj", n),
        }
        for name, value in fields.items():
            value = np.array(value, copy=True)
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def n_steps(self) -> int:
        """Number of steps S."""
        return int(self.times.shape[0])

    @property
    def has_estimate(self) -> np.ndarray:
        """(S,) bool, steps at which there is an estimate."""
        return ~np.all(np.isnan(self.estimate), axis=1)

    @cached_property
    def path_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """APE and RPE (translation parts, metres) of robot j's path in robot i's odometry
        frame, P = T_oi_oj_est T_oj_bj against Q = T_oi_oj_true T_oj_bj, over the steps with an
        estimate, as evo defines them (`evo_ape tum` and `evo_rpe tum` with their defaults;
        the tests compare the two).

        Returns:
            ape: (k,) |t(P) - t(Q)| at each of the k steps with an estimate.
            rpe: (max(k - 1, 0),) |t((Q_a^-1 Q_b)^-1 P_a^-1 P_b)| over consecutive steps a, b
                with an estimate: how much the path jumps when the alignment changes.
        """
        has = self.has_estimate
        truth = compose(self.T_true[has], self.T_oj_bj[has])
        path = compose(se2_from_params(self.estimate[has]), self.T_oj_bj[has])
        ape = np.linalg.norm(path[:, :2, 2] - truth[:, :2, 2], axis=1)
        if ape.shape[0] < 2:
            return ape, np.zeros(0)
        moved_truth = compose(invert(truth[:-1]), truth[1:])
        moved_path = compose(invert(path[:-1]), path[1:])
        rpe = np.linalg.norm(compose(invert(moved_truth), moved_path)[:, :2, 2], axis=1)
        return ape, rpe


def relative_pose_errors(trace: PairTrace) -> np.ndarray:
    """Per-step error of robot j's body pose seen from robot i's body.

    Estimated T_bi_bj = T_oi_bi^-1 T_est T_oj_bj against the true T_oi_bi^-1 T_true T_oj_bj.
    Returns (S, 2): translation norm [m] and |heading| [rad] of T_bi_bj_true^-1 T_bi_bj_est, in
    robot j's body frame; NaN rows where there is no estimate. A heading error of the alignment
    grows into a translation error proportional to robot j's distance from the origin of oj.
    """
    has = trace.has_estimate
    T_est = se2_from_params(np.where(has[:, None], trace.estimate, 0.0))
    T_bi_oi = invert(trace.T_oi_bi)
    err = se2_error(compose(T_bi_oi, trace.T_true, trace.T_oj_bj),
                    compose(T_bi_oi, T_est, trace.T_oj_bj))
    err[~has] = np.nan
    return err


@dataclass(frozen=True)
class Metrics:
    """Scores of one directed pair, or of several pooled together.

    Counts: n_steps, n_estimates (steps with an estimate), n_overlap (steps with map overlap).
    translation_mean/std/median [m], heading_mean/std [rad]: over the steps with an estimate,
    population standard deviation (ddof=0); NaN if there is no estimate.
    availability: share of overlap steps that have an estimate (NaN if no overlap).
    correct_availability: share of overlap steps whose estimate is within both thresholds (NaN
    if no overlap); availability * (1 - false_accept) when every estimate falls on an overlap
    step.
    false_accept: share of estimates whose error exceeds either threshold (NaN if no estimates).
    time_to_first_correct [s]: from the first overlap step to the first step, at or after it, whose
    estimate is within both thresholds (NaN if never or no overlap); pooled, the mean over the
    pairs that have one.
    rpe_translation_mean [m], rpe_heading_mean [rad]: relative pose error of robot j seen from
    robot i, over the steps with an estimate.
    ape_rmse, rpe_rmse [m]: the APE and RPE of robot j's path in robot i's frame
    (`PairTrace.path_errors`), root mean square over the estimate steps (RPE: over their
    consecutive pairs).
    """

    n_steps: int
    n_estimates: int
    n_overlap: int
    translation_mean: float
    translation_std: float
    translation_median: float
    heading_mean: float
    heading_std: float
    availability: float
    correct_availability: float
    false_accept: float
    time_to_first_correct: float
    rpe_translation_mean: float
    rpe_heading_mean: float
    ape_rmse: float
    rpe_rmse: float

    def as_report(self) -> dict[str, float | int | None]:
        """JSON-ready dictionary, keys carrying units, headings in degrees, NaN as None."""

        def num(value: float, scale: float = 1.0) -> float | None:
            return None if math.isnan(value) else float(value) * scale

        deg = math.degrees(1.0)
        return {
            "translation_error_m_mean": num(self.translation_mean),
            "translation_error_m_std": num(self.translation_std),
            "translation_error_m_median": num(self.translation_median),
            "heading_error_deg_mean": num(self.heading_mean, deg),
            "heading_error_deg_std": num(self.heading_std, deg),
            "availability": num(self.availability),
            "correct_availability": num(self.correct_availability),
            "false_accept": num(self.false_accept),
            "time_to_first_correct_s": num(self.time_to_first_correct),
            "rpe_translation_m": num(self.rpe_translation_mean),
            "rpe_heading_deg": num(self.rpe_heading_mean, deg),
            "ape_m": num(self.ape_rmse),
            "rpe_m": num(self.rpe_rmse),
            "n_steps": int(self.n_steps),
            "n_estimates": int(self.n_estimates),
            "n_overlap": int(self.n_overlap),
        }


def _time_to_first_correct(trace: PairTrace, correct: np.ndarray) -> float:
    """Seconds from the first overlap step to the first correct step at or after it, or NaN."""
    overlap_steps = np.flatnonzero(trace.overlap)
    if overlap_steps.size == 0:
        return math.nan
    first = overlap_steps[0]
    # a correct estimate before any overlap is luck or a prior, not the alignment being found
    later = np.flatnonzero(correct[first:])
    if later.size == 0:
        return math.nan
    return float(trace.times[first + later[0]] - trace.times[first])


def _rmse(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def _share(numerator: int, denominator: int) -> float:
    return numerator / denominator if denominator else math.nan


def _mean_std(values: np.ndarray) -> tuple[float, float]:
    if values.size == 0:
        return math.nan, math.nan
    return float(np.mean(values)), float(np.std(values))


def pooled_metrics(traces: Sequence[PairTrace], thresholds: Thresholds | None = None) -> Metrics:
    """Scores of several traces (pairs, seeds) pooled into one summary.

    Means and standard deviations run over the estimate steps of all traces together, and
    availability and false_accept are shares over all their steps together, so pooling equals
    scoring the concatenated run. time_to_first_correct is the mean over the traces that have one.
    Raises DataError on an empty sequence.
    """
    traces = list(traces)
    if not traces:
        raise DataError("pooled_metrics: need at least one PairTrace, got none")
    for k, trace in enumerate(traces):
        if not isinstance(trace, PairTrace):
            raise DataError(f"pooled_metrics: traces[{k}] is a {type(trace).__name__}, "
                            "not a PairTrace")
    thresholds = Thresholds() if thresholds is None else thresholds

    errs, rpes, ttfcs, apes, rpe_paths = [], [], [], [], []
    n_steps = n_overlap = n_available = n_correct = 0
    for trace in traces:
        has = trace.has_estimate
        err = _errors(trace.T_true, trace.estimate, has)
        # NaN compares False, so steps without an estimate are never correct
        correct = (err[:, 0] <= thresholds.translation) & (err[:, 1] <= thresholds.heading)
        errs.append(err[has])
        rpes.append(relative_pose_errors(trace)[has])
        ttfcs.append(_time_to_first_correct(trace, correct))
        ape, rpe_path = trace.path_errors
        apes.append(ape)
        rpe_paths.append(rpe_path)
        n_steps += trace.n_steps
        n_overlap += int(np.count_nonzero(trace.overlap))
        n_available += int(np.count_nonzero(trace.overlap & has))
        n_correct += int(np.count_nonzero(trace.overlap & correct))

    err = np.concatenate(errs)
    rpe = np.concatenate(rpes)
    n_estimates = err.shape[0]
    wrong = (err[:, 0] > thresholds.translation) | (err[:, 1] > thresholds.heading)
    translation_mean, translation_std = _mean_std(err[:, 0])
    heading_mean, heading_std = _mean_std(err[:, 1])
    found = [t for t in ttfcs if not math.isnan(t)]
    return Metrics(
        n_steps=n_steps,
        n_estimates=n_estimates,
        n_overlap=n_overlap,
        translation_mean=translation_mean,
        translation_std=translation_std,
        translation_median=float(np.median(err[:, 0])) if n_estimates else math.nan,
        heading_mean=heading_mean,
        heading_std=heading_std,
        availability=_share(n_available, n_overlap),
        correct_availability=_share(n_correct, n_overlap),
        false_accept=_share(int(np.count_nonzero(wrong)), n_estimates),
        time_to_first_correct=float(np.mean(found)) if found else math.nan,
        rpe_translation_mean=_mean_std(rpe[:, 0])[0],
        rpe_heading_mean=_mean_std(rpe[:, 1])[0],
        ape_rmse=_rmse(np.concatenate(apes)),
        rpe_rmse=_rmse(np.concatenate(rpe_paths)),
    )


def pair_metrics(trace: PairTrace, thresholds: Thresholds | None = None) -> Metrics:
    """Scores of one directed pair over its run; see `Metrics` for the definitions."""
    return pooled_metrics([trace], thresholds)
