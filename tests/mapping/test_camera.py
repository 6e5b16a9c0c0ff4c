"""Tests for tcaff_gtsam.mapping.camera: pinhole rays and projection, the body-optical frame
convention, depth images in metres and depth registration between cameras."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.mapping.camera import (
    ORTHONORMAL_TOL,
    R_BODY_OPTICAL,
    PinholeCamera,
    T_body_camera,
    depth_in_metres,
    register_depth,
    rigid_transform,
)

from tcaff_gtsam.errors import ConfigError, DataError

PROPS = settings(max_examples=60, deadline=None)
FEW = settings(max_examples=15, deadline=None)


@st.composite
def cameras(draw, max_size: int = 64) -> PinholeCamera:
    w = draw(st.integers(8, max_size))
    h = draw(st.integers(8, max_size))
    return PinholeCamera(w, h, draw(st.floats(20.0, 200.0)), draw(st.floats(20.0, 200.0)),
                         draw(st.floats(0.0, w - 1.0)), draw(st.floats(0.0, h - 1.0)))


def project(camera: PinholeCamera, points: np.ndarray) -> np.ndarray:
    """(n, 2) pixel coordinates (u, v) of (n, 3) optical-frame points, through K."""
    uvw = points @ camera.K.T
    return uvw[:, :2] / uvw[:, 2:]


# ---------------------------------------------------------------------------------------------
# PinholeCamera


@PROPS
@given(cameras(), st.data(), st.floats(0.1, 20.0))
def test_rays_times_depth_reproduce_the_point_seen_at_a_pixel(camera, data, z):
    x_over_z, y_over_z = camera.rays()
    assert x_over_z.shape == camera.shape and y_over_z.shape == camera.shape
    u = data.draw(st.integers(0, camera.width - 1))
    v = data.draw(st.integers(0, camera.height - 1))
    point = np.array([x_over_z[v, u] * z, y_over_z[v, u] * z, z])
    # the point lies on the pixel's ray: it projects back onto (u, v) ...
    np.testing.assert_allclose(project(camera, point[None])[0], [u, v], atol=1e-9)
    # ... and the ray is K^-1 (u, v, 1)
    np.testing.assert_allclose(np.linalg.solve(camera.K, [u, v, 1.0]) * z, point, atol=1e-9)


@PROPS
@given(cameras(), st.floats(0.1, 20.0), st.floats(-0.45, 0.45), st.floats(-0.45, 0.45),
       st.data())
def test_round_trip_point_pixel_point(camera, z, du, dv, data):
    """A point seen at a pixel centre (plus a sub-pixel offset) back-projects to itself."""
    u = data.draw(st.integers(0, camera.width - 1))
    v = data.draw(st.integers(0, camera.height - 1))
    point = np.linalg.solve(camera.K, [u + du, v + dv, 1.0]) * z
    uv = project(camera, point[None])[0]
    np.testing.assert_allclose(uv, [u + du, v + dv], atol=1e-9)
    assert np.array_equal(np.rint(uv).astype(int), [u, v])
    x_over_z, y_over_z = camera.rays()
    # the pixel's own ray misses the point by less than half a pixel
    assert abs(x_over_z[v, u] * z - point[0]) <= 0.5 * z / camera.fx + 1e-12
    assert abs(y_over_z[v, u] * z - point[1]) <= 0.5 * z / camera.fy + 1e-12


def test_K_and_shape():
    cam = PinholeCamera(640, 480, 600.0, 610.0, 319.5, 239.0)
    np.testing.assert_array_equal(cam.K, [[600.0, 0, 319.5], [0, 610.0, 239.0], [0, 0, 1]])
    assert cam.shape == (480, 640)


@pytest.mark.parametrize("K", [
    [[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]],
    [500.0, 0, 320, 0, 510.0, 240, 0, 0, 1],
    np.array([[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]]),
])
def test_from_K(K):
    cam = PinholeCamera.from_K(K, 640, 480)
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 500.0, 510.0,
                                                                       320.0, 240.0)
    assert isinstance(cam.width, int) and isinstance(cam.fx, float)
    np.testing.assert_array_equal(cam.K, np.reshape(K, (3, 3)))


@pytest.mark.parametrize("K", [np.eye(2), [1.0] * 8, [[500.0, 0, np.nan], [0, 500, 240], [0, 0, 1]],
                               [[500.0, 0, 320], [0, np.inf, 240], [0, 0, 1]]])
def test_from_K_rejects_bad_matrices(K):
    with pytest.raises(DataError, match="K"):
        PinholeCamera.from_K(K, 640, 480)


@PROPS
@given(st.integers(2, 2000), st.integers(2, 2000), st.floats(10.0, 170.0))
def test_from_fov(width, height, hfov):
    # square pixels: a tall image at a wide hfov has rays near 90 deg at its top and bottom
    vertical = math.degrees(math.atan(height / width * math.tan(math.radians(hfov / 2))))
    if vertical > 89.0 + 1e-6:
        with pytest.raises(ConfigError, match=r"PinholeCamera\.fy = .*89\.0 deg"):
            PinholeCamera.from_fov(width, height, hfov)
        return
    cam = PinholeCamera.from_fov(width, height, hfov)
    assert cam.fx == cam.fy
    assert cam.cx == (width - 1) / 2 and cam.cy == (height - 1) / 2
    # the outer edges of the first and last pixel columns are hfov apart
    x_over_z, _ = cam.rays()
    left = x_over_z[0, 0] - 0.5 / cam.fx
    right = x_over_z[0, -1] + 0.5 / cam.fx
    assert math.degrees(math.atan(right) - math.atan(left)) == pytest.approx(hfov, rel=1e-9)
    assert right == pytest.approx(-left, rel=1e-9)


def test_from_fov_known_value():
    cam = PinholeCamera.from_fov(640, 480, 90.0)
    assert cam.fx == pytest.approx(320.0)
    assert (cam.cx, cam.cy) == (319.5, 239.5)


@pytest.mark.parametrize("field, value", [
    ("width", 0), ("width", -640), ("width", 640.0), ("width", True), ("height", 0),
    ("height", "480"), ("fx", 0.0), ("fx", -500.0), ("fy", 0), ("fy", -1.0),
    ("fx", math.nan), ("fy", math.inf), ("cx", math.nan), ("cy", -math.inf), ("cx", None),
    ("cy", "239.5"), ("fx", True),
])
def test_bad_camera_values_raise_config_error(field, value):
    good = {"width": 640, "height": 480, "fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5}
    with pytest.raises(ConfigError, match=field):
        PinholeCamera(**{**good, field: value})


def test_numpy_numbers_are_accepted():
    cam = PinholeCamera(np.int64(64), np.int32(48), np.float32(50.0), np.float64(50.0), 0, 0)
    assert cam.shape == (48, 64)


GOOD = {"width": 640, "height": 480, "fx": 500.0, "fy": 500.0, "cx": 319.5, "cy": 239.5}


@pytest.mark.parametrize(("field", "value", "rule"), [
    ("fx", 1e-300, "the rays through the image reach 90 deg from the optical axis"),
    ("fy", 1e-3, "reach 89.9"),
    ("fx", 2.0, "reach 89.6"),
    ("fx", 1e300, "gives a field of view of"),
    ("fy", 1e8, "gives a field of view of"),
    ("cx", 1e300, "reach 90 deg"),
    ("cy", -1e6, "reach 89.9"),
    ("cx", 10**400, "must be a finite number of pixels"),
])
def test_intrinsics_out_of_proportion_with_the_image_are_config_errors(field, value, rule):
    """fx = 1e-300 used to be accepted; the front end then failed with an IndexError."""
    with pytest.raises(ConfigError, match=rf"^PinholeCamera\.{field} = .*{rule}"):
        PinholeCamera(**{**GOOD, field: value})


@PROPS
@given(st.integers(1, 4000), st.integers(1, 4000), st.floats(1e-6, 1e8), st.floats(1e-6, 1e8),
       st.floats(-1e5, 1e5), st.floats(-1e5, 1e5))
def test_every_accepted_camera_has_rays_within_89_degrees(width, height, fx, fy, cx, cy):
    try:
        cam = PinholeCamera(width, height, fx, fy, cx, cy)
    except ConfigError as exc:
        assert re.match(r"^PinholeCamera\.(fx|fy|cx|cy) = ", str(exc))
        return
    x_over_z, y_over_z = cam.rays()
    limit = math.tan(math.radians(89.0)) * (1 + 1e-9)
    assert np.abs(x_over_z).max() <= limit and np.abs(y_over_z).max() <= limit
    fov_x = math.degrees(math.atan((width - 0.5 - cx) / fx) - math.atan((-0.5 - cx) / fx))
    assert fov_x >= 0.01


@pytest.mark.parametrize("hfov", [0.0, 0.001, 178.5, 179.9, math.nan])
def test_from_fov_range(hfov):
    with pytest.raises(ConfigError, match=r"^PinholeCamera\.from_fov\.hfov_deg = "):
        PinholeCamera.from_fov(640, 480, hfov)


# ---------------------------------------------------------------------------------------------
# frames


def test_R_body_optical_is_a_rotation_with_the_documented_axes():
    R = R_BODY_OPTICAL
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_array_equal(R @ [0, 0, 1], [1, 0, 0])  # forward
    np.testing.assert_array_equal(R @ [1, 0, 0], [0, -1, 0])  # right
    np.testing.assert_array_equal(R @ [0, 1, 0], [0, 0, -1])  # down


@PROPS
@given(st.floats(-2.0, 3.0), st.floats(-89.0, 89.0), st.floats(-1.0, 1.0))
def test_T_body_camera_is_rigid_with_the_documented_axes(height, pitch_deg, forward):
    T = T_body_camera(height, pitch_deg, forward)
    assert T.shape == (4, 4)
    R = T[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    np.testing.assert_allclose(T[:3, 3], [forward, 0.0, height], atol=0)
    p = math.radians(pitch_deg)
    # optical z: body forward tilted down by the pitch
    np.testing.assert_allclose(R @ [0, 0, 1], [math.cos(p), 0, -math.sin(p)], atol=1e-12)
    # optical x (right): body -y, whatever the pitch
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    # optical y (down): body -z tilted by the pitch (the image top leans forward)
    np.testing.assert_allclose(R @ [0, 1, 0], [-math.sin(p), 0, -math.cos(p)], atol=1e-12)


def test_T_body_camera_sees_a_point_ahead_below_the_image_centre():
    """A camera looking 10 deg down sees a point straight ahead at its own height above the
    image centre (negative optical y), and one on the floor below it."""
    T = T_body_camera(1.0, 10.0)
    T_cb = np.linalg.inv(T)
    level = T_cb @ [3.0, 0.0, 1.0, 1.0]
    floor = T_cb @ [3.0, 0.0, 0.0, 1.0]
    assert level[1] < 0 < floor[1]
    assert level[2] > 0 and floor[2] > 0
    assert abs(level[0]) < 1e-12 and abs(floor[0]) < 1e-12
    assert math.degrees(math.atan2(-level[1], level[2])) == pytest.approx(10.0)


def test_T_body_camera_pitch_zero_default():
    np.testing.assert_array_equal(T_body_camera(0.5)[:3, :3], R_BODY_OPTICAL)


# ---------------------------------------------------------------------------------------------
# depth_in_metres


def test_uint16_millimetres_to_metres():
    raw = np.array([[0, 1, 1000], [1500, 65535, 250]], dtype=np.uint16)
    out = depth_in_metres(raw, 1000.0)
    assert out.dtype == np.float32 and out.shape == raw.shape
    np.testing.assert_allclose(out, raw.astype(np.float64) / 1000.0, rtol=1e-6)
    assert out[0, 0] == 0.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float_metres_pass_through(dtype):
    raw = np.array([[0.0, 0.5, 1.25], [3.0, 7.75, 0.0]], dtype=dtype)
    out = depth_in_metres(raw, 1.0)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, raw.astype(np.float32))
    # a different scale divides
    np.testing.assert_allclose(depth_in_metres(raw, 2.0), raw / 2.0, rtol=1e-6)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_non_finite_depth_is_no_return(dtype):
    raw = np.array([[np.nan, 1.0], [np.inf, -np.inf]], dtype=dtype)
    out = depth_in_metres(raw, 1.0)
    np.testing.assert_array_equal(out, [[0.0, 1.0], [0.0, 0.0]])
    assert np.isnan(raw[0, 0]), "the input must not be modified"


def test_shape_check():
    raw = np.ones((4, 5), dtype=np.float32)
    assert depth_in_metres(raw, 1.0, (4, 5)).shape == (4, 5)
    with pytest.raises(DataError, match=r"shape.*\(5, 4\)"):
        depth_in_metres(raw, 1.0, (5, 4))


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint8, np.int16, np.bool_,
                                   np.complex64, np.complex128, np.float16, np.uint32])
def test_wrong_dtype_raises(dtype):
    with pytest.raises(DataError, match=f"my_depth.*dtype {np.dtype(dtype)}"):
        depth_in_metres(np.ones((3, 4), dtype=dtype), 1.0, name="my_depth")


@pytest.mark.parametrize("shape", [(12,), (3, 4, 1), (1, 3, 4), ()])
def test_wrong_ndim_raises(shape):
    with pytest.raises(DataError, match="shape"):
        depth_in_metres(np.ones(shape, dtype=np.float32), 1.0)


@pytest.mark.parametrize("raw", [[[1.0, 2.0]], 3.0, None, "depth"])
def test_non_array_raises(raw):
    with pytest.raises(DataError, match="numpy array"):
        depth_in_metres(raw, 1.0)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_negative_depth_raises(dtype):
    raw = np.ones((3, 3), dtype=dtype)
    raw[1, 2] = -0.5
    with pytest.raises(DataError, match="negative"):
        depth_in_metres(raw, 1.0)


@pytest.mark.parametrize("scale", [0.0, -1000.0, math.nan, math.inf])
def test_bad_depth_scale_raises(scale):
    with pytest.raises(DataError, match="depth_scale"):
        depth_in_metres(np.ones((2, 2), dtype=np.uint16), scale)


# ---------------------------------------------------------------------------------------------
# register_depth


def translation(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


@FEW
@given(cameras(), st.integers(0, 2**32 - 1))
def test_identity_extrinsics_reproduce_the_depth(camera, seed):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.3, 15.0, camera.shape).astype(np.float32)
    depth[rng.random(camera.shape) < 0.2] = 0.0
    out = register_depth(depth, camera, camera, np.eye(4))
    assert out.dtype == np.float32 and out.shape == camera.shape
    np.testing.assert_allclose(out, depth, rtol=1e-6, atol=0)


def test_depth_max_drops_far_returns():
    cam = PinholeCamera.from_fov(40, 30, 60)
    depth = np.full(cam.shape, 5.0, dtype=np.float32)
    depth[:, :20] = 12.0
    out = register_depth(depth, cam, cam, np.eye(4), depth_max=10.0)
    assert np.all(out[:, :20] == 0) and np.allclose(out[:, 20:], 5.0)


@FEW
@given(st.floats(1.0, 6.0), st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.5, 0.5))
def test_translated_fronto_parallel_plane_has_the_analytic_depth(Z, tx, ty, tz):
    """A plane at depth Z in the depth camera is at depth Z + tz in a colour camera whose origin
    is at -t in the depth frame (T_color_depth = translation t), whatever the intrinsics."""
    depth_cam = PinholeCamera(160, 120, 150.0, 150.0, 80.0, 60.0)
    color_cam = PinholeCamera(100, 80, 70.0, 72.0, 48.5, 41.0)  # wider field, other centre
    depth = np.full(depth_cam.shape, Z, dtype=np.float32)
    out = register_depth(depth, depth_cam, color_cam, translation(tx, ty, tz))
    # Colour pixels whose ray meets the plane inside the depth camera's view, with a margin of
    # a few pixels for the sampling of the depth image, must all show the plane.
    x_over_z, y_over_z = color_cam.rays()
    zc = Z + tz
    xd, yd = x_over_z * zc - tx, y_over_z * zc - ty  # where the colour ray meets the plane
    ud, vd = depth_cam.fx * xd / Z + depth_cam.cx, depth_cam.fy * yd / Z + depth_cam.cy
    inside = (ud > 3) & (ud < depth_cam.width - 4) & (vd > 3) & (vd < depth_cam.height - 4)
    outside = (ud < -2) | (ud > depth_cam.width + 1) | (vd < -2) | (vd > depth_cam.height + 1)
    assert inside.sum() > 100
    # the depth camera is denser than the colour camera here, so every inner pixel is hit
    np.testing.assert_allclose(out[inside], zc, atol=1e-4)
    assert np.all(out[outside] == 0)


def test_occlusion_keeps_the_nearer_return():
    """A near square in front of a far wall: after moving the camera sideways the square slides
    over wall points that now project to the same colour pixels; the square must win."""
    cam = PinholeCamera(200, 100, 100.0, 100.0, 99.5, 49.5)
    depth = np.full(cam.shape, 4.0, dtype=np.float32)
    depth[30:70, 60:120] = 1.0  # the near square, 60 px wide
    t = 0.3  # metres: near points shift 30 px, far points 7.5 px
    out = register_depth(depth, cam, cam, translation(t, 0.0, 0.0))
    # colour pixels of the square's shifted interior ...
    square = np.zeros(cam.shape, dtype=bool)
    square[32:68, 92:148] = True
    np.testing.assert_allclose(out[square], 1.0, atol=1e-5)
    # ... of which some also receive wall points (from depth columns 120-140 shifted by 7.5)
    x_over_z, _ = cam.rays()
    wall_cols = np.flatnonzero(depth[50] == 4.0)
    u_wall = np.rint(cam.fx * (x_over_z[50, wall_cols] * 4.0 + t) / 4.0 + cam.cx).astype(int)
    assert np.isin(np.arange(92, 148), u_wall).sum() >= 8
    # and the wall still shows where the square does not cover it
    np.testing.assert_allclose(out[50, 160:190], 4.0, atol=1e-5)


def test_rotated_depth_camera():
    """A depth camera turned 90 deg about the optical z axis (image rotated): the registered
    depth of a tilted plane matches the plane seen from the colour camera directly."""
    cam = PinholeCamera(81, 81, 80.0, 80.0, 40.0, 40.0)
    # plane z = 3 + 0.2 x in the colour frame; in the depth frame (x_d = y_c, y_d = -x_c)
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # R_color_depth
    T = np.eye(4)
    T[:3, :3] = R
    _, yd = cam.rays()
    # a point (a z, b z, z) of the depth camera is (-b z, a z, z) in colour: z = 3 - 0.2 b z
    zd = 3.0 / (1.0 + 0.2 * yd)
    out = register_depth(zd.astype(np.float32), cam, cam, T)
    xc, _ = cam.rays()
    expected = 3.0 / (1.0 - 0.2 * xc)
    inner = np.s_[2:-2, 2:-2]
    np.testing.assert_allclose(out[inner], expected[inner], rtol=1e-5)


def test_register_depth_rejects_bad_inputs():
    cam = PinholeCamera(20, 10, 20.0, 20.0, 9.5, 4.5)
    good = np.ones(cam.shape, dtype=np.float32)
    with pytest.raises(DataError, match="shape"):
        register_depth(np.ones((11, 20), np.float32), cam, cam, np.eye(4))
    with pytest.raises(DataError, match="dtype"):
        register_depth(np.ones(cam.shape, np.int32), cam, cam, np.eye(4))
    with pytest.raises(DataError, match="T_color_depth"):
        register_depth(good, cam, cam, np.eye(3))
    bad = np.eye(4)
    bad[0, 3] = np.nan
    with pytest.raises(DataError, match="T_color_depth"):
        register_depth(good, cam, cam, bad)
    with pytest.raises(DataError, match="negative"):
        register_depth(-good, cam, cam, np.eye(4))


def test_register_depth_accepts_float64_metres():
    cam = PinholeCamera(20, 10, 20.0, 20.0, 9.5, 4.5)
    depth = np.full(cam.shape, 2.5, dtype=np.float64)
    out = register_depth(depth, cam, cam, np.eye(4))
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, 2.5)


# ---------------------------------------------------------------------------------------------
# rigid_transform: rounded rotations are re-orthonormalised, others refused by how much


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """(4, 4) a uniformly random rotation (a normalised Gaussian quaternion) and translation."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                 [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                 [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = rng.uniform(-10, 10, 3)
    return T


