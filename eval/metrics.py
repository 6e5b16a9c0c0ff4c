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
* the same per overlap (`overlap_spans`: maximal runs of overlap steps, short gaps bridged): the
  median over the overlaps of the seconds from an overlap's first step to the first correct
  estimate inside it, and the share of overlaps that got one at all,
* the NEES of each estimate against the covariance its method reported with it (`step_nees`):
  its mean, the share under the chi-square(3) 95 % bound `NEES_95`, and the confident false
  accepts, estimates off by more than a threshold AND outside their own 99.7 % ellipse
  (NEES > `NEES_997`); undefined (NaN) for a method that reports no covariance,
* judge availability: the share of overlap steps at which a perfect judge of the candidates
  the TCAFF filter was offered holds a correct alignment (`perfect_judge`), what any filter of
  those candidates could reach at best; undefined for traces without candidates,
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
from numbers import Integral, Real

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import (
    _chi2_quantile,
    compose,
    invert,
    se2_error,
    se2_from_params,
    se2_to_params,
    wrap_angle,
)

__all__ = [
    "NEES_95",
    "NEES_997",
    "Metrics",
    "PairTrace",
    "Thresholds",
    "overlap_spans",
    "pair_metrics",
    "perfect_judge",
    "pooled_metrics",
    "relative_pose_errors",
    "step_errors",
    "step_nees",
]

# Tolerance on R^T R = I, det R = 1 and the bottom row (0, 0, 1) of an SE(2) matrix; loose enough
# for transforms that went through float32 files or long chains of products.
_SE2_TOL = 1e-6
# Tolerance on P = P^T of a covariance, relative to its largest entry: products like J S J^T
# (the graph's marginals) are symmetric only to rounding.
_SYMMETRY_TOL = 1e-8

#: chi-square(3) quantiles bounding the NEES of a consistent estimate of (x, y, theta): it falls
#: below NEES_95 (7.815) on 95 % of the steps; beyond NEES_997 (14.16) it lies outside its
#: 99.73 % ellipse, the probability of 3 sigma in one dimension (erf(3 / sqrt 2)): its own
#: covariance calls its error all but impossible.
NEES_95 = _chi2_quantile(0.95, 3)
NEES_997 = _chi2_quantile(math.erf(3.0 / math.sqrt(2.0)), 3)


@dataclass(frozen=True)
class Thresholds:
    """Limits beyond which an estimate counts as wrong (a false accept), and how overlaps and
    the perfect judge are delimited.

    translation: metres; heading: radians. An estimate is correct when both errors are <= their
        threshold and a false accept when either exceeds it.
    overlap_gap_steps: fewer consecutive steps without overlap than this, between two overlap
        steps, do not end an overlap (`overlap_spans`). The default, 5 steps, is 5 s at the
        1 Hz exchanges: a robot looking away for a moment does not start a new overlap.
    judge_hold: seconds the perfect judge holds the last candidate it took (`perfect_judge`).
        The default, 40 s, is how long TCAFF holds its estimate after its last measurement
        (its main tree lives 40 steps without one).
    """

    translation: float = 1.0
    heading: float = math.radians(5.0)
    overlap_gap_steps: int = 5
    judge_hold: float = 40.0

    def __post_init__(self) -> None:
        for name in ("translation", "heading"):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, Real)
                    or not math.isfinite(value) or value <= 0):
                raise ConfigError(f"Thresholds.{name}: expected a finite number > 0, "
                                  f"got {value!r}")
        gap = self.overlap_gap_steps
        if isinstance(gap, bool) or not isinstance(gap, Integral) or gap < 1:
            raise ConfigError(f"Thresholds.overlap_gap_steps: expected an int >= 1, got {gap!r}")
        hold = self.judge_hold
        if (isinstance(hold, bool) or not isinstance(hold, Real) or not math.isfinite(hold)
                or hold < 0):
            raise ConfigError(f"Thresholds.judge_hold: expected a finite number of seconds "
                              f">= 0, got {hold!r}")

    def correct(self, err: np.ndarray) -> np.ndarray:
        """(...,) bool: errors (..., 2) of `step_errors` within both thresholds (NaN errors,
        steps without an estimate, are not)."""
        return (err[..., 0] <= self.translation) & (err[..., 1] <= self.heading)


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


