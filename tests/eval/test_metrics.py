"""Tests for tcaff_gtsam.eval.metrics: per-step errors, pair and pooled metrics, validation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.metrics import (
    PairTrace,
    Thresholds,
    pair_metrics,
    pooled_metrics,
    relative_pose_errors,
    step_errors,
)
from tcaff_gtsam.eval.trajectories import planar_trajectory

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, wrap_angle

PROPS = settings(max_examples=40, deadline=None)

coord = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
seeds = st.integers(0, 2**32 - 1)
NAN3 = [np.nan, np.nan, np.nan]


def make_trace(times, T_true, estimate, overlap, T_oi_bi=None, T_oj_bj=None) -> PairTrace:
    n = len(times)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    return PairTrace(times=np.asarray(times, float), T_true=np.asarray(T_true, float),
                     estimate=np.asarray(estimate, float), overlap=np.asarray(overlap, bool),
                     T_oi_bi=eye if T_oi_bi is None else T_oi_bi,
                     T_oj_bj=eye if T_oj_bj is None else T_oj_bj)


def random_trace(seed: int, t0: float = 0.0) -> PairTrace:
    """A random trace whose estimates fall on both sides of the default thresholds."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 15))
    times = t0 + np.cumsum(rng.uniform(0.1, 2.0, n))
    truth = np.column_stack([rng.uniform(-50, 50, (n, 2)), rng.uniform(-np.pi, np.pi, n)])
    T_true = se2_from_params(truth)
    scale = rng.choice([0.01, 0.1, 3.0], size=(n, 1))
    offset = rng.normal(size=(n, 3)) * scale * [1.0, 1.0, 0.1]
    estimate = se2_to_params(T_true @ se2_from_params(offset))
    estimate[rng.random(n) < 0.3] = np.nan
    overlap = rng.random(n) < 0.7
    poses = [se2_from_params(np.column_stack([rng.uniform(-30, 30, (n, 2)),
                                              rng.uniform(-np.pi, np.pi, n)]))
             for _ in range(2)]
    return make_trace(times, T_true, estimate, overlap, *poses)


def concat(a: PairTrace, b: PairTrace) -> PairTrace:
    return PairTrace(*(np.concatenate([getattr(a, f), getattr(b, f)])
                       for f in ("times", "T_true", "estimate", "overlap", "T_oi_bi", "T_oj_bj")))


# --- step_errors: hand-computed cases ------------------------------------------------------------

def test_step_error_pure_translation():
    err = step_errors(np.eye(3)[None], [[3.0, 4.0, 0.0]])
    np.testing.assert_allclose(err, [[5.0, 0.0]], atol=1e-12)


def test_step_error_is_in_the_truths_frame():
    # truth: at (2, 1), rotated 90 deg. Estimate = truth composed with E = (1, 0, 90 deg), i.e.
    # 1 m along the truth's own x axis (world +y) and turned a further 90 deg: (2, 2, 180 deg).
    # T_true^-1 T_est = E: 1 m, 90 deg. The other order, T_est T_true^-1, has translation
    # t + R_true (1, 0) - R_E t = (2, 1) + (0, 1) - (-1, 2) = (3, 0): 3 m.
    T_true = se2_from_params([2.0, 1.0, np.pi / 2])[None]
    estimate = np.array([[2.0, 2.0, np.pi]])
    err = step_errors(T_true, estimate)
    np.testing.assert_allclose(err, [[1.0, np.pi / 2]], atol=1e-12)
    wrong_order = se2_from_params(estimate[0]) @ np.linalg.inv(T_true[0])
    assert np.hypot(*wrong_order[:2, 2]) == pytest.approx(3.0)


def test_step_error_heading_wraps():
    T_true = se2_from_params([0.0, 0.0, np.pi - 0.01])[None]
    err = step_errors(T_true, [[0.0, 0.0, -np.pi + 0.01]])
    np.testing.assert_allclose(err, [[0.0, 0.02]], atol=1e-12)


