"""Tests for tcaff_gtsam.mapping.lift: ground-truth masks of rendered objects lifted to
observations (the issue's acceptance: centroid, width and height against truths computed from
the scene alone), frames, background spill, empty masks and input checks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rgbd_scenes import (
    CAMERA,
    box_face_centre,
    camera_pose,
    cylinder_visible_centroid,
    touches_border,
)
from tcaff_gtsam.eval.sim.render import RgbdFrame, RgbdScene, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera
from tcaff_gtsam.mapping.lift import (
    LiftParams,
    MaskLifter,
    Observations,
    _footprint_widths,
    _grid_lines,
)

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se3_from_xyz_yaw, transform_points

NOISE = 0.0025  # metres at 1 m; sigma = NOISE z^2


@dataclass
class Setup:
    scene: RgbdScene
    T_world_camera: np.ndarray
    camera_xy: np.ndarray
    truth: np.ndarray  # (3,) visible-surface centroid, world frame
    width: float
    height: float


def one_object(rng: np.random.Generator, distance: float, cylinder: bool,
               box_turn: float = 0.0, walls: bool = False) -> Setup:
    """One object at `distance` metres (horizontal, camera to object centre) within 10 or 20 deg
    of the optical axis, fully in view and taller than the camera, so its top is hidden. Near
    objects are small and seen from a low camera. A box squarely faces the camera, turned by
    `box_turn` radians from that."""
    if distance < 1.5:
        width, height, cam_height, pitch = rng.uniform(0.15, 0.25), 0.35, 0.2, 0.0
        off_axis = math.radians(10)
    else:
        width, height, cam_height, pitch = (rng.uniform(0.3, 0.6), rng.uniform(0.8, 1.2), 0.6,
                                            5.0)
        off_axis = math.radians(20)
    x, y, yaw = rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)
    bearing = yaw + rng.uniform(-off_axis, off_axis)
    camera_xy = np.array([x, y])
    centre = camera_xy + distance * np.array([math.cos(bearing), math.sin(bearing)])
    # A box with yaw = bearing + pi has a face normal pointing at the camera.
    scene = RgbdScene([centre], [width], [height], [cylinder], [bearing + box_turn],
                      walls=room_walls(x - 6, y - 6, x + 6, y + 6) if walls else None)
    T = camera_pose(x, y, yaw, T_body_camera(cam_height, pitch))
    if cylinder:
        truth = cylinder_visible_centroid(centre, width / 2, height, camera_xy)
    else:
        truth = box_face_centre(centre, width, height, camera_xy)
    return Setup(scene, T, camera_xy, truth, width, height)


def lift_gt(setup: Setup, noise: float = 0.0, seed: int = 0,
            T_odom_world: np.ndarray | None = None, frame: RgbdFrame | None = None
            ) -> tuple[Observations, np.ndarray]:
    """The observation of the object's ground-truth mask in `frame` (default: rendered with
    depth noise `noise`), and the mask."""
    if frame is None:
        rng = np.random.default_rng(seed)
        frame = render(setup.scene, setup.T_world_camera, CAMERA, depth_noise=noise,
                       rng=rng if noise else None)
    gt = frame.instance == 1
    assert gt.sum() > 100 and not touches_border(gt), "the object must be fully in view"
    T = setup.T_world_camera if T_odom_world is None else T_odom_world @ setup.T_world_camera
    obs = MaskLifter(CAMERA, 1.0).lift(gt[None], frame.depth, T)
    return obs, gt


def check(obs: Observations, setup: Setup, tol_m: float, tol_rel: float) -> None:
    assert len(obs) == 1
    np.testing.assert_array_equal(obs.mask_indices, [0])
    err = np.linalg.norm(obs.centroids[0] - setup.truth)
    assert err <= tol_m, f"centroid {obs.centroids[0]} is {err:.3f} m from {setup.truth}"
    assert obs.widths[0] == pytest.approx(setup.width, rel=tol_rel)
    assert obs.heights[0] == pytest.approx(setup.height, rel=tol_rel)


RANGES = [0.5, 0.8, 1.2, 2.0, 3.0, 4.0]


@pytest.mark.parametrize("seed", range(2))
@pytest.mark.parametrize("cylinder", [False, True], ids=["box", "cylinder"])
@pytest.mark.parametrize("distance", RANGES)
def test_noise_free_observation_matches_the_truth(distance, cylinder, seed):
    setup = one_object(np.random.default_rng(seed), distance, cylinder)
    obs, _ = lift_gt(setup)
    check(obs, setup, 0.05, 0.15)
    assert obs.point_counts[0] >= LiftParams().min_points


@pytest.mark.parametrize("seed", range(2))
@pytest.mark.parametrize("cylinder", [False, True], ids=["box", "cylinder"])
@pytest.mark.parametrize("distance", RANGES)
def test_noisy_observation_matches_the_truth(distance, cylinder, seed):
    setup = one_object(np.random.default_rng(100 + seed), distance, cylinder)
    obs, _ = lift_gt(setup, NOISE, seed)
    check(obs, setup, 0.1, 0.25)


@settings(max_examples=20, deadline=None)
@given(st.floats(1.0, 4.0), st.floats(math.radians(30), math.radians(60)),
       st.integers(0, 2**32 - 1))
def test_turned_box_width_is_its_side(distance, turn, seed):
    """Two faces visible: the smallest-perimeter rectangle around the L-shaped footprint is the
    box itself, so the width is still the side length."""
    setup = one_object(np.random.default_rng(seed), distance, False, box_turn=turn)
    obs, _ = lift_gt(setup)
    assert len(obs) == 1
    assert obs.widths[0] == pytest.approx(setup.width, rel=0.15)
    assert obs.heights[0] == pytest.approx(setup.height, rel=0.15)
    # the centroid lies inside the box's footprint, on the camera's side of its centre
    centre = setup.scene.xy[0]
    offset = obs.centroids[0, :2] - centre
    assert np.linalg.norm(offset) <= setup.width / math.sqrt(2)
    assert offset @ (setup.camera_xy - centre) > 0


@settings(max_examples=15, deadline=None)
@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-1, 1), st.floats(-np.pi, np.pi),
       st.integers(0, 2**32 - 1), st.booleans())
def test_observation_is_in_the_odometry_frame(ox, oy, oz, oyaw, seed, cylinder):
    """Passing T_odom_camera = T_odom_world T_world_camera moves the centroid by T_odom_world
    and leaves the (gravity-aligned) sizes alone."""
    setup = one_object(np.random.default_rng(seed), 2.5, cylinder)
    T_odom_world = se3_from_xyz_yaw(ox, oy, oz, oyaw)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    in_world, _ = lift_gt(setup, frame=frame)
    in_odom, _ = lift_gt(setup, T_odom_world=T_odom_world, frame=frame)
    assert len(in_world) == len(in_odom) == 1
    # (the accuracy itself is checked above; here a wrong frame would be off by metres)
    expected = transform_points(T_odom_world, setup.truth[None])[0]
    assert np.linalg.norm(in_odom.centroids[0] - expected) <= 0.1
    # the voxel grid is aligned with the output frame, so results differ by about a voxel
    moved = transform_points(T_odom_world, in_world.centroids)[0]
    assert np.linalg.norm(in_odom.centroids[0] - moved) <= 0.03
    assert in_odom.widths[0] == pytest.approx(in_world.widths[0], rel=0.1)
    assert in_odom.heights[0] == pytest.approx(in_world.heights[0], rel=0.1)


def test_identity_and_inverse_frames():
    """Lifting in the camera's own frame (T = I) gives the truth expressed in the camera frame."""
    setup = one_object(np.random.default_rng(4), 2.0, True)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    obs = MaskLifter(CAMERA, 1.0).lift((frame.instance == 1)[None], frame.depth, np.eye(4))
    expected = transform_points(invert(setup.T_world_camera), setup.truth[None])[0]
    assert np.linalg.norm(obs.centroids[0] - expected) <= 0.1
    assert obs.centroids[0, 2] > 1.0  # in front of the camera (optical z forward)


