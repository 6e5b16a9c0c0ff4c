"""Tests for tcaff_gtsam.eval.sim's object sensor and world builders."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from sim_helpers import (
    FEW,
    PROPS,
    angle,
    coord,
    ideal_sensor,
    seeds,
    segment_distance,
    to_body,
    world_from_body,
)
from tcaff_gtsam.eval.sim.maps import OBJECT_CLASSES
from tcaff_gtsam.eval.sim.sensor import observe
from tcaff_gtsam.eval.sim.world import World, along_path, combine, grid, room_walls, scatter

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import (
    compose,
    invert,
    se2_from_params,
    transform_points,
)

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