def test_step_errors_nan_rows_and_batch():
    T_true = se2_from_params([[1.0, 2.0, 0.3], [0.0, 0.0, 0.0], [5.0, -1.0, -2.0]])
    estimate = np.array([[1.0, 2.0, 0.3], NAN3, se2_to_params(T_true[2] @ se2_from_params(
        [0.6, -0.8, 0.25]))])
    err = step_errors(T_true, estimate)
    np.testing.assert_allclose(err[[0, 2]], [[0.0, 0.0], [1.0, 0.25]], atol=1e-12)
    assert np.all(np.isnan(err[1]))


@PROPS
@given(coord, coord, angle, coord, coord, angle)
def test_step_error_matches_closed_form(xt, yt, tht, xe, ye, the):
    err = step_errors(se2_from_params([xt, yt, tht])[None], [[xe, ye, the]])[0]
    c, s = math.cos(tht), math.sin(tht)
    R_true = np.array([[c, -s], [s, c]])
    expected_t = np.linalg.norm(R_true.T @ np.array([xe - xt, ye - yt]))
    assert err[0] == pytest.approx(expected_t, rel=1e-9, abs=1e-9)
    assert err[1] == pytest.approx(abs(wrap_angle(the - tht)), abs=1e-9)


# --- pair_metrics on a hand-made trace -----------------------------------------------------------

TIMES = np.array([0.0, 1.0, 2.0, 3.5, 4.0, 5.25, 6.0, 7.0, 8.0, 9.0])
# offsets of the estimates in the truth's frame (x, y, theta) on steps 4..9
OFFSETS = np.array([[2.0, 0.0, 0.01], [0.03, 0.04, -0.001], [0.06, -0.08, 0.002],
                    [0.0, 0.0, 0.0], [0.0, 0.08, -0.003], [-0.06, 0.0, 0.004]])
TRANS = [2.0, 0.05, 0.1, 0.0, 0.08, 0.06]
HEAD = [0.01, 0.001, 0.002, 0.0, 0.003, 0.004]


def hand_trace() -> PairTrace:
    steps = np.arange(10)
    T_true = se2_from_params(np.column_stack([10.0 + steps, -3.0 + 0.5 * steps, 0.2 * steps]))
    estimate = np.full((10, 3), np.nan)
    estimate[4:] = se2_to_params(T_true[4:] @ se2_from_params(OFFSETS))
    overlap = steps >= 2
    return make_trace(TIMES, T_true, estimate, overlap)


def test_pair_metrics_hand_trace():
    m = pair_metrics(hand_trace())
    assert (m.n_steps, m.n_estimates, m.n_overlap) == (10, 6, 8)
    assert m.availability == pytest.approx(6 / 8)
    assert m.false_accept == pytest.approx(1 / 6)
    # five of the eight overlap steps have a correct estimate
    assert m.correct_availability == pytest.approx(5 / 8)
    assert m.time_to_first_correct == pytest.approx(TIMES[5] - TIMES[2])
    assert m.time_to_first_correct == pytest.approx(3.25)
    assert m.translation_mean == pytest.approx(np.mean(TRANS))
    assert m.translation_std == pytest.approx(np.std(TRANS))
    assert m.translation_median == pytest.approx(np.median(TRANS))
    assert m.heading_mean == pytest.approx(np.mean(HEAD))
    assert m.heading_std == pytest.approx(np.std(HEAD))
    # with robot j at the origin of its odometry frame the RPE is the alignment error itself
    assert m.rpe_translation_mean == pytest.approx(np.mean(TRANS))
    assert m.rpe_heading_mean == pytest.approx(np.mean(HEAD))


