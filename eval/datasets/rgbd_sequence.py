"""Recorded RGB-D sequences with ground-truth camera poses: 7-Scenes and TUM RGB-D folders.

Two layouts are read; `read_sequence` tells them apart by their files.

- 7-Scenes: `frame-XXXXXX.color.png|jpg`, `frame-XXXXXX.depth.png` (uint16 millimetres, 0 and
  65535 = no depth) and `frame-XXXXXX.pose.txt` (4 rows of 4 numbers: T_world_camera, metres)
  per frame; optionally `camera-intrinsics.txt` (3 rows of 3 numbers: K; default fx = fy = 585,
  cx = 320, cy = 240, 7-Scenes' documented depth intrinsics) and `gravity-direction.txt`. The
  frame numbers come from the file names (a folder may hold every 5th frame only); 7-Scenes
  stores no time stamps, so frame i is taken at i / fps.
- TUM RGB-D: `rgb.txt` and `depth.txt` ("timestamp filename" per line), `groundtruth.txt`
  ("timestamp tx ty tz qx qy qz qw": the colour camera's optical frame in the motion-capture
  world), images `rgb/*.png` and `depth/*.png` (uint16, 5000 units per metre, 0 = no depth);
  optionally `accelerometer.txt` ("timestamp ax ay az"), `camera-intrinsics.txt` and
  `gravity-direction.txt`. Each colour frame is paired with the depth frame nearest in time if
  they are at most `max_difference` apart, else it is dropped and counted in
  `RgbdSequence.skipped` (a depth frame may pair with more than one colour frame). Its pose is
  interpolated from the ground truth at the colour time (translation linearly, rotation by
  slerp) when it lies within the ground truth's span and the two samples around it are at most
  `MAX_TRUTH_GAP` apart; otherwise it is NaN.

Frames: camera poses are `T_world_camera`, the camera's optical frame (x right, y down,
z forward) in the data set's world frame, which need not be gravity aligned: `gravity` gives
the direction of gravity in it. Depth stays in raw units (`depth_scale` per metre).

Loading reads the text files and the sizes of the first colour and depth images (from their
headers); `RgbdSequence.read` decodes a frame's images. Anything wrong (a missing file, a row
with the wrong number of columns, a non-number, a non-finite value, a time stamp that repeats
or goes backwards, an image that does not exist or is cut short, a pose that is not rigid) is
a `DataError` naming the file and, for text tables, the line (for images, the frame).

    seq = read_sequence("../shared/data/rgbd/7scenes_redkitchen")
    rgb, depth = seq.read(0)           # depth / seq.depth_scale: metres
    seq.T_world_camera[0]              # (4, 4) the first frame's optical frame in the world
"""

from __future__ import annotations

import logging
import math
import operator
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError
from scipy.spatial.transform import Rotation, Slerp
from tcaff_gtsam.mapping.camera import PinholeCamera, rigid_transform

from tcaff_gtsam.errors import ConfigError, DataError

from .image_files import read_image
from .text_tables import data_lines, number, read_table, read_text

__all__ = [
    "MAX_ACCEL_SCATTER_DEG",
    "MAX_FRAME_NUMBER",
    "MAX_TRUTH_GAP",
    "QUATERNION_TOL",
    "SEVEN_SCENES_INTRINSICS",
    "TUM_INTRINSICS",
    "RgbdSequence",
    "quaternion_norms",
    "read_7scenes",
    "read_sequence",
    "read_tum",
]

logger = logging.getLogger(__name__)

#: (fx, fy, cx, cy) pixels at 640 x 480: 7-Scenes' documented depth camera
SEVEN_SCENES_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
#: (fx, fy, cx, cy) pixels at 640 x 480 of the TUM RGB-D cameras, by the folder name's part;
#: None: the PrimeSense defaults, for folders that name no known camera
TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
    None: (525.0, 525.0, 319.5, 239.5),
}
#: s; ground-truth samples farther apart than this leave the frames between them without truth
#: (motion capture drops out; interpolating across a gap would invent a pose)
MAX_TRUTH_GAP = 0.1
#: the largest | |q| - 1 | of a ground-truth quaternion taken as rounding and normalised
QUATERNION_TOL = 1e-2
#: the largest 7-Scenes frame number (its files number six digits): a year of frames at 30 fps
MAX_FRAME_NUMBER = 999_999_999
#: degrees; accelerometer readings rotated into the world whose median angle to their mean is
#: larger than this do not agree, so they are not in the camera's axes
MAX_ACCEL_SCATTER_DEG = 10.0

