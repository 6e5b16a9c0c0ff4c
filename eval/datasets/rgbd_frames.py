"""Single real RGB-D frames as public data sets ship them: TUM RGB-D, NYU Depth v2, Redwood.

Each loader returns `RealFrame`s: a colour image, depth in metres registered to it, the camera
and, where the data set records it, the camera's orientation with respect to gravity. The
files are the ones Open3D's test data carries (see the README beside them).

    frames = load_folder("../shared/data/rgbd")   # every frame found there, by name
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera, rigid_transform

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se3_from_rt
from tcaff_gtsam.inputs import real_array, shown

from .image_files import read_image
from .text_tables import data_lines, number, read_json

__all__ = ["PRIMESENSE", "RealFrame", "load_folder", "load_nyu", "load_redwood", "load_tum"]

#: Kinect v1 / PrimeSense default intrinsics (525, 525, 319.5, 239.5) at 640 x 480.
PRIMESENSE = PinholeCamera(640, 480, 525.0, 525.0, 319.5, 239.5)
#: metres; nominal camera height of the Redwood frames (sizes and the level planes do not
#: depend on it, only the reported heights of centroids)
REDWOOD_HEIGHT = 1.0


@dataclass(frozen=True)
class RealFrame:
    """One real (or, for Redwood, rendered with sensor-like holes) RGB-D frame.

    Attributes:
        name: e.g. "TUM", "NYU", "redwood_00000".
        rgb: (H, W, 3) uint8, RGB order.
        depth: (H, W) float32 metres registered to `rgb`, 0 = no return.
        camera: intrinsics of both images.
        T_body_camera: (4, 4) the optical frame in a gravity-aligned body frame on the floor
            below the camera (x forward, y left, z up): what `RgbdFrontEnd` and
            `DepthSegmenter` need to tell level planes. Redwood: the rotation from the
            sequence's poses and a nominal height of 1 m (its log does not say where the floor
            is). TUM and NYU single frames carry no pose: pitch and height were read off the
            floor plane seen in the frame, rounded to 5 degrees and 0.1 m (see `load_tum`,
            `load_nyu`).
    """

    name: str
    rgb: np.ndarray
    depth: np.ndarray
    camera: PinholeCamera
    T_body_camera: np.ndarray


def _rgb(path: Path) -> np.ndarray:
    return np.ascontiguousarray(read_image(path, cv2.IMREAD_COLOR)[..., ::-1])


def load_tum(folder: Path | str) -> RealFrame:
    """`TUM_color.png` + `TUM_depth.png` (16-bit, 5000 units per metre), PrimeSense
    intrinsics. The frame carries no pose; the camera, handheld over a desk, looks 25 degrees
    down from 1.7 m (from the floor plane seen in the frame)."""
    folder = Path(folder)
    depth = read_image(folder / "TUM_depth.png", cv2.IMREAD_UNCHANGED)
    if depth.dtype != np.uint16:
        raise DataError(f"{folder / 'TUM_depth.png'}: expected 16-bit depth, got {depth.dtype}")
    return RealFrame("TUM", _rgb(folder / "TUM_color.png"),
                     depth.astype(np.float32) / 5000.0, PRIMESENSE, T_body_camera(1.7, 25.0))


def load_nyu(folder: Path | str) -> RealFrame:
    """`NYU_color.ppm` + `NYU_depth.pgm` (raw Kinect disparity, big-endian), converted to
    metres by Open3D's `create_from_nyu_format`; PrimeSense intrinsics. The frame carries no
    pose; the camera looks 15 degrees down from 1.6 m (from the floor plane seen in the
    frame)."""
    folder = Path(folder)
    raw = read_image(folder / "NYU_depth.pgm", cv2.IMREAD_UNCHANGED)
    if raw.dtype != np.uint16:
        raise DataError(f"{folder / 'NYU_depth.pgm'}: expected 16-bit disparity, got {raw.dtype}")
    # OpenCV hands back the 16-bit samples with the file's (big-endian) byte order
    # unswapped, which is what Open3D's NYU conversion expects: it swaps them itself.
    stored = raw
    rgb = _rgb(folder / "NYU_color.ppm")
    rgbd = o3d.geometry.RGBDImage.create_from_nyu_format(
        o3d.geometry.Image(rgb), o3d.geometry.Image(stored), convert_rgb_to_intensity=False)
    depth = np.asarray(rgbd.depth, dtype=np.float32).copy()
    depth[~np.isfinite(depth)] = 0.0
    return RealFrame("NYU", rgb, depth, PRIMESENSE, T_body_camera(1.6, 15.0))


def load_redwood(folder: Path | str) -> list[RealFrame]:
    """The frames of a Redwood sequence folder (`color/`, `depth/` in millimetres,
    `camera_primesense.json`, `odometry.log` with y-up world poses), in order.

    Raises:
        DataError: naming the file: either file missing or unreadable, a camera file that is
            not JSON of width, height and a 3 x 3 intrinsic_matrix (by column) of a camera, a
            log that is not blocks of a line of 3 ids and 4 rows of 4 numbers of a rigid
            transform; more images than poses; an image missing or unreadable.
    """
    folder = Path(folder)
    camera = _redwood_camera(folder / "camera_primesense.json")
    poses = _redwood_poses(folder / "odometry.log")
    # The log's camera axes are OpenGL's (x right, y up, z backwards): its first pose, the
    # identity, shows an upright, level view in the y-up world. Optical = GL turned about x.
    R_gl_optical = np.diag([1.0, -1.0, -1.0])
    # y-up world -> z-up world: x stays, y (up) becomes z, z becomes -y
    R_zup_yup = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    frames = []
    depths = sorted((folder / "depth").glob("*.png"))
    colours = sorted((folder / "color").glob("*.jpg"))
    if len(depths) != len(colours):
        raise DataError(f"{folder}: {len(colours)} colour and {len(depths)} depth images")
    if len(depths) > len(poses):
        raise DataError(f"{folder / 'odometry.log'}: {len(poses)} poses for {len(depths)} "
                        "frames")
    for d_path, c_path, T_world_gl in zip(depths, colours, poses, strict=False):
        depth = read_image(d_path, cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        R_level_camera = _level(R_zup_yup @ T_world_gl[:3, :3] @ R_gl_optical)
        frames.append(RealFrame(f"redwood_{d_path.stem}", _rgb(c_path), depth, camera,
                                se3_from_rt(R_level_camera, (0.0, 0.0, REDWOOD_HEIGHT))))
    return frames


def _redwood_camera(path: Path) -> PinholeCamera:
    """Open3D's camera intrinsic JSON: width, height and intrinsic_matrix, K by column."""
    intrinsics = read_json(path, "camera file")
    keys = ("width", "height", "intrinsic_matrix")
    if not (isinstance(intrinsics, dict) and set(keys) <= intrinsics.keys()):
        raise DataError(f"{path}: expected a JSON object of {', '.join(keys)}, got "
                        f"{shown(intrinsics)}")
    K = real_array(str(path), "intrinsic_matrix", intrinsics["intrinsic_matrix"])
    if K.shape != (9,) or not np.isfinite(K).all():
        raise DataError(f"{path}: intrinsic_matrix must be 9 finite numbers (K by column), got "
                        f"{shown(intrinsics['intrinsic_matrix'])}")
    try:
        return PinholeCamera.from_K(K.reshape(3, 3).T, intrinsics["width"],
                                    intrinsics["height"])
    except ConfigError as exc:
        raise DataError(f"{path}: not a camera ({exc})") from None