def test_thresholds_are_both_used():
    # heading threshold 0.0035 rad: step 9 (0.004 rad) becomes a false accept too
    m = pair_metrics(hand_trace(), Thresholds(heading=0.0035))
    assert m.false_accept == pytest.approx(2 / 6)
    # translation threshold 0.07 m: steps 4, 6 and 8 are off; the first correct step is 5
    m = pair_metrics(hand_trace(), Thresholds(translation=0.07))
    assert m.false_accept == pytest.approx(3 / 6)
    assert m.time_to_first_correct == pytest.approx(3.25)
    # 0.04 m: only step 7 (exact) is within
    m = pair_metrics(hand_trace(), Thresholds(translation=0.04))
    assert m.false_accept == pytest.approx(5 / 6)
    assert m.time_to_first_correct == pytest.approx(TIMES[7] - TIMES[2])


def test_time_to_first_correct_counts_from_first_overlap():
    T_true = se2_from_params(np.zeros((4, 3)))
    estimate = np.zeros((4, 3))
    estimate[1] = np.nan
    m = pair_metrics(make_trace([0.0, 1.0, 3.0, 4.0], T_true, estimate,
                                [False, True, True, True]))
    # the correct estimate at step 0 precedes the overlap; the clock starts at step 1
    assert m.time_to_first_correct == pytest.approx(2.0)
    assert m.availability == pytest.approx(2 / 3)


def test_no_estimates():
    T_true = se2_from_params(np.zeros((5, 3)))
    m = pair_metrics(make_trace(np.arange(5.0), T_true, np.full((5, 3), np.nan),
                                [False, True, True, False, True]))
    assert (m.n_steps, m.n_estimates, m.n_overlap) == (5, 0, 3)
    assert math.isnan(m.translation_mean) and math.isnan(m.translation_std)
    assert math.isnan(m.translation_median)
    assert math.isnan(m.heading_mean) and math.isnan(m.rpe_translation_mean)
    assert m.availability == 0.0 and m.correct_availability == 0.0
    assert math.isnan(m.false_accept)
    assert math.isnan(m.time_to_first_correct)
    report = m.as_report()
    assert report["translation_error_m_mean"] is None
    assert report["false_accept"] is None
    assert report["availability"] == 0.0
    assert json.loads(json.dumps(report))["time_to_first_correct_s"] is None


def test_no_overlap_gives_nan_availability():
    T_true = se2_from_params(np.zeros((3, 3)))
    m = pair_metrics(make_trace([0.0, 1.0, 2.0], T_true, np.zeros((3, 3)), [False] * 3))
    assert math.isnan(m.availability) and math.isnan(m.correct_availability)
    assert math.isnan(m.time_to_first_correct)
    assert m.false_accept == 0.0
    assert m.as_report()["availability"] is None


def test_as_report_keys_units_and_json():
    m = pair_metrics(hand_trace())
    report = m.as_report()
    assert set(report) == {
        "translation_error_m_mean", "translation_error_m_std", "translation_error_m_median",
        "heading_error_deg_mean", "heading_error_deg_std", "availability",
        "correct_availability", "false_accept", "time_to_first_correct_s",
        "rpe_translation_m", "rpe_heading_deg", "ape_m", "rpe_m", "n_steps",
        "n_estimates", "n_overlap", "nees_mean", "nees_under_95", "confident_false_accept",
        "time_to_first_correct_per_overlap_s_median", "overlaps_found", "judge_availability",
        "n_overlaps"}
    # the trace has no covariance and no candidates: those figures are None, not 0
    assert report["nees_mean"] is None and report["judge_availability"] is None
    assert report["n_overlaps"] == 1 and report["overlaps_found"] == 1.0
    assert report["heading_error_deg_mean"] == pytest.approx(math.degrees(np.mean(HEAD)))
    assert report["heading_error_deg_std"] == pytest.approx(math.degrees(np.std(HEAD)))
    assert report["rpe_heading_deg"] == pytest.approx(math.degrees(np.mean(HEAD)))
    assert report["translation_error_m_mean"] == pytest.approx(np.mean(TRANS))
    assert report["n_estimates"] == 6 and isinstance(report["n_estimates"], int)
    assert json.loads(json.dumps(report, allow_nan=False)) == report