_DEFAULT_SIZE = (640, 480)  # (width, height) pixels the default intrinsics are for
_SEVEN_KINDS = {"color.png": "color", "color.jpg": "color", "depth.png": "depth",
                "pose.txt": "pose"}
_SEVEN_FILE = re.compile(r"frame-(.*)\.(color\.png|color\.jpg|depth\.png|pose\.txt)")
_DIGITS = re.compile(r"[0-9]+")
_TUM_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt")
_NO_DEPTH_7SCENES = 65535  # 7-Scenes marks missing depth with 0 or this


@dataclass(frozen=True, eq=False)
class RgbdSequence:
    """A recorded RGB-D sequence: F frames of registered colour and depth with camera poses.

    Attributes:
        name: the folder's name.
        folder: where it was read from.
        layout: "7scenes" or "tum".
        camera: intrinsics of the colour and the depth images (treated as registered).
        depth_scale: raw depth units per metre (1000 for 7-Scenes, 5000 for TUM).
        times: (F,) float64 s, strictly increasing: 7-Scenes frame number / fps; TUM the colour
            image's time stamp.
        frame_ids: (F,) int64: 7-Scenes the number in the file names; TUM the 0-based row of
            the frame among the data rows (comments left out) of rgb.txt.
        color_paths, depth_paths: F image files each.
        T_world_camera: (F, 4, 4) float64: each frame's camera optical frame (x right, y down,
            z forward) in the world frame, metres; all NaN where there is no truth.
        gravity: (3,) float64 unit vector: the direction of gravity in the world frame.
        skipped: what was left out and how often, e.g. {"colour frames without depth within
            0.02 s": 3}; empty when nothing was.
    """

    name: str
    folder: Path
    layout: str
    camera: PinholeCamera
    depth_scale: float
    times: np.ndarray
    frame_ids: np.ndarray
    color_paths: tuple[Path, ...]
    depth_paths: tuple[Path, ...]
    T_world_camera: np.ndarray
    gravity: np.ndarray
    skipped: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        """F, the number of frames."""
        return len(self.times)

    def read(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(rgb (H, W, 3) uint8 RGB order, depth (H, W) uint16 raw units, 0 = none) of frame k
        (position, 0..F-1), with (H, W) the camera's.

        Raises:
            DataError: k not a position of a frame; an image missing, unreadable, cut short,
                of the wrong dtype, channels or size (naming the file and the frame id).
        """
        try:
            position = operator.index(k)
        except TypeError:
            position = None
        if position is None or isinstance(k, bool) or not 0 <= position < len(self):
            raise DataError(f"k = {k!r}: must be a frame position, an int in 0..{len(self) - 1}"
                            f" ({len(self)} frames)")
        try:
            rgb = _read_color(self.color_paths[position], self.camera)
            depth = _read_depth(self.depth_paths[position], self.camera)
        except DataError as exc:
            raise DataError(f"{exc} (frame {self.frame_ids[position]})") from None
        if self.layout == "7scenes":
            depth[depth == _NO_DEPTH_7SCENES] = 0
        return rgb, depth


# -- arguments ---------------------------------------------------------------------------------


def _folder(folder) -> Path:
    try:
        path = Path(folder)
    except TypeError:
        raise DataError(f"folder = {folder!r}: must be a path") from None
    if not path.is_dir():
        raise DataError(f"{path}: " + ("a file, not a folder" if path.exists()
                                       else "no such folder"))
    return path


def _positive(name: str, value, zero: bool = False) -> float:
    """`value` as a float if it is a finite number > 0 (>= 0 with `zero`); else DataError."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(value) and (value >= 0 if zero else value > 0)
    if not ok:
        raise DataError(f"{name} = {value!r}: must be a finite number {'>=' if zero else '>'} 0")
    return float(value)


def _unit(values: np.ndarray) -> np.ndarray | None:
    """values (3,) scaled to length 1, None if all zero (scaled first: tiny vectors have a
    direction too)."""
    peak = float(np.abs(values).max())
    if peak == 0.0:
        return None
    scaled = values / peak
    return scaled / np.linalg.norm(scaled)


def _gravity_argument(gravity) -> np.ndarray:
    rule = ("must be three finite numbers, not all zero: the direction of gravity in the world "
            "frame")
    try:
        values = np.array(gravity, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"gravity = {gravity!r}: {rule}") from None
    if values.shape != (3,) or not np.all(np.isfinite(values)) or isinstance(gravity, str):
        raise DataError(f"gravity = {gravity!r}: {rule}")
    unit = _unit(values)
    if unit is None:
        raise DataError(f"gravity = {gravity!r}: {rule}")
    return unit


# -- text files --------------------------------------------------------------------------------


def _check_increasing(path: Path, times: np.ndarray, lines: np.ndarray,
                      texts: list[str]) -> None:
    bad = np.flatnonzero(np.diff(times) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        how = "repeats" if times[k] == times[k - 1] else "goes backwards from"
        raise DataError(f"{path}:{lines[k]}: time stamp {times[k]:.6f} s {how} "
                        f"{times[k - 1]:.6f} s on line {lines[k - 1]}; time stamps must "
                        f"increase ({texts[k]!r})")


class _Listing:
    """Whether files exist, from one listing per folder (a data set names thousands)."""

    def __init__(self) -> None:
        self._names: dict[Path, set[str]] = {}

    def __contains__(self, path: Path) -> bool:
        parent = path.parent
        if parent not in self._names:
            try:
                self._names[parent] = {e.name for e in os.scandir(parent) if e.is_file()}
            except (OSError, ValueError):  # ValueError: a NUL in the name
                self._names[parent] = set()
        return path.name in self._names[parent]


def _image_list(path: Path, folder: Path) -> tuple[np.ndarray, tuple[Path, ...]]:
    """TUM's rgb.txt or depth.txt: times (k,) s strictly increasing, and the k image files."""
    lines, texts = data_lines(path)
    if not texts:
        raise DataError(f"{path}: no rows (expected lines of 'timestamp filename')")
    times, paths = np.empty(len(texts)), []
    listing = _Listing()
    for k, (line, text) in enumerate(zip(lines, texts, strict=True)):
        fields = text.split()
        if len(fields) != 2:
            raise DataError(f"{path}:{line}: expected 2 columns (timestamp filename), got "
                            f"{len(fields)} ({text!r})")
        try:
            times[k] = float(fields[0])
        except ValueError:
            raise DataError(f"{path}:{line}: not a number: {fields[0]!r} in {text!r}") from None
        if not math.isfinite(times[k]):
            raise DataError(f"{path}:{line}: non-finite time stamp {fields[0]!r} in {text!r}")
        image = folder / fields[1]
        if image not in listing:
            raise DataError(f"{path}:{line}: no such image {image} ({text!r})")
        paths.append(image)
    _check_increasing(path, times, np.array(lines), texts)
    return times, tuple(paths)


def _numbers(path: Path) -> tuple[list[float], list[int]]:
    """Every number of a small file, with its line; DataError naming file and line for a
    non-number or a non-finite value."""
    values, lines = [], []
    for line, text in zip(*data_lines(path), strict=True):
        for f in text.split():
            values.append(number(path, line, f, text))
            lines.append(line)
    return values, lines


def _gravity_file(path: Path) -> np.ndarray:
    """gravity-direction.txt: three numbers (one per line or on one line) -> (3,) unit."""
    values, _ = _numbers(path)
    if len(values) != 3:
        raise DataError(f"{path}: expected 3 numbers (the direction of gravity in the world "
                        f"frame), got {len(values)}")
    unit = _unit(np.array(values))
    if unit is None:
        raise DataError(f"{path}: the direction of gravity is all zeros")
    return unit


def _pose_file(path: Path) -> np.ndarray:
    """A 7-Scenes pose file: (4, 4) T_world_camera with an exactly orthonormal rotation."""
    rows = [line.split() for line in read_text(path).splitlines() if line.strip()]
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        raise DataError(f"{path}: expected a 4 x 4 matrix (4 rows of 4 numbers), got rows of "
                        f"{[len(r) for r in rows]} numbers")
    try:
        T = np.array(rows, dtype=float)
    except ValueError:
        word = next(f for r in rows for f in r if not _is_float(f))
        raise DataError(f"{path}: not a number: {word!r}") from None
    if not np.all(np.isfinite(T)):
        raise DataError(f"{path}: non-finite value in the pose {T.tolist()}")
    return rigid_transform(f"{path}: the pose", T, DataError)


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# -- images ------------------------------------------------------------------------------------


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) pixels from the image's header, without decoding it."""
    try:
        with Image.open(path) as image:
            return image.size
    except FileNotFoundError:
        raise DataError(f"{path}: no such image") from None
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError,
            Image.DecompressionBombError) as exc:  # a header claiming billions of pixels
        raise DataError(f"{path}: cannot read the image ({exc})") from exc