@pytest.mark.parametrize("cylinder", [False, True])
def test_mask_spilling_onto_the_far_wall_keeps_the_object(cylinder):
    """A ground-truth mask OR-ed with a patch of the wall several metres behind: the wall points
    form a second cluster, and the largest cluster is the object."""
    setup = one_object(np.random.default_rng(7), 2.0, cylinder, walls=True)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    gt = frame.instance == 1
    rows, cols = np.flatnonzero(gt.any(axis=1)), np.flatnonzero(gt.any(axis=0))
    r = (rows[0] + rows[-1]) // 2
    # a 40 x 40 patch of far wall beside the object, at the object's mid height
    for c in (cols[0] - 60, cols[-1] + 60):
        patch = np.zeros_like(gt)
        patch[r - 20:r + 20, c - 20:c + 20] = True
        if np.all(frame.instance[patch] == 0) and np.all(frame.depth[patch] > 4.0):
            break
    else:
        raise AssertionError("no wall patch beside the object")
    mask = gt | patch
    obs = MaskLifter(CAMERA, 1.0).lift(mask[None], frame.depth, setup.T_world_camera)
    check(obs, setup, 0.05, 0.15)
    # without the clustering the wall would pull the centroid far away
    v, u = np.nonzero(mask)
    z = frame.depth[v, u]
    pts = np.linalg.solve(CAMERA.K, np.vstack([u, v, np.ones_like(u)])).T * z[:, None]
    naive = transform_points(setup.T_world_camera, pts).mean(axis=0)
    assert np.linalg.norm(naive - setup.truth) > 0.2