# --- relative pose error -------------------------------------------------------------------------

def test_rpe_zero_for_perfect_estimate():
    trace = random_trace(7)
    has = trace.has_estimate
    perfect = np.where(has[:, None], se2_to_params(trace.T_true), np.nan)
    trace = PairTrace(trace.times, trace.T_true, perfect, trace.overlap, trace.T_oi_bi,
                      trace.T_oj_bj)
    rpe = relative_pose_errors(trace)
    np.testing.assert_allclose(rpe[has], 0.0, atol=1e-9)
    assert np.all(np.isnan(rpe[~has]))


def test_rpe_of_heading_error_is_chord():
    # T_est = T_true R(delta): the alignment is off by a pure rotation delta about the origin of
    # oj. Robot j at distance d from that origin then appears displaced by the chord
    # 2 d sin(delta / 2); delta = 60 deg makes the chord exactly d = 10 m.
    delta, d = np.pi / 3, 10.0
    T_true = se2_from_params([[4.0, -7.0, 0.8], [-2.0, 3.0, -2.5]])
    estimate = se2_to_params(T_true @ se2_from_params([0.0, 0.0, delta]))
    T_oj_bj = se2_from_params([[6.0, 8.0, 1.2], [0.0, -10.0, -0.4]])
    T_oi_bi = se2_from_params([[1.0, 2.0, 0.5], [-30.0, 12.0, 3.0]])
    trace = make_trace([0.0, 1.0], T_true, estimate, [True, True], T_oi_bi, T_oj_bj)
    rpe = relative_pose_errors(trace)
    np.testing.assert_allclose(rpe[:, 0], [d, d], atol=1e-9)
    np.testing.assert_allclose(rpe[:, 0], 2 * d * np.sin(delta / 2), atol=1e-9)
    np.testing.assert_allclose(rpe[:, 1], delta, atol=1e-12)
    # the alignment error itself has no translation; only the RPE sees the lever arm
    np.testing.assert_allclose(step_errors(T_true, estimate)[:, 0], 0.0, atol=1e-9)
    m = pair_metrics(trace)
    assert m.rpe_translation_mean == pytest.approx(d)
    assert m.rpe_heading_mean == pytest.approx(delta)


def test_rpe_translation_hand_case():
    # truth identity, estimate shifted by (1, 0); robot j's body turned 90 deg at (5, 0):
    # seen in bj, the 1 m shift along oj's x is -1 m along bj's y; robot i's pose cancels.
    T_true = np.eye(3)[None]
    trace = make_trace([0.0], T_true, [[1.0, 0.0, 0.0]], [True],
                       se2_from_params([[3.0, 3.0, 2.0]]), se2_from_params([[5.0, 0.0, np.pi / 2]]))
    np.testing.assert_allclose(relative_pose_errors(trace), [[1.0, 0.0]], atol=1e-12)


# --- evo's APE and RPE ------------------------------------------------------------------------


@PROPS
@given(seeds)
def test_ape_is_the_relative_pose_translation_error(seed):
    # the same quantity computed twice: evo's APE of robot j's path in oi, and the error of
    # T_bi_bj (the rotation T_bi_oi keeps norms)
    trace = random_trace(seed)
    has = trace.has_estimate
    ape, rpe = trace.path_errors
    np.testing.assert_allclose(ape, relative_pose_errors(trace)[has, 0], atol=1e-9)
    assert rpe.shape == (max(int(has.sum()) - 1, 0),)
    m = pair_metrics(trace)
    if has.any():
        assert m.ape_rmse == pytest.approx(np.sqrt(np.mean(ape**2)), rel=1e-12)
        assert np.mean(ape) == pytest.approx(m.rpe_translation_mean, rel=1e-9, abs=1e-12)
    else:
        assert math.isnan(m.ape_rmse) and math.isnan(m.rpe_rmse)