def _floats(value, name: str) -> np.ndarray:
    """`value` as a float array, or a DataError naming it."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name}: expected real numbers ({exc})") from None


def _as_covariance(covariance, name: str, has: np.ndarray) -> np.ndarray:
    """Check the (S, 3, 3) covariance of an estimate with an estimate at the steps `has` (S,):
    symmetric positive definite there, all NaN elsewhere; return it as a float array."""
    P = _floats(covariance, name)
    n = has.shape[0]
    if P.shape != (n, 3, 3):
        raise DataError(f"{name}: expected shape ({n}, 3, 3), got {P.shape}")
    bad = np.flatnonzero(has & ~np.all(np.isfinite(P), axis=(1, 2)))
    if bad.size:
        raise DataError(f"{name}: non-finite at step(s) {bad[:5].tolist()}, which have an "
                        f"estimate")
    bad = np.flatnonzero(~has & ~np.all(np.isnan(P), axis=(1, 2)))
    if bad.size:
        raise DataError(f"{name}: must be NaN where there is no estimate, but step(s) "
                        f"{bad[:5].tolist()} hold numbers")
    given = P[has]
    asymmetry = np.abs(given - np.swapaxes(given, 1, 2)).max(axis=(1, 2), initial=0.0)
    scale = np.abs(given).max(axis=(1, 2), initial=0.0)
    lowest = np.linalg.eigvalsh(0.5 * (given + np.swapaxes(given, 1, 2)))[:, 0]
    bad = np.flatnonzero(has)[(asymmetry > _SYMMETRY_TOL * scale) | ~(lowest > 0.0)]
    if bad.size:
        raise DataError(f"{name}: not symmetric positive definite at step(s) "
                        f"{bad[:5].tolist()}")
    return P


def _nees(T_true: np.ndarray, estimate: np.ndarray, P: np.ndarray,
          has: np.ndarray) -> np.ndarray:
    """(S,) NEES of validated inputs, NaN where `has` is False."""
    e = estimate[has] - se2_to_params(T_true[has])
    e[:, 2] = wrap_angle(e[:, 2])
    nees = np.full(has.shape, np.nan)
    nees[has] = np.einsum("ni,ni->n", e, np.linalg.solve(P[has], e[:, :, None])[:, :, 0])
    return nees


def step_nees(T_true, estimate, covariance) -> np.ndarray:
    """Per-step normalised estimation error squared (NEES) of an alignment estimate.

    T_true: (S, 3, 3) true T_oi_oj. estimate: (S, 3) estimated (x [m], y [m], theta [rad]) of
    T_oi_oj, a row of NaN meaning no estimate. covariance: (S, 3, 3) the covariance of those
    three numbers the method reported with the estimate, symmetric positive definite at the
    steps with an estimate, NaN at the others.

    The error is e = x_est - x_true with e_theta wrapped: the error in the parameterisation the
    estimate and its covariance are over (TCAFF's state with its additive Gaussian model, the
    aligner's z, the graph's marginal of (x, y, theta)), not the error in the oj frame that
    `step_errors` measures. NEES = e^T P^-1 e, chi-square with 3 degrees of freedom when the
    covariance is right (mean 3, below `NEES_95` on 95 % of the steps).
    Returns (S,), NaN where there is no estimate.
    Raises:
        DataError: wrong shapes, non-finite or not symmetric positive definite covariances at
            steps with an estimate, numbers at steps without one.
    """
    estimate, has = _as_estimate(estimate, "estimate")
    T_true = _as_se2_stack(T_true, "T_true", estimate.shape[0])
    return _nees(T_true, estimate, _as_covariance(covariance, "covariance", has), has)


def _spans(overlap: np.ndarray, gap_steps: int) -> np.ndarray:
    """`overlap_spans` of checked input."""
    steps = np.flatnonzero(overlap)
    if steps.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # np.diff - 1 steps without overlap lie between two consecutive overlap steps
    breaks = np.flatnonzero(np.diff(steps) - 1 >= gap_steps)
    return np.column_stack([steps[np.r_[0, breaks + 1]], steps[np.r_[breaks, steps.size - 1]]])


def overlap_spans(overlap, gap_steps: int = Thresholds.overlap_gap_steps) -> np.ndarray:
    """The overlaps of a pair: maximal runs of overlap steps, where fewer than `gap_steps`
    consecutive steps without overlap between two overlap steps do not end a run.

    overlap: (S,) bool. Returns (K, 2) int64, the first and the last step (inclusive) of each
    overlap in order; (0, 2) when no step overlaps. E.g. with gap_steps 2, the overlap
    flags 0 1 1 0 1 0 0 1 give [[1, 4], [7, 7]].
    Raises:
        DataError: overlap not a 1-D bool array. ConfigError: gap_steps not an int >= 1.
    """
    Thresholds(overlap_gap_steps=gap_steps)
    overlap = np.asarray(overlap)
    if overlap.ndim != 1 or overlap.dtype != bool:
        raise DataError(f"overlap: expected a (S,) bool array, got shape {overlap.shape} and "
                        f"dtype {overlap.dtype}")
    return _spans(overlap, gap_steps)


def _as_candidates(candidates, name: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Check (steps (M,), z (M, 3)) candidates of a run of n steps; return int64 and float
    copies."""
    if not isinstance(candidates, tuple | list) or len(candidates) != 2:
        raise DataError(f"{name}: expected a pair (steps (M,), z (M, 3)), got "
                        f"{type(candidates).__name__}")
    steps, z = _floats(candidates[0], f"{name} steps"), _floats(candidates[1], f"{name} z")
    if steps.ndim != 1 or z.shape != (steps.shape[0], 3):
        raise DataError(f"{name}: expected steps (M,) and z (M, 3), got {steps.shape} and "
                        f"{z.shape}")
    bad = np.flatnonzero(~np.isfinite(steps) | (steps != np.round(steps)) | (steps < 0)
                         | (steps >= n))
    if bad.size:
        raise DataError(f"{name}: steps must be whole numbers in [0, {n}), got "
                        f"{steps[bad[:5]].tolist()}")
    bad = np.flatnonzero(~np.all(np.isfinite(z), axis=1))
    if bad.size:
        raise DataError(f"{name}: z non-finite at candidate(s) {bad[:5].tolist()}")
    return steps.astype(np.int64), z.copy()