def _camera(folder: Path, default: tuple[float, float, float, float], default_name: str,
            color: Path, depth: Path) -> PinholeCamera:
    """The camera of a sequence: size from its first images, K from camera-intrinsics.txt or
    the layout's default (which holds for 640 x 480 only)."""
    size = _image_size(color)
    depth_size = _image_size(depth)
    if depth_size != size:
        raise DataError(f"{depth}: the depth image is {depth_size[0]} x {depth_size[1]} pixels "
                        f"but the colour image {color} is {size[0]} x {size[1]}; colour and "
                        "depth must have one size")
    path = folder / "camera-intrinsics.txt"
    if not path.exists():
        if size != _DEFAULT_SIZE:
            raise DataError(f"{color}: the image is {size[0]} x {size[1]} pixels but the "
                            f"{default_name} intrinsics are for {_DEFAULT_SIZE[0]} x "
                            f"{_DEFAULT_SIZE[1]}; give the camera's 3 x 3 K in {path}")
        return PinholeCamera(*size, *default)
    K, _, _ = read_table(path, 3, "3 x 3 K: fx 0 cx / 0 fy cy / 0 0 1")
    if K.shape != (3, 3):
        raise DataError(f"{path}: expected a 3 x 3 matrix K (3 rows of 3 numbers), got "
                        f"{K.shape[0]} rows")
    if not (abs(K[0, 1]) <= 1e-9 * abs(K[0, 0]) and K[1, 0] == 0
            and np.allclose(K[2], (0.0, 0.0, 1.0), rtol=0.0, atol=1e-9)):
        raise DataError(f"{path}: expected K = [[fx 0 cx] [0 fy cy] [0 0 1]], got "
                        f"{K.tolist()}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (0.0 <= cx <= size[0] and 0.0 <= cy <= size[1]):
        raise DataError(f"{path}: the principal point ({cx:g}, {cy:g}) lies outside the "
                        f"{size[0]} x {size[1]} pixel images (first: {color}); K is for "
                        "another image size")
    try:
        return PinholeCamera(*size, float(fx), float(fy), float(cx), float(cy))
    except ConfigError as exc:
        raise DataError(f"{path}: {exc}") from None


def _check_size(path: Path, image: np.ndarray, camera: PinholeCamera, what: str) -> None:
    if image.shape[:2] != camera.shape:
        raise DataError(f"{path}: the {what} image is {image.shape[1]} x {image.shape[0]} "
                        f"pixels; the sequence's camera is {camera.width} x {camera.height}")


def _read_color(path: Path, camera: PinholeCamera) -> np.ndarray:
    image = read_image(path, what="colour image")
    if image.dtype != np.uint8:
        raise DataError(f"{path}: the colour image has dtype {image.dtype}; expected uint8")
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise DataError(f"{path}: the colour image has shape {image.shape}; expected 3 "
                        "channels (BGR, or BGRA whose alpha is dropped)")
    _check_size(path, image, camera, "colour")
    code = cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGB
    return cv2.cvtColor(image, code)


def _read_depth(path: Path, camera: PinholeCamera) -> np.ndarray:
    image = read_image(path, what="depth image")
    if image.dtype != np.uint16 or image.ndim != 2:
        raise DataError(f"{path}: the depth image is {image.dtype} with shape {image.shape}; "
                        "expected one channel of uint16")
    _check_size(path, image, camera, "depth")
    return image


def _frozen(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


# -- 7-Scenes ----------------------------------------------------------------------------------


def read_7scenes(folder, gravity=None, fps: float = 30.0) -> RgbdSequence:
    """Read a 7-Scenes sequence folder (see the module's notes).

    Args:
        folder: the folder of frame-XXXXXX.* files.
        gravity: (3,) the direction of gravity in the world frame (normalised); None: from
            the folder's gravity-direction.txt.
        fps: frames per second of the recording (> 0): frame i was taken at i / fps s.
    Returns:
        The sequence, frames in order of their numbers; depth_scale 1000.
    Raises:
        DataError: the folder holds no frames; a frame number appears twice (e.g. a .png and
            a .jpg colour image); a frame lacks its colour image, depth image or pose (naming
            the missing file); a pose file is not 4 x 4 numbers or not a rigid transform; bad
            intrinsics; gravity unknown or not a direction; fps not finite > 0.
    """
    folder = _folder(folder)
    down = None if gravity is None else _gravity_argument(gravity)
    fps = _positive("fps", fps)
    files: dict[str, dict[int, Path]] = {"color": {}, "depth": {}, "pose": {}}
    digits: dict[int, str] = {}
    for entry in sorted(os.listdir(folder)):
        match = _SEVEN_FILE.fullmatch(entry)
        if match is None:
            continue
        number, kind = match.group(1), _SEVEN_KINDS[match.group(2)]
        if _DIGITS.fullmatch(number) is None:
            raise DataError(f"{folder / entry}: expected a frame number of digits after "
                            f"'frame-', got {number!r}")
        n = int(number)
        if n > MAX_FRAME_NUMBER:
            raise DataError(f"{folder / entry}: frame number {number} is beyond "
                            f"{MAX_FRAME_NUMBER} (a year of frames at 30 fps)")
        if n in files[kind]:
            raise DataError(f"{folder / entry}: frame {n} again ({files[kind][n].name} has the "
                            "same number); frame numbers must be unique")
        files[kind][n] = folder / entry
        digits.setdefault(n, number)
    ids = sorted(set().union(*files.values()))
    if not ids:
        raise DataError(f"{folder}: no 7-Scenes frames (frame-XXXXXX.color.png|jpg, "
                        "frame-XXXXXX.depth.png, frame-XXXXXX.pose.txt)")
    suffix = {"color": "color.png (or .color.jpg)", "depth": "depth.png", "pose": "pose.txt"}
    for n in ids:
        for kind, found in files.items():
            if n not in found:
                present = ", ".join(files[k][n].name for k in files if n in files[k])
                raise DataError(f"{folder / f'frame-{digits[n]}.{suffix[kind]}'}: no such "
                                f"file; frame {n} has only {present}")
    frame_ids = np.array(ids, dtype=np.int64)
    times = frame_ids / fps
    if not (np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)):
        raise DataError(f"fps = {fps!r}: gives frame times that are not finite and distinct")
    T = np.stack([_pose_file(files["pose"][n]) for n in ids])
    if down is None:
        path = folder / "gravity-direction.txt"
        if not path.exists():
            raise DataError(f"{folder}: gravity is unknown: put the direction of gravity in "
                            f"the world frame (three numbers) in {path}, or pass it as the "
                            "`gravity` argument")
        down = _gravity_file(path)
    color = tuple(files["color"][n] for n in ids)
    depth = tuple(files["depth"][n] for n in ids)
    camera = _camera(folder, SEVEN_SCENES_INTRINSICS, "7-Scenes", color[0], depth[0])
    return RgbdSequence(folder.resolve().name, folder, "7scenes", camera, 1000.0,
                        _frozen(times), _frozen(frame_ids), color, depth, _frozen(T),
                        _frozen(down))


# -- TUM RGB-D ---------------------------------------------------------------------------------


def _associate(color_times: np.ndarray, depth_times: np.ndarray,
               max_difference: float) -> np.ndarray:
    """(F,) int64: for each colour time the index of the nearest depth time (the earlier one
    on a tie), -1 where it is more than max_difference s away. Both inputs increase."""
    n = len(depth_times)
    after = np.searchsorted(depth_times, color_times)
    lo, hi = np.clip(after - 1, 0, n - 1), np.clip(after, 0, n - 1)
    d_lo, d_hi = np.abs(depth_times[lo] - color_times), np.abs(depth_times[hi] - color_times)
    best = np.where(d_hi < d_lo, hi, lo)
    return np.where(np.minimum(d_lo, d_hi) <= max_difference, best, -1)


def _interpolate(times: np.ndarray, rotations: Rotation, positions: np.ndarray,
                 at: np.ndarray) -> np.ndarray:
    """(q, 4, 4) poses at `at` [s] from samples at `times` (strictly increasing): positions
    linear, rotations by slerp; all NaN outside the samples' span or between two samples more
    than `MAX_TRUTH_GAP` apart."""
    T = np.full((len(at), 4, 4), np.nan)
    n = len(times)
    j = np.searchsorted(times, at, side="right") - 1  # times[j] <= at
    inside = (j >= 0) & (at <= times[-1])
    j = np.clip(j, 0, n - 1)
    k = np.minimum(j + 1, n - 1)
    exact = inside & (times[j] == at)
    gap = times[k] - times[j]
    # a microsecond of slack: time stamps near 1.3e9 s hold about 2e-7 s, so samples stamped
    # 0.1 s apart may differ by a little more in float64
    between = inside & ~exact & (gap <= MAX_TRUTH_GAP + 1e-6)
    use = np.flatnonzero(exact | between)
    if use.size == 0:
        return T
    j, k = j[use], k[use]
    alpha = np.where(between[use], (at[use] - times[j]) / np.where(gap[use] > 0, gap[use], 1.0),
                     0.0)
    # a single sample has nothing to slerp between (only queries at its time are used)
    R = rotations[j] if n == 1 else Slerp(times, rotations)(at[use])
    T[use, :3, :3] = R.as_matrix()
    T[use, :3, 3] = positions[j] + alpha[:, None] * (positions[k] - positions[j])
    T[use, 3] = (0.0, 0.0, 0.0, 1.0)
    return T


def _ground_truth(path: Path) -> tuple[np.ndarray, Rotation, np.ndarray]:
    """groundtruth.txt: times (g,) s, rotations (g,) and positions (g, 3) m."""
    header = "timestamp tx ty tz qx qy qz qw"
    rows, lines, texts = read_table(path, 8, header)
    _check_increasing(path, rows[:, 0], lines, texts)
    q = rows[:, 4:8]
    norm = quaternion_norms(q)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUATERNION_TOL)
    if bad.size:
        k = int(bad[0])
        raise DataError(f"{path}:{lines[k]}: the quaternion (qx qy qz qw) has norm "
                        f"{norm[k]:.6g}, off 1 by {abs(norm[k] - 1.0):.3g} (at most "
                        f"{QUATERNION_TOL:g}) ({texts[k]!r})")
    # scipy's order is TUM's: x, y, z, w
    return rows[:, 0], Rotation.from_quat(q / norm[:, None]), rows[:, 1:4]