@PROPS
@given(seeds)
def test_ape_and_rpe_are_evos(seed):
    """The path errors agree with evo's APE and RPE (translation part, default settings) on
    the same paths, which is what `evo_ape tum` and `evo_rpe tum` compute on exported files."""
    from evo.core import metrics as evo_metrics

    trace = random_trace(seed)
    has = trace.has_estimate
    ape, rpe = trace.path_errors
    if has.sum() < 2:
        return
    times = trace.times[has]
    truth = planar_trajectory(times, trace.T_true[has] @ trace.T_oj_bj[has])
    path = planar_trajectory(times, se2_from_params(trace.estimate[has]) @ trace.T_oj_bj[has])
    for metric, ours in ((evo_metrics.APE, ape), (evo_metrics.RPE, rpe)):
        theirs = metric(evo_metrics.PoseRelation.translation_part)
        theirs.process_data((truth, path))
        np.testing.assert_allclose(ours, theirs.error, atol=1e-9)


def test_rpe_sees_a_jump_of_the_alignment_only():
    # robot j stands still at (2, 0) in oj; the alignment is right, then off by 1 m along x for
    # two steps, then right again: APE 0, 1, 1, 0; RPE (consecutive steps) 1, 0, 1
    T_true = se2_from_params(np.tile([3.0, -1.0, 0.5], (4, 1)))
    off = se2_to_params(se2_from_params([1.0, 0.0, 0.0]) @ T_true[0])
    estimate = [se2_to_params(T_true[0]), off, off, se2_to_params(T_true[0])]
    T_oj_bj = se2_from_params(np.tile([2.0, 0.0, 0.3], (4, 1)))
    trace = make_trace(np.arange(4.0), T_true, estimate, [True] * 4, None, T_oj_bj)
    ape, rpe = trace.path_errors
    np.testing.assert_allclose(ape, [0, 1, 1, 0], atol=1e-9)
    np.testing.assert_allclose(rpe, [1, 0, 1], atol=1e-9)
    m = pair_metrics(trace)
    assert m.rpe_rmse == pytest.approx(np.sqrt(2 / 3))


# --- pooling -------------------------------------------------------------------------------------

@PROPS
@given(seeds, seeds)
def test_pooled_equals_concatenation(seed_a, seed_b):
    a = random_trace(seed_a)
    b = random_trace(seed_b, t0=float(a.times[-1]) + 1.0)
    pooled = pooled_metrics([a, b])
    joined = pair_metrics(concat(a, b))
    for name in ("n_steps", "n_estimates", "n_overlap"):
        assert getattr(pooled, name) == getattr(joined, name)
    for name in ("translation_mean", "translation_std", "heading_mean", "heading_std",
                 "availability", "correct_availability", "false_accept",
                 "rpe_translation_mean", "rpe_heading_mean", "ape_rmse"):
        p, j = getattr(pooled, name), getattr(joined, name)
        assert (math.isnan(p) and math.isnan(j)) or p == pytest.approx(j, rel=1e-9, abs=1e-12)


