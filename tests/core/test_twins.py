"""Maps that fit themselves: `twins.self_motions` and `self_fit` against the geometry they
find, `covering`'s bound, and `Twins` widening an estimate only where a map has fitted itself
over the window."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam import FrameAlignerParams, ObjectMap
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.frame_aligner import AlignmentMeasurement
from tcaff_gtsam.geometry import compose, se2_from_params, se2_to_params, wrap_angle
from tcaff_gtsam.tcaff import AlignmentEstimate
from tcaff_gtsam.twins import MAX_MOTIONS, Twins, covering, self_fit, self_motions

RADIUS = 0.3
DISTINCT = (1.0, math.radians(5.0))
W = 8


def moved(S: np.ndarray, points: np.ndarray) -> np.ndarray:
    T = se2_from_params(S)
    return points @ T[:2, :2].T + T[:2, 2]


def triangle(centre: np.ndarray, heading: float, side: float = 2.0,
             spread: float = 0.15) -> np.ndarray:
    """(6, 2) two objects `spread` apart at each corner of an equilateral triangle of `side`
    metres about `centre`, as MRCLAM's landmarks stand: three-fold symmetric."""
    out = []
    for a in heading + np.array([0.0, 2.0, 4.0]) * math.pi / 3:
        radial = np.array([math.cos(a), math.sin(a)])
        out += [centre + (side / math.sqrt(3) + s * spread / 2) * radial for s in (-1, 1)]
    return np.array(out)


def near(a: np.ndarray, b: np.ndarray) -> bool:
    d = a - b
    return math.hypot(d[0], d[1]) <= DISTINCT[0] and abs(wrap_angle(d[2])) <= DISTINCT[1]