def test_empty_and_tiny_masks_give_no_observation():
    setup = one_object(np.random.default_rng(3), 2.0, False)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    gt = frame.instance == 1
    tiny = np.zeros_like(gt)
    v, u = np.nonzero(gt)
    tiny[v[:5], u[:5]] = True  # 5 pixels < min_points
    no_depth = np.zeros_like(gt)
    no_depth[0:40, 0:40] = True
    depth = frame.depth.copy()
    depth[no_depth] = 0.0  # a region without returns
    floor = (frame.instance == 0) & (frame.depth > 0)
    masks = np.stack([np.zeros_like(gt), gt, tiny, no_depth, floor & ~no_depth])
    # the floor is a flat level slab: room structure, dropped unless slabs are kept
    obs = MaskLifter(CAMERA, 1.0).lift(masks, depth, setup.T_world_camera)
    np.testing.assert_array_equal(obs.mask_indices, [1])
    keep_slabs = MaskLifter(CAMERA, 1.0, LiftParams(slab_extent=math.inf))
    obs = keep_slabs.lift(masks, depth, setup.T_world_camera)
    np.testing.assert_array_equal(obs.mask_indices, [1, 4])
    assert obs.widths[1] >= 0.5 and obs.heights[1] <= 0.05
    assert obs.mask_indices.dtype == np.int64 and obs.point_counts.dtype == np.int64
    assert obs.centroids.shape == (2, 3) and obs.widths.shape == obs.heights.shape == (2,)
    assert np.linalg.norm(obs.centroids[0] - setup.truth) <= 0.05
    assert abs(obs.centroids[1, 2]) < 0.02  # the floor mask lifts to the floor
    # no masks at all
    none = MaskLifter(CAMERA, 1.0).lift(np.zeros((0, *CAMERA.shape), bool), depth,
                                        setup.T_world_camera)
    assert len(none) == 0 and none.centroids.shape == (0, 3) and none.widths.shape == (0,)
    assert none.mask_indices.shape == (0,)


def test_depth_outside_the_range_is_ignored():
    setup = one_object(np.random.default_rng(3), 3.0, True)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    gt = frame.instance == 1
    lifter = MaskLifter(CAMERA, 1.0, LiftParams(depth_max=2.0))
    assert len(lifter.lift(gt[None], frame.depth, setup.T_world_camera)) == 0
    lifter = MaskLifter(CAMERA, 1.0, LiftParams(depth_min=4.0, depth_max=8.0))
    assert len(lifter.lift(gt[None], frame.depth, setup.T_world_camera)) == 0


def test_millimetre_depth_gives_the_same_observation():
    setup = one_object(np.random.default_rng(9), 2.0, True)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    gt = (frame.instance == 1)[None]
    metres = MaskLifter(CAMERA, 1.0).lift(gt, frame.depth, setup.T_world_camera)
    mm = np.round(frame.depth * 1000).astype(np.uint16)
    millis = MaskLifter(CAMERA, 1000.0).lift(gt, mm, setup.T_world_camera)
    np.testing.assert_allclose(millis.centroids, metres.centroids, atol=0.01)
    np.testing.assert_allclose(millis.widths, metres.widths, rtol=0.05)


