"""Tests for tcaff_gtsam.eval.sim: worlds, motion and odometry drift, the object sensor, the
scenario builders and the simulator that turns them into per-robot object maps."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from tcaff_gtsam.eval.config import (
    MappingConfig,
    OdometryDrift,
    RoomLayout,
    ScenarioConfig,
    SensorConfig,
    load_methods,
    load_scenario,
)
from tcaff_gtsam.eval.jobs import evaluate_simulated
from tcaff_gtsam.eval.sim.maps import OBJECT_CLASSES
from tcaff_gtsam.eval.sim.motion import (
    drifting_odometry,
    lawnmower,
    loop,
    poses_along,
    then,
    timed_waypoints,
    wait,
)
from tcaff_gtsam.eval.sim.rgbd import clear_paths
from tcaff_gtsam.eval.sim.scenarios import build_scene
from tcaff_gtsam.eval.sim.sensor import observe
from tcaff_gtsam.eval.sim.simulate import SimRun, simulate
from tcaff_gtsam.eval.sim.world import World, along_path, combine, grid, room_walls, scatter

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import (
    compose,
    invert,
    se2_error,
    se2_from_params,
    se2_to_params,
    transform_points,
    wrap_angle,
)
from tcaff_gtsam.object_map import ObjectMap

PROPS = settings(max_examples=40, deadline=None)
FEW = settings(max_examples=15, deadline=None)

SCENARIOS = ("indoor_return", "same_direction", "opposite_directions", "four_robots",
             "ambiguous_grid")
INDOOR = ("indoor_return", "four_robots", "ambiguous_grid")
SHORT = 20.0  # seconds: every shipped scenario is cut to this for the simulator tests

coord = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False, allow_infinity=False)
seeds = st.integers(0, 2**32 - 1)


def angle_diff(a, b) -> np.ndarray:
    return np.abs(wrap_angle(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)))


def ideal_sensor(**update) -> SensorConfig:
    """A sensor that sees every object in its field of view exactly, and nothing else."""
    base = {"fov_deg": 90.0, "range_min": 0.5, "range_max": 5.0, "p_detect": 1.0,
            "centroid_noise": 0.0, "centroid_noise_per_m": 0.0, "size_noise": 0.0,
            "partial_view": 1.0, "false_per_frame": 0.0}
    return SensorConfig(**{**base, **update})


def world_from_body(pose, body_xy, widths, heights) -> World:
    """A world whose objects sit at body-frame positions `body_xy` of a robot at `pose`."""
    body_xy = np.asarray(body_xy, dtype=float).reshape(-1, 2)
    n = len(body_xy)
    xy = transform_points(se2_from_params(pose), body_xy)
    return World(xy, np.asarray(widths, dtype=float), np.asarray(heights, dtype=float),
                 np.full(n, "box"))


def to_body(pose, points_xy) -> np.ndarray:
    """(n, 2) points of the frame `pose` is expressed in, mapped into that body frame."""
    return transform_points(invert(se2_from_params(pose)), np.asarray(points_xy).reshape(-1, 2))


def segment_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(n,) distance of each point to a polyline (m, 2)."""
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.einsum("nmk,mk->nm", points[:, None, :] - a[None], ab) / np.einsum("mk,mk->m", ab, ab)
    foot = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.min(np.linalg.norm(points[:, None, :] - foot, axis=2), axis=1)


def short(name: str, **update) -> ScenarioConfig:
    return load_scenario(name).model_copy(update={"duration": SHORT, **update})


_RUNS: dict[tuple[str, int], SimRun] = {}


def run_of(name: str, seed: int = 0) -> SimRun:
    """The shortened shipped scenario simulated with `seed` (cached: runs are deterministic)."""
    key = (name, seed)
    if key not in _RUNS:
        _RUNS[key] = simulate(short(name), seed)
    return _RUNS[key]


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


# =============================================================================================
# sensor

# Objects around a robot in its body frame (x forward, y left) against a 90 deg, 0.5-5 m sensor.
BODY_XY = np.array([
    [3.0, 0.0],    # 0 ahead: seen
    [-2.0, 0.0],   # 1 behind
    [7.0, 0.0],    # 2 too far
    [0.3, 0.0],    # 3 too near
    [1.0, 2.0],    # 4 63 deg left: outside the field of view
    [2.0, 1.5],    # 5 37 deg left, 2.5 m: seen
    [4.0, -2.0],   # 6 27 deg right, 4.5 m: seen
    [3.0, 3.2],    # 7 47 deg left: outside
    [4.8, 0.5],    # 8 4.83 m: seen
    [0.0, 3.0],    # 9 to the left
    [3.6, -3.8],   # 10 46.5 deg right: outside
    [5.0, 0.3],    # 11 5.01 m: too far
])
SEEN = [0, 5, 6, 8]
BODY_W = np.linspace(0.3, 0.9, len(BODY_XY))
BODY_H = np.linspace(1.2, 0.4, len(BODY_XY))


