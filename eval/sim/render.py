"""Rendered RGB-D: boxes and cylinders on a floor between walls (and under an optional
ceiling), ray-cast with Open3D.

`RgbdScene` holds the solids as triangle meshes in an Open3D `RaycastingScene`. `render` casts
one ray per pixel from a camera pose and returns what an RGB-D camera with perfect registration
would give: depth along the optical axis, the ground-truth instance of every pixel, and a simply
shaded colour image. Optional depth noise grows with the square of range, like a stereo or
structured-light sensor, and an optional band along the image edges has no depth, like the
edges of a real sensor's registered depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from tcaff_gtsam.mapping.camera import PinholeCamera, rigid_transform

from tcaff_gtsam.errors import DataError

from . import threads
from .threads import cast_threads
from .world import World

__all__ = ["CYLINDER_KINDS", "RgbdFrame", "RgbdScene", "cast_threads", "render"]

#: World object classes drawn as upright cylinders; every other class is drawn as a box.
CYLINDER_KINDS = frozenset({"pole", "tree", "bin"})

_WALL_THICKNESS = 0.1  # metres
_FLOOR_MARGIN = 5.0  # metres of floor beyond the outermost solid
_CYLINDER_SEGMENTS = 48
_LIGHT = np.array([0.3, 0.5, 0.81])  # unit vector towards the light, world frame
_FLOOR_RGB = (150, 150, 150)
_WALL_RGB = (205, 195, 170)
_CEILING_RGB = (235, 235, 228)


@dataclass(frozen=True)
class RgbdFrame:
    """One rendered frame.

    Attributes:
        rgb: (H, W, 3) uint8 colour, RGB order.
        depth: (H, W) float32 metres along the optical axis, 0 where no surface is hit and
            in the blanked band along the edges.
        instance: (H, W) int32, 1 + the index of the object each pixel shows, 0 for floor,
            ceiling, walls and empty space (also where the depth is blanked: the colour
            camera still sees the object there).
    """

    rgb: np.ndarray
    depth: np.ndarray
    instance: np.ndarray


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _box(size: tuple[float, float, float], centre: tuple[float, float, float],
         yaw: float = 0.0) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    mesh.translate(-np.asarray(size) / 2)
    mesh.rotate(_yaw(yaw), center=np.zeros(3))
    return mesh.translate(centre)


def _cylinder(diameter: float, height: float, xy: np.ndarray) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_cylinder(diameter / 2, height, _CYLINDER_SEGMENTS)
    return mesh.translate((xy[0], xy[1], height / 2))


class RgbdScene:
    """Solids standing on a floor (z = 0, z up) in the world frame, ready to ray-cast.

    Args:
        xy: (n, 2) metres, object centres on the floor.
        widths: (n,) metres, box side lengths or cylinder diameters.
        heights: (n,) metres.
        cylinders: (n,) bool, which objects are cylinders (the others are boxes).
        yaws: (n,) radians, box headings (default 0).
        walls: (m, 2, 2) metres, wall segments on the floor.
        wall_height: metres, also the height of the ceiling.
        floor: whether to add the floor.
        ceiling: whether to add a ceiling at `wall_height` over the floor's extent.
    """

    def __init__(self, xy, widths, heights, cylinders=None, yaws=None,
                 walls=None, wall_height: float = 2.5, floor: bool = True,
                 ceiling: bool = False) -> None:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        n = xy.shape[0]
        widths = np.asarray(widths, dtype=float).reshape(-1)
        heights = np.asarray(heights, dtype=float).reshape(-1)
        cylinders = (np.zeros(n, bool) if cylinders is None
                     else np.asarray(cylinders, dtype=bool).reshape(-1))
        yaws = np.zeros(n) if yaws is None else np.asarray(yaws, dtype=float).reshape(-1)
        walls = np.zeros((0, 2, 2)) if walls is None else np.asarray(walls, float).reshape(-1, 2, 2)
        for name, a in (("widths", widths), ("heights", heights), ("cylinders", cylinders),
                        ("yaws", yaws)):
            if a.shape != (n,):
                raise DataError(f"RgbdScene.{name} has shape {a.shape}; expected ({n},)")
        finite = all(np.all(np.isfinite(a)) for a in (xy, widths, heights, yaws, walls))
        if not finite or np.any(widths <= 0) or np.any(heights <= 0):
            raise DataError("RgbdScene: positions must be finite and sizes > 0")
        if ceiling and not (np.isfinite(wall_height) and wall_height > 0):
            raise DataError(f"RgbdScene.wall_height = {wall_height}: a ceiling needs a finite "
                            "height > 0 metres")
        self.xy, self.widths, self.heights = xy, widths, heights
        self.cylinders, self.yaws, self.walls = cylinders, yaws, walls
        self.wall_height, self.floor, self.ceiling = wall_height, floor, ceiling

        self._scene = o3d.t.geometry.RaycastingScene()
        # geometry id -> instance (0: floor, ceiling or wall), and its base colour
        instance_of, colour_of = [], []

        def add(mesh: o3d.geometry.TriangleMesh, instance: int, rgb) -> None:
            gid = self._scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
            assert gid == len(instance_of)  # ids are handed out in order
            instance_of.append(instance)
            colour_of.append(rgb)

        palette = np.random.default_rng(7).integers(40, 230, (max(n, 1), 3))
        for k in range(n):
            if cylinders[k]:
                mesh = _cylinder(widths[k], heights[k], xy[k])
            else:
                mesh = _box((widths[k], widths[k], heights[k]),
                            (xy[k, 0], xy[k, 1], heights[k] / 2), yaws[k])
            add(mesh, k + 1, palette[k])
        for (a, b) in walls:
            d = b - a
            length = float(np.hypot(*d))
            if length > 0:
                centre = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2, wall_height / 2)
                add(_box((length, _WALL_THICKNESS, wall_height), centre,
                         float(np.arctan2(d[1], d[0]))), 0, _WALL_RGB)
        pts = np.vstack([xy, walls.reshape(-1, 2), np.zeros((1, 2))])
        lo, hi = pts.min(axis=0) - _FLOOR_MARGIN, pts.max(axis=0) + _FLOOR_MARGIN
        for z, rgb, wanted in ((-0.005, _FLOOR_RGB, floor),
                               (wall_height + 0.005, _CEILING_RGB, ceiling)):
            if wanted:  # a 1 cm slab whose inner face is at z = 0 or z = wall_height
                centre = ((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, z)
                add(_box((hi[0] - lo[0], hi[1] - lo[1], 0.01), centre), 0, rgb)
        # one extra row for rays that hit nothing (Open3D reports an invalid id)
        self._instance_of = np.asarray([*instance_of, 0], dtype=np.int32)
        self._colour_of = np.asarray([*colour_of, (0, 0, 0)], dtype=float)
        # camera -> (H, W, 3) every pixel's ray direction in the optical frame (`cast`)
        self._directions: dict[PinholeCamera, np.ndarray] = {}

    def __len__(self) -> int:
        return self.xy.shape[0]

    @classmethod
    def from_world(cls, world: World, wall_height: float = 2.5,
                   yaws=None, ceiling: bool = False) -> RgbdScene:
        """A world's objects, classes in `CYLINDER_KINDS` as cylinders, and its walls."""
        cylinders = np.isin(world.kinds, list(CYLINDER_KINDS))
        return cls(world.xy, world.widths, world.heights, cylinders, yaws, world.walls,
                   wall_height, ceiling=ceiling)

    def cast(self, T_world_camera: np.ndarray, camera: PinholeCamera) -> dict[str, np.ndarray]:
        """Raw ray-cast results for every pixel: `depth` (H, W) metres along the optical axis
        (inf for a miss), `geometry` (H, W) index into the scene's solids, `normal` (H, W, 3)."""
        T = rigid_transform("T_world_camera", T_world_camera)
        if camera not in self._directions:
            # Directions with unit optical-z component make the hit distance the depth itself.
            x_over_z, y_over_z = camera.rays()
            self._directions[camera] = np.stack([x_over_z, y_over_z, np.ones(camera.shape)],
                                                axis=-1)
        # (H, W, 6) float32 rays, origin and direction in the world frame, each rounded once
        # from float64
        rays = np.empty((*camera.shape, 6), dtype=np.float32)
        rays[..., :3] = T[:3, 3]
        rays[..., 3:] = self._directions[camera] @ T[:3, :3].T
        hit = self._scene.cast_rays(o3d.core.Tensor(rays), nthreads=threads.per_cast)
        depth = hit["t_hit"].numpy()
        geometry = hit["geometry_ids"].numpy().astype(np.int64)
        missed = ~np.isfinite(depth)
        geometry[missed] = len(self._instance_of) - 1
        return {"depth": depth, "geometry": geometry,
                "normal": hit["primitive_normals"].numpy()}

    def instance_of(self, geometry: np.ndarray) -> np.ndarray:
        """Instance ids (0: floor, ceiling, wall or nothing) of geometry indices from `cast`."""
        return self._instance_of[geometry]

    def colour_of(self, geometry: np.ndarray) -> np.ndarray:
        """(..., 3) float base colours (0-255) of geometry indices from `cast`."""
        return self._colour_of[geometry]