def perturbed(T: np.ndarray, rng: np.random.Generator, norm: float) -> np.ndarray:
    """`T` with its rotation plus a random matrix of Frobenius norm `norm`."""
    E = rng.standard_normal((3, 3))
    out = T.copy()
    out[:3, :3] += norm * E / np.linalg.norm(E)
    return out


def orthonormality_error(R: np.ndarray) -> float:
    return float(np.abs(R @ R.T - np.eye(3)).max())


def refusal(off: float) -> str:
    """The start of the message naming by how much a rotation is not orthonormal."""
    return re.escape(f"max |R R' - I| = {off:.3g}")


def check_accepted(T: np.ndarray, out: np.ndarray, error: float) -> None:
    """`out` is `T` with an exactly orthonormal rotation (det 1) within `error` of T's, the
    same translation and the last row 0 0 0 1."""
    R = out[:3, :3]
    assert out.shape == (4, 4) and out.dtype == np.float64
    assert orthonormality_error(R) < 1e-12
    assert abs(np.linalg.det(R) - 1.0) < 1e-12
    np.testing.assert_array_equal(out[:3, 3], T[:3, 3])
    np.testing.assert_array_equal(out[3], [0.0, 0.0, 0.0, 1.0])
    # the nearest rotation to R + E is no farther from it than R is: |E|_F = error
    assert np.linalg.norm(R - T[:3, :3]) <= error * (1 + 1e-9) + 1e-12


