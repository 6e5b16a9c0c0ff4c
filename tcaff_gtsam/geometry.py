"""SE(2)/SE(3) helpers.

Convention: `T_a_b` maps coordinates in frame b into frame a, `p_a = T_a_b @ p_b`. SE(2) transforms
are (3, 3) homogeneous matrices, SE(3) transforms (4, 4). Functions accept a single transform or a
stack (..., 3, 3) / (..., 4, 4) where it makes sense. Angles are radians, wrapped to [-pi, pi).
Quaternions are w-first (w, x, y, z), as in the Kimera-Multi ground truth.

The public functions check their input and raise `DataError` naming the function and argument;
the library's own per-step code calls the unchecked `_` versions on arrays it has built itself.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import gammaincinv  # chi2.ppf's own formula, without scipy.stats' import

from .errors import DataError
from .inputs import real_array, shown
from .params import _finite

__all__ = [
    "compose",
    "invert",
    "se2_error",
    "se2_from_params",
    "se2_to_params",
    "se2_to_se3",
    "se3_from_rt",
    "se3_from_xyz_quat",
    "se3_from_xyz_yaw",
    "se3_to_se2",
    "se3_to_xyz_quat",
    "transform_points",
    "transform_points_batch",
    "wrap_angle",
]


def _numbers(owner: str, name: str, value) -> np.ndarray:
    """`value` as a float64 array of real numbers, NaN allowed (a missing value), infinities
    not (they have no angle and no place)."""
    arr = real_array(owner, name, value)
    if np.isinf(arr).any():
        raise DataError(f"{owner}: {name} must not be infinite, got {shown(value)}")
    return arr


def wrap_angle(angle):
    """Wrap angle(s) in radians to [-pi, pi). Works on scalars and arrays (any shape); NaN
    stays NaN (a missing angle).

    Raises:
        DataError: angle not real numbers (complex, strings, None) or infinite.
    """
    return _wrap_angle(_numbers("wrap_angle", "angle", angle))


def _wrap_angle(angle):
    if isinstance(angle, float):  # also np.float64; the filter and aligner's scalar path
        wrapped = (angle + math.pi) % (2.0 * math.pi) - math.pi
        return wrapped - 2.0 * math.pi if wrapped >= math.pi else wrapped
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    # np.mod of a tiny negative number rounds to 2 pi, which would give +pi
    wrapped = np.where(wrapped >= np.pi, wrapped - 2.0 * np.pi, wrapped)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def _check_square(T: np.ndarray, sizes: tuple[int, ...], name: str,
                  single: bool = False) -> np.ndarray:
    T = real_array(name, "transform", T)
    if (T.ndim < 2 or (single and T.ndim != 2) or T.shape[-1] != T.shape[-2]
            or T.shape[-1] not in sizes):
        expected = " or ".join(f"({s}, {s})" for s in sizes)
        raise DataError(f"{name}: expected a {'' if single else 'stack of '}{expected} "
                        f"transform{'' if single else 's'}, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise DataError(f"{name}: transform contains non-finite values")
    return T


def se2_from_params(params) -> np.ndarray:
    """(..., 3) parameters (x [m], y [m], theta [rad]) -> (..., 3, 3) SE(2) matrices; a row
    holding NaN gives a matrix holding NaN (a missing pose, as in ground truth with gaps).

    Raises:
        DataError: params not real numbers, infinite, or not of shape (..., 3).
    """
    params = _numbers("se2_from_params", "params", params)
    if params.shape[-1:] != (3,):
        raise DataError(f"se2_from_params: params must have shape (..., 3), got "
                        f"{params.shape}")
    return _se2_from_params(params)


def _se2_from_params(params: np.ndarray) -> np.ndarray:
    params = np.asarray(params, dtype=float)
    c, s = np.cos(params[..., 2]), np.sin(params[..., 2])
    T = np.zeros((*params.shape[:-1], 3, 3))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = c, -s, params[..., 0]
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2] = s, c, params[..., 1]
    T[..., 2, 2] = 1.0
    return T


def se2_to_params(T) -> np.ndarray:
    """(..., 3, 3) SE(2) matrices -> (..., 3) parameters (x, y, theta), theta wrapped."""
    return _se2_to_params(_check_square(T, (3,), "se2_to_params"))


def _se2_to_params(T: np.ndarray) -> np.ndarray:
    theta = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    return np.stack([T[..., 0, 2], T[..., 1, 2], _wrap_angle(theta)], axis=-1)


def se2_error(T_true, T_est) -> np.ndarray:
    """(..., 2) translation [m] and absolute heading [rad] of T_true^-1 T_est, SE(2) stacks."""
    T_true = _check_square(T_true, (3,), "se2_error: T_true")
    T_est = _check_square(T_est, (3,), "se2_error: T_est")
    try:
        relative = invert(T_true) @ T_est
    except ValueError:
        raise DataError(f"se2_error: stacks of shapes {T_true.shape} and {T_est.shape} do not "
                        f"broadcast") from None
    d = _se2_to_params(relative)
    return np.stack([np.hypot(d[..., 0], d[..., 1]), np.abs(d[..., 2])], axis=-1)


def se3_from_rt(R, t) -> np.ndarray:
    """Rotation (3, 3) and translation (3,) [m] -> (4, 4) SE(3) matrix.

    Raises:
        DataError: R not a finite (3, 3) array or t not three finite numbers.
    """
    R = real_array("se3_from_rt", "R", R)
    t = real_array("se3_from_rt", "t", t)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise DataError(f"se3_from_rt: R must be a finite (3, 3) rotation, got {shown(R)}")
    if t.shape != (3,) or not np.isfinite(t).all():
        raise DataError(f"se3_from_rt: t must be three finite numbers, got {shown(t)}")
    return _se3_from_rt(R, t)


def _se3_from_rt(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float)
    return T


def se3_from_xyz_quat(xyz, q_wxyz) -> np.ndarray:
    """Position (3,) [m] and unit quaternion (w, x, y, z) -> (4, 4) SE(3) matrix."""
    xyz = real_array("se3_from_xyz_quat", "xyz", xyz)
    if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
        raise DataError(f"se3_from_xyz_quat: xyz must be a position of three finite "
                        f"numbers (x, y, z), got {shown(xyz)}")
    q = real_array("se3_from_xyz_quat", "q_wxyz", q_wxyz)
    norm = np.linalg.norm(q) if q.shape == (4,) and np.isfinite(q).all() else 0.0
    if not np.isfinite(norm) or norm < 1e-9:
        raise DataError(f"se3_from_xyz_quat: q_wxyz must be a non-zero finite quaternion "
                        f"(w, x, y, z), got {shown(q_wxyz)}")
    R = Rotation.from_quat(np.r_[q[1:], q[0]] / norm).as_matrix()
    return _se3_from_rt(R, xyz)


def se3_to_xyz_quat(T) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) SE(3) matrix -> (position (3,), quaternion (w, x, y, z) with w >= 0)."""
    T = _check_square(T, (4,), "se3_to_xyz_quat", single=True)
    if not np.linalg.det(T[:3, :3]) > 0:
        raise DataError(f"se3_to_xyz_quat: T's rotation block must have a positive "
                        f"determinant, got {shown(T[:3, :3])}")
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    q = np.array([w, x, y, z])
    return T[:3, 3].copy(), q if w >= 0 else -q


