"""CLIPPER's epsilon widened for the maps' span (`FrameAlignerParams.epsilon_drift`): objects
placed through a drifting odometry a long span apart disagree by more than the sensor noise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam import FrameAligner, FrameAlignerParams, ObjectMap
from tcaff_gtsam.clipper import ClipperParams
from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params
from tcaff_gtsam.params import ParameterError


@settings(max_examples=60, deadline=None)
@given(epsilon=st.floats(0.01, 2.0), sigmas=st.floats(0.0, 5.0), d_t=st.floats(0.0, 0.1),
       spans=st.lists(st.floats(0.0, 1e4), min_size=2, max_size=2))
def test_span_epsilon_is_clippers_at_no_span_and_grows_with_the_span(epsilon, sigmas, d_t, spans):
    params = FrameAlignerParams(clipper=ClipperParams(epsilon=epsilon), epsilon_drift=sigmas,
                                map_drift=(d_t, 0.0))
    assert params.span_epsilon(0.0) == epsilon
    short, long = sorted(spans)
    assert epsilon <= params.span_epsilon(short) <= params.span_epsilon(long)
    # its excess over epsilon, squared, is sigmas^2 d_t^2 per second of span
    assert math.isclose(params.span_epsilon(long) ** 2 - epsilon**2, (sigmas * d_t) ** 2 * long,
                        rel_tol=1e-9, abs_tol=1e-12)
    # switched off, it is epsilon itself, to the bit
    assert FrameAlignerParams(clipper=ClipperParams(epsilon=epsilon), epsilon_drift=0.0,
                              map_drift=(d_t, 0.0)).span_epsilon(long) == epsilon


def test_the_defaults_widen_little_at_20_s_and_to_35_cm_at_150_s():
    params = FrameAlignerParams()
    assert params.span_epsilon(20.0) == pytest.approx(0.2655, abs=1e-4)
    assert params.span_epsilon(150.0) == pytest.approx(0.3500, abs=1e-4)
    assert FrameAlignerParams.reference().span_epsilon(150.0) == params.clipper.epsilon


@pytest.mark.parametrize("value", [-0.1, math.inf, -math.inf])
def test_epsilon_drift_out_of_range_is_a_parameter_error_naming_it(value):
    with pytest.raises(ParameterError, match=r"^FrameAlignerParams\.epsilon_drift = "):
        FrameAlignerParams(epsilon_drift=value)


@pytest.mark.parametrize("span", [-1.0, math.nan, math.inf, "150", None, True, [150.0]])
def test_a_bad_span_is_a_data_error_naming_it(span):
    with pytest.raises(DataError, match=r"^FrameAlignerParams\.span_epsilon: span must be "):
        FrameAlignerParams().span_epsilon(span)


def test_settings_that_overflow_epsilon_are_refused_not_returned_as_inf():
    # the largest settings the parameters take, over a span no map has
    params = FrameAlignerParams(epsilon_drift=1e6, map_drift=(1.0, 0.0))
    with pytest.raises(DataError, match=r"overflows epsilon$"):
        params.span_epsilon(1e300)


def bent_maps(bend: float):
    """Twelve objects of one size seen over 140 s; the other robot's map holds them moved by
    a true alignment and shifted along x by `bend` metres times each object's age over 140 s
    (a drift that grew while they were seen), so their distances disagree by up to `bend`."""
    rng = np.random.default_rng(7)
    p = rng.uniform(0.0, 8.0, (12, 2))
    ages = rng.permutation(np.linspace(0.0, 140.0, 12))
    bent = p + np.column_stack([bend * ages / 140.0, np.zeros(12)])
    T = se2_from_params([3.0, -2.0, 0.7])
    q = (bent - T[:2, 2]) @ T[:2, :2]  # the other map's coordinates: T q = bent
    now = 200.0

    def objects(points):
        return ObjectMap(np.column_stack([points, np.zeros(12)]), np.full(12, 0.5),
                         np.full(12, 0.5), now - ages)

    gaps = np.abs(np.linalg.norm(p[:, None] - p[None], axis=2)
                  - np.linalg.norm(bent[:, None] - bent[None], axis=2))
    return objects(p), objects(q), now, gaps.max()


@pytest.mark.parametrize("kappa", [150.0, math.inf])
def test_maps_bent_by_drift_over_a_long_span_keep_more_true_associations(kappa):
    """Distances disagreeing by up to 0.31 m: CLIPPER's 0.25 m keeps the objects whose ages
    lie close enough together (8 of 12); widened for the 150 s span (0.35 m; maps that keep
    every object span their oldest object's age, 140 s: 0.34 m) it also takes pairs further
    apart in age (9), every one of them true. (Not all 12: the similarity of a pair
    disagreeing by 0.3 m is exp(-2) at sigma = 0.15 m, too weak for the densest clique.)"""
    ego, other, now, widest = bent_maps(0.45)
    assert 0.25 < widest < 0.35
    found = {}
    for sigmas in (0.0, FrameAlignerParams().epsilon_drift):
        candidates = FrameAligner(FrameAlignerParams(kappa=kappa, epsilon_drift=sigmas)
                                  ).measurements(ego, other, now)
        assert len(candidates) == 1
        found[sigmas] = candidates[0].associations
        # object k of one map is object k of the other
        np.testing.assert_array_equal(found[sigmas][:, 0], found[sigmas][:, 1])
    assert len(found[FrameAlignerParams().epsilon_drift]) > len(found[0.0])
