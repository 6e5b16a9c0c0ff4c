"""Tests for tcaff_gtsam.eval.sim motion: routes, waits, loops, lawnmowers, and the drifting
odometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from sim_helpers import (
    FEW,
    PROPS,
    angle,
    angle_diff,
    coord,
    seeds,
)
from tcaff_gtsam.eval.sim.motion import (
    drifting_odometry,
    lawnmower,
    loop,
    poses_along,
    then,
    timed_waypoints,
    wait,
)

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import (
    invert,
    se2_error,
    se2_from_params,
    se2_to_params,
    wrap_angle,
)

# =============================================================================================
# motion: knots and true poses


@FEW
@given(start=st.tuples(coord, coord), phi=angle, leg1=st.floats(2.0, 20.0),
       leg2=st.floats(2.0, 20.0), left=st.booleans(), speed=st.floats(0.2, 1.5),
       frac=st.floats(0.0, 1.0))
def test_poses_along_l_route(start, phi, leg1, leg2, left, speed, frac):
    p0 = np.asarray(start)
    u = np.array([np.cos(phi), np.sin(phi)])
    turn = np.pi / 2 if left else -np.pi / 2
    v = np.array([np.cos(phi + turn), np.sin(phi + turn)])
    p1, p2 = p0 + leg1 * u, p0 + leg1 * u + leg2 * v
    knot_t, knot_xy = timed_waypoints([p0, p1, p2], speed, t0=3.0)
    t1, t2 = 3.0 + leg1 / speed, 3.0 + (leg1 + leg2) / speed
    np.testing.assert_allclose(knot_t, [3.0, t1, t2], rtol=1e-12)
    la = 0.5  # the default lookahead: headings are exact further than this from a corner
    ta = 3.0 + la + frac * (t1 - 3.0 - 2 * la)  # on the first leg, away from its ends
    tb = t1 + la + frac * (t2 - t1 - 2 * la)  # on the second leg
    poses = poses_along(knot_t, knot_xy, np.array([0.0, ta, tb, t2 + 5.0]))
    np.testing.assert_allclose(poses[1, :2], p0 + speed * (ta - 3.0) * u, atol=1e-9)
    np.testing.assert_allclose(poses[2, :2], p1 + speed * (tb - t1) * v, atol=1e-9)
    assert angle_diff(poses[1, 2], phi) < 1e-9
    assert angle_diff(poses[2, 2], phi + turn) < 1e-9
    # held before the start (with the first heading) and after the end (with the last one)
    np.testing.assert_allclose(poses[0, :2], p0, atol=1e-9)
    assert angle_diff(poses[0, 2], phi) < 1e-9
    np.testing.assert_allclose(poses[3, :2], p2, atol=1e-9)
    assert angle_diff(poses[3, 2], phi + turn) < 1e-9


def test_poses_along_known_values():
    knots = timed_waypoints([(0.0, 0.0), (10.0, 0.0), (10.0, 6.0)], speed=2.0)
    np.testing.assert_allclose(knots[0], [0.0, 5.0, 8.0])
    poses = poses_along(*knots, np.array([1.0, 2.0, 3.5, 6.0, 7.0]))
    np.testing.assert_allclose(poses, [[2, 0, 0], [4, 0, 0], [7, 0, 0], [10, 2, np.pi / 2],
                                       [10, 4, np.pi / 2]], atol=1e-12)


def test_wait_stands_still_and_keeps_heading():
    first = timed_waypoints([(0.0, 0.0), (4.0, 0.0)], speed=1.0)
    waited = wait(*first, 5.0)
    knot_t, knot_xy = then(waited, [(4.0, 3.0)], speed=1.0)
    np.testing.assert_allclose(knot_t, [0.0, 4.0, 9.0, 12.0])
    np.testing.assert_allclose(knot_xy, [[0, 0], [4, 0], [4, 0], [4, 3]])
    times = np.linspace(4.0, 9.0, 51)
    poses = poses_along(knot_t, knot_xy, times)
    np.testing.assert_allclose(poses[:, :2], np.tile([4.0, 0.0], (len(times), 1)), atol=1e-12)
    # the heading of the leg before the stop, until the lookahead sees the next leg
    assert np.all(angle_diff(poses[times <= 8.5, 2], 0.0) < 1e-12)
    after = poses_along(knot_t, knot_xy, np.array([10.0, 11.0, 20.0]))
    np.testing.assert_allclose(after, [[4, 1, np.pi / 2], [4, 2, np.pi / 2], [4, 3, np.pi / 2]],
                               atol=1e-12)


def test_wait_at_start_takes_first_heading():
    knots = then(wait(np.array([0.0]), np.array([[1.0, 1.0]]), 3.0), [(1.0, -4.0)], speed=0.5)
    times = np.linspace(0.0, 6.0, 61)
    poses = poses_along(*knots, times)
    np.testing.assert_allclose(poses[times <= 3.0, :2], [[1.0, 1.0]] * 31, atol=1e-12)
    assert np.all(angle_diff(poses[:, 2], -np.pi / 2) < 1e-12)


def test_heading_at_a_stop_does_not_depend_on_the_other_query_times():
    knots = wait(*timed_waypoints([(0.0, 0.0), (0.0, 4.0)], 1.0), 5.0)
    together = poses_along(*knots, np.array([3.0, 6.0]))
    alone = poses_along(*knots, np.array([6.0]))
    assert angle_diff(together[1, 2], np.pi / 2) < 1e-12  # this part holds
    np.testing.assert_allclose(alone[0], together[1], atol=1e-12)


def test_standing_still_all_the_time_gives_zero_heading():
    poses = poses_along(np.array([0.0, 5.0]), np.array([[2.0, 3.0], [2.0, 3.0]]),
                        np.linspace(0, 5, 11))
    np.testing.assert_allclose(poses, np.tile([2.0, 3.0, 0.0], (11, 1)))


@PROPS
@given(center=st.tuples(coord, coord), radius=st.floats(0.5, 20.0), laps=st.floats(0.25, 3.0),
       start=angle, ccw=st.booleans(), per_lap=st.integers(8, 72))
def test_loop_radius_and_laps(center, radius, laps, start, ccw, per_lap):
    way = loop(center, radius, laps, start_angle=start, ccw=ccw, points_per_lap=per_lap)
    assert way.shape == (max(round(per_lap * laps), 1) + 1, 2)
    rel = way - np.asarray(center)
    np.testing.assert_allclose(np.linalg.norm(rel, axis=1), radius, rtol=1e-9)
    np.testing.assert_allclose(way[0], np.asarray(center) + radius * np.array(
        [np.cos(start), np.sin(start)]), atol=1e-9)
    turned = np.sum(wrap_angle(np.diff(np.arctan2(rel[:, 1], rel[:, 0]))))
    assert turned == pytest.approx((1.0 if ccw else -1.0) * 2 * np.pi * laps, abs=1e-6)


def check_lawnmower(x0, y0, w, h, lanes, along_x):
    x1, y1 = x0 + w, y0 + h
    way = lawnmower((x0, y0, x1, y1), lanes, along_x=along_x)
    assert way.shape == (2 * lanes, 2)
    main, across = (0, 1) if along_x else (1, 0)
    lo, hi = (x0, x1) if along_x else (y0, y1)
    c_lo, c_hi = (y0, y1) if along_x else (x0, x1)
    lane_pos = np.linspace(c_lo, c_hi, lanes)
    for k in range(lanes):
        a, b = way[2 * k], way[2 * k + 1]
        assert a[across] == pytest.approx(lane_pos[k]) and b[across] == pytest.approx(lane_pos[k])
        # each lane spans the whole rectangle, in alternating directions
        assert sorted((a[main], b[main])) == pytest.approx([lo, hi])
        assert (b[main] - a[main]) * (1 if k % 2 == 0 else -1) > 0
        if k:  # the turn keeps the end of the previous lane's main coordinate
            assert a[main] == pytest.approx(way[2 * k - 1][main])
    np.testing.assert_allclose(way.min(axis=0), [x0, y0])
    np.testing.assert_allclose(way.max(axis=0), [x1, y1])


@PROPS
@given(x0=coord, y0=coord, w=st.floats(1.0, 30.0), h=st.floats(1.0, 30.0),
       lanes=st.integers(2, 8))
def test_lawnmower_covers_bounds_along_x(x0, y0, w, h, lanes):
    check_lawnmower(x0, y0, w, h, lanes, along_x=True)


@PROPS
@given(a=coord, w=st.floats(1.0, 30.0), lanes=st.integers(2, 8))
def test_lawnmower_along_y_on_the_rooms_bounds(a, w, lanes):
    # the room scenario sweeps (a, a, b, b), where x and y bounds coincide
    check_lawnmower(a, a, w, w, lanes, along_x=False)


def test_lawnmower_covers_oblong_bounds_along_y():
    np.testing.assert_allclose(lawnmower((0.0, 0.0, 1.0, 2.0), 2, along_x=False),
                               [[0, 0], [0, 2], [1, 2], [1, 0]])
    check_lawnmower(-3.0, 5.0, 4.0, 10.0, 3, along_x=False)


def test_motion_rejects_bad_input():
    with pytest.raises(DataError):
        timed_waypoints([(0.0, 0.0), (1.0, 0.0)], speed=0.0)
    with pytest.raises(DataError):
        timed_waypoints([0.0, 1.0, 2.0], speed=1.0)
    with pytest.raises(DataError):
        drifting_odometry(np.random.default_rng(0), np.zeros((5, 2)), 0.1, 0.0, 0.0)
    with pytest.raises(DataError):
        drifting_odometry(np.random.default_rng(0), np.zeros((5, 3)), 0.0, 0.0, 0.0)


# =============================================================================================
# motion: drifting odometry


def smooth_path(seed: int, steps: int, dt: float, start) -> np.ndarray:
    """(steps + 1, 3) unicycle poses with smoothly varying speed and turn rate, heading wrapped."""
    rng = np.random.default_rng(seed)
    t = dt * np.arange(steps)
    speed = rng.uniform(0.2, 2.0) * (1 + 0.5 * np.sin(rng.uniform(0.1, 2) * t + rng.uniform(0, 7)))
    omega = rng.uniform(-1.5, 1.5) * np.sin(rng.uniform(0.05, 1) * t + rng.uniform(0, 7))
    theta = start[2] + np.r_[0.0, np.cumsum(omega * dt)]
    xy = np.asarray(start[:2]) + np.vstack([np.zeros(2), np.cumsum(
        (speed * dt)[:, None] * np.column_stack([np.cos(theta[:-1]), np.sin(theta[:-1])]),
        axis=0)])
    return np.column_stack([xy, wrap_angle(theta)])


@PROPS
@given(seed=seeds, steps=st.integers(1, 300), dt=st.floats(0.02, 0.5),
       start=st.tuples(coord, coord, angle))
def test_noiseless_odometry_is_true_motion_from_first_pose(seed, steps, dt, start):
    poses = smooth_path(seed, steps, dt, start)
    odom = drifting_odometry(np.random.default_rng(seed), poses, dt, 0.0, 0.0)
    assert odom.shape == poses.shape
    np.testing.assert_allclose(odom[0], [0.0, 0.0, 0.0], atol=1e-12)
    expected = se2_to_params(invert(se2_from_params(poses[0])) @ se2_from_params(poses))
    np.testing.assert_allclose(odom[:, :2], expected[:, :2], atol=1e-7)
    assert np.all(angle_diff(odom[:, 2], expected[:, 2]) < 1e-9)
    assert np.all((odom[:, 2] >= -np.pi) & (odom[:, 2] < np.pi))


def test_noiseless_odometry_on_poses_along_a_route():
    knots = then(wait(*timed_waypoints([(3.0, 1.0), (8.0, 1.0), (8.0, 7.0)], 0.7), 4.0),
                 [(-2.0, 4.0), (3.0, 1.0)], 0.9)
    dt = 0.1
    poses = poses_along(*knots, dt * np.arange(400))
    odom = drifting_odometry(np.random.default_rng(1), poses, dt, 0.0, 0.0)
    T_w_o = se2_from_params(poses) @ invert(se2_from_params(odom))
    # the odometry frame is the first true pose, for good
    err = se2_error(np.broadcast_to(se2_from_params(poses[0]), T_w_o.shape), T_w_o)
    assert err.max() < 1e-9


def test_odometry_heading_error_grows_like_sqrt_time():
    dt, n_seeds = 0.1, 400
    poses = smooth_path(7, 200, dt, (0.0, 0.0, 0.0))
    rel_heading = poses[:, 2] - poses[0, 2]
    for heading_rw in (0.01, 0.05):
        errors = np.array([wrap_angle(drifting_odometry(
            np.random.default_rng(seed), poses, dt, heading_rw, 0.02)[:, 2] - rel_heading)
            for seed in range(n_seeds)])
        for t in (5.0, 20.0):
            spread = np.std(errors[:, round(t / dt)])
            expected = heading_rw * np.sqrt(t)
            assert expected / 1.5 < spread < 1.5 * expected, (heading_rw, t, spread)
        assert np.std(errors[:, 0]) == 0.0


def test_odometry_position_error_of_a_standing_robot_grows_like_sqrt_time():
    dt, position_rw = 0.1, 0.05
    poses = np.tile([1.0, 2.0, 0.3], (201, 1))
    odom = np.array([drifting_odometry(np.random.default_rng(seed), poses, dt, 0.0, position_rw)
                     for seed in range(300)])
    np.testing.assert_allclose(odom[:, :, 2], 0.0, atol=1e-12)  # no heading noise: no turning
    for t in (5.0, 20.0):
        spread = np.std(odom[:, round(t / dt), :2], axis=0)
        expected = position_rw * np.sqrt(t)
        assert np.all((expected / 1.5 < spread) & (spread < 1.5 * expected)), (t, spread)


@FEW
@given(seed=seeds)
def test_odometry_same_seed_same_drift(seed):
    poses = smooth_path(3, 100, 0.1, (1.0, -2.0, 0.5))
    a = drifting_odometry(np.random.default_rng(seed), poses, 0.1, 0.01, 0.02)
    b = drifting_odometry(np.random.default_rng(seed), poses, 0.1, 0.01, 0.02)
    c = drifting_odometry(np.random.default_rng(seed + 1), poses, 0.1, 0.01, 0.02)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a[1:], c[1:])