@settings(max_examples=60, deadline=None)
@given(cx=st.floats(-50, 50), cy=st.floats(-50, 50), heading=st.floats(-math.pi, math.pi))
def test_a_triangle_of_clusters_fits_itself_turned_by_a_third_about_its_centre(cx, cy, heading):
    points = triangle(np.array([cx, cy]), heading)
    found = self_motions(points, points, np.ones((6, 6), bool), RADIUS, DISTINCT)
    thirds = [se2_to_params(compose(se2_from_params([cx, cy, 0.0]),
                                    se2_from_params([0.0, 0.0, a]),
                                    se2_from_params([-cx, -cy, 0.0])))
              for a in (2 * math.pi / 3, -2 * math.pi / 3)]
    assert len(found) == 2
    for third in thirds:
        assert any(np.allclose(S[:2], third[:2], atol=1e-6)
                   and abs(wrap_angle(S[2] - third[2])) < 1e-6 for S in found)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_every_motion_found_lands_each_object_on_one_it_may_be_and_a_planted_one_is_found(seed):
    """A set and the set moved by a distinct motion S0, in one map: S0 is found (within the
    distinct thresholds), and every motion returned puts each object of the set within the
    radius of a map object the gate allows, its centroid moved away from where the identity
    and every other motion returned take it."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-6, 6, (int(rng.integers(3, 7)), 2))
    S0 = np.array([*rng.uniform(-8, 8, 2), rng.uniform(-math.pi, math.pi)])
    if near(S0, np.zeros(3)):
        S0[2] += math.pi
    recent = np.vstack([points, moved(S0, points) + rng.normal(0, 0.03, points.shape),
                        rng.uniform(-12, 12, (int(rng.integers(0, 6)), 2))])
    gate = np.ones((len(points), len(recent)), bool)
    found = self_motions(points, recent, gate, RADIUS, DISTINCT)
    assert any(near(S, S0) for S in found)
    centre = points.mean(axis=0)

    def apart(a, b):  # judged by where the set's centroid goes
        return (np.linalg.norm(moved(a, centre[None]) - moved(b, centre[None])) > DISTINCT[0]
                or abs(wrap_angle(a[2] - b[2])) > DISTINCT[1])

    for k, S in enumerate(found):
        gap = np.linalg.norm(moved(S, points)[:, None] - recent[None], axis=2)
        assert (gap.min(axis=1) <= RADIUS + 1e-9).all()
        assert apart(S, np.zeros(3))
        assert all(apart(S, other) for other in found[:k])


@pytest.mark.parametrize("offset", [0.0, 30.0, 1000.0])
def test_the_motions_found_do_not_depend_on_where_the_map_lies_in_its_frame(offset):
    """Near-identity and duplicate motions are judged by where the set's centroid goes, not
    the frame's origin: two pairs 3 m apart fit themselves by a half turn only, wherever
    they are."""
    points = np.array([[0.0, 0.0], [0.0, -0.1], [3.0, 0.0], [3.0, 0.1]]) + offset
    found = self_motions(points, points, np.ones((4, 4), bool), RADIUS, DISTINCT)
    assert len(found) == 1
    assert abs(abs(found[0][2]) - math.pi) < 0.05


def test_the_gate_decides_where_an_object_may_land():
    points = triangle(np.zeros(2), 0.3)
    assert len(self_motions(points, points, np.eye(6, dtype=bool), RADIUS, DISTINCT)) == 0
    gate = np.ones((6, 6), bool)
    gate[0, 2:] = False  # object 0 may land only on its own corner
    assert len(self_motions(points, points, gate, RADIUS, DISTINCT)) == 0


def test_no_motion_from_a_set_too_small_or_too_tight_to_turn():
    points = triangle(np.zeros(2), 0.0)
    gate = np.ones((6, 6), bool)
    assert self_motions(points[:1], points, gate[:1], RADIUS, DISTINCT).shape == (0, 3)
    assert self_motions(points[:2], points, gate[:2], RADIUS, DISTINCT).shape == (0, 3)  # 0.15 m
    assert self_motions(points, points[:1], gate[:, :1], RADIUS, DISTINCT).shape == (0, 3)


def test_an_asymmetric_map_does_not_fit_itself():
    rng = np.random.default_rng(4)
    for _ in range(50):
        recent = rng.uniform(0, 30, (15, 2))
        points = recent[rng.choice(15, 6, replace=False)]
        assert len(self_motions(points, recent, np.ones((6, 15), bool), RADIUS, DISTINCT)) == 0


def test_a_grid_of_many_fits_returns_at_most_the_cap():
    xy = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0)), -1).reshape(-1, 2) * 1.5
    found = self_motions(xy[:30], xy, np.ones((30, 400), bool), RADIUS, DISTINCT)
    assert len(found) == MAX_MOTIONS


def test_self_fit_counts_the_objects_that_land_on_another():
    points = triangle(np.array([3.0, -1.0]), 0.4)
    gate = np.ones((6, 6), bool)
    third = self_motions(points, points, gate, RADIUS, DISTINCT)[0]
    assert self_fit(third, points, gate, RADIUS) == 6
    # the identity lands each object on itself, which does not count, and 0.15 m neighbours
    # within the radius, which do
    assert self_fit(np.zeros(3), points, gate, RADIUS) == 6
    assert self_fit(np.zeros(3), points, gate, 0.1) == 0
    assert self_fit(third, points, np.eye(6, dtype=bool), RADIUS) == 0
    assert self_fit(np.array([100.0, 0.0, 0.0]), points, gate, RADIUS) == 0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(1, 4))
def test_covering_is_never_narrower_and_puts_each_twin_within_its_mixture(seed, m):
    """P' - P is positive semi-definite, and each twin's offset d has d' P'^-1 d <= m + 1
    (P' holds d d' / (m + 1)): a twin that is the truth is never outside the claim."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(3, 3))
    P = A @ A.T * 0.01 + np.eye(3) * 1e-4
    B = rng.normal(size=(3, 3))
    R = B @ B.T * 0.01 + np.eye(3) * 1e-4
    x = np.array([*rng.uniform(-20, 20, 2), rng.uniform(-math.pi, math.pi)])
    twins = np.column_stack([rng.uniform(-20, 20, (m, 2)), rng.uniform(-math.pi, math.pi, m)])
    wide = covering(P, x, twins, R)
    assert np.linalg.eigvalsh(wide - P).min() > -1e-9
    for z in twins:
        d = z - x
        d[2] = wrap_angle(d[2])
        assert d @ np.linalg.solve(wide, d) <= m + 1 + 1e-6
    # one twin: an equal mixture of two, about x
    d = twins[0] - x
    d[2] = wrap_angle(d[2])
    np.testing.assert_allclose(covering(P, x, twins[:1], R), P + (R + np.outer(d, d)) / 2,
                               rtol=1e-12, atol=1e-12)
    # the offsets are the wrapped ones: a twin across +-pi is near, not 2 pi away
    across = covering(P, np.array([0.0, 0.0, 3.1]), np.array([[0.0, 0.0, -3.1]]), R)
    assert across[2, 2] - P[2, 2] < R[2, 2] + 0.01