@dataclass(frozen=True)
class PairTrace:
    """Everything needed to score one directed pair (i, j) over a run of S steps.

    times: (S,) seconds, strictly increasing.
    T_true: (S, 3, 3) true T_oi_oj at each step.
    estimate: (S, 3) estimated (x [m], y [m], theta [rad]) of T_oi_oj; a row of NaN = no estimate.
    overlap: (S,) bool, steps at which the two maps share enough objects for an alignment.
    T_oi_bi: (S, 3, 3) robot i's odometry pose (its body bi in its odometry frame oi).
    T_oj_bj: (S, 3, 3) robot j's odometry pose.
    covariance: (S, 3, 3) the covariance of (x, y, theta) the method reported with each
        estimate, symmetric positive definite at the steps with an estimate, NaN rows at the
        others; None when the method reports none (its NEES is then undefined).
    candidates: (steps (M,) int, z (M, 3)) the candidate alignments (x, y, theta of T_oi_oj)
        the estimate was chosen from, each at its step, for the perfect judge
        (`perfect_judge`); None when the method has no candidates to judge.

    The arrays are stored as read-only float (bool for overlap, int64 for candidate steps)
    copies.
    """

    times: np.ndarray
    T_true: np.ndarray
    estimate: np.ndarray
    overlap: np.ndarray
    T_oi_bi: np.ndarray
    T_oj_bj: np.ndarray
    covariance: np.ndarray | None = None
    candidates: tuple[np.ndarray, np.ndarray] | None = None

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
        estimate, has = _as_estimate(self.estimate, "PairTrace.estimate", n)
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
        if self.covariance is not None:
            fields["covariance"] = _as_covariance(self.covariance, "PairTrace.covariance", has)
        for name, value in fields.items():
            value = np.array(value, copy=True)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.candidates is not None:
            candidates = _as_candidates(self.candidates, "PairTrace.candidates", n)
            for value in candidates:
                value.setflags(write=False)
            object.__setattr__(self, "candidates", candidates)

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