def quaternion_norms(q: np.ndarray) -> np.ndarray:
    """(n,) norms of the finite quaternions q (n, 4), scaled by each one's largest component
    first: the norm of 1e200s would overflow (and be taken for inf)."""
    peak = np.abs(q).max(axis=1)
    return np.linalg.norm(q / np.where(peak > 0, peak, 1.0)[:, None], axis=1) * peak


def _gravity_from_accelerometer(path: Path, truth: tuple[np.ndarray, Rotation, np.ndarray]
                                ) -> np.ndarray:
    """(3,) unit: the direction of gravity in the world from accelerometer.txt, its readings
    taken as in the colour camera's optical frame (see `read_tum`)."""
    rows, lines, texts = read_table(path, 4, "timestamp ax ay az")
    _check_increasing(path, rows[:, 0], lines, texts)
    T = _interpolate(*truth, rows[:, 0])
    usable = np.isfinite(T[:, 0, 0]) & np.any(rows[:, 1:4] != 0, axis=1)
    if not usable.any():
        raise DataError(f"{path}: no reading lies within the ground truth's span (with samples "
                        f"at most {MAX_TRUTH_GAP:g} s apart), so gravity is unknown; put its "
                        f"direction in the world frame in {path.parent / 'gravity-direction.txt'}"
                        " or pass the `gravity` argument")
    # at rest an accelerometer reads the reaction to gravity: up, so gravity is -a. Scaled by
    # the largest reading (all of them alike: the mean's direction stays) or each by its own
    # (the directions), the rotations and the sum cannot overflow
    R, a = T[usable, :3, :3], rows[usable, 1:4]
    mean = _unit(-np.einsum("kij,kj->ki", R, a / np.abs(a).max()).mean(axis=0))
    down = -np.einsum("kij,kj->ki", R, a / np.abs(a).max(axis=1, keepdims=True))
    directions = down / np.linalg.norm(down, axis=1, keepdims=True)
    if mean is None:
        scatter = 180.0
    else:
        scatter = float(np.degrees(np.median(np.arccos(np.clip(directions @ mean, -1, 1)))))
    if not scatter <= MAX_ACCEL_SCATTER_DEG:
        raise DataError(f"{path}: the accelerometer readings do not agree in the world frame "
                        f"(median angle to their mean {scatter:.1f} deg, at most "
                        f"{MAX_ACCEL_SCATTER_DEG:g}), so their axes are not the colour "
                        "camera's optical axes; give the direction of gravity in the world "
                        "frame as the `gravity` argument (or in "
                        f"{path.parent / 'gravity-direction.txt'})")
    return mean


