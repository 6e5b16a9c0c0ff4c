"""Tests for the consistency and overlap metrics of tcaff_gtsam.eval.metrics: NEES against the
reported covariances, confident false accepts, overlaps and the time to a correct estimate in
each, and the perfect judge of the candidates."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import solve_triangular
from scipy.stats import chi2
from tcaff_gtsam.eval.metrics import (
    NEES_95,
    NEES_997,
    PairTrace,
    Thresholds,
    overlap_spans,
    pair_metrics,
    perfect_judge,
    pooled_metrics,
    step_nees,
)

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_error, se2_from_params, se2_to_params

PROPS = settings(max_examples=60, deadline=None)
seeds = st.integers(0, 2**32 - 1)
NAN3 = [np.nan] * 3
NAN33 = np.full((3, 3), np.nan)


def make_trace(times, truth, estimate, overlap, covariance=None, candidates=None) -> PairTrace:
    """A trace of robots standing at their odometry origins; truth (S, 3) parameters."""
    n = len(times)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    return PairTrace(np.asarray(times, float), se2_from_params(np.asarray(truth, float)),
                     np.asarray(estimate, float), np.asarray(overlap, bool), eye, eye,
                     covariance, candidates)


def random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3, 3) covariances L L^T with sigmas from 1 cm to 10 m (and 10 mrad to 10 rad) and
    random correlations: L = diag(sigma) (I + a strictly lower random part)."""
    L = np.eye(3) + 0.7 * np.tril(rng.normal(size=(n, 3, 3)), -1)
    L *= 10.0 ** rng.uniform(-2, 1, (n, 3, 1))
    return L @ np.swapaxes(L, 1, 2)


# --- the chi-square bounds ----------------------------------------------------------------------

def test_the_bounds_are_chi_square_3_quantiles():
    assert NEES_95 == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)
    assert NEES_95 == pytest.approx(7.815, abs=5e-4)
    # the 99.7 % ellipse: the probability of 3 sigma in one dimension
    assert NEES_997 == pytest.approx(chi2.ppf(chi2.cdf(9.0, 1), 3), rel=1e-12)
    assert NEES_997 == pytest.approx(14.16, abs=5e-3)


# --- NEES ---------------------------------------------------------------------------------------

