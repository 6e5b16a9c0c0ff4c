"""Tests for tcaff_gtsam.geometry: SE(2)/SE(3) helpers, angle wrapping and input validation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import (
    _chi2_quantile,
    compose,
    invert,
    se2_error,
    se2_from_params,
    se2_to_params,
    se2_to_se3,
    se3_from_rt,
    se3_from_xyz_quat,
    se3_from_xyz_yaw,
    se3_to_se2,
    se3_to_xyz_quat,
    transform_points,
    transform_points_batch,
    wrap_angle,
)

PROPS = settings(max_examples=40, deadline=None)

coord = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False)
seeds = st.integers(0, 2**32 - 1)


def angle_diff(a, b):
    """Smallest absolute difference of two angles (radians), robust at the +-pi seam."""
    d = np.asarray(a, float) - np.asarray(b, float)
    return np.abs(np.arctan2(np.sin(d), np.cos(d)))


def random_se2(rng: np.random.Generator, shape=()) -> np.ndarray:
    params = np.concatenate([rng.uniform(-50, 50, (*shape, 2)),
                             rng.uniform(-np.pi, np.pi, (*shape, 1))], axis=-1)
    return se2_from_params(params)


def random_se3(rng: np.random.Generator) -> np.ndarray:
    R = Rotation.random(random_state=rng).as_matrix()
    return se3_from_rt(R, rng.uniform(-50, 50, 3))


def random_transform(rng: np.random.Generator, dim: int) -> np.ndarray:
    return random_se2(rng) if dim == 2 else random_se3(rng)


# ---------------------------------------------------------------------------------------------
# wrap_angle


@PROPS
@given(st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False))
def test_wrap_angle_scalar_range_and_equivalence(a):
    w = wrap_angle(a)
    assert isinstance(w, float)
    assert -math.pi <= w < math.pi
    k = (a - w) / (2 * math.pi)
    assert abs(k - round(k)) < 1e-9
    assert angle_diff(w, a) < 1e-9


@PROPS
@given(seeds, st.integers(1, 50))
def test_wrap_angle_array_range_and_equivalence(seed, n):
    rng = np.random.default_rng(seed)
    a = rng.uniform(-100, 100, (n, 2))
    w = wrap_angle(a)
    assert isinstance(w, np.ndarray)
    assert w.shape == a.shape
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    k = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    np.testing.assert_array_equal(w, [[wrap_angle(float(x)) for x in row] for row in a])


@pytest.mark.parametrize(
    ("a", "expected"),
    [(0.0, 0.0), (math.pi, -math.pi), (-math.pi, -math.pi), (3 * math.pi, -math.pi),
     (2 * math.pi, 0.0), (1.5 * math.pi, -0.5 * math.pi), (-1.5 * math.pi, 0.5 * math.pi),
     (7.0, 7.0 - 2 * math.pi)],
)
def test_wrap_angle_known_values(a, expected):
    assert wrap_angle(a) == pytest.approx(expected, abs=1e-12)


def test_wrap_angle_just_below_minus_pi_stays_in_range():
    a = np.nextafter(-np.pi, -np.inf)
    w = wrap_angle(a)
    assert -np.pi <= w < np.pi


# ---------------------------------------------------------------------------------------------
# SE(2) parameters


@PROPS
@given(coord, coord, angle)
def test_se2_params_round_trip(x, y, theta):
    T = se2_from_params([x, y, theta])
    assert T.shape == (3, 3)
    np.testing.assert_allclose(T[2], [0, 0, 1])
    np.testing.assert_allclose(T[:2, :2] @ T[:2, :2].T, np.eye(2), atol=1e-12)
    assert np.linalg.det(T[:2, :2]) == pytest.approx(1.0)
    out = se2_to_params(T)
    assert out.shape == (3,)
    np.testing.assert_allclose(out[:2], [x, y], atol=1e-12)
    assert -np.pi <= out[2] < np.pi
    assert angle_diff(out[2], theta) < 1e-9


def test_se2_from_params_known_matrix():
    T = se2_from_params([1.0, 2.0, np.pi / 2])
    np.testing.assert_allclose(T, [[0, -1, 1], [1, 0, 2], [0, 0, 1]], atol=1e-15)


@PROPS
@given(seeds, st.integers(1, 6), st.integers(1, 4))
def test_se2_params_round_trip_batched(seed, n, m):
    rng = np.random.default_rng(seed)
    params = np.concatenate([rng.uniform(-50, 50, (n, m, 2)),
                             rng.uniform(-np.pi, np.pi, (n, m, 1))], axis=-1)
    T = se2_from_params(params)
    assert T.shape == (n, m, 3, 3)
    for i in range(n):
        for j in range(m):
            np.testing.assert_allclose(T[i, j], se2_from_params(params[i, j]), atol=1e-15)
    out = se2_to_params(T)
    assert out.shape == (n, m, 3)
    np.testing.assert_allclose(out[..., :2], params[..., :2], atol=1e-12)
    assert np.all(angle_diff(out[..., 2], params[..., 2]) < 1e-9)


# ---------------------------------------------------------------------------------------------
# compose / invert


@PROPS
@given(seeds, st.sampled_from([2, 3]))
def test_compose_with_inverse_is_identity(seed, dim):
    T = random_transform(np.random.default_rng(seed), dim)
    Ti = invert(T)
    eye = np.eye(dim + 1)
    np.testing.assert_allclose(compose(T, Ti), eye, atol=1e-12)
    np.testing.assert_allclose(compose(Ti, T), eye, atol=1e-12)
    np.testing.assert_allclose(Ti, np.linalg.inv(T), atol=1e-12)
    np.testing.assert_allclose(invert(Ti), T, atol=1e-12)


@PROPS
@given(seeds, st.sampled_from([2, 3]))
def test_compose_is_associative_and_matches_matmul(seed, dim):
    rng = np.random.default_rng(seed)
    A, B, C = (random_transform(rng, dim) for _ in range(3))
    left = compose(compose(A, B), C)
    right = compose(A, compose(B, C))
    np.testing.assert_allclose(left, right, atol=1e-10)
    np.testing.assert_allclose(compose(A, B, C), A @ B @ C, atol=1e-10)
    np.testing.assert_allclose(compose(A), A)


def test_compose_order_is_left_to_right():
    T_a_b = se2_from_params([1.0, 0.0, np.pi / 2])
    T_b_c = se2_from_params([1.0, 0.0, 0.0])
    # Origin of c is at (1, 0) in b, which is (1, 1) in a.
    np.testing.assert_allclose(compose(T_a_b, T_b_c)[:2, 2], [1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(compose(T_b_c, T_a_b)[:2, 2], [2.0, 0.0], atol=1e-12)


@PROPS
@given(seeds, st.integers(1, 5))
def test_invert_and_compose_stacks(seed, n):
    rng = np.random.default_rng(seed)
    T = random_se2(rng, (n,))
    Ti = invert(T)
    assert Ti.shape == (n, 3, 3)
    np.testing.assert_allclose(compose(T, Ti), np.broadcast_to(np.eye(3), (n, 3, 3)),
                               atol=1e-12)
    for k in range(n):
        np.testing.assert_allclose(Ti[k], np.linalg.inv(T[k]), atol=1e-12)


# ---------------------------------------------------------------------------------------------
# transform_points


@PROPS
@given(seeds, st.sampled_from([2, 3]), st.integers(0, 20))
def test_transform_points_matches_homogeneous_product(seed, dim, n):
    rng = np.random.default_rng(seed)
    T = random_transform(rng, dim)
    pts = rng.uniform(-20, 20, (n, dim))
    out = transform_points(T, pts)
    assert out.shape == (n, dim)
    homog = np.hstack([pts, np.ones((n, 1))])
    expected = (T @ homog.T).T[:, :dim]
    np.testing.assert_allclose(out, expected, atol=1e-10)
    back = transform_points(invert(T), out)
    np.testing.assert_allclose(back, pts, atol=1e-9)


def test_transform_points_known_value():
    T = se2_from_params([1.0, 2.0, np.pi / 2])
    np.testing.assert_allclose(transform_points(T, [[1.0, 0.0]]), [[1.0, 3.0]], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# quaternions


@PROPS
@given(st.tuples(coord, coord, coord),
       st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 4))
def test_se3_xyz_quat_round_trip(xyz, q):
    q = np.array(q)
    assume(np.linalg.norm(q) > 0.1)
    T = se3_from_xyz_quat(xyz, q)
    assert T.shape == (4, 4)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    xyz_out, q_out = se3_to_xyz_quat(T)
    np.testing.assert_allclose(xyz_out, xyz, atol=0)
    assert q_out.shape == (4,)
    assert q_out[0] >= 0
    assert np.linalg.norm(q_out) == pytest.approx(1.0)
    qn = q / np.linalg.norm(q)
    err = min(np.abs(q_out - qn).max(), np.abs(q_out + qn).max())
    assert err < 1e-9
    # Rebuilding from the output gives the same transform.
    np.testing.assert_allclose(se3_from_xyz_quat(xyz_out, q_out), T, atol=1e-12)


def test_se3_from_xyz_quat_known_rotation_w_first():
    h = math.sqrt(0.5)
    T = se3_from_xyz_quat([1.0, 2.0, 3.0], [h, 0.0, 0.0, h])  # 90 deg about z, w first
    expected = np.array([[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], float)
    np.testing.assert_allclose(T, expected, atol=1e-12)
    T = se3_from_xyz_quat([0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0])  # 180 deg about x
    np.testing.assert_allclose(T, np.diag([1.0, -1.0, -1.0, 1.0]), atol=1e-12)
    T = se3_from_xyz_quat([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(T, np.eye(4), atol=1e-15)


def test_se3_from_xyz_quat_normalises():
    h = math.sqrt(0.5)
    np.testing.assert_allclose(se3_from_xyz_quat([0, 0, 0], [5.0, 0.0, 0.0, 5.0]),
                               se3_from_xyz_quat([0, 0, 0], [h, 0.0, 0.0, h]), atol=1e-12)


@pytest.mark.parametrize("big", [-2**63 - 1, 2**64, 10**300])
def test_se3_from_xyz_yaw_takes_python_ints_beyond_int64(big):
    """As the floats they are (numpy made them objects without a cos)."""
    T = se3_from_xyz_yaw(big, 0, 0, big)
    np.testing.assert_array_equal(T, se3_from_xyz_yaw(float(big), 0.0, 0.0, float(big)))


def test_se3_to_xyz_quat_known_value_and_sign():
    h = math.sqrt(0.5)
    T = se3_from_xyz_yaw(1.0, 2.0, 3.0, -np.pi / 2)
    xyz, q = se3_to_xyz_quat(T)
    np.testing.assert_allclose(xyz, [1, 2, 3])
    np.testing.assert_allclose(q, [h, 0, 0, -h], atol=1e-12)
    # A quaternion with negative w comes back with w >= 0 (same rotation).
    T = se3_from_xyz_quat([0, 0, 0], [-h, 0.0, 0.0, -h])
    _, q = se3_to_xyz_quat(T)
    np.testing.assert_allclose(q, [h, 0, 0, h], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# SE(3) <-> SE(2)


@PROPS
@given(coord, coord, coord, angle)
def test_se3_to_se2_of_xyz_yaw(x, y, z, yaw):
    T3 = se3_from_xyz_yaw(x, y, z, yaw)
    np.testing.assert_allclose(T3[:3, 3], [x, y, z])
    np.testing.assert_allclose(T3[2, :3], [0, 0, 1])
    T2 = se3_to_se2(T3)
    assert T2.shape == (3, 3)
    params = se2_to_params(T2)
    np.testing.assert_allclose(params[:2], [x, y], atol=1e-12)
    assert angle_diff(params[2], yaw) < 1e-9
    np.testing.assert_allclose(T2, se2_from_params([x, y, yaw]), atol=1e-12)


@PROPS
@given(angle, st.floats(-1.5, 1.5), st.floats(-3.1, 3.1), coord, coord, coord)
def test_se3_to_se2_with_roll_pitch_keeps_heading(yaw, pitch, roll, x, y, z):
    R = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    T3 = se3_from_rt(R, [x, y, z])
    T2 = se3_to_se2(T3)
    params = se2_to_params(T2)
    np.testing.assert_allclose(params[:2], [x, y], atol=1e-12)
    heading = math.atan2(R[1, 0], R[0, 0])  # the rotated x axis projected onto the plane
    assert angle_diff(params[2], heading) < 1e-9
    assert angle_diff(params[2], yaw) < 1e-9
    # The SE(2) x axis is parallel to the horizontal projection of the rotated x axis.
    proj = R[:2, 0] / np.linalg.norm(R[:2, 0])
    np.testing.assert_allclose(T2[:2, 0], proj, atol=1e-9)


@PROPS
@given(coord, coord, angle, coord)
def test_se2_to_se3_round_trip(x, y, theta, z):
    T2 = se2_from_params([x, y, theta])
    T3 = se2_to_se3(T2, z=z)
    assert T3.shape == (4, 4)
    np.testing.assert_allclose(T3[:3, 3], [x, y, z])
    np.testing.assert_allclose(T3[2, :3], [0, 0, 1])
    np.testing.assert_allclose(T3[3], [0, 0, 0, 1])
    np.testing.assert_allclose(T3[:2, :2], T2[:2, :2])
    np.testing.assert_allclose(se3_to_se2(T3), T2, atol=1e-12)


@PROPS
@given(seeds, st.integers(1, 5))
def test_se2_se3_conversions_batched(seed, n):
    T2 = random_se2(np.random.default_rng(seed), (n,))
    T3 = se2_to_se3(T2)
    assert T3.shape == (n, 4, 4)
    np.testing.assert_allclose(T3[:, 2, 3], 0.0)
    np.testing.assert_allclose(se3_to_se2(T3), T2, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# validation


@pytest.mark.parametrize("bad", [np.eye(2), np.zeros((3, 4)), np.zeros(3), np.eye(4), 1.0])
def test_se2_to_params_rejects_wrong_shapes(bad):
    with pytest.raises(DataError):
        se2_to_params(bad)


@pytest.mark.parametrize("bad", [[1.0, 2.0], np.zeros((3, 2)), np.zeros((2, 4)), 1.0])
def test_se2_from_params_rejects_wrong_shapes(bad):
    with pytest.raises(DataError):
        se2_from_params(bad)


@pytest.mark.parametrize("fn", [se3_to_se2, se3_to_xyz_quat])
@pytest.mark.parametrize("bad", [np.eye(3), np.zeros((4, 3)), np.eye(5), np.zeros(4)])
def test_se3_functions_reject_wrong_shapes(fn, bad):
    with pytest.raises(DataError):
        fn(bad)


@pytest.mark.parametrize("bad", [np.eye(2), np.eye(5), np.zeros((3, 4)), np.zeros(9)])
def test_se2_to_se3_invert_compose_reject_wrong_shapes(bad):
    with pytest.raises(DataError):
        se2_to_se3(bad)
    with pytest.raises(DataError):
        invert(bad)
    with pytest.raises(DataError):
        compose(bad)
    with pytest.raises(DataError):
        compose(np.eye(3), bad)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("dim", [2, 3])
def test_non_finite_transforms_rejected(value, dim):
    T = np.eye(dim + 1)
    T[0, dim] = value
    with pytest.raises(DataError, match="non-finite"):
        invert(T)
    with pytest.raises(DataError, match="non-finite"):
        compose(np.eye(dim + 1), T)
    with pytest.raises(DataError, match="non-finite"):
        compose(T, np.eye(dim + 1))
    with pytest.raises(DataError, match="non-finite"):
        transform_points(T, np.zeros((1, dim)))
    conv = se2_to_params if dim == 2 else se3_to_se2
    with pytest.raises(DataError, match="non-finite"):
        conv(T)


def test_non_finite_in_a_stack_rejected():
    T = np.stack([np.eye(3)] * 4)
    T[2, 1, 1] = np.nan
    with pytest.raises(DataError):
        invert(T)
    with pytest.raises(DataError):
        se2_to_params(T)


@pytest.mark.parametrize(
    "q", [[0.0, 0.0, 0.0, 0.0], [1e-12, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1, 0, 0, 0, 0],
          [np.nan, 0.0, 0.0, 1.0], [np.inf, 0.0, 0.0, 0.0]],
)
def test_bad_quaternions_rejected(q):
    with pytest.raises(DataError, match="quaternion"):
        se3_from_xyz_quat([0.0, 0.0, 0.0], q)


def test_compose_se2_with_se3_rejected():
    with pytest.raises(DataError, match="compose"):
        compose(np.eye(3), np.eye(4))
    with pytest.raises(DataError, match="compose"):
        compose(np.eye(4), np.eye(4), np.eye(3))


def test_compose_needs_a_transform():
    with pytest.raises(DataError):
        compose()


@pytest.mark.parametrize(
    ("T", "pts"),
    [(np.eye(3), np.zeros((4, 3))), (np.eye(4), np.zeros((4, 2))), (np.eye(3), np.zeros(2)),
     (np.eye(3), np.zeros((1, 2, 2)))],
)
def test_transform_points_rejects_wrong_point_shapes(T, pts):
    with pytest.raises(DataError, match="points"):
        transform_points(T, pts)


@pytest.mark.parametrize("xyz", [[1.0, 2.0], [1.0, np.nan, 0.0]])
def test_se3_from_xyz_quat_rejects_bad_position_with_data_error(xyz):
    with pytest.raises(DataError, match="position"):
        se3_from_xyz_quat(xyz, [1.0, 0.0, 0.0, 0.0])


@settings(max_examples=50, deadline=None)
@given(st.floats(-20, 20), st.floats(-20, 20), st.floats(-3.1, 3.1),
       st.floats(-2, 2), st.floats(-2, 2), st.floats(-1.0, 1.0))
def test_se2_error_is_the_size_of_the_right_perturbation(x, y, th, dx, dy, dth):
    T = se2_from_params([x, y, th])
    err = se2_error(T, T @ se2_from_params([dx, dy, dth]))
    np.testing.assert_allclose(err, [math.hypot(dx, dy), abs(dth)], atol=1e-9)
    assert se2_error(np.stack([T, T]), np.stack([T, T])).shape == (2, 2)


def test_transform_points_batch_applies_one_transform_per_point_or_per_set():
    rng = np.random.default_rng(0)
    T = se2_from_params(np.column_stack([rng.normal(size=(6, 2)), rng.uniform(-3, 3, 6)]))
    xy = rng.normal(size=(6, 4, 2))
    per_set = transform_points_batch(T[:, None], xy)
    assert per_set.shape == (6, 4, 2)
    for f in range(6):
        assert np.allclose(per_set[f], transform_points(T[f], xy[f]), atol=1e-12)
    per_point = transform_points_batch(T, xy[:, 0])
    assert np.allclose(per_point, per_set[:, 0], atol=1e-12)
    T3 = np.array([se3_from_xyz_yaw(*rng.normal(size=3), rng.uniform(-3, 3))
                   for _ in range(5)])
    p3 = rng.normal(size=(5, 3))
    assert np.allclose(transform_points_batch(T3, p3),
                       [transform_points(T3[k], p3[k:k + 1])[0] for k in range(5)])
    with pytest.raises(DataError, match="transform_points_batch"):
        transform_points_batch(T, rng.normal(size=(6, 3)))


@settings(deadline=None)  # the first example imports scipy.stats
@given(st.floats(0.5, 0.99999), st.integers(1, 6))
def test_the_gates_chi2_quantile_is_scipys(probability, dof):
    from scipy.stats import chi2

    assert _chi2_quantile(probability, dof) == float(chi2.ppf(probability, dof))
