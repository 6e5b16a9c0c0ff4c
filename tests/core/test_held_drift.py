"""How an alignment held without registrations drifts: `covariance.held_drift` against the
frames' turns it models, `TCAFF.update`'s per-step held_Q and `PairwiseAligner` giving it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import TCAFF, FrameAlignerParams, ObjectMap, PairwiseAligner, TCAFFParams
from tcaff_gtsam.covariance import held_drift
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.pairwise import held_growth
from tcaff_gtsam.tcaff import AlignmentEstimate

coordinate = st.floats(-60, 60)


def turned_about(point: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) the SE(2) turn by `angle` about `point` (2,)."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    T = np.eye(3)
    T[:2, :2], T[:2, 2] = R, point - R @ point
    return T


def turn_direction(T: np.ndarray, left: bool, point: np.ndarray) -> np.ndarray:
    """(3,) how x of T_oi_oj moves per radian when robot i's frame (left) or robot j's turns
    about `point` in that frame: central differences of the composed transforms."""
    h = 1e-6
    moved = []
    for a in (h, -h):
        D = turned_about(point, a)
        moved.append(se2_to_params(D @ T if left else T @ np.linalg.inv(D)))
    step = moved[0] - moved[1]
    step[2] = (step[2] + np.pi) % (2 * np.pi) - np.pi
    return step / (2 * h)


@settings(max_examples=40, deadline=None)
@given(x=st.tuples(coordinate, coordinate, st.floats(-np.pi, np.pi)),
       ego=st.tuples(coordinate, coordinate), other=st.tuples(coordinate, coordinate),
       d_t=st.floats(0, 0.5), d_theta=st.floats(0, 0.05))
def test_held_drift_is_the_covariance_of_each_frame_turning_about_its_robot(
        x, ego, other, d_t, d_theta):
    """The growth is d_t^2 in each translation axis plus half of d_theta^2 for each robot's
    frame turning about where that robot is, each turn's direction taken from composing the
    SE(2) transforms themselves: robot i's turn acts on T_oi_oj from the left, robot j's from
    the right."""
    x, ego, other = np.array(x), np.array(ego), np.array(other)
    T = se2_from_params(x)
    g_i = turn_direction(T, True, ego)
    g_j = turn_direction(T, False, other)
    expected = (d_t**2 * np.diag([1.0, 1.0, 0.0])
                + 0.5 * d_theta**2 * (np.outer(g_i, g_i) + np.outer(g_j, g_j)))
    growth = held_drift(x, ego, other, (d_t, d_theta))
    np.testing.assert_allclose(growth, expected, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(growth, growth.T)
    assert growth[2, 2] == pytest.approx(d_theta**2)


def test_robots_at_one_place_share_one_lever_and_the_origin_has_none():
    """Where robot i stands where robot j does (p_i = T_oi_oj p_j) the two turns move the
    alignment alike; at both frames' origins a turn leaves the translation alone."""
    x = np.array([3.0, -4.0, 0.6])
    other = np.array([12.0, 5.0])
    ego = se2_from_params(x)[:2] @ np.r_[other, 1.0]
    d_theta = 0.01
    growth = held_drift(x, ego, other, (0.0, d_theta))
    g = turn_direction(se2_from_params(x), False, other)
    np.testing.assert_allclose(growth, d_theta**2 * np.outer(g, g), rtol=1e-5, atol=1e-12)
    assert np.linalg.matrix_rank(growth, tol=1e-12) == 1
    at_origin = held_drift(np.array([0.0, 0.0, 0.6]), np.zeros(2), np.zeros(2), (0.1, d_theta))
    np.testing.assert_allclose(at_origin, np.diag([0.01, 0.01, d_theta**2]), atol=1e-15)


@pytest.mark.parametrize(("args", "error", "match"), [
    (([1.0, 2.0], [0.0, 0.0], [0.0, 0.0], (0.01, 0.01)), DataError, "x must have shape"),
    (([1.0, 2.0, np.nan], [0.0, 0.0], [0.0, 0.0], (0.01, 0.01)), DataError, "x must be finite"),
    (([1.0, 2.0, 0.1], [0.0, 0.0, 1.0], [0.0, 0.0], (0.01, 0.01)), DataError,
     "ego_point must have shape"),
    (([1.0, 2.0, 0.1], [0.0, 0.0], ["a", "b"], (0.01, 0.01)), DataError,
     "other_point must be real"),
    (([1.0, 2.0, 0.1], [0.0, 1e12], [0.0, 0.0], (0.01, 0.01)), DataError, "ego_point must be"),
    (([1.0, 2.0, 0.1], [0.0, 0.0], [0.0, 0.0], (-0.01, 0.01)), ConfigError, "map_drift"),
    (([1.0, 2.0, 0.1], [0.0, 0.0], [0.0, 0.0], "drift"), ConfigError, "map_drift"),
])
def test_held_drift_refuses_bad_input_naming_it(args, error, match):
    with pytest.raises(error, match=rf"^held_drift[:.] ?{match}"):
        held_drift(*args)


