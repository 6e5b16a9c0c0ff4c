"""Tests for tcaff_gtsam.mapping.objects: a track's merged cloud (`ObjectCloud`), the upright box
of a cloud (`cloud_extent`), its shape (`shape_features`) and colour bins (`colour_bins`); and
the clouds that `lift.Observations` carries."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rgbd_scenes import SMALL_CAMERA, T_BC, majority_instance
from tcaff_gtsam.eval.sim.render import RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.frontend import RgbdFrontEnd
from tcaff_gtsam.mapping.lift import Observations
from tcaff_gtsam.mapping.mapper import MapperParams
from tcaff_gtsam.mapping.objects import (
    ObjectCloud,
    cloud_extent,
    colour_bins,
    shape_features,
)

from tcaff_gtsam.association import size_compatible
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se3_from_xyz_yaw, transform_points
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import FrameAlignerParams

FEW = settings(max_examples=25, deadline=None)


def voxel_keys(points: np.ndarray, voxel: float) -> list[tuple[int, int, int]]:
    return [tuple(k) for k in np.floor(points / voxel).astype(np.int64)]


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def box_faces(width: float, depth: float, height: float, n_w: int = 31, n_d: int = 21,
              n_h: int = 11) -> np.ndarray:
    """(n, 3) grid samples on two adjacent faces of an axis-aligned box centred on the origin
    (floor at z = 0): the face at y = -depth/2 and the face at x = +width/2 (an L in the
    footprint, as a camera at a corner sees a box)."""
    u = np.linspace(-width / 2, width / 2, n_w)
    v = np.linspace(-depth / 2, depth / 2, n_d)
    z = np.linspace(0.0, height, n_h)
    front = np.array([(x, -depth / 2, h) for x in u for h in z])
    side = np.array([(width / 2, y, h) for y in v[1:] for h in z])
    return np.vstack([front, side])


# ---------------------------------------------------------------------------------------------
# ObjectCloud


@FEW
@given(st.integers(0, 2**32 - 1), st.floats(0.01, 0.2))
def test_the_newest_point_of_each_voxel_wins(seed, voxel):
    rng = np.random.default_rng(seed)
    old = rng.uniform(0.0, 1.0, (300, 3))
    new = rng.uniform(0.5, 1.5, (300, 3))
    cloud = ObjectCloud(voxel, 10**6)
    cloud.add(old, 1.0)
    cloud.add(new, 2.0)
    assert cloud.voxel == voxel  # never full: no doubling
    keys = voxel_keys(cloud.points, voxel)
    assert len(set(keys)) == len(keys) == len(cloud), "one point per voxel"
    new_keys = set(voxel_keys(new, voxel))
    assert set(keys) == new_keys | set(voxel_keys(old, voxel))
    new_points = {tuple(p) for p in new}
    old_points = {tuple(p) for p in old}
    for p, k, t in zip(cloud.points, keys, cloud.seen, strict=True):
        if k in new_keys:
            assert tuple(p) in new_points and t == 2.0
        else:
            assert tuple(p) in old_points and t == 1.0
    np.testing.assert_array_equal(cloud.lo, cloud.points.min(axis=0))
    np.testing.assert_array_equal(cloud.hi, cloud.points.max(axis=0))


@FEW
@given(st.integers(0, 2**32 - 1), st.integers(16, 200), st.integers(1, 5))
def test_never_more_than_max_points_the_voxel_doubling(seed, max_points, batches):
    rng = np.random.default_rng(seed)
    voxel = 0.01
    cloud = ObjectCloud(voxel, max_points)
    seen = []
    for b in range(batches):
        pts = rng.uniform(-1.0, 1.0, (int(rng.integers(1, 500)), 3)) * rng.uniform(0.05, 2.0)
        seen.append(pts)
        cloud.add(pts, float(b))
        assert 1 <= len(cloud) <= max_points
        doublings = math.log2(cloud.voxel / voxel)
        assert doublings == round(doublings) and doublings >= 0
        keys = voxel_keys(cloud.points, cloud.voxel)
        assert len(set(keys)) == len(keys)
        # every voxel any point was seen in is still occupied, at the current voxel edge
        assert set(keys) == set(voxel_keys(np.vstack(seen), cloud.voxel))
        # and the voxel is no coarser than it needs to be
        if cloud.voxel > voxel:
            assert len(set(voxel_keys(np.vstack(seen), cloud.voxel / 2))) > max_points


def test_few_points_keep_the_voxel():
    cloud = ObjectCloud(0.05, 16)
    cloud.add(np.arange(48.0).reshape(16, 3), 0.0)  # 16 voxels, all distinct
    assert cloud.voxel == 0.05 and len(cloud) == 16
    cloud.add(np.array([[100.0, 100.0, 100.0]]), 1.0)  # the 17th voxel: doubles
    assert cloud.voxel > 0.05 and len(cloud) <= 16


def test_forget_drops_the_voxels_unseen_for_longer_than_the_span():
    cloud = ObjectCloud(0.1, 1000)
    a = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05]])
    b = np.array([[1.05, 0.05, 0.05]])
    c = np.array([[2.05, 0.05, 0.05], [0.15, 0.05, 0.05]])  # one voxel of a seen again
    cloud.add(a, 0.0)
    cloud.add(b, 5.0)
    cloud.add(c, 10.0)
    cloud.forget(15.0, 10.0)  # 15 - 0 > 10: a's first voxel goes; 15 - 5 = 10 stays
    assert sorted(map(tuple, cloud.points.round(6))) == sorted(
        [(0.15, 0.05, 0.05), (1.05, 0.05, 0.05), (2.05, 0.05, 0.05)])
    assert sorted(cloud.seen.tolist()) == [5.0, 10.0, 10.0]
    np.testing.assert_allclose(cloud.lo, [0.15, 0.05, 0.05])
    cloud.forget(100.0, 1.0)
    assert len(cloud) == 0 and cloud.points.shape == (0, 3)
    assert np.all(cloud.lo == np.inf) and np.all(cloud.hi == -np.inf)
    assert cloud.share_on(a, 0.1) == 0.0


@FEW
@given(st.integers(0, 2**32 - 1), st.floats(0.01, 0.3), st.floats(0.005, 0.1))
def test_share_on_own_points_is_one_and_far_points_zero(seed, cell, voxel):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.3, 0.3, (200, 3)) + rng.uniform(-50, 50, 3)
    cloud = ObjectCloud(voxel, 10**6)
    cloud.add(pts, 0.0)
    assert cloud.share_on(cloud.points, cell) == 1.0
    if cell <= voxel:  # the cells are the voxels: every voxel a point fell in is occupied
        assert cloud.share_on(pts, cell) == 1.0
    direction = rng.standard_normal(3)
    far = pts + (1.0 + 0.6 * math.sqrt(3)) * direction / np.linalg.norm(direction)
    assert cloud.share_on(far, cell) == 0.0
    # half on, half off
    own = cloud.points
    shift = far[0] - pts[0]
    h = len(own) // 2
    mixed = np.vstack([own[:h], own[:h] + shift])
    assert cloud.share_on(mixed, cell) == 0.5
    # the cache of cells follows the cloud: after adding the far points they are on it
    cloud.add(far, 1.0)
    assert cloud.share_on(cloud.points, cell) == 1.0
    assert cloud.share_on(cloud.points[cloud.seen == 1.0], cell) == 1.0
    if cell <= voxel:
        assert cloud.share_on(far, cell) == 1.0


def test_share_on_counts_grid_cells_of_the_coarser_of_cell_and_voxel():
    cloud = ObjectCloud(0.5, 1000)
    cloud.add(np.array([[0.1, 0.1, 0.1]]), 0.0)
    probe = np.array([[0.4, 0.4, 0.4], [0.6, 0.1, 0.1]])
    assert cloud.share_on(probe, 0.05) == 0.5  # in the 0.5 m voxel, and not
    assert cloud.share_on(probe, 1.0) == 1.0  # both in the 1 m cell


def test_absorb_takes_the_other_clouds_points_and_times():
    a, b = ObjectCloud(0.1, 1000), ObjectCloud(0.1, 1000)
    a.add(np.array([[0.05, 0.05, 0.05]]), 1.0)
    b.add(np.array([[1.05, 0.05, 0.05], [1.05, 1.05, 0.05]]), 2.0)
    a.absorb(b)
    assert len(a) == 3 and len(b) == 2
    assert sorted(a.seen.tolist()) == [1.0, 2.0, 2.0]
    np.testing.assert_allclose(a.hi, [1.05, 1.05, 0.05])
    assert a.share_on(b.points, 0.1) == 1.0
    a.absorb(ObjectCloud(0.1, 1000))  # an empty one changes nothing
    assert len(a) == 3


def test_absorb_keeps_the_newest_point_of_a_shared_voxel():
    fresh, stale = ObjectCloud(0.1, 1000), ObjectCloud(0.1, 1000)
    fresh.add(np.array([[0.01, 0.01, 0.01]]), 5.0)
    stale.add(np.array([[0.02, 0.02, 0.02]]), 1.0)
    fresh.absorb(stale)
    assert fresh.seen.tolist() == [5.0]
    np.testing.assert_array_equal(fresh.points, [[0.01, 0.01, 0.01]])


# ---------------------------------------------------------------------------------------------
# cloud_extent


@FEW
@given(st.floats(0.1, 2.0), st.floats(0.1, 2.0), st.floats(0.1, 2.0),
       st.floats(-math.pi, math.pi), st.floats(-50, 50), st.floats(-50, 50),
       st.floats(-1.0, 1.0))
def test_two_faces_of_a_box_give_the_box_whatever_the_pose(a, b, height, yaw, x, y, z):
    """Samples on two adjacent faces (an L footprint, as from a corner) give the box's width
    (longer side), depth and height and its centre, turned about z and moved anywhere: the
    smallest-perimeter footprint rectangle is the box, not one along the diagonal (whose
    area ties with the box's)."""
    width, depth = max(a, b), min(a, b)
    pts = box_faces(a, b, height) @ yaw_matrix(yaw).T + (x, y, z)
    ext = cloud_extent(pts)
    assert ext.width == pytest.approx(width, abs=2e-3)
    assert ext.depth == pytest.approx(depth, abs=2e-3)
    assert ext.height == pytest.approx(height, abs=1e-9)
    np.testing.assert_allclose(ext.centre, [x, y, z + height / 2], atol=2e-3)
    padded = cloud_extent(pts, pad=0.02)
    assert padded.width == pytest.approx(ext.width + 0.02, abs=1e-9)
    assert padded.depth == pytest.approx(ext.depth + 0.02, abs=1e-9)
    assert padded.height == pytest.approx(ext.height + 0.02, abs=1e-9)
    np.testing.assert_allclose(padded.centre, ext.centre, atol=1e-9)


def test_single_point_and_a_line_have_sensible_extents():
    one = cloud_extent(np.array([[1.0, 2.0, 3.0]]), pad=0.01)
    assert (one.width, one.depth, one.height) == pytest.approx((0.01, 0.01, 0.01))
    np.testing.assert_allclose(one.centre, [1.0, 2.0, 3.0])
    line = cloud_extent(np.column_stack([np.linspace(0, 1, 50), np.linspace(0, 1, 50),
                                         np.zeros(50)]))
    assert line.width == pytest.approx(math.sqrt(2), abs=1e-6)
    assert line.depth == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize(("voxel", "max_points", "name"), [
    (0.0, 10, "voxel"), (-0.01, 10, "voxel"), (math.nan, 10, "voxel"), (math.inf, 10, "voxel"),
    ("0.02", 10, "voxel"), (0.02, 0, "max_points"), (0.02, 2.5, "max_points"),
    (0.02, None, "max_points")])
def test_bad_cloud_settings_are_config_errors_naming_them(voxel, max_points, name):
    with pytest.raises(ConfigError, match=rf"^ObjectCloud\.{name} = "):
        ObjectCloud(voxel, max_points)


@pytest.mark.parametrize(("points", "match"), [
    (np.zeros((0, 3)), r"shape \(n, 3\) with n >= 1, got \(0, 3\)"),
    (np.zeros((4, 2)), r"shape \(n, 3\) with n >= 1, got \(4, 2\)"),
    (np.array([[0.0, math.nan, 0.0]]), "non-finite"),
    ([["a", "b", "c"]], "points")])
def test_cloud_extent_refuses_what_is_not_a_cloud(points, match):
    with pytest.raises(DataError, match=r"^cloud_extent: .*" + match):
        cloud_extent(points)


@pytest.mark.parametrize("rgb", [np.zeros((4, 4, 3), np.float32), np.zeros((4, 4), np.uint8),
                                 np.zeros((4, 4, 4), np.uint8), [[[0, 0, 0]]]])
def test_colour_bins_refuses_what_is_not_an_rgb_image(rgb):
    with pytest.raises(DataError, match="rgb"):
        colour_bins(rgb, 12, 3)


def test_a_few_stray_points_above_and_below_do_not_stretch_the_height():
    pts = box_faces(0.6, 0.4, 0.5)  # 671 points: 6 are trimmed at each end
    stray = np.array([[0.0, -0.2, 3.0], [0.3, 0.0, 2.5], [0.1, -0.2, -1.5]])
    ext = cloud_extent(np.vstack([pts, stray]))
    assert ext.height == pytest.approx(0.5, abs=0.06)
    assert ext.centre[2] == pytest.approx(0.25, abs=0.03)
    assert (ext.width, ext.depth) == pytest.approx((0.6, 0.4), abs=0.02)


def test_a_stray_point_to_the_side_does_not_turn_or_stretch_the_box():
    pts = box_faces(0.6, 0.4, 0.5)
    ext = cloud_extent(np.vstack([pts, [[3.0, 2.0, 0.2]]]))
    assert (ext.width, ext.depth) == pytest.approx((0.6, 0.4), abs=0.02)
    np.testing.assert_allclose(ext.centre[:2], [0.0, 0.0], atol=0.02)


# ---------------------------------------------------------------------------------------------
# shape_features


@FEW
@given(st.integers(0, 2**32 - 1), st.sampled_from(["line", "plane", "blob"]))
def test_shape_features_sum_to_one_and_name_the_shape_whatever_the_pose(seed, kind):
    rng = np.random.default_rng(seed)
    n = 400
    if kind == "line":
        pts = np.column_stack([rng.uniform(0, 2.0, n), 0.01 * rng.standard_normal((n, 2))])
    elif kind == "plane":
        pts = np.column_stack([rng.uniform(0, 1.0, (n, 2)), 0.005 * rng.standard_normal(n)])
    else:
        pts = rng.uniform(0, 0.5, (n, 3))
    f = shape_features(pts)
    assert f.shape == (3,) and np.all(f >= 0)
    assert f.sum() == pytest.approx(1.0, abs=1e-12)
    which = {"line": 0, "plane": 1, "blob": 2}[kind]
    assert int(np.argmax(f)) == which and f[which] > 0.6, f"{kind}: {f}"
    moved = pts @ random_rotation(rng).T + rng.uniform(-100, 100, 3)
    np.testing.assert_allclose(shape_features(moved), f, atol=1e-7)
    np.testing.assert_allclose(shape_features(pts[rng.permutation(n)]), f, atol=1e-12)


def test_shape_features_of_degenerate_clouds_are_uniform():
    for pts in (np.zeros((0, 3)), np.ones((1, 3)), np.ones((2, 3)), np.ones((10, 3))):
        np.testing.assert_allclose(shape_features(pts), [1 / 3, 1 / 3, 1 / 3])


# ---------------------------------------------------------------------------------------------
# colour_bins


def test_pure_colours_land_in_different_hue_bins_and_greys_in_the_last():
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]],
                    [[128, 128, 128], [0, 0, 0], [255, 255, 255], [30, 0, 0]],
                    [[200, 185, 185], [250, 20, 20], [20, 70, 20], [60, 60, 200]]],
                   dtype=np.uint8)
    hue_bins, sat_bins = 12, 3
    grey = hue_bins * sat_bins
    bins = colour_bins(rgb, hue_bins, sat_bins)
    assert bins.shape == (3, 4) and bins.dtype == np.int64
    red, green, blue, yellow = bins[0]
    # hue (0-255) 0, 85, 171 and 43: bins 0, 3, 8 and 2 of 12; full saturation: the top one
    assert (red, green, blue, yellow) == (0 * 3 + 2, 3 * 3 + 2, 8 * 3 + 2, 2 * 3 + 2)
    # grey, black, white, too dark, too pale: the grey bin
    assert bins[1].tolist() == [grey] * 4 and bins[2, 0] == grey
    # a slightly off red is still red; a dark green still green; a greyish blue blue
    assert bins[2, 1] // sat_bins == 0
    assert bins[2, 2] // sat_bins == 3
    assert bins[2, 3] // sat_bins in (7, 8) and bins[2, 3] % sat_bins < 2