def _redwood_poses(path: Path) -> list[np.ndarray]:
    """A trajectory log: per frame a line of 3 ids, then 4 rows of 4 numbers, T_world_camera."""
    lines, texts = data_lines(path)
    if len(texts) % 5:
        raise DataError(f"{path}: expected blocks of 5 lines (3 ids, then 4 rows of a pose), "
                        f"got {len(texts)} lines")
    poses = []
    for k in range(0, len(texts), 5):
        if len(texts[k].split()) != 3:
            raise DataError(f"{path}:{lines[k]}: expected 3 ids, got {texts[k]!r}")
        rows = []
        for line, text in zip(lines[k + 1:k + 5], texts[k + 1:k + 5], strict=True):
            fields = text.split()
            if len(fields) != 4:
                raise DataError(f"{path}:{line}: expected a row of 4 numbers, got {text!r}")
            rows.append([number(path, line, f, text) for f in fields])
        poses.append(rigid_transform(f"{path}:{lines[k + 1]}: the pose", rows, DataError))
    return poses


def _level(R_world_camera: np.ndarray) -> np.ndarray:
    """The camera's rotation in the gravity-aligned frame that shares its heading (x forward
    along the optical axis's horizontal part, z up)."""
    forward = R_world_camera[:, 2]
    yaw = math.atan2(forward[1], forward[0])
    c, s = math.cos(yaw), math.sin(yaw)
    R_world_level = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return R_world_level.T @ R_world_camera


def load_folder(folder: Path | str) -> dict[str, RealFrame]:
    """Every frame in a folder laid out like `../shared/data/rgbd`, by name."""
    folder = Path(folder)
    out: dict[str, RealFrame] = {}
    if (folder / "TUM_depth.png").exists():
        out["TUM"] = load_tum(folder)
    if (folder / "NYU_depth.pgm").exists():
        out["NYU"] = load_nyu(folder)
    if (folder / "redwood_livingroom").is_dir():
        out.update((f.name, f) for f in load_redwood(folder / "redwood_livingroom"))
    return out