def se3_from_xyz_yaw(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """Gravity-aligned SE(3): translation (x, y, z) [m] and a rotation about z by yaw [rad].

    Raises:
        DataError: any argument not a finite real number.
    """
    for name, value in (("x", x), ("y", y), ("z", z), ("yaw", yaw)):
        if not _finite(value):
            raise DataError(f"se3_from_xyz_yaw: {name} must be a finite number, got "
                            f"{shown(value)}")
    # as floats: numpy takes a Python int beyond int64 as an object, which has no cos
    return _se3_from_xyz_yaw(float(x), float(y), float(z), float(yaw))


def _se3_from_xyz_yaw(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, z]
    return T


def se3_to_se2(T) -> np.ndarray:
    """Gravity-aligned projection of (..., 4, 4) SE(3) onto the x-y plane -> (..., 3, 3) SE(2).

    Keeps x and y of the translation and the yaw of the rotation, i.e. the heading of the rotated
    x axis projected onto the plane (the yaw of a z-y-x Euler decomposition); z, roll and pitch are
    dropped. Frames are assumed to have z along gravity.
    """
    return _se3_to_se2(_check_square(T, (4,), "se3_to_se2"))


def _se3_to_se2(T: np.ndarray) -> np.ndarray:
    yaw = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    return _se2_from_params(np.stack([T[..., 0, 3], T[..., 1, 3], yaw], axis=-1))


def se2_to_se3(T, z: float = 0.0) -> np.ndarray:
    """(..., 3, 3) SE(2) -> (..., 4, 4) gravity-aligned SE(3) at height z [m].

    Raises:
        DataError: T not a finite stack of (3, 3) transforms, z not a finite number.
    """
    T = _check_square(T, (3,), "se2_to_se3")
    if not _finite(z):
        raise DataError(f"se2_to_se3: z must be a finite number of metres, got {shown(z)}")
    out = np.zeros((*T.shape[:-2], 4, 4))
    out[..., :2, :2] = T[..., :2, :2]
    out[..., :2, 3] = T[..., :2, 2]
    out[..., 2, 2] = 1.0
    out[..., 2, 3] = z
    out[..., 3, 3] = 1.0
    return out


def compose(*transforms) -> np.ndarray:
    """Compose transforms left to right: compose(T_a_b, T_b_c) = T_a_c. Stacks broadcast."""
    if not transforms:
        raise DataError("compose: need at least one transform")
    out = _check_square(transforms[0], (3, 4), "compose: transforms[0]")
    for k, T in enumerate(transforms[1:], start=1):
        T = _check_square(T, (3, 4), f"compose: transforms[{k}]")
        if T.shape[-1] != out.shape[-1]:
            raise DataError(f"compose: cannot compose {out.shape} with {T.shape}")
        out = out @ T
    return out


def invert(T) -> np.ndarray:
    """Inverse of (..., 3, 3) SE(2) or (..., 4, 4) SE(3) transforms, using R' and -R' t."""
    T = _check_square(T, (3, 4), "invert")
    d = T.shape[-1] - 1
    R = T[..., :d, :d]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :d, :d] = Rt
    out[..., :d, d] = -np.einsum("...ij,...j->...i", Rt, T[..., :d, d])
    out[..., d, d] = 1.0
    return out