def render(scene: RgbdScene, T_world_camera: np.ndarray, camera: PinholeCamera,
           depth_noise: float = 0.0, rng: np.random.Generator | None = None,
           depth_max: float = 10.0, invalid_border=0) -> RgbdFrame:
    """Render one RGB-D frame.

    Args:
        T_world_camera: (4, 4) the camera's optical frame (x right, y down, z forward) in the
            world frame.
        depth_noise: metres of depth noise standard deviation at 1 m range; it grows with the
            square of the range. 0 for exact depth.
        rng: random generator for the noise (required when depth_noise > 0).
        depth_max: metres; farther surfaces give no return (depth 0).
        invalid_border: pixels along the image edges without depth (depth 0), as a real
            sensor's registered depth has: one int for every edge or (top, bottom, left,
            right). Colour and instance ids are unchanged there.
    """
    if not depth_noise >= 0 or (depth_noise > 0 and rng is None):  # NaN fails too
        raise DataError(f"render: depth_noise = {depth_noise} needs to be >= 0 and, when > 0, "
                        "an rng")
    top, bottom, left, right = _border_band(invalid_border)
    hit = scene.cast(T_world_camera, camera)
    depth = hit["depth"].astype(np.float32)
    valid = np.isfinite(depth) & (depth <= depth_max)
    depth[~valid] = 0.0
    if depth_noise > 0:
        depth += (depth_noise * depth**2 * rng.standard_normal(depth.shape)).astype(np.float32)
        depth[depth < 0] = 0.0
    H, W = depth.shape
    depth[:top], depth[H - bottom:], depth[:, :left], depth[:, W - right:] = 0.0, 0.0, 0.0, 0.0
    instance = scene.instance_of(hit["geometry"])
    # Lambertian shading with some ambient light; the floor and walls are shaded the same way.
    lambert = np.abs(hit["normal"] @ _LIGHT)
    shaded = scene.colour_of(hit["geometry"])  # (H, W, 3) base colours, a fresh array
    shaded *= (0.35 + 0.65 * lambert)[..., None]
    rgb = np.clip(shaded, 0, 255, out=shaded).astype(np.uint8)
    return RgbdFrame(rgb, depth, instance)


def _border_band(invalid_border) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) pixels of `render`'s invalid_border, or DataError."""
    many = isinstance(invalid_border, list | tuple) or np.ndim(invalid_border) == 1
    widths = tuple(invalid_border) if many else (invalid_border,) * 4
    if len(widths) != 4 or not all(isinstance(w, int | np.integer) and not isinstance(w, bool)
                                   and w >= 0 for w in widths):
        raise DataError(f"render: invalid_border = {invalid_border!r} must be an int >= 0 "
                        "pixels or four of them (top, bottom, left, right)")
    return tuple(int(w) for w in widths)
