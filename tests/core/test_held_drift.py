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
from tcaff_gtsam.geometry import compose, se2_from_params, se2_to_params, wrap_angle
from tcaff_gtsam.pairwise import HeldDrift, fed_by
from tcaff_gtsam.tcaff import AlignmentEstimate

coordinate = st.floats(-60, 60)


def turned_about(point: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) the SE(2) turn by `angle` about `point` (2,)."""
    return compose(se2_from_params([*point, 0.0]), se2_from_params([0.0, 0.0, angle]),
                   se2_from_params([*-point, 0.0]))


def turn_direction(T: np.ndarray, left: bool, point: np.ndarray) -> np.ndarray:
    """(3,) how x of T_oi_oj moves per radian when robot i's frame (left) or robot j's turns
    about `point` in that frame: central differences of the composed transforms."""
    h = 1e-6
    moved = []
    for a in (h, -h):
        D = turned_about(point, a)
        moved.append(se2_to_params(D @ T if left else T @ np.linalg.inv(D)))
    step = moved[0] - moved[1]
    step[2] = wrap_angle(step[2])
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
    # central differences of transforms tens of metres from the origin carry about 1e-9 of
    # rounding per unit of lever
    scale = d_t**2 + d_theta**2 * (1.0 + g_i @ g_i + g_j @ g_j)
    np.testing.assert_allclose(growth, expected, rtol=1e-5, atol=1e-7 * scale + 1e-300)
    np.testing.assert_allclose(growth, growth.T)
    assert growth[2, 2] == pytest.approx(d_theta**2, rel=1e-6, abs=1e-8 * scale)


def test_robots_at_one_place_share_one_lever_and_the_origin_has_none():
    """Where robot i stands where robot j does (p_i = T_oi_oj p_j) the two turns move the
    alignment alike; at both frames' origins a turn leaves the translation alone."""
    x = np.array([3.0, -4.0, 0.6])
    other = np.array([12.0, 5.0])
    ego = se2_from_params(x)[:2] @ np.r_[other, 1.0]
    d_theta = 0.01
    growth = held_drift(x, ego, other, (0.0, d_theta))
    g = turn_direction(se2_from_params(x), False, other)
    np.testing.assert_allclose(growth, d_theta**2 * np.outer(g, g), rtol=1e-5,
                               atol=1e-7 * d_theta**2 * (g @ g))
    # one direction, the others lifted only to 1e-9 of it
    assert np.linalg.matrix_rank(growth, tol=1e-6 * np.abs(growth).max()) == 1
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


def fed_pair_drift(pair: PairwiseAligner) -> HeldDrift:
    """A HeldDrift for the pair's aligner and filter, as the pair makes its own."""
    return HeldDrift(pair.aligner.params, pair.filter.params)


def test_the_pair_grows_a_held_alignment_about_where_its_robots_are():
    """Far from the frames' origins, an alignment held after its maps stop overlapping grows,
    once it has gone W steps unmeasured, by `HeldDrift.growth` of the maps of that step: the
    aligner's map drift with each heading turning about where its robot's map is, which
    moves the translation more than the drift's own translation part."""
    ego, other, apart, now = drifting_maps(se2_from_params([30.0, -25.0, 0.8]))
    pair = PairwiseAligner()
    drift = fed_pair_drift(pair)
    assert drift.applies
    W = pair.filter.params.window
    estimates, growths = [], []
    for k in range(40):
        t = now + 0.01 * k
        seen = other if k < 20 else apart
        growths.append(drift.growth(pair.filter.held, ego, seen, t))
        estimates.append(pair.update(t, ego, seen))
    assert estimates[19].measurement >= 0
    assert all(e is not None and e.measurement < 0 for e in estimates[20:])
    diagonal = pair.filter.params.held_Q
    for k in range(20 + W, 40):
        step = estimates[k].P - estimates[k - 1].P
        np.testing.assert_allclose(step, growths[k], rtol=1e-6, atol=1e-15)
        assert step[0, 0] + step[1, 1] > 10 * (diagonal[0, 0] + diagonal[1, 1])


