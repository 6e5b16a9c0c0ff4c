"""SE(2)/SE(3) helpers.

Convention: `T_a_b` maps coordinates in frame b into frame a, `p_a = T_a_b @ p_b`. SE(2) transforms
are (3, 3) homogeneous matrices, SE(3) transforms (4, 4). Functions accept a single transform or a
stack (..., 3, 3) / (..., 4, 4) where it makes sense. Angles are radians, wrapped to [-pi, pi).
Quaternions are w-first (w, x, y, z), as in the Kimera-Multi ground truth.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import DataError

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


def wrap_angle(angle):
    """Wrap angle(s) in radians to [-pi, pi). Works on scalars and arrays."""
    wrapped = np.mod(np.asarray(angle, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    # np.mod of a tiny negative number rounds to 2 pi, which would give +pi
    wrapped = np.where(wrapped >= np.pi, wrapped - 2.0 * np.pi, wrapped)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def _check_square(T: np.ndarray, sizes: tuple[int, ...], name: str,
                  single: bool = False) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if (T.ndim < 2 or (single and T.ndim != 2) or T.shape[-1] != T.shape[-2]
            or T.shape[-1] not in sizes):
        expected = " or ".join(f"({s}, {s})" for s in sizes)
        raise DataError(f"{name}: expected a {'' if single else 'stack of '}{expected} "
                        f"transform{'' if single else 's'}, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise DataError(f"{name}: transform contains non-finite values")
    return T


def se2_from_params(params) -> np.ndarray:
    """(..., 3) parameters (x [m], y [m], theta [rad]) -> (..., 3, 3) SE(2) matrices."""
    params = np.asarray(params, dtype=float)
    if params.shape[-1:] != (3,):
        raise DataError(f"se2 params: expected shape (..., 3), got {params.shape}")
    c, s = np.cos(params[..., 2]), np.sin(params[..., 2])
    T = np.zeros((*params.shape[:-1], 3, 3))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = c, -s, params[..., 0]
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2] = s, c, params[..., 1]
    T[..., 2, 2] = 1.0
    return T


def se2_to_params(T) -> np.ndarray:
    """(..., 3, 3) SE(2) matrices -> (..., 3) parameters (x, y, theta), theta wrapped."""
    T = _check_square(T, (3,), "T")
    theta = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    return np.stack([T[..., 0, 2], T[..., 1, 2], wrap_angle(theta)], axis=-1)


def se2_error(T_true, T_est) -> np.ndarray:
    """(..., 2) translation [m] and absolute heading [rad] of T_true^-1 T_est, SE(2) stacks."""
    d = se2_to_params(invert(T_true) @ np.asarray(T_est, dtype=float))
    return np.stack([np.hypot(d[..., 0], d[..., 1]), np.abs(d[..., 2])], axis=-1)


def se3_from_rt(R, t) -> np.ndarray:
    """Rotation (3, 3) and translation (3,) -> (4, 4) SE(3) matrix."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float)
    return T


def se3_from_xyz_quat(xyz, q_wxyz) -> np.ndarray:
    """Position (3,) [m] and unit quaternion (w, x, y, z) -> (4, 4) SE(3) matrix."""
    xyz = np.asarray(xyz, dtype=float)
    if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
        raise DataError(f"position: expected three finite numbers (x, y, z), got {xyz!r}")
    q = np.asarray(q_wxyz, dtype=float)
    norm = np.linalg.norm(q)
    if q.shape != (4,) or not np.isfinite(norm) or norm < 1e-9:
        raise DataError(f"quaternion: expected a non-zero finite (w, x, y, z), got {q_wxyz!r}")
    R = Rotation.from_quat(np.r_[q[1:], q[0]] / norm).as_matrix()
    return se3_from_rt(R, xyz)


def se3_to_xyz_quat(T) -> tuple[np.ndarray, np.ndarray]:
    """(4, 4) SE(3) matrix -> (position (3,), quaternion (w, x, y, z) with w >= 0)."""
    T = _check_square(T, (4,), "T", single=True)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    q = np.array([w, x, y, z])
    return T[:3, 3].copy(), q if w >= 0 else -q


def se3_from_xyz_yaw(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """Gravity-aligned SE(3): translation (x, y, z) [m] and a rotation about z by yaw [rad]."""
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
    T = _check_square(T, (4,), "T")
    yaw = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    return se2_from_params(np.stack([T[..., 0, 3], T[..., 1, 3], yaw], axis=-1))


def se2_to_se3(T, z: float = 0.0) -> np.ndarray:
    """(..., 3, 3) SE(2) -> (..., 4, 4) gravity-aligned SE(3) at height z [m]."""
    T = _check_square(T, (3,), "T")
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
    out = _check_square(transforms[0], (3, 4), "transforms[0]")
    for k, T in enumerate(transforms[1:], start=1):
        T = _check_square(T, (3, 4), f"transforms[{k}]")
        if T.shape[-1] != out.shape[-1]:
            raise DataError(f"compose: cannot compose {out.shape} with {T.shape}")
        out = out @ T
    return out


def invert(T) -> np.ndarray:
    """Inverse of (..., 3, 3) SE(2) or (..., 4, 4) SE(3) transforms, using R' and -R' t."""
    T = _check_square(T, (3, 4), "T")
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
    T_a_b = _check_square(T_a_b, (3, 4), "T_a_b", single=True)
    points_b = np.asarray(points_b, dtype=float)
    d = T_a_b.shape[-1] - 1
    if points_b.ndim != 2 or points_b.shape[1] != d:
        raise DataError(f"points: expected shape (n, {d}), got {points_b.shape}")
    return points_b @ T_a_b[:d, :d].T + T_a_b[:d, d]


def transform_points_batch(T_a_b, points_b) -> np.ndarray:
    """Points (..., d) mapped from frame b into frame a by transforms (..., d+1, d+1), the two
    broadcast against each other: one transform per point ((k, 3, 3) with (k, 2)), or one per
    set of points ((F, 1, 3, 3) with (F, n, 2))."""
    T_a_b = np.asarray(T_a_b, dtype=float)
    points_b = np.asarray(points_b, dtype=float)
    d = T_a_b.shape[-1] - 1
    if T_a_b.shape[-2:] not in ((3, 3), (4, 4)) or points_b.shape[-1:] != (d,):
        raise DataError(f"transform_points_batch: need T (..., d+1, d+1) with d = 2 or 3 and "
                        f"points (..., d), got {T_a_b.shape} and {points_b.shape}")
    return np.einsum("...ij,...j->...i", T_a_b[..., :d, :d], points_b) + T_a_b[..., :d, d]