# -- Twins ---------------------------------------------------------------------------------------

def a_map(points: np.ndarray, now: float) -> ObjectMap:
    n = len(points)
    return ObjectMap(np.column_stack([points, np.zeros(n)]), np.full(n, 0.3), np.full(n, 0.3),
                     np.full(n, now))


def estimate(hypothesis: int = 1, measurement: int = 0) -> AlignmentEstimate:
    return AlignmentEstimate(np.array([1.0, -2.0, 0.3]), np.diag([0.04, 0.04, 0.003]), 1.0,
                             hypothesis, 1, 3, measurement)


def measurement(n: int = 6) -> list[AlignmentMeasurement]:
    """One candidate associating the first n objects of each map with each other."""
    pairs = np.column_stack([np.arange(n), np.arange(n)])
    return [AlignmentMeasurement(np.array([1.0, -2.0, 0.3]), np.diag([0.02, 0.02, 0.001]),
                                 pairs, 1.0, 0.05)]


def run(twins: Twins, ego_points, other_points, steps: int, hypothesis: int = 1,
        measured: bool = True, start: float = 0.0) -> list[AlignmentEstimate | None]:
    out = []
    for s in range(steps):
        now = start + s
        out.append(twins.update(estimate(hypothesis, 0 if measured else -1), measurement(),
                                a_map(ego_points, now), a_map(other_points, now), now))
    return out


SYMMETRIC = triangle(np.array([4.0, 1.0]), 0.2)
SPREAD = np.random.default_rng(7).uniform(-10, 10, (6, 2))


def test_an_estimate_is_widened_once_its_map_has_fitted_itself_over_the_window():
    twins = Twins(FrameAlignerParams(), W)
    out = run(twins, SYMMETRIC, SPREAD, W + 3)
    plain = estimate().P
    for e in out[:W]:
        np.testing.assert_array_equal(e.P, plain)
    for e in out[W:]:
        assert np.linalg.eigvalsh(e.P - plain).min() > -1e-12
        assert e.P[2, 2] > plain[2, 2] + 1.0  # the twins are a third of a turn away
    # each twin, S o x for the ego map's turns by a third, within the claim
    x = estimate().x
    for third in self_motions(SYMMETRIC, SYMMETRIC, np.ones((6, 6), bool), RADIUS, DISTINCT):
        d = se2_to_params(se2_from_params(third) @ se2_from_params(x)) - x
        d[2] = wrap_angle(d[2])
        assert d @ np.linalg.solve(out[-1].P, d) <= 3 + 1e-6


def test_the_other_robots_map_gives_twins_on_the_right():
    twins = Twins(FrameAlignerParams(), W)
    out = run(twins, SPREAD, SYMMETRIC, W + 1)
    x = estimate().x
    third = self_motions(SYMMETRIC, SYMMETRIC, np.ones((6, 6), bool), RADIUS, DISTINCT)[0]
    right = se2_to_params(se2_from_params(x) @ se2_from_params(third)) - x
    left = se2_to_params(se2_from_params(third) @ se2_from_params(x)) - x
    for d in (right, left):
        d[2] = wrap_angle(d[2])
    # covered as x o S, not as S o x
    assert right @ np.linalg.solve(out[-1].P, right) <= 3 + 1e-6
    assert left @ np.linalg.solve(out[-1].P, left) > 10