@PROPS
@given(seeds)
def test_nees_is_the_mahalanobis_distance_of_the_parameter_error(seed):
    """Against an independent computation: the error of each parameter taken by hand (the
    heading through atan2 of its sine and cosine, the estimate's angle given unwrapped), and
    e^T P^-1 e as |L^-1 e|^2 with P's Cholesky factor."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 12))
    truth = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    P = random_spd(rng, n)
    error = np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.normal(size=(n, 3)))
    error *= rng.choice([0.1, 1.0, 10.0], size=(n, 1))
    estimate = truth + error
    estimate[:, 2] += 2 * np.pi * rng.integers(-2, 3, n)  # the same angle, another turn
    missing = rng.random(n) < 0.3
    estimate[missing] = np.nan
    P[missing] = np.nan
    got = step_nees(se2_from_params(truth), estimate, P)
    assert np.all(np.isnan(got[missing]))
    for k in np.flatnonzero(~missing):
        dx, dy = estimate[k, :2] - truth[k, :2]
        dtheta = math.atan2(math.sin(estimate[k, 2] - truth[k, 2]),
                            math.cos(estimate[k, 2] - truth[k, 2]))
        y = solve_triangular(np.linalg.cholesky(P[k]), [dx, dy, dtheta], lower=True)
        assert got[k] == pytest.approx(float(y @ y), rel=1e-6, abs=1e-9)


def test_nees_uses_the_parameters_error_not_the_error_in_the_oj_frame():
    # truth turned 90 deg; the estimate 0.3 m off along the parameters' x. The covariance is
    # narrow in x (0.3 m) and wide in y (10 m): NEES 1. In the truth's oj frame the same error
    # lies along y, where a wrong formula would find (0.3 / 10)^2 = 0.0009.
    truth = np.array([[5.0, -2.0, np.pi / 2]])
    estimate = truth + np.array([0.3, 0.0, 0.0])
    P = np.diag([0.3**2, 10.0**2, 1.0])[None]
    assert step_nees(se2_from_params(truth), estimate, P)[0] == pytest.approx(1.0)


def test_nees_hand_cases_and_heading_wrap():
    truth = np.array([[1.0, 2.0, 0.1], [0.0, 0.0, np.pi - 0.01], [3.0, 3.0, 0.0]])
    estimate = np.array([[1.3, 2.0, 0.15], [0.0, 0.0, -np.pi + 0.01], NAN3])
    P = np.array([np.diag([0.09, 1.0, 0.0025]), np.diag([1.0, 1.0, 0.01**2]), NAN33])
    got = step_nees(se2_from_params(truth), estimate, P)
    # (0.3^2 / 0.09) + (0.05^2 / 0.0025) = 2; heading 0.02 across +-pi over 0.01: 4
    np.testing.assert_allclose(got[:2], [2.0, 4.0], rtol=1e-9)
    assert math.isnan(got[2])
    # a correlation: e = (1, 1, 0) with P = [[1, 0.5], [0.5, 1]] in x, y: e^T P^-1 e = 4 / 3
    P_corr = np.array([[1.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])[None]
    got = step_nees(np.eye(3)[None], [[1.0, 1.0, 0.0]], P_corr)
    assert got[0] == pytest.approx(4 / 3)


def test_nees_of_gaussian_errors_follows_chi_square_3():
    """Errors drawn from the covariance: mean NEES 3, 95 % under NEES_95, 0.27 % beyond
    NEES_997 (20 000 draws: three standard errors of the shares are 0.5 and 0.11 points)."""
    rng = np.random.default_rng(7)
    n = 20_000
    truth = np.column_stack([rng.uniform(-20, 20, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    P = random_spd(rng, n)
    P[:, 2, :] *= 0.01  # headings of a few degrees: no draw wraps past +-pi
    P[:, :, 2] *= 0.01
    estimate = truth + np.einsum("nij,nj->ni", np.linalg.cholesky(P), rng.normal(size=(n, 3)))
    m = pair_metrics(make_trace(np.arange(n), truth, estimate, np.ones(n, bool), P))
    assert m.nees_mean == pytest.approx(3.0, abs=0.07)
    assert m.nees_under_95 == pytest.approx(0.95, abs=0.005)
    nees = step_nees(se2_from_params(truth), estimate, P)
    assert np.mean(nees > NEES_997) == pytest.approx(0.0027, abs=0.0011)


def test_confident_false_accepts_need_both_a_wrong_estimate_and_a_small_covariance():
    truth = np.zeros((5, 3))
    estimate = np.array([
        [0.1, 0.0, 0.0],     # right, NEES 1 with 0.1 m sigma
        [2.0, 0.0, 0.0],     # 2 m off, but its covariance says +-2 m: NEES 1
        [2.0, 0.0, 0.0],     # 2 m off at 0.1 m sigma: NEES 400, a confident false accept
        [0.5, 0.0, 0.0],     # right (0.5 m), at 0.1 m sigma: NEES 25, not a false accept
        [0.0, 0.0, 0.1],     # 5.7 deg off at a 0.03 rad sigma: NEES 11.1, inside 99.7 %
    ])
    sigma = np.array([[0.1, 1, 1], [2.0, 1, 1], [0.1, 1, 1], [0.1, 1, 1], [1, 1, 0.03]])
    P = np.array([np.diag(s**2) for s in sigma])
    m = pair_metrics(make_trace(np.arange(5), truth, estimate, np.ones(5, bool), P))
    assert m.false_accept == pytest.approx(3 / 5)
    assert m.confident_false_accept == pytest.approx(1 / 5)
    assert m.nees_under_95 == pytest.approx(2 / 5)  # 1, 1; not 400, 25, 11.1
    assert m.nees_mean == pytest.approx((1 + 1 + 400 + 25 + (0.1 / 0.03) ** 2) / 5)
    report = m.as_report()
    assert report["confident_false_accept"] == pytest.approx(0.2)
    assert report["nees_mean"] == pytest.approx(m.nees_mean)


def test_no_covariance_gives_no_nees_and_pooling_needs_every_trace_to_have_one():
    truth, estimate = np.zeros((3, 3)), np.zeros((3, 3))
    bare = make_trace(np.arange(3), truth, estimate, np.ones(3, bool))
    m = pair_metrics(bare)
    assert math.isnan(m.nees_mean) and math.isnan(m.nees_under_95)
    assert math.isnan(m.confident_false_accept)
    report = m.as_report()
    assert report["nees_mean"] is None and report["confident_false_accept"] is None
    assert report["false_accept"] == 0.0  # the other figures stay
    with_cov = make_trace(np.arange(3), truth, estimate, np.ones(3, bool),
                          np.tile(np.eye(3), (3, 1, 1)))
    assert pair_metrics(with_cov).nees_mean == 0.0
    assert math.isnan(pooled_metrics([with_cov, bare]).nees_mean)
    # a covariance but no estimate at all: nothing to average
    empty = make_trace(np.arange(2), np.zeros((2, 3)), [NAN3, NAN3], [True, True],
                       np.full((2, 3, 3), np.nan))
    assert pair_metrics(empty).as_report()["nees_mean"] is None
    assert pooled_metrics([with_cov, empty]).nees_mean == 0.0


def _fields(n: int = 3) -> dict:
    estimate = np.zeros((n, 3))
    estimate[1] = np.nan
    covariance = np.tile(np.eye(3), (n, 1, 1))
    covariance[1] = np.nan
    return {"times": np.arange(float(n)), "T_true": se2_from_params(np.zeros((n, 3))),
            "estimate": estimate, "overlap": np.ones(n, bool),
            "T_oi_bi": se2_from_params(np.zeros((n, 3))),
            "T_oj_bj": se2_from_params(np.zeros((n, 3))), "covariance": covariance}


def _with(step: int, matrix) -> np.ndarray:
    covariance = _fields()["covariance"]
    covariance[step] = matrix
    return covariance


@pytest.mark.parametrize(("value", "pattern"), [
    (np.tile(np.eye(3), (2, 1, 1)), r"covariance: expected shape \(3, 3, 3\), got \(2, 3, 3\)"),
    (np.zeros((3, 3)), r"covariance: expected shape \(3, 3, 3\)"),
    (_with(0, NAN33), r"covariance: non-finite at step\(s\) \[0\]"),
    (_with(2, np.diag([1.0, np.inf, 1.0])), r"covariance: non-finite at step\(s\) \[2\]"),
    (_with(1, np.eye(3)), r"covariance: must be NaN where there is no estimate.*\[1\]"),
    (_with(0, [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
     r"covariance: not symmetric positive definite at step\(s\) \[0\]"),
    (_with(2, np.diag([1.0, -1.0, 1.0])), r"covariance: not symmetric positive definite.*\[2\]"),
    (_with(0, np.zeros((3, 3))), r"covariance: not symmetric positive definite.*\[0\]"),
    (_with(0, np.diag([1.0, 0.0, 1.0])), r"covariance: not symmetric positive definite.*\[0\]"),
    ("a", "covariance: expected real numbers"),
])
def test_bad_covariances_are_named(value, pattern):
    fields = _fields()
    fields["covariance"] = value
    with pytest.raises(DataError, match="PairTrace." + pattern):
        PairTrace(**fields)
    if not isinstance(value, str) and np.shape(value) == (3, 3, 3):
        with pytest.raises(DataError, match=r"^" + pattern):
            step_nees(fields["T_true"], fields["estimate"], value)


def test_covariance_is_kept_read_only_and_rounding_asymmetry_passes():
    fields = _fields()
    fields["covariance"][0, 0, 1] = 1e-12  # rounding of J S J^T
    trace = PairTrace(**fields)
    with pytest.raises(ValueError, match="read-only"):
        trace.covariance[0, 0, 0] = 2.0


# --- overlaps -----------------------------------------------------------------------------------

def test_overlap_spans_hand_example():
    flags = np.array([0, 1, 1, 0, 1, 0, 0, 1, 0, 0, 0], bool)
    # one step without overlap (3) is bridged by any gap >= 2; two (5, 6) need 3
    np.testing.assert_array_equal(overlap_spans(flags, 1), [[1, 2], [4, 4], [7, 7]])
    np.testing.assert_array_equal(overlap_spans(flags, 2), [[1, 4], [7, 7]])
    np.testing.assert_array_equal(overlap_spans(flags, 3), [[1, 7]])
    np.testing.assert_array_equal(overlap_spans(flags), [[1, 7]])  # the default, 5 steps
    assert overlap_spans(np.zeros(4, bool), 2).shape == (0, 2)
    np.testing.assert_array_equal(overlap_spans(np.ones(4, bool), 1), [[0, 3]])


def naive_spans(flags: np.ndarray, gap: int) -> list[list[int]]:
    """Step by step: an overlap runs on until `gap` steps in a row lack overlap."""
    spans, start, last, quiet = [], None, None, 0
    for s, flag in enumerate(flags):
        if flag:
            if start is None:
                start = s
            last, quiet = s, 0
        elif start is not None:
            quiet += 1
            if quiet >= gap:
                spans.append([start, last])
                start = None
    if start is not None:
        spans.append([start, last])
    return spans


@PROPS
@given(st.lists(st.booleans(), min_size=1, max_size=40), st.integers(1, 6))
def test_overlap_spans_match_a_step_by_step_split(flags, gap):
    flags = np.array(flags, bool)
    assert overlap_spans(flags, gap).tolist() == naive_spans(flags, gap)


def test_overlap_spans_refuse_bad_input():
    with pytest.raises(DataError, match=r"overlap: expected a \(S,\) bool"):
        overlap_spans(np.ones((2, 2), bool))
    with pytest.raises(DataError, match=r"overlap.*dtype"):
        overlap_spans(np.array([0.0, 1.0]))
    with pytest.raises(ConfigError, match="overlap_gap_steps"):
        overlap_spans(np.ones(3, bool), 0)


def test_time_to_first_correct_per_overlap_hand_example():
    # times (s):  0   1   2   4   5   7   8  10  11  13  15  16  17  18  20
    # overlap:    .   x   x   .   x   .   .   .   x   x   x   .   .   .   x     (gap 2 steps)
    # estimate:   ok  .   .   ok  ok  .   .   .   ok  ok  bad .   .   .   .
    # overlaps:   [1, 4] from t = 1: first correct at step 3 (t = 4, a gap step inside it): 3 s
    #             [8, 10] from t = 11: correct at once: 0 s
    #             [14, 14]: no estimate: not found
    times = [0, 1, 2, 4, 5, 7, 8, 10, 11, 13, 15, 16, 17, 18, 20]
    overlap = [0, 1, 1, 0, 1, 0, 0, 0, 1, 1, 1, 0, 0, 0, 1]
    S = len(times)
    estimate = np.full((S, 3), np.nan)
    estimate[[0, 3, 4, 8, 9]] = 0.0
    estimate[10] = [3.0, 0.0, 0.0]
    trace = make_trace(times, np.zeros((S, 3)), estimate, overlap)
    m = pair_metrics(trace, Thresholds(overlap_gap_steps=2))
    assert m.n_overlaps == 3
    assert m.overlaps_found == pytest.approx(2 / 3)
    assert m.time_to_first_correct_overlap_median == pytest.approx(np.median([3.0, 0.0]))
    # the per-run figure counts from the first overlap step only: 3 s too
    assert m.time_to_first_correct == pytest.approx(3.0)
    # with gap 4 the gap 11-13 is bridged: [1, 14] found after 3 s
    m = pair_metrics(trace, Thresholds(overlap_gap_steps=4))
    assert (m.n_overlaps, m.overlaps_found) == (1, 1.0)
    assert m.time_to_first_correct_overlap_median == pytest.approx(3.0)
    # with gap 1 every run of overlap is its own: [1, 2] (no estimate), [4, 4] (0 s),
    # [8, 10] (0 s), [14, 14] (none)
    m = pair_metrics(trace, Thresholds(overlap_gap_steps=1))
    assert (m.n_overlaps, m.overlaps_found) == (4, 0.5)
    assert m.time_to_first_correct_overlap_median == 0.0
    report = m.as_report()
    assert report["time_to_first_correct_per_overlap_s_median"] == 0.0
    assert report["overlaps_found"] == 0.5 and report["n_overlaps"] == 4


def test_a_correct_estimate_after_its_overlap_ended_is_not_found_in_it():
    times = np.arange(6.0)
    estimate = np.full((6, 3), np.nan)
    estimate[4] = 0.0
    trace = make_trace(times, np.zeros((6, 3)), estimate, [1, 1, 0, 0, 0, 0])
    m = pair_metrics(trace, Thresholds(overlap_gap_steps=2))
    assert (m.n_overlaps, m.overlaps_found) == (1, 0.0)
    assert math.isnan(m.time_to_first_correct_overlap_median)
    assert m.as_report()["time_to_first_correct_per_overlap_s_median"] is None
    # the per-run figure has no end: it counts the estimate 4 s after the first overlap step
    assert m.time_to_first_correct == 4.0


def naive_times(trace: PairTrace, gap: int, thresholds: Thresholds) -> list[float]:
    """Per overlap of `naive_spans`, the seconds to its first correct step, scanned."""
    err = se2_error(trace.T_true, se2_from_params(np.nan_to_num(trace.estimate)))
    out = []
    for a, b in naive_spans(trace.overlap, gap):
        hits = [s for s in range(a, b + 1) if trace.has_estimate[s]
                and err[s, 0] <= thresholds.translation and err[s, 1] <= thresholds.heading]
        out.append(trace.times[hits[0]] - trace.times[a] if hits else math.nan)
    return out


@PROPS
@given(seeds, seeds, st.integers(1, 4))
def test_per_overlap_figures_pool_the_overlaps_of_every_trace(seed_a, seed_b, gap):
    traces = []
    for seed in (seed_a, seed_b):
        rng = np.random.default_rng(seed)
        n = int(rng.integers(1, 30))
        times = np.cumsum(rng.uniform(0.5, 2.0, n))
        truth = np.column_stack([rng.uniform(-9, 9, (n, 2)), rng.uniform(-3, 3, n)])
        estimate = se2_to_params(se2_from_params(truth) @ se2_from_params(
            rng.normal(size=(n, 3)) * rng.choice([0.1, 3.0], (n, 1)) * [1, 1, 0.05]))
        estimate[rng.random(n) < 0.4] = np.nan
        traces.append(make_trace(times, truth, estimate, rng.random(n) < 0.6))
    thresholds = Thresholds(overlap_gap_steps=gap)
    expected = [t for trace in traces for t in naive_times(trace, gap, thresholds)]
    m = pooled_metrics(traces, thresholds)
    assert m.n_overlaps == len(expected)
    found = [t for t in expected if not math.isnan(t)]
    if expected:
        assert m.overlaps_found == pytest.approx(len(found) / len(expected))
    else:
        assert math.isnan(m.overlaps_found)
    if found:
        assert m.time_to_first_correct_overlap_median == pytest.approx(np.median(found))
    else:
        assert math.isnan(m.time_to_first_correct_overlap_median)


# --- the perfect judge --------------------------------------------------------------------------

def test_perfect_judge_hand_example():
    """The truth sits at the origin but for steps 5 and 6, where it moves 0.8 m along x.

    step  time  candidates (x of each)        the judge
    0     0     3.0 (wrong)                   nothing
    1     1     3.0, 0.6, 0.2 (two right)     takes 0.2, the nearer
    2     2     -                             holds 0.2
    3     3     2.0 (wrong)                   holds 0.2
    4     4     -                             holds 0.2
    5     5     -  (truth at 0.8: 0.2 is 0.6 m off, still right)   holds 0.2
    6     6     -  (truth at 1.3: 1.1 m off)  drops it
    7     7     -  (truth back at 0)           nothing: dropped for good
    8     30    0.1                            takes 0.1
    9     60    -                              holds (30 s since the take)
    10    71    -                              nothing: 41 s since the take, beyond 40 s
    """
    times = [0, 1, 2, 3, 4, 5, 6, 7, 30, 60, 71]
    S = len(times)
    truth = np.zeros((S, 3))
    truth[5, 0], truth[6, 0] = 0.8, 1.3
    steps = np.array([0, 1, 1, 1, 3, 8])
    z = np.zeros((6, 3))
    z[:, 0] = [3.0, 3.0, 0.6, 0.2, 2.0, 0.1]
    overlap = np.ones(S, bool)
    overlap[[0, 9]] = False
    trace = make_trace(times, truth, np.full((S, 3), np.nan), overlap,
                       candidates=(steps, z))
    held = perfect_judge(trace)
    expected_x = [np.nan, 0.2, 0.2, 0.2, 0.2, 0.2, np.nan, np.nan, 0.1, 0.1, np.nan]
    np.testing.assert_array_equal(held[:, 0], expected_x)
    np.testing.assert_array_equal(np.isnan(held[:, 1]), np.isnan(expected_x))
    # held on overlap steps 1-5 and 8 of the 9 overlap steps
    m = pair_metrics(trace)
    assert m.judge_availability == pytest.approx(6 / 9)
    assert m.as_report()["judge_availability"] == pytest.approx(6 / 9)
    # a judge that holds 25 s lets 0.1 go at step 9, 30 s after taking it
    np.testing.assert_array_equal(perfect_judge(trace, Thresholds(judge_hold=25.0))[:, 0],
                                  [*expected_x[:9], np.nan, np.nan])
    # nearest by the larger share of its threshold: 0.6 m / 1 m against 4 deg / 5 deg
    z2 = np.array([[0.6, 0.0, 0.0], [0.0, 0.0, math.radians(4.0)]])
    trace2 = make_trace([0.0], np.zeros((1, 3)), [NAN3], [True], candidates=(np.zeros(2), z2))
    np.testing.assert_array_equal(perfect_judge(trace2)[0], z2[0])


def naive_judge(trace: PairTrace, thresholds: Thresholds) -> np.ndarray:
    """The judge step by step, one candidate at a time."""
    steps, z = trace.candidates
    out = np.full((trace.n_steps, 3), np.nan)
    held, since = None, 0.0

    def off(T_true, x):
        return se2_error(T_true, se2_from_params(x))

    def right(e):
        return e[0] <= thresholds.translation and e[1] <= thresholds.heading

    for s in range(trace.n_steps):
        best, best_score = None, math.inf
        for k in np.flatnonzero(steps == s):
            e = off(trace.T_true[s], z[k])
            score = max(e[0] / thresholds.translation, e[1] / thresholds.heading)
            if right(e) and score < best_score:
                best, best_score = z[k], score
        if best is not None:
            held, since = best, trace.times[s]
        elif held is not None and not (trace.times[s] - since <= thresholds.judge_hold
                                       and right(off(trace.T_true[s], held))):
            held = None
        if held is not None:
            out[s] = held
    return out


@PROPS
@given(seeds)
def test_perfect_judge_matches_a_step_by_step_judge(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    times = np.cumsum(rng.uniform(1.0, 12.0, n))
    # a truth that drifts slowly, so that held candidates stay right for a while
    truth = np.cumsum(rng.normal(0, [0.3, 0.3, 0.02], (n, 3)), axis=0)
    m = int(rng.integers(0, 3 * n))
    steps = rng.integers(0, n, m)
    z = truth[steps] + rng.normal(size=(m, 3)) * rng.choice([0.2, 2.0], (m, 1)) * [1, 1, 0.05]
    thresholds = Thresholds(judge_hold=float(rng.choice([0.0, 15.0, 40.0])))
    trace = make_trace(times, truth, np.full((n, 3), np.nan), rng.random(n) < 0.7,
                       candidates=(steps, z))
    expected = naive_judge(trace, thresholds)
    np.testing.assert_allclose(perfect_judge(trace, thresholds), expected, rtol=0, atol=0)
    held = ~np.isnan(expected[:, 0])
    m = pair_metrics(trace, thresholds)
    if trace.overlap.any():
        assert m.judge_availability == pytest.approx(
            np.count_nonzero(held & trace.overlap) / np.count_nonzero(trace.overlap))
    # what the judge holds is always right
    if held.any():
        e = se2_error(trace.T_true[held], se2_from_params(expected[held]))
        assert np.all(e[:, 0] <= thresholds.translation) and np.all(e[:, 1] <= thresholds.heading)


def test_judge_availability_needs_candidates_on_every_trace():
    truth = np.zeros((2, 3))
    judged = make_trace([0.0, 1.0], truth, [NAN3, NAN3], [True, True],
                        candidates=(np.array([0]), np.zeros((1, 3))))
    bare = make_trace([0.0, 1.0], truth, [NAN3, NAN3], [True, True])
    assert pair_metrics(judged).judge_availability == 1.0
    assert math.isnan(pair_metrics(bare).judge_availability)
    assert math.isnan(pooled_metrics([judged, bare]).judge_availability)
    assert pair_metrics(bare).as_report()["judge_availability"] is None
    no_candidates = make_trace([0.0, 1.0], truth, [NAN3, NAN3], [True, False],
                               candidates=(np.zeros(0), np.zeros((0, 3))))
    assert pooled_metrics([judged, no_candidates]).judge_availability == pytest.approx(2 / 3)
    with pytest.raises(DataError, match="perfect_judge: the trace has no candidates"):
        perfect_judge(bare)


@pytest.mark.parametrize(("candidates", "pattern"), [
    (np.zeros((1, 3)), "expected a pair"),
    ((np.array([0, 1]), np.zeros((1, 3))), r"steps \(M,\) and z \(M, 3\).*\(2,\).*\(1, 3\)"),
    ((np.array([2]), np.zeros((1, 3))), r"whole numbers in \[0, 2\), got \[2.0\]"),
    ((np.array([0.5]), np.zeros((1, 3))), "whole numbers"),
    ((np.array([-1]), np.zeros((1, 3))), "whole numbers"),
    ((np.array([0]), np.array([[0.0, np.nan, 0.0]])), r"z non-finite at candidate\(s\) \[0\]"),
    ((["a"], np.zeros((1, 3))), "steps: expected real numbers"),
])
def test_bad_candidates_are_named(candidates, pattern):
    with pytest.raises(DataError, match="PairTrace.candidates.*" + pattern):
        make_trace([0.0, 1.0], np.zeros((2, 3)), [NAN3, NAN3], [True, True],
                   candidates=candidates)


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"overlap_gap_steps": 0}, "overlap_gap_steps"),
    ({"overlap_gap_steps": 2.5}, "overlap_gap_steps"),
    ({"overlap_gap_steps": True}, "overlap_gap_steps"),
    ({"judge_hold": -1.0}, "judge_hold"),
    ({"judge_hold": math.inf}, "judge_hold"),
])
def test_thresholds_refuse_bad_overlap_gaps_and_holds(kwargs, field):
    with pytest.raises(ConfigError, match=f"Thresholds.{field}.*got"):
        Thresholds(**kwargs)


def test_threshold_defaults_of_overlaps_and_the_judge():
    assert Thresholds().overlap_gap_steps == 5 and Thresholds().judge_hold == 40.0