TRUTH = np.array([4.0, -1.0, 0.7])
EMPTY = np.empty((0, 3))
R = np.diag([0.04, 0.04, 1e-3])
HELD_Q = np.diag([1e-4, 1e-4, 2e-5])


def held_run(filt: TCAFF, growth_at) -> list:
    """20 steps measuring TRUTH, then 30 without; `growth_at(k)` is the held_Q given at the
    k-th step (0-based)."""
    out = []
    for k in range(50):
        zs = TRUTH[None] if k < 20 else EMPTY
        out.append(filt.update(zs, np.broadcast_to(R, (len(zs), 3, 3)), held_Q=growth_at(k)))
    return out


def test_a_held_estimate_grows_by_the_held_Q_given_at_each_step():
    """Given at a step, held_Q replaces params.held_Q for that step's growth of a leaf held
    for more than W steps; the first W steps still grow by Q."""
    params = TCAFFParams(held_Q=HELD_Q)
    W, Q = params.window, params.Q
    given = [np.diag([1e-3 * (1 + k % 3), 2e-3, 1e-5 * (1 + k % 2)]) for k in range(50)]
    estimates = held_run(TCAFF(params), lambda k: given[k])
    plain = held_run(TCAFF(params), lambda k: None)
    measured = estimates[19]
    assert measured.measurement == 0
    np.testing.assert_array_equal(measured.P, plain[19].P)
    for k in range(1, 30):
        growth = min(k, W) * Q + sum(given[20 + m] for m in range(W, k))
        np.testing.assert_allclose(estimates[19 + k].P, measured.P + growth, rtol=1e-9)
        np.testing.assert_allclose(plain[19 + k].P, measured.P + min(k, W) * Q
                                   + max(0, k - W) * HELD_Q, rtol=1e-9)


@pytest.mark.parametrize(("params", "held_Q", "match"), [
    (TCAFFParams(), HELD_Q, "params.held_Q is None"),
    (TCAFFParams(held_Q=HELD_Q), np.eye(2), r"held_Q must have shape \(3, 3\)"),
    (TCAFFParams(held_Q=HELD_Q), np.diag([1.0, np.nan, 1.0]), "held_Q"),
    (TCAFFParams(held_Q=HELD_Q), np.diag([1.0, -1.0, 1.0]), "held_Q is not positive definite"),
    (TCAFFParams(held_Q=HELD_Q), np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]),
     "held_Q is not symmetric"),
    (TCAFFParams(held_Q=HELD_Q), "diag", "held_Q"),
])
def test_a_bad_held_Q_is_refused_and_the_filter_goes_on_as_before(params, held_Q, match):
    filt, twin = TCAFF(params), TCAFF(params)
    for _ in range(3):
        for f in (filt, twin):
            f.update(TRUTH[None], R[None])
    with pytest.raises(DataError, match=rf"^TCAFF\.update: .*{match}"):
        filt.update(TRUTH[None], R[None], held_Q=held_Q)
    assert filt.step == twin.step == 3
    a, b = filt.update(TRUTH[None], R[None]), twin.update(TRUTH[None], R[None])
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)


def drifting_maps(T_oi_oj: np.ndarray) -> tuple[ObjectMap, ObjectMap, ObjectMap, float]:
    """The ego map, the other map sharing its objects under T_oi_oj, another map of the
    other robot sharing none, and the time they were made."""
    pair = overlapping_maps(np.random.default_rng(4), 30, 0.8, 0.02, T_oi_oj=T_oi_oj)
    apart = overlapping_maps(np.random.default_rng(5), 30, 0.8, 0.02, T_oi_oj=T_oi_oj)
    return pair.ego, pair.other, apart.other, pair.now