def test_a_silent_step_keeps_the_robot_where_it_was_last_seen():
    """An empty map (a step on which the neighbour's map did not arrive) leaves that robot
    where its last map placed it: the growth is the last step's, not the diagonal's."""
    ego, other, apart, now = drifting_maps(se2_from_params([30.0, -25.0, 0.8]))
    pair = PairwiseAligner()
    W = pair.filter.params.window
    for k in range(20 + W + 2):
        pair.update(now + 0.01 * k, ego, other if k < 20 else apart)
    placed = pair._held_drift.points
    held = pair.filter.held
    estimate = pair.update(now + 0.01 * (20 + W + 2), ego, ObjectMap.empty())
    points = pair._held_drift.points
    np.testing.assert_array_equal(points[1], placed[1])
    np.testing.assert_allclose(estimate.P - held.P,
                               held_drift(held.x, points[0], placed[1],
                                          pair.aligner.params.map_drift), rtol=1e-6)


def test_it_applies_to_the_map_drifts_own_held_Q_however_it_was_given():
    """The lever replaces the held_Q made of the aligner's map drift, whether `fed_by` made it
    or the caller passed the same one (the study's stages pass theirs); a held_Q of the
    caller's own is kept."""
    ego, other, apart, now = drifting_maps(se2_from_params([30.0, -25.0, 0.8]))
    made = PairwiseAligner()
    again = PairwiseAligner(made.aligner.params, made.filter.params)
    own = np.diag([1e-3, 1e-3, 1e-5])
    kept = PairwiseAligner(FrameAlignerParams(), TCAFFParams(held_Q=own))
    assert fed_pair_drift(again).applies and not fed_pair_drift(kept).applies
    W = made.filter.params.window
    runs = [[p.update(now + 0.01 * k, ego, other if k < 20 else apart) for k in range(40)]
            for p in (made, again, kept)]
    for a, b in zip(runs[0], runs[1], strict=True):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a.P, b.P)
    for k in range(20 + W, 40):
        np.testing.assert_allclose(runs[2][k].P - runs[2][k - 1].P, own, rtol=1e-6,
                                   atol=1e-15)


def test_the_growth_needs_a_held_alignment_and_both_robots_seen():
    ego, other, _, now = drifting_maps(se2_from_params([3.0, 1.0, 0.2]))
    pair = PairwiseAligner()
    for k in range(12):
        pair.update(now + 0.01 * k, ego, other)
    held = pair.filter.held
    assert held is not None
    assert fed_pair_drift(pair).growth(None, ego, other, now) is None
    assert fed_pair_drift(pair).growth(held, ObjectMap.empty(), other, now) is None
    assert fed_pair_drift(pair).growth(held, ego, ObjectMap.empty(), now) is None
    growth = fed_pair_drift(pair).growth(held, ego, other, now)
    assert growth.shape == (3, 3) and np.all(np.linalg.eigvalsh(growth) > 0)
    assert HeldDrift(FrameAlignerParams(), TCAFFParams()).growth(held, ego, other, now) is None


def test_each_robot_is_placed_at_its_most_recently_seen_objects():
    """A robot is where its map's latest objects are: weighted by 1 / (offset + age^2), an
    object seen 10 s ago barely moves the lever of one seen now; with an offset so small that
    the weights overflow, the objects seen now alone place it."""
    now = 50.0

    def a_map(recent_xy, old_xy):
        return ObjectMap(np.array([[*recent_xy, 0.5], [*old_xy, 0.5], [*old_xy, 1.5]]),
                         np.ones(3), np.ones(3), np.array([now, now - 10.0, now - 12.0]))

    x = np.array([2.0, -3.0, 0.4])
    estimate = AlignmentEstimate(x, np.eye(3), 0.0, 1, 1, 1, 0)
    for params, rtol in [(FrameAlignerParams(), 2e-3),
                         (FrameAlignerParams(weight_offset=5e-324), 1e-12)]:
        drift = HeldDrift(params, fed_by(TCAFFParams(), params))
        growth = drift.growth(estimate, a_map((40.0, 5.0), (0.0, 0.0)),
                              a_map((-20.0, 30.0), (1.0, 1.0)), now)
        assert np.all(np.isfinite(growth))
        np.testing.assert_allclose(
            growth, held_drift(x, np.array([40.0, 5.0]), np.array([-20.0, 30.0]),
                               params.map_drift), rtol=rtol)