@PROPS
@given(pose=st.tuples(coord, coord, angle), seed=seeds)
def test_ideal_sensor_sees_exactly_the_objects_in_view(pose, seed):
    pose = np.asarray(pose)
    world = world_from_body(pose, BODY_XY, BODY_W, BODY_H)
    centroids, widths, heights, labels = observe(np.random.default_rng(seed), world, pose, pose,
                                                 ideal_sensor())
    assert labels.dtype == np.int64
    assert labels.tolist() == SEEN
    np.testing.assert_allclose(centroids, world.centroids[SEEN], atol=1e-9)
    np.testing.assert_allclose(centroids[:, 2], BODY_H[SEEN] / 2, atol=1e-12)
    np.testing.assert_allclose(widths, BODY_W[SEEN], rtol=1e-12)
    np.testing.assert_allclose(heights, BODY_H[SEEN], rtol=1e-12)


@PROPS
@given(pose_true=st.tuples(coord, coord, angle), pose_odom=st.tuples(coord, coord, angle),
       seed=seeds)
def test_detections_are_expressed_through_the_odometry_pose(pose_true, pose_odom, seed):
    pose_true, pose_odom = np.asarray(pose_true), np.asarray(pose_odom)
    world = world_from_body(pose_true, BODY_XY, BODY_W, BODY_H)
    centroids, _, heights, labels = observe(np.random.default_rng(seed), world, pose_true,
                                            pose_odom, ideal_sensor())
    assert labels.tolist() == SEEN  # what is seen depends on the true pose only
    np.testing.assert_allclose(to_body(pose_odom, centroids[:, :2]), BODY_XY[SEEN], atol=1e-9)
    # and back into the world through the true pose
    T_w_o = compose(se2_from_params(pose_true), invert(se2_from_params(pose_odom)))
    np.testing.assert_allclose(transform_points(T_w_o, centroids[:, :2]), world.xy[SEEN],
                               atol=1e-8)
    np.testing.assert_allclose(centroids[:, 2], world.centroids[SEEN, 2], atol=1e-12)
    np.testing.assert_allclose(heights, BODY_H[SEEN])


@PROPS
@given(seed=seeds, pose=st.tuples(coord, coord, angle), fov=st.floats(10.0, 360.0),
       range_min=st.floats(0.0, 3.0), span=st.floats(0.5, 15.0))
def test_visibility_matches_range_and_bearing(seed, pose, fov, range_min, span):
    rng = np.random.default_rng(seed)
    pose = np.asarray(pose)
    body = rng.uniform(-20, 20, (60, 2))
    world = world_from_body(pose, body, np.full(60, 0.5), np.full(60, 0.5))
    sensor = ideal_sensor(fov_deg=fov, range_min=range_min, range_max=range_min + span)
    _, _, _, labels = observe(rng, world, pose, pose, sensor)
    dist = np.hypot(body[:, 0], body[:, 1])
    bearing = np.degrees(np.abs(np.arctan2(body[:, 1], body[:, 0])))
    inside = (dist >= range_min) & (dist <= range_min + span) & (bearing <= fov / 2)
    assert labels.tolist() == np.flatnonzero(inside).tolist()


@FEW
@given(seed=seeds, pose_true=st.tuples(coord, coord, angle),
       pose_odom=st.tuples(coord, coord, angle), fov=st.floats(10.0, 360.0),
       range_min=st.floats(0.0, 3.0), span=st.floats(0.6, 15.0), rate=st.floats(0.5, 4.0))
def test_false_segments_lie_in_view(seed, pose_true, pose_odom, fov, range_min, span, rate):
    rng = np.random.default_rng(seed)
    range_max = max(range_min + span, 0.6)
    sensor = ideal_sensor(fov_deg=fov, range_min=range_min, range_max=range_max,
                          false_per_frame=rate)
    empty = World(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=str))
    counts = []
    for _ in range(30):
        centroids, widths, heights, labels = observe(rng, empty, np.asarray(pose_true),
                                                     np.asarray(pose_odom), sensor)
        counts.append(len(labels))
        assert np.all(labels == -1)
        body = to_body(np.asarray(pose_odom), centroids[:, :2])
        dist = np.hypot(body[:, 0], body[:, 1])
        assert np.all((dist >= range_min - 1e-9) & (dist <= range_max + 1e-9))
        assert np.all(np.degrees(np.abs(np.arctan2(body[:, 1], body[:, 0]))) <= fov / 2 + 1e-6)
        assert np.all((widths > 0) & (heights > 0))
        np.testing.assert_allclose(centroids[:, 2], heights / 2)
    assert sum(counts) > 0


def test_false_segment_rate_and_labels_with_real_objects():
    rng = np.random.default_rng(5)
    world = world_from_body((0.0, 0.0, 0.0), BODY_XY, BODY_W, BODY_H)
    sensor = ideal_sensor(false_per_frame=0.5)
    n_false, n_frames = 0, 400
    for _ in range(n_frames):
        *_, labels = observe(rng, world, np.zeros(3), np.zeros(3), sensor)
        assert labels[:len(SEEN)].tolist() == SEEN  # real detections first, then the false
        assert np.all(labels[len(SEEN):] == -1)
        n_false += len(labels) - len(SEEN)
    assert 0.4 < n_false / n_frames < 0.6