def test_the_pair_grows_a_held_alignment_about_where_its_robots_are():
    """Far from the frames' origins, an alignment held after its maps stop overlapping grows,
    once it has gone W steps unmeasured, by `held_growth` of the maps of that step: the
    aligner's map drift with each heading turning about where its robot's map is, which
    moves the translation more than the drift's own translation part."""
    T_oi_oj = se2_from_params([30.0, -25.0, 0.8])
    ego, other, apart, now = drifting_maps(T_oi_oj)
    pair = PairwiseAligner()
    W = pair.filter.params.window
    estimates, growths = [], []
    for k in range(40):
        t = now + 0.01 * k
        seen = other if k < 20 else apart
        growths.append(held_growth(pair.aligner.params, pair.filter.held, ego, seen, t))
        estimates.append(pair.update(t, ego, seen))
    assert estimates[19].measurement >= 0
    assert all(e is not None and e.measurement < 0 for e in estimates[20:])
    diagonal = pair.filter.params.held_Q
    for k in range(20 + W, 40):
        step = estimates[k].P - estimates[k - 1].P
        np.testing.assert_allclose(step, growths[k], rtol=1e-6, atol=1e-15)
        assert step[0, 0] + step[1, 1] > 10 * (diagonal[0, 0] + diagonal[1, 1])


def test_a_pair_with_a_held_Q_of_its_own_keeps_it():
    """A filter that names its own held_Q grows by it: the maps' lever is for the held_Q the
    pair makes of the aligner's map drift."""
    T_oi_oj = se2_from_params([30.0, -25.0, 0.8])
    ego, other, apart, now = drifting_maps(T_oi_oj)
    own = np.diag([1e-3, 1e-3, 1e-5])
    pair = PairwiseAligner(FrameAlignerParams(), TCAFFParams(held_Q=own))
    W = pair.filter.params.window
    estimates = [pair.update(now + 0.01 * k, ego, other if k < 20 else apart)
                 for k in range(40)]
    for k in range(20 + W, 40):
        np.testing.assert_allclose(estimates[k].P - estimates[k - 1].P, own, rtol=1e-6,
                                   atol=1e-15)


def test_held_growth_needs_a_held_alignment_and_two_maps():
    params = FrameAlignerParams()
    ego, other, _, now = drifting_maps(se2_from_params([3.0, 1.0, 0.2]))
    empty = ObjectMap(np.empty((0, 3)), np.empty(0), np.empty(0), np.empty(0))
    assert held_growth(params, None, ego, other, now) is None
    pair = PairwiseAligner()
    for k in range(12):
        pair.update(now + 0.01 * k, ego, other)
    held = pair.filter.held
    assert held is not None
    assert held_growth(params, held, empty, other, now) is None
    assert held_growth(params, held, ego, empty, now) is None
    growth = held_growth(params, held, ego, other, now)
    assert growth.shape == (3, 3) and np.all(np.linalg.eigvalsh(growth) > 0)


def test_held_growth_places_each_robot_at_its_most_recently_seen_objects():
    """A robot is where its map's latest objects are: weighted as a registration weights
    them, an object seen 10 s ago barely moves the lever of one seen now."""
    params = FrameAlignerParams()
    now = 50.0

    def a_map(recent_xy, old_xy):
        return ObjectMap(np.array([[*recent_xy, 0.5], [*old_xy, 0.5], [*old_xy, 1.5]]),
                         np.ones(3), np.ones(3), np.array([now, now - 10.0, now - 12.0]))

    x = np.array([2.0, -3.0, 0.4])
    estimate = AlignmentEstimate(x, np.eye(3), 0.0, 1, 1, 1, 0)
    growth = held_growth(params, estimate, a_map((40.0, 5.0), (0.0, 0.0)),
                         a_map((-20.0, 30.0), (1.0, 1.0)), now)
    np.testing.assert_allclose(
        growth, held_drift(x, np.array([40.0, 5.0]), np.array([-20.0, 30.0]),
                           params.map_drift), rtol=2e-3)


def test_held_growth_refuses_bad_input_naming_it():
    ego, other, _, now = drifting_maps(se2_from_params([3.0, 1.0, 0.2]))
    params = FrameAlignerParams()
    good = AlignmentEstimate(np.array([1.0, 2.0, 0.3]), np.eye(3), 0.0, 1, 1, 1, 0)
    with pytest.raises(ConfigError, match=r"held_growth\.params"):
        held_growth(TCAFFParams(), good, ego, other, now)
    for held in ("x", AlignmentEstimate(np.array([1.0, np.nan, 0.3]), np.eye(3), 0.0, 1, 1, 1, 0),
                 AlignmentEstimate(np.array([1.0, 2.0]), np.eye(2), 0.0, 1, 1, 1, 0)):
        with pytest.raises(DataError, match=r"^held_growth: held must be"):
            held_growth(params, held, ego, other, now)
    with pytest.raises(DataError, match=r"^held_growth: other_map must be an ObjectMap"):
        held_growth(params, good, ego, other.centroids, now)
    with pytest.raises(DataError, match=r"^held_growth: now"):
        held_growth(params, good, ego, other, float("nan"))