def test_several_objects_at_once_keep_their_order():
    scene = RgbdScene([[3.0, 1.0], [4.0, -1.0], [2.5, -0.2]], [0.4, 0.5, 0.3], [1.0, 0.9, 0.8],
                      [True, False, True], [0.0, 0.0, 0.0])
    T = camera_pose(0.0, 0.0, 0.0)
    frame = render(scene, T, CAMERA)
    masks = np.stack([frame.instance == k for k in (3, 1, 2)])
    obs = MaskLifter(CAMERA, 1.0).lift(masks, frame.depth, T)
    np.testing.assert_array_equal(obs.mask_indices, [0, 1, 2])
    # each observation is near its own object's centre
    for i, k in enumerate((2, 0, 1)):
        assert np.linalg.norm(obs.centroids[i, :2] - scene.xy[k]) < scene.widths[k] / 2 + 0.02
        assert obs.widths[i] == pytest.approx(scene.widths[k], rel=0.15)


# ---------------------------------------------------------------------------------------------
# input checks

def small_frame():
    setup = one_object(np.random.default_rng(0), 2.0, True)
    frame = render(setup.scene, setup.T_world_camera, CAMERA)
    return setup, frame, (frame.instance == 1)[None]


@pytest.mark.parametrize("bad", [
    lambda m: m.astype(np.uint8),
    lambda m: m[0],
    lambda m: m[:, :-1],
    lambda m: m[:, :, :, None],
    lambda m: m.tolist(),
])
def test_bad_masks_raise(bad):
    setup, frame, masks = small_frame()
    with pytest.raises(DataError, match="masks"):
        MaskLifter(CAMERA, 1.0).lift(bad(masks), frame.depth, setup.T_world_camera)


def scaled(T):
    out = T.copy()
    out[:3, :3] *= 2.0
    return out


def sheared(T):
    out = T.copy()
    out[0, 1] += 0.1
    return out


def bottom(T):
    out = T.copy()
    out[3, 0] = 0.5
    return out


def with_nan(T):
    out = T.copy()
    out[1, 3] = np.nan
    return out


@pytest.mark.parametrize("bad", [scaled, sheared, bottom, with_nan, lambda T: T[:3],
                                 lambda T: T[:3, :3], lambda T: "pose", lambda T: None,
                                 lambda T: -T])
def test_bad_pose_raises(bad):
    setup, frame, masks = small_frame()
    with pytest.raises(DataError, match="T_odom_camera"):
        MaskLifter(CAMERA, 1.0).lift(masks, frame.depth, bad(setup.T_world_camera))


def test_pose_as_nested_list_is_accepted():
    setup, frame, masks = small_frame()
    a = MaskLifter(CAMERA, 1.0).lift(masks, frame.depth, setup.T_world_camera)
    b = MaskLifter(CAMERA, 1.0).lift(masks, frame.depth, setup.T_world_camera.tolist())
    np.testing.assert_array_equal(a.centroids, b.centroids)


def test_measure_is_lift_on_depth_in_metres():
    """The front end converts and checks depth itself, then calls the public `measure`."""
    setup, frame, masks = small_frame()
    lifter = MaskLifter(CAMERA, 1000.0)
    millimetres = np.round(frame.depth * 1000.0).astype(np.uint16)
    lifted = lifter.lift(masks, millimetres, setup.T_world_camera)
    measured = lifter.measure(masks, millimetres.astype(np.float32) / np.float32(1000.0),
                              setup.T_world_camera)
    assert len(measured) == len(lifted) > 0
    for name in ("centroids", "widths", "heights", "point_counts", "mask_indices"):
        np.testing.assert_array_equal(getattr(measured, name), getattr(lifted, name))


@pytest.mark.parametrize(("args", "match"), [
    (lambda m, z, T: (m, z.astype(np.uint16), T), "z must be"),
    (lambda m, z, T: (m, z[:-1], T), "z must be"),
    (lambda m, z, T: (m, z.tolist(), T), "z must be"),
    (lambda m, z, T: (m[0], z, T), "masks"),
    (lambda m, z, T: (m, z, T[:3]), "T_odom_camera"),
])
def test_measure_checks_types_and_shapes(args, match):
    setup, frame, masks = small_frame()
    z = frame.depth.astype(np.float32)
    with pytest.raises(DataError, match=match):
        MaskLifter(CAMERA, 1.0).measure(*args(masks, z, setup.T_world_camera))