@FEW
@given(st.integers(0, 2**32 - 1), st.integers(1, 16), st.integers(1, 6))
def test_colour_bins_are_in_range_and_greys_are_grey(seed, hue_bins, sat_bins):
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    rgb[0] = rng.integers(0, 256, (30, 1), dtype=np.uint8)  # a row of greys
    bins = colour_bins(rgb, hue_bins, sat_bins)
    assert bins.min() >= 0 and bins.max() <= hue_bins * sat_bins
    assert np.all(bins[0] == hue_bins * sat_bins)
    # the same colour in another image gets the same bin: bins are per pixel
    np.testing.assert_array_equal(colour_bins(np.ascontiguousarray(rgb[5:, 7:]), hue_bins,
                                              sat_bins), bins[5:, 7:])


# ---------------------------------------------------------------------------------------------
# Observations carry their clouds


def test_observations_keep_each_cloud_with_its_observation():
    clouds = [np.full((2, 3), 1.0), np.full((3, 3), 2.0), np.full((1, 3), 3.0)]
    obs = Observations(np.arange(9.0).reshape(3, 3), np.array([1.0, 2.0, 3.0]),
                       np.array([0.5, 0.6, 0.7]), np.array([2, 3, 1]), np.array([4, 7, 9]),
                       np.vstack(clouds), np.array([0, 2, 5, 6]))
    for got, want in zip(obs.clouds(), clouds, strict=True):
        np.testing.assert_array_equal(got, want)


