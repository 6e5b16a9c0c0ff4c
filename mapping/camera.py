"""Camera geometry: pinhole intrinsics, the optical-frame axes, depth images and registration.

Frames: a camera's optical frame has x right, y down and z forward (OpenCV and ROS
`*_optical_frame`); a robot's body frame has x forward, y left and z up. `T_a_b` maps points in
frame b into frame a (4 x 4 homogeneous). Depth images hold raw values; metres = raw /
depth_scale (1000 for 16-bit millimetre images, 1 for float images in metres), 0 = no return.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se3_from_rt
from tcaff_gtsam.params import ParameterError, _finite, _int_at_least, _real, _require

__all__ = [
    "ORTHONORMAL_TOL",
    "R_BODY_OPTICAL",
    "PinholeCamera",
    "T_body_camera",
    "check_camera",
    "check_depth_scale",
    "depth_in_metres",
    "register_depth",
    "rigid_transform",
]

#: (3, 3) rotation of a camera's optical axes into a forward-looking body frame: optical z
#: (forward) is body x, optical x (right) is body -y, optical y (down) is body -z.
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

_DEPTH_DTYPES = (np.uint16, np.float32, np.float64)

#: degrees; a pinhole image holds no ray at 90 deg from the optical axis, and rays near it put
#: points of ordinary depth hundreds of metres to the side
MAX_RAY_DEG = 89.0
#: degrees; the narrowest field of view accepted along either image axis
MIN_FOV_DEG = 0.01
#: pixels; the widest (or tallest) image, the largest int32 (OpenCV's pixel coordinates)
_MAX_PIXELS = 2**31 - 1
#: the largest max |R R' - I| of a pose's rotation taken as rounding and re-orthonormalised:
#: poses stored to four digits (7-Scenes: up to 4e-4), and products of a few of them, stay well
#: within it; a rotation off by more is not a pose (a scale or shear of a per cent or more)
ORTHONORMAL_TOL = 1e-2
#: rotations orthonormal to this are taken as they are (float64 products of rotations)
_EXACT = 1e-12


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera without distortion.

    Attributes:
        width, height: image size in pixels.
        fx, fy: focal lengths in pixels; cx, cy: principal point in pixels (0 = the centre of
            the first pixel).

    Raises:
        ConfigError: naming the field: sizes not ints >= 1; intrinsics not finite numbers;
            focal lengths not > 0; intrinsics whose rays through the image's edges lie more
            than `MAX_RAY_DEG` from the optical axis (a focal length tiny for the image, e.g.
            fx = 1e-300, or a principal point far outside it), or that give a field of view
            under `MIN_FOV_DEG` along an axis (a focal length huge for the image).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        o = "PinholeCamera"
        for name in ("width", "height"):
            v = getattr(self, name)
            _require(_int_at_least(v, 1) and v <= _MAX_PIXELS, o, name, v,
                     f"must be an int in [1, {_MAX_PIXELS}] pixels")
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            _require(_finite(v), o, name, v, "must be a finite number of pixels")
        _require(self.fx > 0, o, "fx", self.fx, "must be > 0 pixels")
        _require(self.fy > 0, o, "fy", self.fy, "must be > 0 pixels")
        steepest = math.tan(math.radians(MAX_RAY_DEG)) * (1.0 + 1e-9)  # from_fov's rounding
        for f_name, c_name, size_name in (("fx", "cx", "width"), ("fy", "cy", "height")):
            f, c, size = getattr(self, f_name), getattr(self, c_name), getattr(self, size_name)
            lo, hi = (-0.5 - c) / f, (size - 0.5 - c) / f  # x / z (y / z) of the image's edges
            if max(abs(lo), abs(hi)) > steepest:
                # blame the principal point when it lies outside the image and a centred one
                # would do
                outside = not -0.5 <= c <= size - 0.5 and 0.5 * size / f <= steepest
                name, value = (c_name, c) if outside else (f_name, f)
                reach = math.degrees(math.atan(max(abs(lo), abs(hi))))
                raise ParameterError(o, name, value, (
                    f"with {f_name} = {f}, {c_name} = {c} and {size_name} = {size} the rays "
                    f"through the image reach {reach:.6g} deg from the optical axis; every "
                    f"pixel's ray must lie within {MAX_RAY_DEG} deg of it"))
            fov = math.degrees(math.atan(hi) - math.atan(lo))
            _require(fov >= MIN_FOV_DEG, o, f_name, f,
                     f"gives a field of view of {fov:.3g} deg across {size_name} = {size} "
                     f"pixels; must be at least {MIN_FOV_DEG} deg")

    @classmethod
    def from_K(cls, K, width: int, height: int) -> PinholeCamera:
        """From a (3, 3) intrinsic matrix (a ROS CameraInfo `K`, row-major, may be flat)."""
        try:
            K = np.asarray(K, dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"PinholeCamera.from_K: K must hold 9 numbers, got {K!r}") from None
        if K.size != 9 or not np.all(np.isfinite(K)):
            raise DataError(f"PinholeCamera.from_K: K must hold 9 finite numbers, got {K!r}")
        K = K.reshape(3, 3)
        return cls(width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                   float(K[1, 2]))

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> PinholeCamera:
        """Square pixels, the principal point at the image centre, horizontal field of view in
        degrees (`MIN_FOV_DEG` to 2 `MAX_RAY_DEG`).

        Raises:
            ConfigError: hfov_deg out of range, a size not an int in [1, 2**31 - 1], or a
                vertical field of view that `PinholeCamera` refuses (a very tall image at a
                wide hfov).
        """
        _require(_real(hfov_deg) and MIN_FOV_DEG <= hfov_deg <= 2 * MAX_RAY_DEG,
                 "PinholeCamera.from_fov", "hfov_deg", hfov_deg,
                 f"must be in [{MIN_FOV_DEG}, {2 * MAX_RAY_DEG}] degrees")
        for name, value in (("width", width), ("height", height)):
            _require(_int_at_least(value, 1) and value <= _MAX_PIXELS, "PinholeCamera.from_fov",
                     name, value, f"must be an int in [1, {_MAX_PIXELS}] pixels")
        f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2, (height - 1) / 2)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of its images."""
        return self.height, self.width

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) each: x / z and y / z of every pixel's ray in the optical frame, so that a
        pixel with depth z sees the point (x_over_z z, y_over_z z, z)."""
        u = (np.arange(self.width) - self.cx) / self.fx
        v = (np.arange(self.height) - self.cy) / self.fy
        return np.broadcast_to(u, self.shape), np.broadcast_to(v[:, None], self.shape)


def T_body_camera(height: float, pitch_deg: float = 0.0,
                  forward: float = 0.0) -> np.ndarray:
    """(4, 4) a forward-looking camera's optical frame in the body frame.

    Args:
        height: metres above the body origin; forward: metres ahead of it.
        pitch_deg: degrees the camera looks down (positive) from horizontal.
    """
    p = math.radians(pitch_deg)
    # pitch down about body y (left): positive angle turns x (forward) towards -z
    R_pitch = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0],
                        [-math.sin(p), 0.0, math.cos(p)]])
    return se3_from_rt(R_pitch @ R_BODY_OPTICAL, (forward, 0.0, height))


def check_camera(name: str, camera) -> PinholeCamera:
    """`camera` if it is a PinholeCamera; else ConfigError naming `name`."""
    if not isinstance(camera, PinholeCamera):
        raise ConfigError(f"{name} = {camera!r}: must be a PinholeCamera")
    return camera


def check_depth_scale(name: str, depth_scale) -> float:
    """`depth_scale` (raw depth units per metre) as a float if finite and > 0; else
    ConfigError naming `name`."""
    ok = _real(depth_scale) and math.isfinite(depth_scale) and depth_scale > 0
    _require(ok, name.rsplit(".", 1)[0], name.rsplit(".", 1)[-1], depth_scale,
             "must be a finite number > 0 (raw units per metre: 1000 for mm, 1 for m)")
    return float(depth_scale)


def rigid_transform(name: str, T, error: type[Exception] = DataError) -> np.ndarray:
    """`T` as a (4, 4) float array with an exactly orthonormal rotation, if it is a finite
    rigid transform up to `ORTHONORMAL_TOL`; else `error` naming `name` and by how much.

    Poses read from files, or composed from a few of them, are orthonormal only to the digits
    they were stored with (7-Scenes' to about 4e-4); those rotations are replaced by the
    nearest rotation (the SVD's U V'), so that nothing downstream inherits the shear. A
    rotation farther than `ORTHONORMAL_TOL` from orthonormal (max |R R' - I|), a determinant
    of the wrong sign or a last row other than 0 0 0 1 is not a pose: refused.
    """
    try:
        M = np.array(T, dtype=float)
    except (TypeError, ValueError):
        raise error(f"{name} must be a (4, 4) matrix, got {type(T).__name__}") from None
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise error(f"{name} must be a finite (4, 4) matrix, got shape {M.shape}")
    R = M[:3, :3]
    off = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    row = float(np.abs(M[3] - (0.0, 0.0, 0.0, 1.0)).max())
    if off > ORTHONORMAL_TOL or det <= 0 or row > ORTHONORMAL_TOL:
        raise error(f"{name} is not a rigid transform: max |R R' - I| = {off:.3g} (at most "
                    f"{ORTHONORMAL_TOL:g}), det R = {det:.6g} (must be > 0), last row "
                    f"{M[3].tolist()} (must be 0 0 0 1 within {ORTHONORMAL_TOL:g})")
    if off > _EXACT:
        U, _, Vt = np.linalg.svd(R)
        M[:3, :3] = U @ Vt
    M[3] = (0.0, 0.0, 0.0, 1.0)
    return M


def depth_in_metres(depth, depth_scale: float, shape: tuple[int, int] | None = None,
                    name: str = "depth", copy: bool = True) -> np.ndarray:
    """A raw depth image as (H, W) float32 metres, 0 where there is no return.

    Args:
        depth: (H, W) uint16, float32 or float64 raw depth; NaN and inf count as no return.
        depth_scale: raw units per metre (> 0).
        shape: the (H, W) the image must have, if given.
        copy: False: `depth` itself is returned when it is float32 metres already (depth_scale
            1, every value finite and >= 0), for a caller that only reads it.

    Raises:
        DataError: wrong type, dtype or shape, or negative depth.
    """
    if not isinstance(depth, np.ndarray):
        raise DataError(f"{name} must be a numpy array, got {type(depth).__name__}")
    if depth.dtype not in _DEPTH_DTYPES:
        raise DataError(f"{name} has dtype {depth.dtype}; expected uint16 (raw units) or "
                        "float32/float64")
    if depth.ndim != 2 or (shape is not None and depth.shape != tuple(shape)):
        want = "(H, W)" if shape is None else str(tuple(shape))
        raise DataError(f"{name} has shape {depth.shape}; expected {want}")
    if not (_real(depth_scale) and math.isfinite(depth_scale) and depth_scale > 0):
        raise DataError(f"depth_scale = {depth_scale!r}: must be a finite number > 0")
    if depth.dtype == np.float32 and depth_scale == 1 and not copy:
        metres = depth
    else:
        metres = depth.astype(np.float32)
        if depth_scale != 1:
            np.divide(metres, np.float32(depth_scale), out=metres)
    if metres.size and not (metres.min() >= 0 and metres.max() < np.inf):
        # NaN, infinities or negative values (two reductions found them; the rest is rare)
        if metres is depth:
            metres = depth.copy()
        metres[~np.isfinite(metres)] = 0.0
        if (metres < 0).any():
            raise DataError(f"{name} has negative value {float(metres.min())} m")
    return metres


def register_depth(depth: np.ndarray, depth_camera: PinholeCamera,
                   color_camera: PinholeCamera, T_color_depth: np.ndarray,
                   depth_max: float = 20.0, depth_scale: float = 1.0) -> np.ndarray:
    """Re-project a depth image into another camera (the colour camera), nearest return kept.

    When a depth pixel covers more than one colour pixel (a coarser or wider depth camera),
    each point fills its footprint: holes are filled with the nearest return in a window as
    wide as one depth pixel seen in the colour image.

    Args:
        depth: (H_d, W_d) raw depth in the depth camera, 0 = no return.
        T_color_depth: (4, 4) the depth camera's optical frame in the colour camera's.
        depth_max: metres (> 0); returns beyond this are dropped.
        depth_scale: raw depth units per metre (1 for metres, 1000 for millimetres).

    Returns:
        (H_c, W_c) float32 metres in the colour camera, 0 where no point projects.
    """
    depth_m = depth_in_metres(depth, depth_scale, depth_camera.shape, "depth")
    T = rigid_transform("T_color_depth", T_color_depth)
    if not (_real(depth_max) and depth_max > 0):
        raise DataError(f"depth_max = {depth_max!r}: must be a number > 0 metres")
    x_over_z, y_over_z = depth_camera.rays()
    valid = (depth_m > 0) & (depth_m <= depth_max)
    if not valid.any():
        return np.zeros(color_camera.shape, dtype=np.float32)
    z = depth_m[valid]
    points = np.column_stack([x_over_z[valid] * z, y_over_z[valid] * z, z])
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points.astype(np.float32)))
    # Open3D keeps the nearest point per pixel (a z-buffer), so occlusions come out right.
    image = cloud.project_to_depth_image(
        color_camera.width, color_camera.height,
        o3d.core.Tensor(color_camera.K, o3d.core.float64),
        o3d.core.Tensor(T, o3d.core.float64), depth_scale=1.0, depth_max=depth_max)
    out = np.asarray(image.as_tensor().numpy()[..., 0], dtype=np.float32)
    footprint = max(color_camera.fx / depth_camera.fx, color_camera.fy / depth_camera.fy)
    if footprint > 1.0:
        k = 2 * math.ceil(footprint / 2) + 1  # odd window covering one depth pixel
        none = np.float32(2 * depth_max)  # stands for "no return" in the min filter
        nearest = cv2.erode(np.where(out > 0, out, none).astype(np.float32),
                            np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT,
                            borderValue=float(none))
        holes = (out == 0) & (nearest < none)
        out[holes] = nearest[holes]
    return out