def test_pooled_time_to_first_correct_is_mean_over_pairs_that_have_one():
    a = hand_trace()  # 3.25 s
    T_true = se2_from_params(np.zeros((3, 3)))
    b = make_trace([0.0, 1.0, 3.0], T_true, [NAN3, [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
                   [True, True, True])  # 3.0 s
    never = make_trace([0.0, 1.0], T_true[:2], [NAN3, NAN3], [True, True])
    assert pooled_metrics([a, b, never]).time_to_first_correct == pytest.approx(3.125)
    assert math.isnan(pooled_metrics([never, never]).time_to_first_correct)
    assert pooled_metrics([a, b]).false_accept == pytest.approx(2 / 8)


def test_pooled_empty_raises():
    with pytest.raises(DataError, match="at least one"):
        pooled_metrics([])


# --- validation ----------------------------------------------------------------------------------

def _good_fields(n: int = 4) -> dict:
    return {"times": np.arange(float(n)), "T_true": se2_from_params(np.zeros((n, 3))),
            "estimate": np.zeros((n, 3)), "overlap": np.ones(n, bool),
            "T_oi_bi": se2_from_params(np.zeros((n, 3))),
            "T_oj_bj": se2_from_params(np.zeros((n, 3)))}


@pytest.mark.parametrize(("field", "value", "pattern"), [
    ("estimate", np.zeros((4, 2)), r"estimate.*\(4, 3\).*\(4, 2\)"),
    ("estimate", np.zeros((3, 3)), r"estimate.*\(3, 3\)"),
    ("estimate", np.array([[0.0, np.nan, 0.0]] * 4), "estimate.*partly non-finite"),
    ("estimate", np.array([[0.0, 0.0, np.inf]] * 4), "estimate.*partly non-finite"),
    ("T_true", np.zeros((4, 2, 2)), r"T_true.*\(4, 3, 3\).*\(4, 2, 2\)"),
    ("T_true", se2_from_params(np.zeros((4, 3))) * 2.0, "T_true.*not an SE\\(2\\)"),
    ("T_oi_bi", np.full((4, 3, 3), np.nan), "T_oi_bi.*non-finite"),
    ("T_oj_bj", np.eye(3), r"T_oj_bj.*\(3, 3\)"),
    ("overlap", np.ones(5, bool), r"overlap.*\(4,\).*\(5,\)"),
    ("overlap", np.array([0.0, 0.5, 1.0, 1.0]), "overlap.*booleans"),
    ("times", np.array([0.0, 1.0, 1.0, 2.0]), r"times.*strictly increasing.*times\[2\]"),
    ("times", np.array([0.0, 2.0, 1.0, 3.0]), "times.*strictly increasing"),
    ("times", np.zeros((4, 1)), r"times.*\(S,\)"),
    ("times", np.array([0.0, 1.0, np.inf, 3.0]), "times.*non-finite"),
])
def test_pair_trace_rejects_bad_input(field, value, pattern):
    fields = _good_fields()
    fields[field] = value
    with pytest.raises(DataError, match=pattern):
        PairTrace(**fields)


def test_pair_trace_accepts_int_overlap_and_is_read_only():
    fields = _good_fields()
    fields["overlap"] = np.array([0, 1, 1, 0])
    trace = PairTrace(**fields)
    assert trace.overlap.dtype == bool and trace.overlap.tolist() == [False, True, True, False]
    with pytest.raises(ValueError, match="read-only"):
        trace.estimate[0, 0] = 1.0


def test_step_errors_rejects_bad_shapes():
    with pytest.raises(DataError, match="estimate"):
        step_errors(np.eye(3)[None], [[1.0, 2.0]])
    with pytest.raises(DataError, match="T_true"):
        step_errors(np.eye(3)[None].repeat(2, axis=0), [[1.0, 2.0, 0.0]])
    with pytest.raises(DataError, match="T_true"):
        step_errors(np.zeros((1, 2, 2)), [[1.0, 2.0, 0.0]])


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"translation": -1.0}, "translation"),
    ({"translation": 0.0}, "translation"),
    ({"heading": math.inf}, "heading"),
    ({"heading": math.nan}, "heading"),
    ({"translation": "1"}, "translation"),
])
def test_thresholds_reject_bad_values(kwargs, field):
    with pytest.raises(ConfigError, match=f"Thresholds.{field}.*got"):
        Thresholds(**kwargs)


def test_thresholds_defaults():
    assert Thresholds().translation == 1.0
    assert Thresholds().heading == pytest.approx(math.radians(5.0))