def test_detection_probability():
    rng = np.random.default_rng(11)
    body = np.column_stack([np.linspace(1.0, 4.0, 40), np.zeros(40)])
    world = world_from_body((0.0, 0.0, 0.0), body, np.full(40, 0.4), np.full(40, 0.4))
    seen = np.zeros(40)
    for _ in range(200):
        *_, labels = observe(rng, world, np.zeros(3), np.zeros(3), ideal_sensor(p_detect=0.6))
        seen[labels] += 1
    assert 0.55 < seen.sum() / (200 * 40) < 0.65
    assert seen.min() > 0.4 * 200  # every object, not only some of them


def test_centroid_noise_grows_with_range():
    rng = np.random.default_rng(2)
    body = np.array([[1.0, 0.0], [9.0, 0.0]])
    world = world_from_body((0.0, 0.0, 0.0), body, [0.5, 0.5], [1.0, 1.0])
    sensor = ideal_sensor(range_max=10.0, centroid_noise=0.05, centroid_noise_per_m=0.02)
    errors = np.array([observe(rng, world, np.zeros(3), np.zeros(3), sensor)[0]
                       - world.centroids for _ in range(500)])
    spread = errors.std(axis=0)  # (object, axis)
    for k, r in enumerate((1.0, 9.0)):
        expected = 0.05 + 0.02 * r
        assert np.all((spread[k] > expected / 1.3) & (spread[k] < 1.3 * expected)), spread[k]
    assert np.all(np.abs(errors.mean(axis=0)) < 0.03)  # unbiased with full views


@PROPS
@given(seed=seeds, pose=st.tuples(coord, coord, angle), partial=st.floats(0.1, 1.0))
def test_partial_views_shrink_sizes_and_pull_towards_the_camera(seed, pose, partial):
    rng = np.random.default_rng(seed)
    pose = np.asarray(pose)
    n = 40
    widths = rng.uniform(0.25, 3.0, n)  # seen widths stay above the 2 cm floor
    heights = rng.uniform(0.25, 3.0, n)
    # objects in view, the camera outside every object's footprint
    dist = np.maximum(rng.uniform(0.5, 8.0, n), widths / 2 + 0.01)
    bearing = rng.uniform(-0.7, 0.7, n)
    body = dist[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    world = world_from_body(pose, body, widths, heights)
    sensor = ideal_sensor(range_min=0.3, range_max=9.0, partial_view=partial)
    centroids, seen_w, seen_h, labels = observe(rng, world, pose, pose, sensor)
    assert labels.tolist() == list(range(n))
    assert np.all(seen_w <= widths + 1e-12) and np.all(seen_w >= partial * widths - 1e-12)
    assert np.all(seen_h <= heights + 1e-12) and np.all(seen_h >= partial * heights - 1e-12)
    got = to_body(pose, centroids[:, :2])
    got_dist = np.hypot(got[:, 0], got[:, 1])
    # along the line of sight, never further than the object, never behind the camera ...
    assert np.all(got_dist <= dist + 1e-9)
    np.testing.assert_allclose(got[:, 0] * body[:, 1] - got[:, 1] * body[:, 0], 0.0,
                               atol=1e-8)
    assert np.all(np.einsum("ij,ij->i", got, body) >= -1e-12)
    # ... by half the unseen width, and the centroid height is half the seen height
    # pulled by half the unseen width, at most halfway to the camera
    np.testing.assert_allclose(dist - got_dist, np.minimum((widths - seen_w) / 2, dist / 2),
                               atol=1e-9)
    np.testing.assert_allclose(centroids[:, 2], seen_h / 2, atol=1e-12)
    assert np.all(centroids[:, 2] <= heights / 2 + 1e-12)


def test_partial_view_never_pushes_a_centroid_away():
    rng = np.random.default_rng(0)
    body = np.tile([0.35, 0.0], (50, 1))  # 0.35 m ahead of objects 3 m wide
    world = world_from_body((0.0, 0.0, 0.0), body, np.full(50, 3.0), np.full(50, 1.0))
    sensor = ideal_sensor(range_min=0.3, partial_view=0.2)
    centroids, *_ = observe(rng, world, np.zeros(3), np.zeros(3), sensor)
    assert len(centroids) == 50
    assert np.all(centroids[:, 0] >= 0.0)  # not behind the camera
    assert np.all(np.hypot(centroids[:, 0], centroids[:, 1]) <= 0.35 + 1e-9)


def test_false_segments_of_a_short_range_sensor_stay_in_range():
    rng = np.random.default_rng(0)
    empty = World(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0, dtype=str))
    sensor = ideal_sensor(range_min=0.1, range_max=0.4, false_per_frame=3.0)
    for _ in range(20):
        centroids, *_ = observe(rng, empty, np.zeros(3), np.zeros(3), sensor)
        assert np.all(np.hypot(centroids[:, 0], centroids[:, 1]) <= 0.4 + 1e-9)