@pytest.mark.parametrize("depth, match", [
    (lambda d: d.astype(np.int32), "dtype"),
    (lambda d: d.astype(np.complex64), "dtype"),
    (lambda d: d[:-1], "shape"),
    (lambda d: d[..., None], "shape"),
    (lambda d: -d, "negative"),
    (lambda d: d.tolist(), "numpy"),
])
def test_bad_depth_raises(depth, match):
    setup, frame, masks = small_frame()
    with pytest.raises(DataError, match=match):
        MaskLifter(CAMERA, 1.0).lift(masks, depth(frame.depth), setup.T_world_camera)


@pytest.mark.parametrize("kwargs", [
    {"voxel_size": 0.0}, {"voxel_size": -0.02}, {"voxel_size": math.nan}, {"outlier_std": 0},
    {"cluster_eps": math.inf}, {"depth_max": 0.0}, {"max_points": 0}, {"max_points": 2.5},
    {"outlier_neighbors": True}, {"cluster_min_points": 0}, {"min_points": -3},
    {"depth_min": -0.1}, {"depth_min": 9.0},
])
def test_bad_lift_params_raise_config_error(kwargs):
    with pytest.raises(ConfigError):
        LiftParams(**kwargs)


@pytest.mark.parametrize("field", [f for f in vars(LiftParams())])
@pytest.mark.parametrize("value", [None, "1", [1.0], True, math.nan], ids=repr)
def test_lift_params_refuse_junk_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=f"^LiftParams.{field} = "):
        LiftParams(**{field: value})


def test_height_does_not_depend_on_where_the_grid_falls():
    """A mask sampled on a coarse grid keeps its lowest and highest rows (its outline), so
    shifting the mask by a pixel does not change the height."""
    z = np.full(CAMERA.shape, 2.0, np.float32)
    heights = []
    for shift in range(4):
        mask = np.zeros(CAMERA.shape, bool)
        mask[150 + shift:250 + shift, 200:300] = True
        obs = MaskLifter(CAMERA, 1.0).lift(mask[None], z, T_body_camera(0.0))  # level camera
        heights.append(obs.heights[0])
    truth = 100 * 2.0 / CAMERA.fy  # 100 rows of a wall 2 m ahead
    assert np.ptp(heights) < 0.01
    assert np.allclose(heights, truth, rtol=0.05)


@given(st.integers(0, 400), st.integers(1, 200), st.floats(1.0, 9.0))
def test_grid_lines_are_anchored_and_about_step_apart(start, length, step):
    lines = _grid_lines(start, start + length, step) + start
    assert np.all((lines >= start) & (lines < start + length))
    # the same lines as the whole image's grid, cut to the range
    whole = _grid_lines(0, start + length, step)
    np.testing.assert_array_equal(lines, whole[whole >= start])
    gaps = np.diff(whole)
    assert np.all((gaps >= math.floor(step)) & (gaps <= math.ceil(step)))
    assert whole[0] == 0


@given(st.lists(st.tuples(st.floats(0.05, 3.0), st.floats(0.05, 3.0), st.floats(-np.pi, np.pi),
                          st.floats(-50, 50), st.floats(-50, 50)), min_size=1, max_size=5),
       st.integers(0, 2**31))
def test_footprint_widths_are_the_longer_side_of_each_rectangle(rects, seed):
    """Points filling turned rectangles, several clouds at once: each width is the longer
    side, whatever the turn."""
    rng = np.random.default_rng(seed)
    clouds = []
    for a, b, turn, x, y in rects:
        corners = np.array([[0, 0], [a, 0], [a, b], [0, b]]) - [a / 2, b / 2]
        inner = rng.uniform(-0.5, 0.5, (30, 2)) * [a, b]
        R = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        clouds.append(np.vstack([corners, inner]) @ R.T + [x, y])
    ends = np.cumsum([c.shape[0] for c in clouds])
    widths = _footprint_widths(np.vstack(clouds), ends - 34, ends)
    # the hull is computed in float32, about 1e-5 m at 50 m
    np.testing.assert_allclose(widths, [max(a, b) for a, b, *_ in rects], atol=1e-4)


