"""Tests for tcaff_gtsam.eval.sim.render: ray-cast depth against analytic distances, instance
ids, the floor and walls, depth noise and input checks."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rgbd_scenes import camera_pose
from tcaff_gtsam.eval.sim.render import RgbdFrame, RgbdScene, cast_threads, render
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se3_from_xyz_yaw

FEW = settings(max_examples=25, deadline=None)

# odd sizes: the principal point is a pixel centre, so the centre pixel looks straight ahead
CAM = PinholeCamera.from_fov(161, 121, 80)


def world_points(frame: RgbdFrame, T_world_camera: np.ndarray, camera: PinholeCamera,
                 where: np.ndarray) -> np.ndarray:
    """(n, 3) world points seen at the pixels `where` (independent back-projection through K)."""
    v, u = np.nonzero(where)
    z = frame.depth[v, u].astype(float)
    rays = np.linalg.solve(camera.K, np.vstack([u, v, np.ones_like(u)]).astype(float)).T
    pts = rays * z[:, None]
    return pts @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]


@FEW
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-math.pi, math.pi), st.floats(1.0, 6.0),
       st.floats(0.3, 1.5), st.floats(0.2, 1.2), st.floats(-0.3, 0.3))
def test_depth_of_a_box_face_straight_ahead(x, y, yaw, distance, width, cam_height, forward):
    """A box squarely facing the camera, taller than the camera: every pixel showing it has
    depth (distance to its centre - half its side - the camera's forward offset)."""
    ahead = np.array([math.cos(yaw), math.sin(yaw)])
    centre = np.array([x, y]) + (forward + distance + width / 2) * ahead
    scene = RgbdScene([centre], [width], [cam_height + 1.0], yaws=[yaw])
    T = se3_from_xyz_yaw(x, y, 0.0, yaw) @ T_body_camera(cam_height, 0.0, forward)
    frame = render(scene, T, CAM)
    face = frame.instance == 1
    expected = distance
    assert face[60, 80], "the centre pixel sees the box"
    assert frame.depth[60, 80] == pytest.approx(expected, abs=1e-3)
    # fronto-parallel: the whole face is at that depth (no side face is visible)
    np.testing.assert_allclose(frame.depth[face], expected, atol=1e-3)


@FEW
@given(st.floats(-20.0, 10.0), st.floats(2.0, 6.0), st.floats(1.2, 2.0))
def test_depth_along_a_pitched_optical_axis(pitch_deg, distance, cam_height):
    """The centre pixel of a pitched camera meets a wall at distance d at depth d / cos(pitch)
    (depth is along the optical axis, which is the ray itself there)."""
    scene = RgbdScene(np.zeros((0, 2)), [], [], walls=[[[distance, -20.0], [distance, 20.0]]],
                      wall_height=10.0, floor=False)
    T = camera_pose(0.0, 0.0, 0.0, T_body_camera(cam_height, pitch_deg))
    frame = render(scene, T, CAM)
    wall_face = distance - 0.05  # walls are 0.1 m thick, centred on their segment
    assert frame.depth[60, 80] == pytest.approx(wall_face / math.cos(math.radians(pitch_deg)),
                                                abs=1e-3)
    # every pixel's point lies on the wall's face
    pts = world_points(frame, T, CAM, frame.depth > 0)
    np.testing.assert_allclose(pts[:, 0], wall_face, atol=1e-3)


def test_cylinder_depth_and_silhouette():
    """An upright cylinder straight ahead: the centre pixel is at d - r; the visible angular
    half-width is asin(r / d)."""
    d, r = 3.0, 0.4
    scene = RgbdScene([[d, 0.0]], [2 * r], [2.0], cylinders=[True])
    T = camera_pose(0.0, 0.0, 0.0, T_body_camera(1.0, 0.0))
    frame = render(scene, T, CAM)
    assert frame.depth[60, 80] == pytest.approx(d - r, abs=2e-3)  # 48-gon: tiny facet error
    cols = np.flatnonzero(frame.instance[60] == 1)
    half = math.atan((cols[-1] + 0.5 - CAM.cx) / CAM.fx)
    assert half == pytest.approx(math.asin(r / d), abs=1.5 / CAM.fx)
    # every cylinder pixel's point lies on the side surface
    pts = world_points(frame, T, CAM, frame.instance == 1)
    radial = np.hypot(pts[:, 0] - d, pts[:, 1])
    assert np.all(radial <= r + 1e-3) and np.all(radial >= r * math.cos(math.pi / 48) - 1e-3)


def room_scene() -> RgbdScene:
    """A 6 x 4 m room, a box on the left and a cylinder on the right of a robot at (1, 2)
    looking along +x (body y is left)."""
    return RgbdScene([[4.0, 2.8], [4.5, 1.0]], [0.6, 0.5], [0.9, 1.2], cylinders=[False, True],
                     walls=room_walls(0.0, 0.0, 6.0, 4.0))


def test_instance_ids_are_the_right_objects():
    scene = room_scene()
    T = camera_pose(1.0, 2.0, 0.0, T_body_camera(0.6, 5.0))
    cam = PinholeCamera.from_fov(320, 240, 87)
    frame = render(scene, T, cam)
    assert frame.instance.dtype == np.int32 and frame.instance.shape == cam.shape
    assert set(np.unique(frame.instance)) == {0, 1, 2}
    # object 0 is left (+y) of the robot, so in the left of the image; object 1 in the right
    cols = np.arange(cam.width)[None].repeat(cam.height, 0)
    assert cols[frame.instance == 1].max() < cam.cx < cols[frame.instance == 2].min()
    # every pixel of instance k + 1 sees a point of object k
    box = world_points(frame, T, cam, frame.instance == 1)
    assert np.all(np.abs(box[:, :2] - [4.0, 2.8]) <= 0.3 + 1e-3)
    assert np.all((box[:, 2] >= -1e-3) & (box[:, 2] <= 0.9 + 1e-3))
    cyl = world_points(frame, T, cam, frame.instance == 2)
    assert np.all(np.hypot(cyl[:, 0] - 4.5, cyl[:, 1] - 1.0) <= 0.25 + 1e-3)
    assert np.all((cyl[:, 2] >= -1e-3) & (cyl[:, 2] <= 1.2 + 1e-3))


def test_turning_around_swaps_left_and_right():
    scene = RgbdScene([[0.0, 1.0], [0.0, -1.0]], [0.4, 0.4], [1.0, 1.0])
    cam = PinholeCamera.from_fov(320, 240, 100)
    cols = np.arange(cam.width)[None].repeat(cam.height, 0)
    # standing at (-2, 0) looking along +x: object 0 (y = +1) is on the left
    f = render(scene, camera_pose(-2.0, 0.0, 0.0, T_body_camera(0.5)), cam)
    assert cols[f.instance == 1].mean() < cam.cx < cols[f.instance == 2].mean()
    # standing at (2, 0) looking along -x: object 0 is on the right
    f = render(scene, camera_pose(2.0, 0.0, math.pi, T_body_camera(0.5)), cam)
    assert cols[f.instance == 2].mean() < cam.cx < cols[f.instance == 1].mean()


def test_floor_and_walls_are_instance_zero():
    scene = room_scene()
    T = camera_pose(1.0, 2.0, 0.3, T_body_camera(0.6, 5.0))
    cam = PinholeCamera.from_fov(320, 240, 87)
    frame = render(scene, T, cam)
    background = frame.instance == 0
    pts = world_points(frame, T, cam, background & (frame.depth > 0))
    on_floor = np.abs(pts[:, 2]) < 1e-3
    on_wall = (np.minimum.reduce([np.abs(pts[:, 0]), np.abs(pts[:, 0] - 6.0),
                                  np.abs(pts[:, 1]), np.abs(pts[:, 1] - 4.0)]) < 0.05 + 1e-3)
    assert on_floor.sum() > 1000 and on_wall.sum() > 1000
    assert np.all(on_floor | on_wall)


def test_empty_room_and_empty_space():
    cam = PinholeCamera.from_fov(64, 48, 90)
    # no objects, no walls, no floor: nothing is hit
    nothing = RgbdScene(np.zeros((0, 2)), [], [], floor=False)
    f = render(nothing, camera_pose(0.0, 0.0, 0.0), cam)
    assert np.all(f.depth == 0) and np.all(f.instance == 0) and np.all(f.rgb == 0)
    # floor and walls only: everything is instance 0, and there is depth everywhere
    room = RgbdScene(np.zeros((0, 2)), [], [], walls=room_walls(-3, -3, 3, 3), wall_height=5.0)
    f = render(room, camera_pose(0.0, 0.0, 1.0), cam)
    assert np.all(f.instance == 0) and np.all(f.depth > 0)
    # looking above the walls: empty space is depth 0, instance 0, black
    f = render(room, camera_pose(0.0, 0.0, 0.0, T_body_camera(1.0, -60.0)), cam)
    sky = f.depth == 0
    assert sky.sum() > 100 and np.all(f.instance[sky] == 0) and np.all(f.rgb[sky] == 0)


def test_depth_max_drops_far_surfaces():
    scene = RgbdScene(np.zeros((0, 2)), [], [], walls=[[[5.0, -20.0], [5.0, 20.0]]],
                      floor=False)
    T = camera_pose(0.0, 0.0, 0.0, T_body_camera(1.0))
    assert render(scene, T, CAM).depth[60, 80] == pytest.approx(4.95, abs=1e-3)
    assert np.all(render(scene, T, CAM, depth_max=4.0).depth == 0)


def test_rgb_is_uint8_and_objects_differ_from_the_floor():
    scene = room_scene()
    cam = PinholeCamera.from_fov(160, 120, 87)
    frame = render(scene, camera_pose(1.0, 2.0, 0.0), cam)
    assert frame.rgb.dtype == np.uint8 and frame.rgb.shape == (*cam.shape, 3)
    assert frame.depth.dtype == np.float32 and frame.depth.shape == cam.shape
    assert not np.array_equal(frame.rgb[frame.instance == 1].mean(0),
                              frame.rgb[frame.instance == 0].mean(0))


def test_noise_is_zero_mean_and_grows_with_the_square_of_range():
    cam = PinholeCamera.from_fov(320, 240, 87)
    scene = RgbdScene(np.zeros((0, 2)), [], [], walls=room_walls(-1.0, -6.0, 9.0, 6.0))
    T = camera_pose(0.0, 0.0, 0.0, T_body_camera(0.8, 8.0))
    clean = render(scene, T, cam)
    sigma1 = 0.01
    noisy = render(scene, T, cam, depth_noise=sigma1, rng=np.random.default_rng(3))
    again = render(scene, T, cam, depth_noise=sigma1, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(noisy.depth, again.depth)  # seeded: reproducible
    np.testing.assert_array_equal(noisy.instance, clean.instance)  # noise only on depth
    z = clean.depth.astype(float)
    err = noisy.depth.astype(float) - z
    stds = []
    for lo, hi in ((0.5, 2.0), (2.0, 4.0), (4.0, 6.0), (6.0, 9.0)):
        sel = (z >= lo) & (z < hi)
        assert sel.sum() > 2000, (lo, hi)
        e = err[sel]
        zz = z[sel]
        expected_sigma = sigma1 * np.sqrt(np.mean(zz**4))
        # zero mean: within 4 standard errors
        assert abs(e.mean()) < 4 * expected_sigma / math.sqrt(e.size), (lo, hi)
        # normalised by z^2 the noise has std sigma1 everywhere
        assert np.std(e / zz**2) == pytest.approx(sigma1, rel=0.06), (lo, hi)
        stds.append(e.std())
    assert all(a < b for a, b in itertools.pairwise(stds))
    assert np.all(noisy.depth[z == 0] == 0)  # no return stays no return


def test_one_thread_casts_the_same_frame():
    """A process given one core (a study's pool worker) renders every pixel as on all cores,
    again and again with the camera's rays kept."""
    scene, cam = room_scene(), PinholeCamera.from_fov(160, 120, 87)
    T = camera_pose(1.0, 2.0, 0.3)
    every_core = render(scene, T, cam, depth_noise=0.01, rng=np.random.default_rng(1))
    try:
        cast_threads(1)
        for _ in range(2):
            one = render(scene, T, cam, depth_noise=0.01, rng=np.random.default_rng(1))
            for name in ("rgb", "depth", "instance"):
                np.testing.assert_array_equal(getattr(one, name), getattr(every_core, name))
    finally:
        cast_threads(0)
    for bad in (-1, 1.5, None, True):
        with pytest.raises(DataError, match=r"cast_threads: count = .*: must be an int in "
                                            r"\[0, 1024\] \(MAX_THREADS\)"):
            cast_threads(bad)


def test_noise_free_by_default():
    scene = room_scene()
    T = camera_pose(1.0, 2.0, 0.0)
    a = render(scene, T, CAM)
    b = render(scene, T, CAM, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(a.depth, b.depth)


@pytest.mark.parametrize("kwargs", [{"depth_noise": -0.01}, {"depth_noise": 0.01},
                                    {"depth_noise": -0.01, "rng": np.random.default_rng(0)}])
def test_bad_noise_raises(kwargs):
    with pytest.raises(DataError, match="depth_noise"):
        render(room_scene(), camera_pose(1.0, 2.0, 0.0), CAM, **kwargs)


@pytest.mark.parametrize("T", [np.eye(3), np.full((4, 4), np.nan), np.zeros((4, 4, 1))])
def test_bad_pose_raises(T):
    with pytest.raises(DataError, match="T_world_camera"):
        render(room_scene(), T, CAM)


@pytest.mark.parametrize("kwargs, match", [
    ({"widths": [0.5]}, "widths"),
    ({"heights": [1.0, 1.0, 1.0]}, "heights"),
    ({"cylinders": [True]}, "cylinders"),
    ({"yaws": [0.0, 0.0, 0.0]}, "yaws"),
    ({"widths": [0.5, -0.1]}, "sizes"),
    ({"heights": [0.0, 1.0]}, "sizes"),
    ({"xy": [[0.0, np.nan], [1.0, 1.0]]}, "finite"),
    ({"yaws": [0.0, np.inf]}, "finite"),
    ({"walls": [[[0.0, 0.0], [np.nan, 1.0]]]}, "finite"),
    ({"ceiling": True, "wall_height": np.nan}, "wall_height"),
    ({"ceiling": True, "wall_height": 0.0}, "wall_height"),
])
def test_bad_scene_raises(kwargs, match):
    args = {"xy": [[0.0, 0.0], [2.0, 0.0]], "widths": [0.5, 0.5], "heights": [1.0, 1.0]}
    with pytest.raises(DataError, match=match):
        RgbdScene(**{**args, **kwargs})


def test_scene_len():
    assert len(room_scene()) == 2
    assert len(RgbdScene(np.zeros((0, 2)), [], [])) == 0


def test_ceiling_is_level_at_the_wall_height_and_instance_zero():
    walls = room_walls(0.0, 0.0, 6.0, 4.0)
    scene = RgbdScene([[4.0, 2.8]], [0.6], [0.9], walls=walls, wall_height=2.4, ceiling=True)
    T = camera_pose(1.0, 2.0, 0.3, T_body_camera(1.0, -30.0))
    cam = PinholeCamera.from_fov(320, 240, 87)
    frame = render(scene, T, cam)
    pts = world_points(frame, T, cam, (frame.instance == 0) & (frame.depth > 0))
    up = pts[:, 2] > 1.0
    on_wall = (np.minimum.reduce([np.abs(pts[:, 0]), np.abs(pts[:, 0] - 6.0),
                                  np.abs(pts[:, 1]), np.abs(pts[:, 1] - 4.0)]) < 0.05 + 1e-3)
    on_ceiling = up & ~on_wall
    assert on_ceiling.sum() > 5000
    np.testing.assert_allclose(pts[on_ceiling, 2], 2.4, atol=1e-3)
    # without the ceiling the same rays leave the room over the walls
    open_top = render(RgbdScene([[4.0, 2.8]], [0.6], [0.9], walls=walls, wall_height=2.4), T, cam)
    assert np.all(open_top.depth[(frame.instance == 0) & (frame.depth > 0)][on_ceiling] == 0)


def test_no_ceiling_and_no_band_by_default():
    scene = room_scene()
    T = camera_pose(1.0, 2.0, 0.0, T_body_camera(1.0, -40.0))
    a = render(scene, T, CAM)
    b = render(RgbdScene(scene.xy, scene.widths, scene.heights, scene.cylinders,
                         walls=scene.walls, ceiling=False), T, CAM, invalid_border=0)
    assert (a.depth == 0).sum() > 100  # open space above the walls
    for x, y in ((a.depth, b.depth), (a.instance, b.instance), (a.rgb, b.rgb)):
        np.testing.assert_array_equal(x, y)


@FEW
@given(st.integers(0, 30), st.integers(0, 30), st.integers(0, 40), st.integers(0, 40),
       st.booleans())
def test_invalid_border_blanks_exactly_the_band(top, bottom, left, right, one_width):
    widths = top if one_width else (top, bottom, left, right)
    if one_width:
        bottom = left = right = top
    scene = room_scene()
    T = camera_pose(1.0, 2.0, 0.2)
    full = render(scene, T, CAM)
    cut = render(scene, T, CAM, invalid_border=widths)
    H, W = CAM.shape
    band = np.zeros((H, W), bool)
    band[:top], band[H - bottom:], band[:, :left], band[:, W - right:] = True, True, True, True
    assert np.all(cut.depth[band] == 0)
    np.testing.assert_array_equal(cut.depth[~band], full.depth[~band])
    # the colour camera still sees what is there
    np.testing.assert_array_equal(cut.rgb, full.rgb)
    np.testing.assert_array_equal(cut.instance, full.instance)


@pytest.mark.parametrize("invalid_border", [-1, 1.5, True, "4", (1, 2, 3), (1, 2, 3, -4),
                                            [[1, 2], [3, 4]], None, np.nan])
def test_bad_invalid_border_raises(invalid_border):
    with pytest.raises(DataError, match=r"render: invalid_border = .* must be an int >= 0"):
        render(room_scene(), camera_pose(1.0, 2.0, 0.0), CAM, invalid_border=invalid_border)