# =============================================================================================
# world


@PROPS
@given(seed=seeds, n=st.integers(0, 25), x0=coord, y0=coord, w=st.floats(10.0, 30.0),
       h=st.floats(10.0, 30.0), min_gap=st.floats(0.0, 1.5),
       classes=st.lists(st.sampled_from(sorted(OBJECT_CLASSES)), min_size=1, max_size=4,
                        unique=True))
def test_scatter_respects_bounds_gap_and_classes(seed, n, x0, y0, w, h, min_gap, classes):
    world = scatter(np.random.default_rng(seed), n, (x0, y0, x0 + w, y0 + h), tuple(classes),
                    min_gap=min_gap)
    assert len(world) == n
    assert world.xy.shape == (n, 2) and world.widths.shape == world.heights.shape == (n,)
    assert np.all((world.xy >= (x0, y0)) & (world.xy <= (x0 + w, y0 + h)))
    if n > 1:
        d = np.linalg.norm(world.xy[:, None] - world.xy[None], axis=2)
        assert d[~np.eye(n, dtype=bool)].min() >= min_gap
    assert set(world.kinds.tolist()) <= set(classes)
    for k, wd, ht in zip(world.kinds, world.widths, world.heights, strict=True):
        (w_lo, w_hi), (h_lo, h_hi) = OBJECT_CLASSES[str(k)]
        assert w_lo <= wd <= w_hi and h_lo <= ht <= h_hi
    np.testing.assert_allclose(world.centroids, np.column_stack([world.xy, world.heights / 2]))
    assert world.walls.shape == (0, 2, 2)


def test_scatter_raises_when_impossible():
    with pytest.raises(DataError):
        scatter(np.random.default_rng(0), 10, (0.0, 0.0, 1.0, 1.0), min_gap=2.0)
    with pytest.raises(DataError):
        scatter(np.random.default_rng(0), 3, (0.0, 0.0, 10.0, 10.0), ("spaceship",))
    with pytest.raises(DataError):
        scatter(np.random.default_rng(0), -1, (0.0, 0.0, 10.0, 10.0))


def test_scatter_is_deterministic_per_generator():
    a = scatter(np.random.default_rng(4), 12, (0.0, 0.0, 10.0, 10.0), ("box", "bin"))
    b = scatter(np.random.default_rng(4), 12, (0.0, 0.0, 10.0, 10.0), ("box", "bin"))
    c = scatter(np.random.default_rng(5), 12, (0.0, 0.0, 10.0, 10.0), ("box", "bin"))
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.widths, b.widths)
    assert not np.allclose(a.xy, c.xy)


@PROPS
@given(rows=st.integers(1, 7), cols=st.integers(1, 7), spacing=st.floats(0.1, 5.0),
       size=st.floats(0.05, 2.0), origin=st.tuples(coord, coord))
def test_grid_count_and_positions(rows, cols, spacing, size, origin):
    world = grid(rows, cols, spacing, size, origin)
    assert len(world) == rows * cols
    expected = {(round(origin[0] + spacing * c, 9), round(origin[1] + spacing * r, 9))
                for r in range(rows) for c in range(cols)}
    got = {(round(float(x), 9), round(float(y), 9)) for x, y in world.xy}
    assert got == expected
    np.testing.assert_allclose(world.xy.min(axis=0), origin, atol=1e-9)
    np.testing.assert_allclose(world.xy.max(axis=0), np.asarray(origin) + spacing * np.array(
        [cols - 1, rows - 1]), atol=1e-9)
    assert np.all(world.widths == size) and np.all(world.heights == size)
    assert np.all(world.kinds == "grid")


@PROPS
@given(seed=seeds, n_vertices=st.integers(2, 6), near=st.floats(0.0, 4.0),
       extra=st.floats(0.1, 6.0), per_100m=st.floats(20.0, 200.0))
def test_along_path_stays_in_the_lateral_band(seed, n_vertices, near, extra, per_100m):
    rng = np.random.default_rng(seed)
    path = np.cumsum(rng.uniform(-30, 30, (n_vertices, 2)), axis=0)
    world = along_path(rng, path, per_100m, (near, near + extra), ("tree", "pole"))
    assert world.xy.shape == (len(world), 2)
    assert set(world.kinds.tolist()) <= {"tree", "pole"}
    if len(world):
        assert np.all(segment_distance(world.xy, path) <= near + extra + 1e-9)


@PROPS
@given(seed=seeds, start=st.tuples(coord, coord), phi=angle, length=st.floats(20.0, 200.0),
       near=st.floats(0.0, 4.0), extra=st.floats(0.1, 6.0))