def test_a_motion_of_the_other_map_gives_the_twin_that_pairs_each_ego_object_with_its_image():
    """The other map holds a set A and A moved by S0 (no symmetry of its own, so S0 alone is
    found): the twin pairs e_k with S0 o_k, x o S0^-1, which is covered; x o S0 is not."""
    rng = np.random.default_rng(11)
    A = rng.uniform(-4, 4, (4, 2))
    S0 = np.array([7.0, -2.0, 1.1])
    other = np.vstack([A, moved(S0, A)])
    x = estimate().x
    ego = moved(x, A)
    twins = Twins(FrameAlignerParams(), W)
    out = None
    for step in range(W + 1):
        now = float(step)
        out = twins.update(estimate(), measurement(4), a_map(ego, now), a_map(other, now), now)
    T_x, T_S = se2_from_params(x), se2_from_params(S0)
    for T, inside in ((T_x @ np.linalg.inv(T_S), True), (T_x @ T_S, False)):
        d = se2_to_params(T) - x
        d[2] = wrap_angle(d[2])
        assert (d @ np.linalg.solve(out.P, d) <= 2 + 1e-6) == inside
    # and that twin does pair each ego object with the image of its other object
    np.testing.assert_allclose(moved(se2_to_params(T_x @ np.linalg.inv(T_S)), moved(S0, A)),
                               ego, atol=1e-9)


def test_maps_that_do_not_fit_themselves_leave_the_estimate_as_it_is():
    twins = Twins(FrameAlignerParams(), W)
    for e in run(twins, SPREAD, SPREAD + 1.0, 3 * W):
        np.testing.assert_array_equal(e.P, estimate().P)


def test_one_step_of_the_window_without_the_fit_holds_the_widening_back_for_a_window():
    twins = Twins(FrameAlignerParams(), W)
    run(twins, SYMMETRIC, SPREAD, W + 1)
    out = run(twins, SPREAD * 0.5, SPREAD, 1, start=W + 1)  # other objects, still associated
    out += run(twins, SYMMETRIC, SPREAD, W + 2, start=W + 2)
    np.testing.assert_array_equal(out[0].P, estimate().P)
    for e in out[1:W + 1]:
        np.testing.assert_array_equal(e.P, estimate().P)
    assert out[W + 1].P[2, 2] > estimate().P[2, 2] + 1.0


def test_a_held_estimate_keeps_its_twins_and_a_new_hypothesis_starts_without_them():
    twins = Twins(FrameAlignerParams(), W)
    run(twins, SYMMETRIC, SPREAD, W + 1)
    held = run(twins, SYMMETRIC, SPREAD, 3, measured=False, start=W + 1)
    assert all(e.P[2, 2] > estimate().P[2, 2] + 1.0 for e in held)
    switched = run(twins, SYMMETRIC, SPREAD, 2, hypothesis=2, measured=False, start=W + 4)
    for e in switched:
        np.testing.assert_array_equal(e.P, estimate().P)


def test_no_estimate_gives_none_and_forgets_the_twins():
    twins = Twins(FrameAlignerParams(), W)
    run(twins, SYMMETRIC, SPREAD, W + 1)
    assert twins.update(None, [], a_map(SYMMETRIC, W + 1.0), a_map(SPREAD, W + 1.0),
                        W + 1.0) is None
    held = run(twins, SYMMETRIC, SPREAD, 1, measured=False, start=W + 2)
    np.testing.assert_array_equal(held[0].P, estimate().P)


def test_empty_maps_neither_break_nor_count_towards_the_window():
    """A silent step (the other robot's map empty) leaves the fit of its earlier maps."""
    twins = Twins(FrameAlignerParams(), W)
    run(twins, SPREAD, SYMMETRIC, W)
    now = float(W)
    e = twins.update(estimate(measurement=-1), [], a_map(SPREAD, now),
                     a_map(np.zeros((0, 2)), now), now)
    np.testing.assert_array_equal(e.P, estimate().P)  # W maps of it, not W + 1
    out = run(twins, SPREAD, SYMMETRIC, 1, start=W + 1.0)
    assert out[0].P[2, 2] > estimate().P[2, 2] + 1.0


