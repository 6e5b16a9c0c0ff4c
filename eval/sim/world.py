"""Object-level worlds: where objects stand and how big they are, in the world frame.

A `World` is a plain set of arrays. Builders place objects at random in a rectangle, on a regular
grid or along both sides of a path; `combine` joins them. Walls are kept for plotting only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import point_array

from .maps import MAX_OBJECTS, OBJECT_CLASSES, _grid_size
from .sizes import amount, count

__all__ = ["World", "along_path", "combine", "grid", "scatter"]


@dataclass(frozen=True, eq=False)
class World:
    """Static objects in the world frame (z up, the floor at z = 0).

    Attributes:
        xy: (n, 2) metres, object centres on the floor plane.
        widths: (n,) metres, horizontal extents; heights: (n,) metres, vertical extents.
        kinds: (n,) str, object classes (keys of `OBJECT_CLASSES` or "grid").
        walls: (m, 2, 2) metres, wall segments drawn in figures.
    """

    xy: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    kinds: np.ndarray
    walls: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))

    def __len__(self) -> int:
        return self.xy.shape[0]

    @property
    def centroids(self) -> np.ndarray:
        """(n, 3) metres, object centroids (standing on the floor)."""
        return np.column_stack([self.xy, self.heights / 2])


def _sizes(rng: np.random.Generator, kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Log-uniform widths and heights within each object's class ranges."""
    ranges = np.array([OBJECT_CLASSES[k] for k in kinds]).reshape(-1, 2, 2)
    lo, hi = np.log(ranges[:, :, 0]), np.log(ranges[:, :, 1])
    size = np.exp(rng.uniform(lo, hi))
    return size[:, 0], size[:, 1]


def scatter(rng: np.random.Generator, n: int, bounds: tuple[float, float, float, float],
            classes: tuple[str, ...] = ("box",), min_gap: float = 0.8) -> World:
    """`n` objects of the given classes placed uniformly in a rectangle, at least `min_gap`
    metres apart (centre to centre) where the space allows.

    Args:
        n: an int in [0, MAX_OBJECTS].
        bounds: (x_min, y_min, x_max, y_max) metres.
    """
    n = count("scatter", "n", n, MAX_OBJECTS, "MAX_OBJECTS")
    unknown = sorted(set(classes) - set(OBJECT_CLASSES))
    if unknown:
        raise DataError(f"scatter: need known classes, got unknown classes {unknown}")
    x0, y0, x1, y1 = bounds
    xy = np.zeros((0, 2))
    for _ in range(50 * max(n, 1)):  # rejection sampling; 50 tries per object is plenty
        if len(xy) == n:
            break
        p = rng.uniform((x0, y0), (x1, y1))
        if len(xy) == 0 or np.min(np.linalg.norm(xy - p, axis=1)) >= min_gap:
            xy = np.vstack([xy, p])
    if len(xy) < n:
        raise DataError(f"scatter: cannot place {n} objects {min_gap} m apart in {bounds}")
    kinds = np.asarray(classes)[rng.integers(len(classes), size=n)]
    widths, heights = _sizes(rng, kinds)
    return World(xy, widths, heights, kinds)


def grid(rows: int, cols: int, spacing: float, size: float,
         origin: tuple[float, float] = (0.0, 0.0)) -> World:
    """rows x cols identical objects `spacing` metres apart, the first at `origin`; rows and
    cols ints >= 1, rows x cols at most MAX_OBJECTS (DataError otherwise)."""
    rows, cols = _grid_size("grid", rows, cols)
    ij = np.argwhere(np.ones((rows, cols), dtype=bool)).astype(float)
    n = len(ij)
    return World(np.asarray(origin) + spacing * ij[:, ::-1], np.full(n, size), np.full(n, size),
                 np.full(n, "grid"))


def along_path(rng: np.random.Generator, path: np.ndarray, per_100m: float,
               lateral: tuple[float, float], classes: tuple[str, ...]) -> World:
    """Objects on both sides of a polyline, `per_100m` of them per 100 m of path, each between
    lateral[0] and lateral[1] metres from it.

    Args:
        path: (m, 2) metres, the polyline's vertices.
        per_100m: a finite number >= 0; per_100m x length / 100 (the mean number of objects
            drawn) at most MAX_OBJECTS.
    Raises:
        DataError: a path that is not finite (m, 2) points, per_100m not a finite number >= 0
            or asking for more than MAX_OBJECTS objects on the path.
    """
    o = "along_path"
    path = point_array(o, "path", path, 2)
    per_100m = amount(o, "per_100m", per_100m)
    seg = np.diff(path, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    length = seg_len.sum()
    mean = per_100m * length / 100.0
    if not mean <= MAX_OBJECTS:  # also NaN, on a path too long for the floats
        raise DataError(f"{o}: per_100m = {per_100m!r} on the {length:g} m path is {mean:.3g} "
                        f"objects, more than MAX_OBJECTS = {MAX_OBJECTS}")
    n = rng.poisson(mean)
    s = np.sort(rng.uniform(0.0, length, n))
    k = np.clip(np.searchsorted(np.cumsum(seg_len), s, side="right"), 0, len(seg) - 1)
    along = s - np.r_[0.0, np.cumsum(seg_len)][k]
    unit = seg[k] / seg_len[k, None]
    normal = np.column_stack([-unit[:, 1], unit[:, 0]])
    offset = rng.uniform(*lateral, n) * rng.choice([-1.0, 1.0], n)
    xy = path[k] + along[:, None] * unit + offset[:, None] * normal
    kinds = np.asarray(classes)[rng.integers(len(classes), size=n)]
    widths, heights = _sizes(rng, kinds)
    return World(xy, widths, heights, kinds)


def combine(*worlds: World, walls: np.ndarray | None = None) -> World:
    """One world holding every object of `worlds` (in that order) and the given walls."""
    walls = np.concatenate([w.walls for w in worlds] + ([] if walls is None else [walls]))
    return World(np.concatenate([w.xy for w in worlds]),
                 np.concatenate([w.widths for w in worlds]),
                 np.concatenate([w.heights for w in worlds]),
                 np.concatenate([w.kinds for w in worlds]), walls.reshape(-1, 2, 2))


def room_walls(x0: float, y0: float, x1: float, y1: float,
               door: tuple[float, float] | None = None) -> np.ndarray:
    """(m, 2, 2) wall segments of a rectangular room, with an optional door gap (y_from, y_to)
    in its right-hand wall."""
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    walls = [[corners[0], corners[1]], [corners[2], corners[3]], [corners[3], corners[0]]]
    if door is None:
        walls.append([corners[1], corners[2]])
    else:
        walls += [[(x1, y0), (x1, door[0])], [(x1, door[1]), (x1, y1)]]
    return np.asarray(walls, dtype=float)