# ---------------------------------------------------------------------------------------------
# one object seen from several sides keeps its size (through the front end)

#: a 0.6 x 0.4 x 0.8 m box (taller than the 0.6 m camera, so no view shows its top), turned
#: 0.4 rad, built from six 0.2 m columns (the renderer's boxes are square)
BOX_CENTRE, BOX_YAW, BOX_SIZE = np.array([5.0, 4.0]), 0.4, (0.6, 0.4, 0.8)
#: odometry = this gravity-aligned transform of the world frame
T_ODOM_WORLD = se3_from_xyz_yaw(1.0, -2.0, 0.0, 0.7)


def box_scene() -> RgbdScene:
    u = np.array([math.cos(BOX_YAW), math.sin(BOX_YAW)])
    v = np.array([-u[1], u[0]])
    columns = [BOX_CENTRE + (i - 1) * 0.2 * u + (j - 0.5) * 0.2 * v
               for i in range(3) for j in range(2)]
    return RgbdScene(columns, [0.2] * 6, [BOX_SIZE[2]] * 6, None, [BOX_YAW] * 6,
                     walls=room_walls(0, 0, 10, 8))


def map_box(bearings_deg, mapper_params: MapperParams) -> tuple[RgbdFrontEnd, list]:
    """The front end after one frame from each bearing (degrees from the box's long axis, so
    0 faces its 0.4 m end), 1.8 m from its centre and facing it, odometry = truth."""
    scene = box_scene()
    front = RgbdFrontEnd(SMALL_CAMERA, T_BC, depth_scale=1.0, mapper_params=mapper_params)
    lifted = []
    for i, bearing in enumerate(bearings_deg):
        b = BOX_YAW + math.radians(bearing)
        x, y = BOX_CENTRE + 1.8 * np.array([math.cos(b), math.sin(b)])
        T_world_body = se3_from_xyz_yaw(x, y, 0.0, b + math.pi)
        frame = render(scene, T_world_body @ T_BC, SMALL_CAMERA)
        result = front.process(0.1 * i, frame.rgb, frame.depth, T_ODOM_WORLD @ T_world_body)
        lifted.append([majority_instance(frame.instance, m) for m in result.masks])
    return front, lifted