def test_masks_lifted_together_match_each_lifted_alone():
    """The clouds of all masks are cleaned together; no mask may see another's points."""
    scene = RgbdScene([[2.5, 0.4], [2.6, -0.1], [4.0, -1.0], [2.0, -0.6]], [0.4, 0.5, 0.6, 0.3],
                      [1.0, 0.9, 0.7, 0.8], [True, False, False, True], [0.0, 0.3, 0.0, 0.0])
    T = camera_pose(0.0, 0.0, 0.0)
    frame = render(scene, T, CAMERA, depth_noise=NOISE, rng=np.random.default_rng(3))
    masks = np.stack([frame.instance == k for k in (1, 2, 3, 4)])
    assert all(m.sum() > 400 for m in masks)
    lifter = MaskLifter(CAMERA, 1.0)
    together = lifter.lift(masks, frame.depth, T)
    np.testing.assert_array_equal(together.mask_indices, [0, 1, 2, 3])
    for i in range(4):
        alone = lifter.lift(masks[i:i + 1], frame.depth, T)
        # the voxel grid's corner follows the lowest point of the batch: at most a voxel apart
        np.testing.assert_allclose(together.centroids[i], alone.centroids[0], atol=0.005)
        assert together.widths[i] == pytest.approx(alone.widths[0], abs=0.02)
        assert together.heights[i] == pytest.approx(alone.heights[0], abs=0.02)
        assert together.point_counts[i] == pytest.approx(alone.point_counts[0], rel=0.1)


def test_depth_max_beyond_what_a_wide_camera_can_clean_is_a_config_error():
    """The clouds are cleaned 1000 m apart; a 178 deg camera sees points 20 m deep more than
    500 m to the side, which would mix the clouds up."""
    wide = PinholeCamera.from_fov(320, 240, 178.0)
    MaskLifter(wide, 1.0)  # the default depth_max of 8 m is fine
    with pytest.raises(ConfigError, match=r"^LiftParams\.depth_max = 20\.0: .* must stay "
                                          r"under 500 m"):
        MaskLifter(wide, 1.0, LiftParams(depth_max=20.0))


def test_a_piece_of_wall_is_dropped_as_a_vertical_slab():
    """A wide, flat, upright patch of wall (3.6 x 0.9 m, 3 m ahead) is room structure; an
    object's face of the same depth but narrower than `wall_extent` is not."""
    scene = RgbdScene([[0.5, 0.5]], [0.2], [0.2], [False], [0.0], walls=room_walls(0, 0, 10, 8))
    T = camera_pose(7.0, 4.0, 0.0, T_body_camera(1.0))
    frame = render(scene, T, CAMERA)
    wall = np.zeros(CAMERA.shape, dtype=bool)
    wall[190:290, 120:520] = True  # straight ahead, all on the wall x = 10
    narrow = np.zeros_like(wall)
    narrow[190:290, 260:380] = True  # 1.1 m of the same wall
    assert np.all(frame.depth[wall] > 2.9)
    masks = np.stack([wall, narrow])
    obs = MaskLifter(CAMERA, 1.0).lift(masks, frame.depth, T)
    np.testing.assert_array_equal(obs.mask_indices, [1])
    keep = MaskLifter(CAMERA, 1.0, LiftParams(wall_extent=math.inf)).lift(masks, frame.depth, T)
    np.testing.assert_array_equal(keep.mask_indices, [0, 1])
    assert keep.widths[0] >= 1.5


def test_a_wide_face_in_front_of_the_wall_is_kept_as_an_object():
    """A sideboard's front (1.8 x 0.9 m, 0.5 m before the wall, 2.5 m ahead of a level
    camera) is as wide and as flat as a piece of wall, but it stands in front of the wall on
    both sides: it is kept, with its width; a wider patch of the wall above it is dropped, and
    so is the front itself when the wall around it is brought level with it (no step)."""
    scene = RgbdScene([[10.4, 4.0]], [1.8], [0.9], [False], [0.0],
                      walls=room_walls(0, 0, 10, 8))
    T = camera_pose(7.0, 4.0, 0.0, T_body_camera(1.0))
    frame = render(scene, T, CAMERA)
    face = frame.instance == 1
    top = np.flatnonzero(face.any(axis=1))[0]
    wall = np.zeros_like(face)
    wall[top - 60:top - 10, 60:580] = True
    assert np.all(frame.instance[wall] == 0)
    obs = MaskLifter(CAMERA, 1.0).lift(np.stack([face, wall]), frame.depth, T)
    np.testing.assert_array_equal(obs.mask_indices, [0])
    assert abs(obs.widths[0] - 1.8) < 0.1
    flush = np.minimum(frame.depth, 2.5)
    assert len(MaskLifter(CAMERA, 1.0).lift(face[None], flush, T)) == 0
