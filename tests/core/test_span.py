"""kappa from the odometry's drift: misplacement of an object seen a span ago, the advice, and
the VIO-like drift model it is drawn with."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.span import (
    SPANS,
    advise_kappa,
    misplacement,
    random_drive,
    vio_like_odometry,
)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), x=st.floats(-50, 50), y=st.floats(-50, 50),
       yaw=st.floats(-math.pi, math.pi))
def test_an_odometry_frame_anywhere_misplaces_nothing(seed, x, y, yaw):
    """Exact odometry in another frame (the truth moved and turned as a whole) places every
    object where the truth does: the error is zero at every span."""
    times, T = random_drive(np.random.default_rng(seed), 120.0, 0.5)
    offset = se2_from_params([x, y, yaw])
    rms = misplacement(times, T, offset @ T, SPANS[:6])
    np.testing.assert_allclose(rms, 0.0, atol=1e-9)


def test_a_heading_error_after_the_sighting_misplaces_by_range_times_angle():
    """Standing still, the odometry's heading turning by a constant rate: an object seen
    `span` s ago straight ahead at range r is misplaced by 2 r sin(rate span / 2)."""
    times = np.arange(0.0, 100.0 + 1e-9, 0.5)
    rate = math.radians(0.1)
    T_true = se2_from_params(np.zeros((times.size, 3)))
    T_odom = se2_from_params(np.column_stack([np.zeros((times.size, 2)), rate * times]))
    spans = np.array([5.0, 20.0, 60.0])
    rms = misplacement(times, T_true, T_odom, spans, landmark_range=3.0, every=1.0)
    np.testing.assert_allclose(rms, 2 * 3.0 * np.sin(rate * spans / 2), rtol=1e-9)
    assert np.isnan(misplacement(times, T_true, T_odom, np.array([150.0]))[0])
    # a single robot's times may be a plain list
    np.testing.assert_allclose(misplacement(times.tolist(), T_true, T_odom, spans, 3.0, 1.0),
                               rms)
    # several robots pool their errors: the same robot twice gives the same figure
    np.testing.assert_allclose(misplacement([times, times], [T_true, T_true], [T_odom, T_odom],
                                            spans, 3.0, 1.0), rms)


def test_a_scale_error_misplaces_by_the_error_times_the_distance_moved():
    times = np.arange(0.0, 60.0 + 1e-9, 0.1)
    T_true = se2_from_params(np.column_stack([0.4 * times, np.zeros((times.size, 2))]))
    T_odom = se2_from_params(np.column_stack([1.02 * 0.4 * times, np.zeros((times.size, 2))]))
    rms = misplacement(times, T_true, T_odom, np.array([10.0, 30.0]), 2.0, 1.0)
    np.testing.assert_allclose(rms, 0.02 * 0.4 * np.array([10.0, 30.0]), rtol=1e-6)


def test_the_advice_is_the_longest_span_of_the_first_run_within_half_epsilon():
    spans = np.array([5.0, 10.0, 20.0, 30.0])
    advice = advise_kappa(np.array([0.01, 0.1, 0.125, 0.2]), spans, epsilon=0.25)
    assert advice.kappa == 20.0 and advice.bound == 0.125
    # a span past the bound ends the run, even if a longer one happens to be within again
    assert advise_kappa(np.array([0.01, 0.2, 0.1, 0.1]), spans, 0.25).kappa == 5.0
    assert advise_kappa(np.array([0.2, 0.3, 0.4, 0.5]), spans, 0.25).kappa is None
    assert advise_kappa(np.array([0.01, 0.02, np.nan, np.nan]), spans, 0.25).kappa == 10.0
    assert advise_kappa(np.array([0.01, 0.02, 0.03, 0.04]), spans, 0.25).kappa == 30.0


def test_vio_like_drift_grows_with_its_rates_and_is_the_truth_without_them():
    rng = np.random.default_rng(3)
    times, T = random_drive(rng, 600.0, 0.5)
    exact = vio_like_odometry(np.random.default_rng(0), times, T, 0.0, 0.0)
    np.testing.assert_allclose(exact, np.linalg.inv(T[0]) @ T, atol=1e-9)
    rms = {}
    for rate in (0.5, 1.0, 4.0):
        runs = [misplacement(times, T, vio_like_odometry(np.random.default_rng(s), times, T,
                                                         rate, 0.01), SPANS[:8])
                for s in range(4)]
        rms[rate] = np.mean(runs, axis=0)
        assert np.all(np.diff(rms[rate]) > 0)  # the longer the span, the larger the error
    assert np.all(rms[0.5] < rms[1.0]) and np.all(rms[1.0] < rms[4.0])
    # the heading's random walk: after one minute its std is the rate
    ends = [se2_to_params(vio_like_odometry(np.random.default_rng(s), times[:601], T[:601],
                                            2.0, 0.0)[-1] @ np.linalg.inv(
        np.linalg.inv(T[0]) @ T[600]))[2] for s in range(400)]
    assert np.degrees(np.std(ends)) == pytest.approx(2.0, rel=0.15)


@pytest.mark.parametrize(("call", "match"), [
    (lambda t, T: misplacement(t[::-1], T, T), "times must be 2 or more increasing"),
    (lambda t, T: misplacement(t, T[:-1], T), r"T_world_body must be \(\d+, 3, 3\)"),
    (lambda t, T: misplacement(t, T, T[..., :2]), r"T_odom_body must be \(\d+, 3, 3\)"),
    (lambda t, T: misplacement(t, T, T, [10.0, 5.0]), "spans must be increasing"),
    (lambda t, T: misplacement(t, T, T, [0.0]), "spans must be increasing"),
    (lambda t, T: misplacement(t, T, T, landmark_range=-1.0), "landmark_range"),
    (lambda t, T: misplacement(t, T, T, every=math.nan), "every"),
    (lambda t, T: misplacement(t, np.where(T == 1.0, np.nan, T), T), "non-finite"),
    (lambda t, T: advise_kappa([0.1, 0.2], [5.0, 10.0, 20.0]), r"rms must be \(3,\)"),
    (lambda t, T: advise_kappa([0.1], [5.0], epsilon=0.0), "epsilon"),
    (lambda t, T: vio_like_odometry(np.random.default_rng(0), t, T, -1.0, 0.0),
     "heading_rw_deg_per_sqrt_min"),
    (lambda t, T: random_drive(np.random.default_rng(0), math.inf, 1.0), "duration"),
    (lambda t, T: random_drive(np.random.default_rng(0), 10.0, -1.0), "speed"),
    (lambda t, T: random_drive(None, 10.0, 1.0), "rng must be a numpy Generator"),
    (lambda t, T: vio_like_odometry(0, t, T, 1.0, 0.01), "rng must be a numpy Generator"),
    (lambda t, T: misplacement([t, t], [T], [T, T]), "must be lists of 2 pose arrays"),
    (lambda t, T: misplacement([t, t], T, T), "must be lists of 2 pose arrays"),
])
def test_bad_arguments_are_data_errors_naming_them(call, match):
    times, T = random_drive(np.random.default_rng(0), 30.0, 0.5, step=0.5)
    with pytest.raises(DataError, match=match):
        call(times, T)