def test_along_a_straight_path_objects_are_between_near_and_far(seed, start, phi, length,
                                                                near, extra):
    rng = np.random.default_rng(seed)
    u = np.array([np.cos(phi), np.sin(phi)])
    # a straight path cut into uneven pieces
    cuts = np.sort(np.r_[0.0, rng.uniform(0, length, 3), length])
    path = np.asarray(start) + cuts[:, None] * u
    path = path[np.r_[True, np.diff(cuts) > 1e-6]]
    world = along_path(rng, path, 100.0, (near, near + extra), ("rock",))
    rel = world.xy - np.asarray(start)
    along = rel @ u
    side = rel @ np.array([-u[1], u[0]])
    assert np.all((along >= -1e-9) & (along <= length + 1e-9))
    assert np.all((np.abs(side) >= near - 1e-9) & (np.abs(side) <= near + extra + 1e-9))


def test_along_path_density_and_both_sides():
    path = np.array([[0.0, 0.0], [80.0, 0.0], [200.0, 0.0]])
    counts, left = [], 0
    for seed in range(40):
        world = along_path(np.random.default_rng(seed), path, 50.0, (2.0, 9.0), ("tree",))
        counts.append(len(world))
        left += int(np.sum(world.xy[:, 1] > 0))
    assert 90 < np.mean(counts) < 110  # 50 per 100 m over 200 m
    assert 0.4 < left / sum(counts) < 0.6  # about half on each side


def test_combine_concatenates_in_order():
    a = grid(2, 3, 1.0, 0.5)
    b = scatter(np.random.default_rng(0), 4, (10.0, 10.0, 20.0, 20.0), ("bench",))
    walls_a = room_walls(0.0, 0.0, 5.0, 5.0)
    a = World(a.xy, a.widths, a.heights, a.kinds, walls_a)
    extra = np.array([[[0.0, 0.0], [1.0, 1.0]]])
    both = combine(a, b, walls=extra)
    assert len(both) == len(a) + len(b) == 10
    np.testing.assert_array_equal(both.xy, np.vstack([a.xy, b.xy]))
    np.testing.assert_array_equal(both.widths, np.r_[a.widths, b.widths])
    np.testing.assert_array_equal(both.heights, np.r_[a.heights, b.heights])
    assert both.kinds.tolist() == a.kinds.tolist() + b.kinds.tolist()
    np.testing.assert_array_equal(both.walls, np.concatenate([walls_a, extra]))
    np.testing.assert_array_equal(both.centroids, np.vstack([a.centroids, b.centroids]))
    assert combine(a).walls.shape == (4, 2, 2)
    assert combine(b).walls.shape == (0, 2, 2)


@PROPS
@given(x0=coord, y0=coord, w=st.floats(2.0, 20.0), h=st.floats(2.0, 20.0),
       door=st.tuples(st.floats(0.1, 0.45), st.floats(0.55, 0.9)))
def test_room_walls(x0, y0, w, h, door):
    x1, y1 = x0 + w, y0 + h
    closed = room_walls(x0, y0, x1, y1)
    lengths = np.linalg.norm(closed[:, 1] - closed[:, 0], axis=1)
    assert closed.shape == (4, 2, 2)
    assert lengths.sum() == pytest.approx(2 * (w + h))
    d0, d1 = y0 + door[0] * h, y0 + door[1] * h
    opened = room_walls(x0, y0, x1, y1, door=(d0, d1))
    assert opened.shape == (5, 2, 2)
    lengths = np.linalg.norm(opened[:, 1] - opened[:, 0], axis=1)
    assert lengths.sum() == pytest.approx(2 * (w + h) - (d1 - d0))
    # no wall crosses the middle of the door in the right-hand wall
    gap = np.array([x1, (d0 + d1) / 2])
    assert segment_distance(gap[None], opened[0]).item() > 0  # sanity of the helper
    assert min(segment_distance(gap[None], seg).item() for seg in opened) > 0.01
    assert min(segment_distance(gap[None], seg).item() for seg in closed) < 1e-9


# =============================================================================================
# scenarios


def test_indoor_return_robot_leaves_and_comes_back():
    cfg = load_scenario("indoor_return")
    lay = cfg.layout
    scene = build_scene(cfg, np.random.default_rng(0))
    assert len(scene.knots) == 2
    t = np.arange(0.0, cfg.duration + 1.0, 1.0)
    home = [poses_along(*k, t)[:, :2] for k in scene.knots]
    in_home = np.all((home[1] > 0) & (home[1] < lay.room), axis=1)
    in_away = home[1][:, 0] > lay.room + 6.0
    assert np.all(np.all((home[0] > 0) & (home[0] < lay.room), axis=1))  # robot 0 stays
    assert np.all(in_home[t < lay.leave_at])
    assert np.all(in_away[(t > lay.leave_at + 30) & (t < lay.return_at - 30)])
    assert np.all(in_home[t > lay.return_at + 10])
    # both rooms' boxes are in the world: the home ones inside the home room
    n_home = lay.boxes
    assert len(scene.world) == lay.boxes + lay.away_boxes
    assert np.all((scene.world.xy[:n_home] >= 1.0) & (scene.world.xy[:n_home] <= lay.room - 1))
    assert np.all(scene.world.xy[n_home:, 0] > lay.room + 4.0)