def perfect_judge(trace: PairTrace, thresholds: Thresholds | None = None) -> np.ndarray:
    """What a perfect judge of the pair's candidates holds at each step.

    At each step the judge sees that step's candidates (`PairTrace.candidates`) and the truth.
    It takes a correct candidate (both errors within `thresholds`) whenever there is one, the
    one nearest the truth (smallest larger share of its threshold) when there are several.
    Otherwise it keeps the candidate it took last, for at most `thresholds.judge_hold` seconds
    after taking it and only while that candidate stays within the thresholds of the moving
    truth: once it does not, it is dropped until the next take. So the judge holds a correct
    alignment exactly at the steps its row is not NaN: what a method that answers with one of
    these candidates, held as long, could reach at best.

    Returns:
        (S, 3) (x [m], y [m], theta [rad]) of the T_oi_oj held; NaN rows where it holds none.
    Raises:
        DataError: the trace has no candidates.
    """
    if trace.candidates is None:
        raise DataError("perfect_judge: the trace has no candidates")
    thresholds = Thresholds() if thresholds is None else thresholds
    steps, z = trace.candidates
    n = trace.n_steps
    index = np.arange(n)
    taken = np.full((n, 3), np.nan)
    if steps.size:
        err = se2_error(trace.T_true[steps], se2_from_params(z))
        nearness = np.maximum(err[:, 0] / thresholds.translation, err[:, 1] / thresholds.heading)
        correct = np.flatnonzero(thresholds.correct(err))
        # per step, its correct candidate nearest the truth: the first of each step in this order
        order = correct[np.lexsort((nearness[correct], steps[correct]))]
        took, first = np.unique(steps[order], return_index=True)
        taken[took] = z[order[first]]
    take = ~np.isnan(taken[:, 0])
    last_take = np.maximum.accumulate(np.where(take, index, -1))
    held = last_take >= 0
    kept = taken[np.maximum(last_take, 0)]
    err = np.full((n, 2), np.nan)
    if held.any():
        err[held] = se2_error(trace.T_true[held], se2_from_params(kept[held]))
    fresh = trace.times - trace.times[np.maximum(last_take, 0)] <= thresholds.judge_hold
    good = held & thresholds.correct(err) & fresh
    # a held candidate that failed at one step stays dropped until the next take
    last_bad = np.maximum.accumulate(np.where(good, -1, index))
    holding = held & (last_bad < last_take)
    return np.where(holding[:, None], kept, np.nan)


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
    nees_mean: mean NEES (`step_nees`) over the estimate steps; nees_under_95: share of the
    estimates with NEES < `NEES_95`; confident_false_accept: share of the estimates that are
    false accepts with NEES > `NEES_997` (outside their own 99.7 % ellipse). All three NaN
    when a trace has no covariance or there is no estimate.
    n_overlaps: overlaps (`overlap_spans`, gaps of fewer than `Thresholds.overlap_gap_steps`
    bridged). time_to_first_correct_overlap_median [s]: median, over the overlaps that got a
    correct estimate, of the seconds from the overlap's first step to the first step inside it
    (up to its last overlap step) whose estimate is correct; 0 when a correct estimate is held
    into it. overlaps_found: share of the overlaps that got one (NaN without overlaps).
    judge_availability: share of the overlap steps at which `perfect_judge` holds a correct
    alignment (NaN when a trace has no candidates, or no overlap).
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
    nees_mean: float
    nees_under_95: float
    confident_false_accept: float
    n_overlaps: int
    time_to_first_correct_overlap_median: float
    overlaps_found: float
    judge_availability: float

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
            "nees_mean": num(self.nees_mean),
            "nees_under_95": num(self.nees_under_95),
            "confident_false_accept": num(self.confident_false_accept),
            "time_to_first_correct_per_overlap_s_median": num(
                self.time_to_first_correct_overlap_median),
            "overlaps_found": num(self.overlaps_found),
            "judge_availability": num(self.judge_availability),
            "n_steps": int(self.n_steps),
            "n_estimates": int(self.n_estimates),
            "n_overlap": int(self.n_overlap),
            "n_overlaps": int(self.n_overlaps),
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