def test_a_far_lever_with_little_translation_drift_is_still_a_covariance():
    """Ten kilometres from the origins with a micrometre of translation drift the growth is
    still positive definite, and a pair takes it at its held steps."""
    growth = held_drift([1e4, 1e4, 0.3], [1e4, 1e4], [1e4, -1e4], (1e-6, 0.01))
    eig = np.linalg.eigvalsh(growth)
    assert eig[0] >= 0.99e-9 * eig[-1] > 0
    filt = TCAFF(TCAFFParams(held_Q=np.eye(3) * 1e-4))
    filt.update(np.array([[1e4, 1e4, 0.3]]), np.diag([0.01, 0.01, 1e-4])[None], held_Q=growth)


def test_held_drift_growth_refuses_bad_input_naming_it():
    ego, other, _, now = drifting_maps(se2_from_params([3.0, 1.0, 0.2]))
    params = FrameAlignerParams()
    drift = HeldDrift(params, fed_by(TCAFFParams(), params))
    good = AlignmentEstimate(np.array([1.0, 2.0, 0.3]), np.eye(3), 0.0, 1, 1, 1, 0)
    with pytest.raises(ConfigError, match=r"HeldDrift\.aligner"):
        HeldDrift(TCAFFParams(), TCAFFParams())
    with pytest.raises(ConfigError, match=r"HeldDrift\.tcaff"):
        HeldDrift(params, params)
    for held in ("x", AlignmentEstimate(np.array([1.0, np.nan, 0.3]), np.eye(3), 0.0, 1, 1, 1, 0),
                 AlignmentEstimate(np.array([1.0, 2.0]), np.eye(2), 0.0, 1, 1, 1, 0)):
        with pytest.raises(DataError, match=r"^HeldDrift\.growth: held must be"):
            drift.growth(held, ego, other, now)
    with pytest.raises(DataError, match=r"^HeldDrift\.growth: other_map must be an ObjectMap"):
        drift.growth(good, ego, other.centroids, now)
    with pytest.raises(DataError, match=r"^HeldDrift\.growth: now"):
        drift.growth(good, ego, other, float("nan"))
    assert drift.points == (None, None)  # nothing placed by a refused call


def test_the_growth_given_is_for_a_hold_by_the_assumed_drift_only():
    """Where the main hypothesis's registrations jitter more than the reference allows (its
    alignment drifts faster than assumed) a hold grows by Q, whatever growth is given; and a
    dropped hypothesis, kept dormant, grows by Q too."""
    shift = np.array([0.4, 0.0, 0.02])
    jumpy = [(TRUTH + (shift if t % 2 else -shift))[None] for t in range(20)] + [EMPTY] * 30
    params = TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q)
    big = np.diag([1.0, 1.0, 0.1])
    given, plain = TCAFF(params), TCAFF(params)
    for zs in jumpy:
        Rs = np.broadcast_to(R, (len(zs), 3, 3))
        a, b = given.update(zs, Rs, held_Q=big), plain.update(zs, Rs)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a.P, b.P)
    # dropped after drop_after = 12 unmeasured steps, then dormant: the growth given after the
    # drop changes nothing, the recall on the truth's return included
    params = TCAFFParams(held_Q=HELD_Q, drop_after=12)
    given, plain = TCAFF(params), TCAFF(params)
    stream = [TRUTH[None]] * 20 + [EMPTY] * 30 + [TRUTH[None]] * 5
    dropped = False
    for k, zs in enumerate(stream):
        Rs = np.broadcast_to(R, (len(zs), 3, 3))
        a = given.update(zs, Rs, held_Q=big if dropped else None)
        b = plain.update(zs, Rs)
        dropped = dropped or (k > 20 and plain.held is None)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a.P, b.P)
    assert dropped and plain.estimate is not None