@pytest.mark.parametrize("name", ["same_direction", "opposite_directions"])
def test_outdoor_robots_start_separated_along_the_path(name):
    cfg = load_scenario(name)
    lay = cfg.layout
    scene = build_scene(cfg, np.random.default_rng(3))
    start = [k[1][0] for k in scene.knots]
    # the path winds gently, so the straight distance is a little under the arc length
    gap = np.linalg.norm(start[1] - start[0])
    assert 0.9 * lay.separation < gap <= lay.separation + 1e-9
    for k in scene.knots:
        np.testing.assert_allclose(np.linalg.norm(np.diff(k[1], axis=0), axis=1) / lay.speed,
                                   np.diff(k[0]), rtol=1e-9)
    t = np.array([0.0, 10.0])
    p = [poses_along(*k, t) for k in scene.knots]
    if name == "same_direction":  # robot 1 follows robot 0
        assert start[0][0] > start[1][0]
        assert p[0][1, 0] > p[0][0, 0] and p[1][1, 0] > p[1][0, 0]
    else:  # they drive towards each other
        assert start[0][0] < start[1][0]
        assert p[0][1, 0] > p[0][0, 0] and p[1][1, 0] < p[1][0, 0]
        assert np.linalg.norm(p[1][1, :2] - p[0][1, :2]) < gap - 20.0


def test_grid_formations():
    """abreast: half a lane apart all the time; opposite: from the end of the sweep, back."""
    abreast = load_scenario("ambiguous_grid")
    opposite = load_scenario("ambiguous_grid_opposite")
    assert (abreast.layout.formation, opposite.layout.formation) == ("abreast", "opposite")
    t = np.arange(0.0, abreast.duration, 1.0)
    scene = build_scene(abreast, np.random.default_rng(0))
    p0, p1 = (poses_along(*k, t) for k in scene.knots)
    np.testing.assert_allclose(p1[:, :2] - p0[:, :2], np.tile([0.0, 1.25], (len(t), 1)),
                               atol=1e-9)
    scene = build_scene(opposite, np.random.default_rng(0))
    p0, p1 = (poses_along(*k, t) for k in scene.knots)
    assert np.linalg.norm(p0[0, :2] - p1[0, :2]) > 5.0  # the last lane's end
    assert np.mean(np.linalg.norm(p0[:, :2] - p1[:, :2], axis=1) > 0.5) > 0.5


# =============================================================================================
# simulate


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenarios_simulate(name):
    run = run_of(name)
    cfg = run.scenario
    assert isinstance(run, SimRun) and run.seed == 0
    n, S = cfg.n_robots, int(SHORT)
    assert run.n_robots == n
    np.testing.assert_allclose(run.times, np.arange(1.0, SHORT + 1.0))
    assert run.poses_true.shape == run.poses_odom.shape == (n, S, 3)
    assert len(run.maps) == len(run.labels) == n
    for r in range(n):
        assert len(run.maps[r]) == len(run.labels[r]) == S
        for s in range(S):
            m, lab = run.maps[r][s], run.labels[r][s]
            assert isinstance(m, ObjectMap)
            assert lab.dtype == np.int64 and lab.shape == (len(m),)
            assert np.all((lab >= -1) & (lab < len(run.world)))
            assert np.all(m.last_seen <= run.times[s] + 1e-9)
        assert len(run.maps[r][-1]) > 0 and np.any(run.labels[r][-1] >= 0)
    for i in range(n):
        for j in range(n):
            assert run.T_true(i, j).shape == (S, 3, 3)
            assert run.overlap(i, j).shape == (S,)


@pytest.mark.parametrize("name", SCENARIOS)
def test_same_seed_same_run_other_seed_other_run(name):
    a, b = run_of(name, 0), simulate(short(name), 0)
    np.testing.assert_array_equal(a.poses_true, b.poses_true)
    np.testing.assert_array_equal(a.poses_odom, b.poses_odom)
    np.testing.assert_array_equal(a.world.xy, b.world.xy)
    for r in range(a.n_robots):
        for s in range(len(a.times)):
            np.testing.assert_array_equal(a.maps[r][s].centroids, b.maps[r][s].centroids)
            np.testing.assert_array_equal(a.maps[r][s].widths, b.maps[r][s].widths)
            np.testing.assert_array_equal(a.maps[r][s].last_seen, b.maps[r][s].last_seen)
            np.testing.assert_array_equal(a.labels[r][s], b.labels[r][s])
    c = run_of(name, 1)
    assert not np.array_equal(a.poses_odom, c.poses_odom)
    last_a, last_c = a.maps[0][-1].centroids, c.maps[0][-1].centroids
    assert last_a.shape != last_c.shape or not np.allclose(last_a, last_c)