def read_tum(folder, gravity=None, max_difference: float = 0.02) -> RgbdSequence:
    """Read a TUM RGB-D sequence folder (see the module's notes).

    Gravity comes from the `gravity` argument; else from gravity-direction.txt in the folder;
    else from accelerometer.txt. For the last, the readings are ASSUMED to be in the colour
    camera's optical frame (x right, y down, z forward), m/s^2: an accelerometer at rest
    measures the reaction to gravity, pointing up, so each reading within the ground truth's
    span is rotated into the world with the interpolated pose and gravity is the normalised
    mean of -R_world_camera a. If the rotated directions scatter by more than
    `MAX_ACCEL_SCATTER_DEG` (median angle to their mean) the assumption does not hold (the
    readings are in another sensor's axes) and a DataError asks for `gravity`.

    Args:
        folder: the folder of rgb.txt, depth.txt and groundtruth.txt.
        gravity: (3,) the direction of gravity in the world frame (normalised), or None.
        max_difference: s (>= 0); a colour frame without a depth frame this close is dropped.
    Returns:
        The sequence: one frame per colour image with a depth image within max_difference, in
        order of time; frames outside the ground truth or in its gaps have NaN poses;
        depth_scale 5000. Intrinsics: camera-intrinsics.txt if present, else by the folder's
        name (`TUM_INTRINSICS`).
    Raises:
        DataError: a required file missing (naming them); a bad row (naming file and line: wrong
            column count, non-number, non-finite value, time stamp repeated or going back, an
            image that does not exist, a quaternion whose norm is off 1 by more than
            `QUATERNION_TOL`); no colour frame with depth; image size not the camera's; gravity
            unknown or not a direction; max_difference not finite >= 0.
    """
    folder = _folder(folder)
    down = None if gravity is None else _gravity_argument(gravity)
    max_difference = _positive("max_difference", max_difference, zero=True)
    missing = [str(folder / name) for name in _TUM_FILES if not (folder / name).is_file()]
    if missing:
        raise DataError(f"{folder}: missing {', '.join(missing)} (a TUM RGB-D folder holds "
                        f"{', '.join(_TUM_FILES)})")
    color_times, color_paths = _image_list(folder / "rgb.txt", folder)
    depth_times, depth_paths = _image_list(folder / "depth.txt", folder)
    truth = _ground_truth(folder / "groundtruth.txt")
    pair = _associate(color_times, depth_times, max_difference)
    keep = np.flatnonzero(pair >= 0)
    if keep.size == 0:
        raise DataError(f"{folder}: no colour frame of rgb.txt has a depth frame of depth.txt "
                        f"within max_difference = {max_difference:g} s")
    skipped = {}
    if keep.size < len(pair):
        skipped[f"colour frames without depth within {max_difference:g} s"] = (
            len(pair) - keep.size)
    times = color_times[keep]
    T = _interpolate(*truth, times)
    without = int(np.sum(np.isnan(T[:, 0, 0])))
    if without:
        logger.info("%s: %d of %d frames have no ground truth (NaN poses)", folder, without,
                    len(times))
    if down is None:
        if (folder / "gravity-direction.txt").exists():
            down = _gravity_file(folder / "gravity-direction.txt")
        elif (folder / "accelerometer.txt").exists():
            down = _gravity_from_accelerometer(folder / "accelerometer.txt", truth)
        else:
            raise DataError(f"{folder}: gravity is unknown (no gravity-direction.txt, no "
                            "accelerometer.txt): put the direction of gravity in the world "
                            f"frame (three numbers) in {folder / 'gravity-direction.txt'}, or "
                            "pass it as the `gravity` argument")
    name = folder.resolve().name
    found = re.search(r"freiburg[123]", name)
    default = TUM_INTRINSICS[found.group(0) if found else None]
    label = f"TUM {found.group(0)}" if found else "PrimeSense default"
    color = tuple(color_paths[k] for k in keep)
    depth = tuple(depth_paths[k] for k in pair[keep])
    camera = _camera(folder, default, label, color[0], depth[0])
    return RgbdSequence(name, folder, "tum", camera, 5000.0, _frozen(times),
                        _frozen(keep.astype(np.int64)), color, depth, _frozen(T),
                        _frozen(down), skipped)