def transform_points(T_a_b, points_b) -> np.ndarray:
    """Map points (n, d) from frame b into frame a with T_a_b ((d+1, d+1)); returns (n, d)."""
    T_a_b = _check_square(T_a_b, (3, 4), "transform_points: T_a_b", single=True)
    points_b = real_array("transform_points", "points_b", points_b)
    d = T_a_b.shape[-1] - 1
    if points_b.ndim != 2 or points_b.shape[1] != d:
        raise DataError(f"transform_points: points_b must have shape (n, {d}), got "
                        f"{points_b.shape}")
    if not np.isfinite(points_b).all():
        raise DataError("transform_points: points_b holds non-finite values")
    return _transform_points(T_a_b, points_b)


def _transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    d = T_a_b.shape[-1] - 1
    return points_b @ T_a_b[:d, :d].T + T_a_b[:d, d]


def transform_points_batch(T_a_b, points_b) -> np.ndarray:
    """Points (..., d) mapped from frame b into frame a by transforms (..., d+1, d+1), the two
    broadcast against each other: one transform per point ((k, 3, 3) with (k, 2)), or one per
    set of points ((F, 1, 3, 3) with (F, n, 2)). A transform or point holding NaN (none
    known then) gives NaN points.

    Raises:
        DataError: arguments not real numbers, infinite, or of shapes that do not fit.
    """
    o = "transform_points_batch"
    T_a_b = _numbers(o, "T_a_b", T_a_b)
    points_b = _numbers(o, "points_b", points_b)
    d = T_a_b.shape[-1] - 1 if T_a_b.ndim else 0
    if T_a_b.shape[-2:] not in ((3, 3), (4, 4)) or points_b.shape[-1:] != (d,):
        raise DataError(f"{o}: need T (..., d+1, d+1) with d = 2 or 3 and points (..., d), "
                        f"got {T_a_b.shape} and {points_b.shape}")
    try:
        np.broadcast_shapes(T_a_b.shape[:-2], points_b.shape[:-1])
    except ValueError:
        raise DataError(f"{o}: T_a_b {T_a_b.shape} and points_b {points_b.shape} do not "
                        f"broadcast") from None
    return np.einsum("...ij,...j->...i", T_a_b[..., :d, :d], points_b) + T_a_b[..., :d, d]


def _chi2_quantile(probability: float, dof: int) -> float:
    """The squared Mahalanobis distance within which a `dof`-dimensional Gaussian falls with
    `probability` (scipy.stats.chi2.ppf(probability, dof), to the last bit)."""
    return float(2.0 * gammaincinv(dof / 2.0, probability))