@PROPS
@given(st.integers(0, 2**32 - 1), st.floats(-7.0, -0.5))
def test_rotations_off_by_rounding_are_made_orthonormal_and_the_rest_refused(seed, log_norm):
    """A pose whose rotation is perturbed by a random matrix of Frobenius norm `norm` (1e-7
    to 0.3) is accepted, and comes back with the nearest rotation, exactly when
    max |R R' - I| is within ORTHONORMAL_TOL; otherwise it is refused with that error in the
    message."""
    norm = 10.0**log_norm
    rng = np.random.default_rng(seed)
    T0 = random_pose(rng)
    T = perturbed(T0, rng, norm)
    off = orthonormality_error(T[:3, :3])
    given_T = T.copy()
    if off <= ORTHONORMAL_TOL:
        out = rigid_transform("T_test", T)
        check_accepted(T, out, norm)
        assert np.linalg.norm(out[:3, :3] - T0[:3, :3]) <= 2 * norm + 1e-12
    else:
        with pytest.raises(DataError, match=r"^T_test is not a rigid transform: "
                           + refusal(off)):
            rigid_transform("T_test", T)
    np.testing.assert_array_equal(T, given_T)  # the caller's array is left alone


@FEW
@given(st.integers(0, 2**32 - 1))
def test_a_rotation_off_by_1e_4_is_accepted_and_one_off_by_0_1_refused(seed):
    rng = np.random.default_rng(seed)
    T0 = random_pose(rng)
    near = perturbed(T0, rng, 1e-4)
    assert 1e-6 < orthonormality_error(near[:3, :3]) < 1e-3
    out = rigid_transform("T_odom_body", near)
    check_accepted(near, out, 1e-4)
    np.testing.assert_allclose(out, T0, atol=2e-4)
    # 0.1 along the rotation's own axes (a scale and a shear, not a turn): clearly no rotation
    S = rng.standard_normal((3, 3))
    S = (S + S.T) / np.linalg.norm(S + S.T)
    far = T0.copy()
    far[:3, :3] = T0[:3, :3] @ (np.eye(3) + 0.1 * S)
    off = orthonormality_error(far[:3, :3])
    assert off > ORTHONORMAL_TOL
    with pytest.raises(DataError, match=refusal(off)) as info:
        rigid_transform("T_odom_body", far)
    message = str(info.value)
    assert message.startswith("T_odom_body is not a rigid transform")
    assert f"det R = {np.linalg.det(far[:3, :3]):.6g}" in message
    assert "last row" in message