# -- either ------------------------------------------------------------------------------------


def read_sequence(folder, gravity=None, fps: float = 30.0) -> RgbdSequence:
    """Read a 7-Scenes or TUM RGB-D folder, whichever it is (see `read_7scenes`, `read_tum`;
    fps is 7-Scenes' only: TUM stores time stamps).

    Raises:
        DataError: the folder is neither (naming it and what each layout holds) or both; and
            whatever the layout's loader raises.
    """
    folder = _folder(folder)
    tum = any((folder / name).is_file() for name in _TUM_FILES)
    seven = any(_SEVEN_FILE.fullmatch(entry) for entry in os.listdir(folder))
    if tum and seven:
        raise DataError(f"{folder}: holds both 7-Scenes frames (frame-*) and TUM RGB-D lists "
                        f"({', '.join(_TUM_FILES)}); use read_7scenes or read_tum")
    if seven:
        return read_7scenes(folder, gravity, fps)
    if tum:
        _positive("fps", fps)
        return read_tum(folder, gravity)
    raise DataError(f"{folder}: neither a 7-Scenes sequence (frame-XXXXXX.color.png|jpg, "
                    "frame-XXXXXX.depth.png, frame-XXXXXX.pose.txt) nor a TUM RGB-D sequence "
                    f"({', '.join(_TUM_FILES)})")