def _time_to_first_correct_per_overlap(trace: PairTrace, spans: np.ndarray,
                                        correct: np.ndarray) -> np.ndarray:
    """(K,) seconds from each overlap's first step to the first correct step inside it (NaN
    for an overlap without one); spans (K, 2) as `overlap_spans` gives them."""
    n = trace.n_steps
    # per step, the first correct step at or after it (n: none)
    next_correct = np.minimum.accumulate(np.where(correct, np.arange(n), n)[::-1])[::-1]
    first = next_correct[spans[:, 0]]
    found = first <= spans[:, 1]
    seconds = np.full(len(spans), np.nan)
    seconds[found] = trace.times[first[found]] - trace.times[spans[found, 0]]
    return seconds


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
    The NEES figures pool the estimates of every trace and are NaN unless every trace has a
    covariance; judge_availability likewise needs every trace's candidates. The per-overlap
    figures pool the overlaps of every trace.
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

    errs, rpes, ttfcs, apes, rpe_paths, neeses, per_overlap = [], [], [], [], [], [], []
    n_steps = n_overlap = n_available = n_correct = n_judged = 0
    for trace in traces:
        has = trace.has_estimate
        err = _errors(trace.T_true, trace.estimate, has)
        # NaN compares False, so steps without an estimate are never correct
        correct = thresholds.correct(err)
        errs.append(err[has])
        if trace.covariance is not None:
            neeses.append(_nees(trace.T_true, trace.estimate, trace.covariance, has)[has])
        spans = _spans(trace.overlap, thresholds.overlap_gap_steps)
        per_overlap.append(_time_to_first_correct_per_overlap(trace, spans, correct))
        if trace.candidates is not None:
            judged = ~np.isnan(perfect_judge(trace, thresholds)[:, 0])
            n_judged += int(np.count_nonzero(trace.overlap & judged))
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
    every_covariance = len(neeses) == len(traces)
    nees = np.concatenate(neeses) if every_covariance else np.full(n_estimates, np.nan)
    confident = wrong & (nees > NEES_997)
    overlap_seconds = np.concatenate(per_overlap)
    overlap_found = overlap_seconds[~np.isnan(overlap_seconds)]
    every_candidate = all(t.candidates is not None for t in traces)
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
        nees_mean=_mean_std(nees)[0] if every_covariance else math.nan,
        nees_under_95=(_share(int(np.count_nonzero(nees < NEES_95)), n_estimates)
                       if every_covariance else math.nan),
        confident_false_accept=(_share(int(np.count_nonzero(confident)), n_estimates)
                                if every_covariance else math.nan),
        n_overlaps=overlap_seconds.shape[0],
        time_to_first_correct_overlap_median=(float(np.median(overlap_found))
                                              if overlap_found.size else math.nan),
        overlaps_found=_share(overlap_found.shape[0], overlap_seconds.shape[0]),
        judge_availability=_share(n_judged, n_overlap) if every_candidate else math.nan,
    )


def pair_metrics(trace: PairTrace, thresholds: Thresholds | None = None) -> Metrics:
    """Scores of one directed pair over its run; see `Metrics` for the definitions."""
    return pooled_metrics([trace], thresholds)
