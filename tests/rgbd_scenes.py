"""Shared helpers of the RGB-D tests: rendered rooms, camera poses and ground-truth geometry.

Everything here is computed from the scene description alone (positions, sizes, poses), never
from the mapping code under test, so the tests can compare the code against it.
"""

from __future__ import annotations

import math

import numpy as np
from tcaff_gtsam.eval.sim.render import RgbdScene
from tcaff_gtsam.eval.sim.world import room_walls
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera

from tcaff_gtsam.geometry import se3_from_xyz_yaw

#: The camera of the acceptance tests: 640 x 480, 87 deg horizontal field of view.
CAMERA = PinholeCamera.from_fov(640, 480, 87)
#: The small camera of the (slower) trajectory tests.
SMALL_CAMERA = PinholeCamera.from_fov(320, 240, 87)
#: 0.6 m above the body origin, looking 5 deg down.
T_BC = T_body_camera(0.6, 5)

ROOM = (0.0, 0.0, 10.0, 8.0)  # x0, y0, x1, y1 in metres


def camera_pose(x: float, y: float, yaw: float, T_bc: np.ndarray = T_BC) -> np.ndarray:
    """(4, 4) T_world_camera of a robot at (x, y) heading `yaw` with the camera at `T_bc`."""
    return se3_from_xyz_yaw(x, y, 0.0, yaw) @ T_bc


def half_extent(width: float, cylinder: bool) -> float:
    """Largest horizontal distance of an object's surface from its centre (any box yaw)."""
    return width / 2 if cylinder else width / math.sqrt(2)


def random_room(rng: np.random.Generator, n: int, room=ROOM, gap: float = 1.0,
                widths=(0.3, 0.7), heights=(0.4, 1.4), max_tries: int = 2000) -> RgbdScene:
    """A walled room with n random boxes (random yaw) and cylinders whose surfaces are at least
    `gap` metres from each other and from the walls."""
    x0, y0, x1, y1 = room
    xy, ws, hs, cyl, yaws = [], [], [], [], []
    for _ in range(max_tries):
        if len(xy) == n:
            break
        w = rng.uniform(*widths)
        c = bool(rng.random() < 0.5)
        e = half_extent(w, c)
        p = rng.uniform((x0 + gap + e, y0 + gap + e), (x1 - gap - e, y1 - gap - e))
        if all(np.hypot(*(p - q)) >= gap + e + half_extent(wq, cq)
               for q, wq, cq in zip(xy, ws, cyl, strict=True)):
            xy.append(p)
            ws.append(w)
            hs.append(rng.uniform(*heights))
            cyl.append(c)
            yaws.append(rng.uniform(0, np.pi / 2))
    assert len(xy) == n, "could not place the objects"
    return RgbdScene(np.array(xy), ws, hs, cyl, yaws, walls=room_walls(*room))


def solo(scene: RgbdScene, k: int) -> RgbdScene:
    """The same room holding only object k (for telling whether k is occluded)."""
    return RgbdScene(scene.xy[k:k + 1], scene.widths[k:k + 1], scene.heights[k:k + 1],
                     scene.cylinders[k:k + 1], scene.yaws[k:k + 1], walls=scene.walls,
                     wall_height=scene.wall_height, floor=scene.floor, ceiling=scene.ceiling)


def free_pose(rng: np.random.Generator, scene: RgbdScene, room=ROOM, clearance: float = 0.7,
              max_tries: int = 1000) -> tuple[float, float, float]:
    """A random robot (x, y, yaw) in the room, `clearance` metres from every object's surface
    and 0.5 m from the walls."""
    x0, y0, x1, y1 = room
    for _ in range(max_tries):
        p = rng.uniform((x0 + 0.5, y0 + 0.5), (x1 - 0.5, y1 - 0.5))
        if all(np.hypot(*(p - q)) >= clearance + half_extent(w, c)
               for q, w, c in zip(scene.xy, scene.widths, scene.cylinders, strict=True)):
            return float(p[0]), float(p[1]), float(rng.uniform(-np.pi, np.pi))
    raise AssertionError("no free pose")


def touches_border(mask: np.ndarray, margin: int = 3) -> bool:
    """Whether a (H, W) mask has a pixel within `margin` pixels of the image edge."""
    return bool(mask[:margin].any() or mask[-margin:].any() or mask[:, :margin].any()
                or mask[:, -margin:].any())


def bbox_size(mask: np.ndarray) -> tuple[int, int]:
    """(rows, cols) spanned by a non-empty mask's bounding box."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return int(rows[-1] - rows[0] + 1), int(cols[-1] - cols[0] + 1)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0


def cylinder_visible_centroid(axis_xy, radius: float, height: float, camera_xy) -> np.ndarray:
    """Area-weighted centroid of an upright cylinder's side surface seen from `camera_xy`
    (camera below its top, whole height in view): on the line from the axis to the camera, at
    r sin(a) / a from the axis with cos(a) = r / d, at half height."""
    axis_xy, camera_xy = np.asarray(axis_xy, float), np.asarray(camera_xy, float)
    towards = camera_xy - axis_xy
    d = float(np.hypot(*towards))
    a = math.acos(radius / d)
    xy = axis_xy + towards / d * radius * math.sin(a) / a
    return np.array([xy[0], xy[1], height / 2])


def box_face_centre(centre_xy, width: float, height: float, camera_xy) -> np.ndarray:
    """Centre of the face of a box that squarely faces `camera_xy` (the camera lies on the
    face's normal through the box centre)."""
    centre_xy, camera_xy = np.asarray(centre_xy, float), np.asarray(camera_xy, float)
    towards = camera_xy - centre_xy
    xy = centre_xy + towards / np.hypot(*towards) * width / 2
    return np.array([xy[0], xy[1], height / 2])


def majority_instance(instance: np.ndarray, mask: np.ndarray) -> int:
    """The ground-truth instance most of a mask's pixels show."""
    return int(np.bincount(instance[mask]).argmax())


def pose_facing(rng: np.random.Generator, scene: RgbdScene, k: int, distance=(1.2, 5.0),
                max_yaw_offset: float = math.radians(25), room=ROOM, clearance: float = 0.7,
                max_tries: int = 1000) -> tuple[float, float, float]:
    """A random free robot (x, y, yaw) at a random distance from object k's centre, heading
    towards it give or take `max_yaw_offset`."""
    x0, y0, x1, y1 = room
    for _ in range(max_tries):
        bearing = rng.uniform(-np.pi, np.pi)
        p = scene.xy[k] + rng.uniform(*distance) * np.array([np.cos(bearing), np.sin(bearing)])
        if not (x0 + 0.5 < p[0] < x1 - 0.5 and y0 + 0.5 < p[1] < y1 - 0.5):
            continue
        if all(np.hypot(*(p - q)) >= clearance + half_extent(w, c)
               for q, w, c in zip(scene.xy, scene.widths, scene.cylinders, strict=True)):
            yaw = bearing + np.pi + rng.uniform(-max_yaw_offset, max_yaw_offset)
            return float(p[0]), float(p[1]), float(yaw)
    raise AssertionError("no free pose facing the object")