@pytest.mark.parametrize("covariance", ["constant", "residual"])
def test_a_covariance_that_is_not_calibrated_is_left_as_it_is(covariance):
    twins = Twins(FrameAlignerParams(covariance=covariance), W)
    for e in run(twins, SYMMETRIC, SPREAD, W + 3):
        np.testing.assert_array_equal(e.P, estimate().P)


@pytest.mark.parametrize("args", [("params", 8), (FrameAlignerParams(), 0),
                                  (FrameAlignerParams(), 2.0), (FrameAlignerParams(), True)])
def test_bad_settings_are_refused_by_name(args):
    with pytest.raises(ConfigError, match="params" if args[0] == "params" else "window"):
        Twins(*args)


GOOD_GATE = np.ones((6, 6), bool)


@pytest.mark.parametrize("call, name", [
    (lambda: self_motions(SYMMETRIC[:, :1], SYMMETRIC, GOOD_GATE, RADIUS, DISTINCT), "points"),
    (lambda: self_motions(SYMMETRIC, np.full((6, 2), np.nan), GOOD_GATE, RADIUS, DISTINCT),
     "recent"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, np.ones((6, 5), bool), RADIUS, DISTINCT), "gate"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, GOOD_GATE.astype(int), RADIUS, DISTINCT),
     "gate"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, GOOD_GATE, 0.0, DISTINCT), "radius"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, GOOD_GATE, float("nan"), DISTINCT), "radius"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, GOOD_GATE, RADIUS, (1.0,)), "distinct"),
    (lambda: self_motions(SYMMETRIC, SYMMETRIC, GOOD_GATE, RADIUS, (1.0, -0.1)), "distinct"),
    (lambda: self_fit(np.zeros(2), SYMMETRIC, GOOD_GATE, RADIUS), "S"),
    (lambda: self_fit(np.zeros(3), SYMMETRIC, GOOD_GATE[:5], RADIUS), "gate"),
    (lambda: self_fit(np.zeros(3), SYMMETRIC * 1e200, GOOD_GATE, RADIUS), "recent"),
    (lambda: covering(np.eye(2), np.zeros(3), np.zeros((1, 3)), np.eye(3)), "P"),
    (lambda: covering(np.eye(3), np.zeros(3), np.zeros((1, 3)), np.full((3, 3), np.inf)), "R"),
    (lambda: covering(np.eye(3), np.zeros(3), np.zeros(3), np.eye(3)), "twins"),
    (lambda: covering(np.eye(3), np.array([0.0, np.nan, 0.0]), np.zeros((1, 3)), np.eye(3)),
     "x"),
])
def test_bad_arrays_are_refused_by_name(call, name):
    with pytest.raises(DataError, match=name):
        call()


def test_bad_steps_are_refused_by_name_and_leave_the_twins_as_they_were():
    twins = Twins(FrameAlignerParams(), W)
    run(twins, SYMMETRIC, SPREAD, W + 1)
    seen, found = twins.seen, twins.found
    now = W + 1.0
    ego, other = a_map(SYMMETRIC, now), a_map(SPREAD, now)
    for args, name in [((estimate(), [], ego, other, now), "measurement 0"),
                       ((estimate(), [object()], ego, other, now), "taken"),
                       (("x", measurement(), ego, other, now), "estimate"),
                       ((estimate(), measurement(), SYMMETRIC, other, now), "ego_map"),
                       ((estimate(), measurement(), ego, other, float("nan")), "now"),
                       ((estimate(), measurement(8), ego, other, now), "ego_map")]:
        with pytest.raises(DataError, match=name):
            twins.update(*args)
        assert twins.seen is seen and twins.found is found
    assert twins.update(estimate(), measurement(), ego, other, now).P[2, 2] > 1.0