def shared_residuals(run: SimRun) -> np.ndarray:
    """Distances (metres, x-y) between robot i's map entries and robot j's entries of the same
    world object mapped through T_true(i, j), over all ordered pairs and exchanges."""
    out = []
    for i in range(run.n_robots):
        for j in range(run.n_robots):
            if i == j:
                continue
            T = run.T_true(i, j)
            for s in range(len(run.times)):
                li, lj = run.labels[i][s], run.labels[j][s]
                common = np.intersect1d(li[li >= 0], lj[lj >= 0])
                for label in common.tolist():
                    ci = run.maps[i][s].centroids[li == label, :2]
                    cj = run.maps[j][s].centroids[lj == label, :2]
                    mapped = transform_points(T[s], cj)
                    out.append(np.min(np.linalg.norm(ci[:, None] - mapped[None], axis=2)))
    return np.asarray(out)


@pytest.mark.parametrize("name", SCENARIOS)
def test_true_alignment_maps_shared_objects_onto_each_other(name):
    run = run_of(name)
    res = shared_residuals(run)
    assert len(res) >= 50  # the robots do map common objects
    limit = 0.3 if name in INDOOR else 0.6
    assert np.median(res) < limit, np.median(res)
    assert np.quantile(res, 0.9) < 3 * limit
    # T_true(j, i) is the inverse of T_true(i, j)
    np.testing.assert_allclose(run.T_true(1, 0) @ run.T_true(0, 1),
                               np.broadcast_to(np.eye(3), (len(run.times), 3, 3)), atol=1e-9)


@pytest.mark.parametrize("name", SCENARIOS)
def test_true_poses_follow_the_scene_knots(name):
    run = run_of(name, 2)
    scene = build_scene(run.scenario, np.random.default_rng(2))
    np.testing.assert_array_equal(run.world.xy, scene.world.xy)
    for r, knots in enumerate(scene.knots):
        expected = poses_along(*knots, run.times)
        np.testing.assert_allclose(run.poses_true[r, :, :2], expected[:, :2], atol=1e-9)
        assert np.all(angle_diff(run.poses_true[r, :, 2], expected[:, 2]) < 1e-9)
        # the odometry frame is the true pose at t = 0, up to the drift
        T_w_o = run.T_w_o(r)
        start = se2_from_params(poses_along(*knots, np.array([0.0]))[0])
        err = se2_error(np.broadcast_to(start, T_w_o.shape), T_w_o)
        assert err[:, 0].max() < 2.0 and err[:, 1].max() < np.radians(5)


def test_without_drift_the_odometry_frame_is_the_first_pose_and_maps_are_exact():
    cfg = short("indoor_return", odometry=OdometryDrift(heading_rw_deg=0.0, position_rw=0.0),
                sensor=ideal_sensor(range_max=5.0))
    run = simulate(cfg, 4)
    scene = build_scene(cfg, np.random.default_rng(4))
    for r in range(2):
        start = se2_from_params(poses_along(*scene.knots[r], np.array([0.0]))[0])
        err = se2_error(np.broadcast_to(start, (len(run.times), 3, 3)), run.T_w_o(r))
        assert err.max() < 1e-9
        # an exact sensor and no drift: every map entry sits on its world object
        for s in range(len(run.times)):
            m, lab = run.maps[r][s], run.labels[r][s]
            assert np.all(lab >= 0)
            world_xy = transform_points(run.T_w_o(r)[s], m.centroids[:, :2])
            np.testing.assert_allclose(world_xy, run.world.xy[lab], atol=1e-9)
    res = shared_residuals(run)
    assert len(res) > 0 and res.max() < 1e-9


def hand_overlap(run: SimRun, i: int, j: int, s: int, need: int) -> bool:
    t, kappa = run.times[s], run.scenario.mapping.kappa
    a = {int(x) for x, seen in zip(run.labels[i][s], run.maps[i][s].last_seen, strict=True)
         if x >= 0 and t - seen < kappa}
    b = {int(x) for x, seen in zip(run.labels[j][s], run.maps[j][s].last_seen, strict=True)
         if x >= 0 and t - seen < kappa}
    return len(a & b) >= need


@pytest.mark.parametrize("name", SCENARIOS)
def test_overlap_is_sharing_enough_recent_labelled_objects(name):
    run = run_of(name)
    n = run.n_robots
    for i in range(n):
        for j in range(n):
            got = run.overlap(i, j)
            expected = [hand_overlap(run, i, j, s, run.scenario.min_shared)
                        for s in range(len(run.times))]
            assert got.tolist() == expected
            np.testing.assert_array_equal(got, run.overlap(j, i))
    # with a short kappa only what was just seen counts; with min_shared = 1 more steps overlap
    for update in ({"min_shared": 1}, {"min_shared": 12},
                   {"mapping": run.scenario.mapping.model_copy(update={"kappa": 2.0})}):
        other = SimRun(run.scenario.model_copy(update=update), run.seed, run.times,
                       run.poses_true, run.poses_odom, run.maps, run.labels, run.world)
        need = other.scenario.min_shared
        for s in range(len(run.times)):
            assert other.overlap(0, 1)[s] == hand_overlap(other, 0, 1, s, need)
    loose = SimRun(run.scenario.model_copy(update={"min_shared": 1}), run.seed, run.times,
                   run.poses_true, run.poses_odom, run.maps, run.labels, run.world)
    assert np.all(loose.overlap(0, 1) >= run.overlap(0, 1))