def test_exact_rotations_are_returned_as_given():
    """Rotations orthonormal to float64 rounding are not touched (no SVD noise)."""
    T = T_body_camera(0.6, 5.0, 0.2)
    out = rigid_transform("T", T)
    np.testing.assert_array_equal(out, T)
    assert out is not T


def test_reflections_and_bad_last_rows_are_refused_naming_them():
    mirror = np.diag([1.0, 1.0, -1.0, 1.0])  # orthonormal, det -1
    with pytest.raises(DataError, match=re.escape("det R = -1 (must be > 0)")):
        rigid_transform("T_mirror", mirror)
    row = np.eye(4)
    row[3, 0] = 0.05
    with pytest.raises(DataError, match=r"T_row is not a rigid transform: .*last row "
                       + re.escape("[0.05, 0.0, 0.0, 1.0]")):
        rigid_transform("T_row", row)
    # a last row off by rounding is set to 0 0 0 1
    row[3] = (1e-5, 0.0, 0.0, 1.0 + 1e-5)
    np.testing.assert_array_equal(rigid_transform("T_row", row)[3], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ConfigError, match="T_scaled"):
        rigid_transform("T_scaled", np.diag([1.1, 1.1, 1.1, 1.0]), ConfigError)


def test_front_end_takes_rounded_poses_and_refuses_sheared_ones_naming_them():
    """Through `RgbdFrontEnd.process`: an odometry pose off by 1e-4 maps the frame as the
    exact pose does; one off by 0.1 is a DataError naming T_odom_body and the error size, as
    is a per-frame T_body_camera; a sheared mount is a ConfigError."""
    from tcaff_gtsam.eval.sim.render import RgbdScene, render
    from tcaff_gtsam.mapping.frontend import RgbdFrontEnd

    from tcaff_gtsam.geometry import se3_from_xyz_yaw

    cam = PinholeCamera.from_fov(320, 240, 87)
    T_bc = T_body_camera(0.6, 5.0)
    scene = RgbdScene([[2.5, 0.2]], [0.5], [0.9])
    T_odom_body = se3_from_xyz_yaw(0.3, -0.1, 0.0, 0.05)
    frame = render(scene, T_odom_body @ T_bc, cam)
    rng = np.random.default_rng(3)
    rounded = perturbed(T_odom_body, rng, 1e-4)
    exact = RgbdFrontEnd(cam, T_bc, depth_scale=1.0).process(0.0, frame.rgb, frame.depth,
                                                            T_odom_body)
    front = RgbdFrontEnd(cam, T_bc, depth_scale=1.0)
    got = front.process(0.0, frame.rgb, frame.depth, rounded)
    assert len(exact.observations) == len(got.observations) == 1
    np.testing.assert_allclose(got.observations.centroids, exact.observations.centroids,
                               atol=2e-3)
    sheared = T_odom_body.copy()
    sheared[:3, :3] = sheared[:3, :3] @ np.diag([1.1, 1.0, 1.0])
    off = orthonormality_error(sheared[:3, :3])
    with pytest.raises(DataError, match=r"^T_odom_body is not a rigid transform: "
                       + refusal(off)):
        front.process(0.1, frame.rgb, frame.depth, sheared)
    sheared_mount = T_bc.copy()
    sheared_mount[:3, :3] = sheared_mount[:3, :3] @ np.diag([1.0, 1.1, 1.0])
    off = orthonormality_error(sheared_mount[:3, :3])
    with pytest.raises(DataError, match=r"^T_body_camera is not a rigid transform: "
                       + refusal(off)):
        front.process(0.1, frame.rgb, frame.depth, T_odom_body, T_body_camera=sheared_mount)
    with pytest.raises(ConfigError, match=r"^RgbdFrontEnd.T_body_camera is not a rigid "
                       + "transform: " + refusal(off)):
        RgbdFrontEnd(cam, sheared_mount, depth_scale=1.0)
    # nothing was mapped by the refused frames; a later good one still is
    assert len(front.mapper) == 1
    assert len(front.process(0.2, frame.rgb, frame.depth, rounded).observations) == 1