def box_errors(om: ObjectMap) -> tuple[float, bool]:
    """(horizontal distance of the object's centroid from the box's centre in metres, whether
    its width and height pass the aligner's default size gate against the box's)."""
    p = FrameAlignerParams()
    truth = ObjectMap([[0.0, 0.0, 0.0]], [max(BOX_SIZE[:2])], [BOX_SIZE[2]], [0.0])
    centre = transform_points(invert(T_ODOM_WORLD), om.centroids)[0]
    assert abs(centre[2] - BOX_SIZE[2] / 2) < 0.05
    gate = size_compatible(om, truth, p.size_ratio, p.size_abs_diff)
    return float(np.hypot(*(centre[:2] - BOX_CENTRE))), bool(gate[0, 0])


def test_a_box_seen_around_a_corner_keeps_its_size_and_centre():
    """Three frames, from its 0.4 m end, from the corner and from its 0.6 m side: one track
    whose merged cloud is the box (two faces: an L), so its width and height are within the
    aligner's size gate of the box's and its centroid within 0.1 m of the box's centre (the
    running means of the three views' own centroids are 0.19 m off, towards the corner).
    The first view alone (the 0.4 m end, a single face) gives a width outside the gate and a
    centroid on that face, 0.3 m off."""
    front, lifted = map_box([0, 45, 90], MapperParams())
    assert all(len(found) == 1 and found[0] > 0 for found in lifted), lifted
    om = front.object_map()
    assert len(om) == 1 and len(front.mapper) == 1
    off, in_gate = box_errors(om)
    assert in_gate, f"width {om.widths[0]:.3f}, height {om.heights[0]:.3f}"
    assert off < 0.1
    assert om.widths[0] == pytest.approx(0.6, abs=0.05)
    assert om.descriptors is not None and om.descriptors.shape[0] == 1

    single, _ = map_box([0], MapperParams(nu=1))
    om1 = single.object_map()
    assert len(om1) == 1
    off1, in_gate1 = box_errors(om1)
    assert not in_gate1 and off1 > 0.2, f"one view: {off1:.3f} m off, width {om1.widths[0]}"