def test_overlap_is_not_trivial():
    run = run_of("indoor_return")
    ov = run.overlap(0, 1)
    assert ov.any() and not ov.all()
    assert run.overlap(0, 0)[-1]  # a robot overlaps with itself once it has mapped enough


@pytest.mark.parametrize("robots", [3, 4, 6])
def test_room_layout_gives_every_robot_its_data(robots):
    cfg = ScenarioConfig(name="room", duration=15.0,
                         layout=RoomLayout(kind="room", robots=robots, room=12.0, objects=20),
                         mapping=MappingConfig(frame_rate=5.0))
    assert cfg.n_robots == robots
    done = []
    run = simulate(cfg, 0, progress=done.append)
    assert done == pytest.approx([(r + 1) / robots for r in range(robots)])
    assert run.n_robots == robots
    assert run.poses_true.shape == run.poses_odom.shape == (robots, 15, 3)
    assert len(run.maps) == len(run.labels) == robots
    assert all(len(m) == 15 for m in run.maps)
    assert all(len(run.maps[r][-1]) > 0 for r in range(robots))
    # everybody drives inside the room, and not all along the same path
    assert np.all((run.poses_true[:, :, :2] > 0) & (run.poses_true[:, :, :2] < 12.0))
    starts = run.poses_true[:, 0, :2]
    d = np.linalg.norm(starts[:, None] - starts[None], axis=2)
    assert d[~np.eye(robots, dtype=bool)].min() > 0.1
    assert run.T_true(robots - 1, 0).shape == (15, 3, 3)


def test_per_robot_odometry_drift_is_used():
    cfg = short("indoor_return", odometry=[
        OdometryDrift(heading_rw_deg=0.0, position_rw=0.0),
        OdometryDrift(heading_rw_deg=2.0, position_rw=0.1)])
    run = simulate(cfg, 0)
    first = run.T_w_o(0)
    assert se2_error(np.broadcast_to(first[0], first.shape), first).max() < 1e-9
    second = run.T_w_o(1)
    assert se2_error(np.broadcast_to(second[0], second.shape), second)[:, 0].max() > 0.05


def test_frame_rate_below_the_map_exchange_rate_is_refused():
    # every 1 Hz map exchange needs a frame at or before it
    with pytest.raises(ValidationError, match="frame_rate"):
        MappingConfig(nu=1, kappa=20.0, frame_rate=0.5)
    cfg = short("indoor_return", duration=10.0,
                mapping=MappingConfig(nu=1, kappa=20.0, frame_rate=1.0))
    run = simulate(cfg, 0)
    assert all(len(run.maps[r]) == len(run.times) for r in range(run.n_robots))


# -- rendered RGB-D perception -------------------------------------------------------------------


def test_clear_paths_moves_objects_off_the_paths_and_keeps_them_apart():
    rng = np.random.default_rng(3)
    world = scatter(rng, 12, (0.0, 0.0, 10.0, 10.0), ("box", "bin"), min_gap=1.2)
    path = np.column_stack([np.linspace(0, 10, 400), np.full(400, 5.0)])
    cleared = clear_paths(rng, world, [path], clearance=0.4)
    assert len(cleared) == len(world)  # a 10 x 10 m room has room for all of them
    reach = 0.4 + cleared.widths / np.sqrt(2)
    assert np.all(np.abs(cleared.xy[:, 1] - 5.0) > reach - 1e-9)
    untouched = np.abs(world.xy[:, 1] - 5.0) > 0.4 + world.widths / np.sqrt(2)
    np.testing.assert_array_equal(cleared.xy[untouched], world.xy[untouched])


@pytest.mark.slow
def test_rendered_scenario_maps_only_real_objects_and_tcaff_aligns_them():
    """The indoor RGB-D scenario runs the real front end: every map entry is a real object
    (nothing from the floor or walls), few are duplicates, and TCAFF's alignment is right."""
    shipped = load_scenario("indoor_rgbd")
    # 32 s at 280 x 210 instead of 120 s at 320 x 240: ray casting and mapping cost by the
    # frame and the pixel. The robots share objects from about 17 s and TCAFF aligns both
    # directions from 25 s, 7 steps each; smaller images leave too few objects to align
    config = shipped.model_copy(update={"duration": 32.0, "camera": shipped.camera.model_copy(
        update={"width": 280, "height": 210})})
    run = simulate(config, seed=0)
    final = [run.labels[r][-1] for r in range(run.n_robots)]
    for labels in final:
        assert labels.size >= 4
        assert np.all(labels >= 0)
        assert np.unique(labels).size >= labels.size - 1  # at most one duplicate per map
    job = evaluate_simulated(run, load_methods("tcaff_only"))
    tcaff = job.metrics["tcaff"]["all"]
    assert tcaff["false_accept"] == 0.0
    assert tcaff["translation_error_m_mean"] < 0.35
