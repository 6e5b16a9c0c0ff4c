"""An object's accumulated cloud: every view of a tracked object merged into one voxel set, and
what does not depend on the viewpoint read off it (centre, extent, shape).

One view of an object shows one or two of its faces: its centroid lies on the seen side and
its width and height are those of the part in view, so the same object mapped by two robots
from two sides gives two different sizes and centroids. The union of the views converges to
the whole object as the robot moves around it. Frames: the robot's gravity-aligned odometry
frame (metres, z up), as the lifted clouds are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import real_array
from tcaff_gtsam.params import _int_at_least, _real, _require

__all__ = ["CloudExtent", "ObjectCloud", "check_rgb", "cloud_extent", "colour_bins",
           "footprint_rectangles", "shape_features"]

#: voxel indices are packed into one int64 key, 21 bits per axis, wrapping around: two voxels
#: share a key only 2**21 voxels apart (42 km at 2 cm), and clouds are only compared when
#: their boxes touch
_BITS = 21
#: share of the points trimmed at each end of an axis when measuring extents: a few stray
#: points (a mask that bled onto the background in one view) must not stretch the object
TRIM = 0.01


@dataclass(frozen=True)
class CloudExtent:
    """The box around a cloud, upright (gravity aligned) and turned about z to its footprint.

    Attributes:
        centre: (3,) metres, the box's centre (the footprint rectangle's centre; halfway
            between the lowest and highest points).
        width: metres, the footprint's longer side; depth: its shorter side.
        height: metres, the extent along z.
    """

    centre: np.ndarray
    width: float
    depth: float
    height: float


def cloud_extent(points: np.ndarray, pad: float = 0.0) -> CloudExtent:
    """The upright box of a cloud: its footprint's smallest-perimeter rectangle (which for a
    box seen on two faces is the box itself, not one along the diagonal; its axes from all
    points but the `TRIM` share farthest from their median), with the extents measured
    between the `TRIM` and 1 - `TRIM` order statistics along the rectangle's axes and z.

    Args:
        points: (n, 3) metres, n >= 1, gravity-aligned frame.
        pad: metres added to each extent (voxel averaging pulls extreme points inside).

    Raises:
        DataError: points not an (n, 3) array of finite numbers with n >= 1.
    """
    points = real_array("cloud_extent", "points", points)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
        raise DataError(f"cloud_extent: points must have shape (n, 3) with n >= 1, got "
                        f"{points.shape}")
    if not np.isfinite(points).all():
        raise DataError("cloud_extent: points holds non-finite values")
    xy = points[:, :2]
    # the rectangle's axes from the points but the farthest TRIM share from their median, so
    # that a stray point of one view cannot turn the box
    core = xy
    if xy.shape[0] >= 1.0 / TRIM:
        radius = np.hypot(*(xy - np.median(xy, axis=0)).T)
        core = xy[radius <= np.partition(radius, int((1.0 - TRIM) * (xy.shape[0] - 1)))[
            int((1.0 - TRIM) * (xy.shape[0] - 1))]]
    hull = cv2.convexHull(core.astype(np.float32)).reshape(-1, 2).astype(np.float64)
    u = footprint_rectangles(hull, np.array([0, hull.shape[0]]))[1][0]
    v = np.array([-u[1], u[0]])
    lo, hi = _trimmed_range(np.column_stack([xy @ u, xy @ v, points[:, 2]]))
    mid = 0.5 * (lo + hi)
    size = hi - lo + pad
    centre = np.array([*(mid[0] * u + mid[1] * v), mid[2]])
    return CloudExtent(centre, float(max(size[0], size[1])), float(min(size[0], size[1])),
                       float(size[2]))


@numba.njit(cache=True)
def footprint_rectangles(hulls: np.ndarray, bounds: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The smallest-perimeter rectangle around each of convex hulls stacked one after
    another (hull g is hulls[bounds[g]:bounds[g + 1]], (h, 2) metres, in order around it).

    Not the smallest-area rectangle: for the L of a box's two visible faces that one ties
    between the box itself and one along the diagonal, while the smallest perimeter picks the
    box. One side of the optimal rectangle lies along a hull edge.

    Returns:
        (g,) metres, each rectangle's longer side (0 for a hull without an edge), and (g, 2)
        the unit direction of the hull edge it lies along ((1, 0) for none).
    """
    widths = np.zeros(bounds.size - 1)
    axes = np.zeros((bounds.size - 1, 2))
    axes[:, 0] = 1.0
    for g in range(bounds.size - 1):
        pts = hulls[bounds[g]:bounds[g + 1]]
        h = pts.shape[0]
        best = np.inf
        for i in range(h):
            ex = pts[(i + 1) % h, 0] - pts[i, 0]
            ey = pts[(i + 1) % h, 1] - pts[i, 1]
            norm = np.sqrt(ex * ex + ey * ey)
            if norm < 1e-12:
                continue
            ux, uy = ex / norm, ey / norm
            lo_a = lo_c = np.inf
            hi_a = hi_c = -np.inf
            for j in range(h):
                along = pts[j, 0] * ux + pts[j, 1] * uy
                across = pts[j, 1] * ux - pts[j, 0] * uy
                lo_a, hi_a = min(lo_a, along), max(hi_a, along)
                lo_c, hi_c = min(lo_c, across), max(hi_c, across)
            if (hi_a - lo_a) + (hi_c - lo_c) < best:
                best = (hi_a - lo_a) + (hi_c - lo_c)
                widths[g] = max(hi_a - lo_a, hi_c - lo_c)
                axes[g, 0], axes[g, 1] = ux, uy
    return widths, axes


def _trimmed_range(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d,) each: the values (n, d) at the `TRIM` and 1 - `TRIM` ranks of each column (order
    statistics: a partial sort, not an interpolated quantile)."""
    n = values.shape[0]
    k = int(TRIM * (n - 1))
    part = np.partition(values, (k, n - 1 - k), axis=0)
    return part[k], part[n - 1 - k]


def shape_features(points: np.ndarray) -> np.ndarray:
    """(3,) linearity, planarity and scattering of a cloud: with the eigenvalues l1 >= l2 >= l3
    of its covariance, (l1 - l2) / l1, (l2 - l3) / l1 and l3 / l1, which sum to 1. A pole is
    linear, a board planar, a box or a plant scattered; rotating or moving the cloud changes
    none of them. Fewer than 3 points, or a single point repeated: (1/3, 1/3, 1/3)."""
    if points.shape[0] < 3:
        return np.full(3, 1.0 / 3.0)
    c = points - points.mean(axis=0)
    l3, l2, l1 = np.maximum(np.linalg.eigvalsh(c.T @ c / points.shape[0]), 0.0)
    if l1 <= 1e-12:
        return np.full(3, 1.0 / 3.0)
    return np.array([(l1 - l2) / l1, (l2 - l3) / l1, l3 / l1])


class ObjectCloud:
    """The accumulated cloud of one tracked object: one point per occupied voxel, the newest
    view's point winning, each stamped with the time it was last seen.

    At most `max_points` voxels are kept: beyond that the voxel edge doubles (a large object,
    a cabinet or a table, is described by fewer, coarser voxels). Voxels unseen for longer
    than a span are forgotten (`forget`), so that odometry drift over a long track does not
    blur it.

    Args:
        voxel: metres, the initial voxel edge (> 0).
        max_points: the most voxels kept (>= 1).

    Attributes:
        points: (n, 3) metres; seen: (n,) s, when each was last seen.
        lo, hi: (3,) the corners of the points' axis-aligned box (inf and -inf when empty).
    """

    def __init__(self, voxel: float, max_points: int) -> None:
        _require(_real(voxel) and math.isfinite(voxel) and voxel > 0, "ObjectCloud", "voxel",
                 voxel, "must be a finite number > 0 metres")
        _require(_int_at_least(max_points, 1), "ObjectCloud", "max_points", max_points,
                 "must be an int >= 1")
        self.voxel = float(voxel)
        self.max_points = int(max_points)
        self._set(np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return self.points.shape[0]

    def add(self, points: np.ndarray, t: float) -> None:
        """Merge one view's points ((n, 3) metres) seen at time t (s)."""
        if points.shape[0] == 0:
            return
        self._merge(points, np.full(points.shape[0], float(t)))

    def absorb(self, other: ObjectCloud) -> None:
        """Merge another track's cloud into this one (two tracks of one object)."""
        if len(other):
            self._merge(other.points, other.seen)

    def forget(self, t: float, span: float) -> None:
        """Drop the voxels last seen more than `span` seconds before t."""
        keep = t - self.seen <= span
        if not keep.all():
            self._set(self.points[keep], self.seen[keep], self._keys[keep])

    def share_on(self, points: np.ndarray, cell: float) -> float:
        """The share of `points` ((n, 3) metres, n >= 1) in cells of a grid of edge `cell`
        metres (or of the voxel edge, when the voxels have grown coarser) that this cloud
        occupies: how much of a new view lies on the object already seen. A lookup in the
        cloud's sorted cells, not a nearest-neighbour search."""
        if len(self) == 0:
            return 0.0
        cell = max(cell, self.voxel)
        return self._share(_voxel_keys(points, cell), cell)

    def share_of(self, other: ObjectCloud, cell: float) -> float:
        """`share_on(other.points, cell)`, with the other cloud's cells kept from one call to
        the next while it does not change (most tracks do not, from one frame to the next)."""
        if len(self) == 0 or len(other) == 0:
            return 0.0
        cell = max(cell, self.voxel)
        return self._share(other._cells_at(cell)[0], cell)

    def _cells_at(self, cell: float) -> tuple[np.ndarray, np.ndarray]:
        """(n,) the cell of each point and (m,) the distinct cells, sorted, on the grid of
        edge `cell`; kept until the cloud or the cell edge changes."""
        if self._cells is None or self._cells[0] != cell:
            keys = _voxel_keys(self.points, cell)
            self._cells = (cell, keys, np.unique(keys))
        return self._cells[1], self._cells[2]

    def _share(self, keys: np.ndarray, cell: float) -> float:
        cells = self._cells_at(cell)[1]
        at = np.minimum(np.searchsorted(cells, keys), cells.size - 1)
        return float(np.count_nonzero(cells[at] == keys)) / keys.size

    def _set(self, points: np.ndarray, seen: np.ndarray, keys: np.ndarray) -> None:
        self.points, self.seen, self._keys = points, seen, keys
        # (cell edge, each point's cell, the distinct cells): made when next needed
        self._cells: tuple[float, np.ndarray, np.ndarray] | None = None
        empty = points.shape[0] == 0
        self.lo = np.full(3, np.inf) if empty else points.min(axis=0)
        self.hi = np.full(3, -np.inf) if empty else points.max(axis=0)

    def _merge(self, points: np.ndarray, seen: np.ndarray) -> None:
        # newest first, incoming before kept at equal times: np.unique keeps each key's first
        # occurrence, so the newest point of a voxel wins, whichever cloud it came from
        points = np.concatenate([points, self.points])
        seen = np.concatenate([seen, self.seen])
        order = np.argsort(-seen, kind="stable")
        points, seen = points[order], seen[order]
        while True:
            keys = _voxel_keys(points, self.voxel)
            _, first = np.unique(keys, return_index=True)
            if first.size <= self.max_points:
                break
            self.voxel *= 2.0
        self._set(points[first], seen[first], keys[first])


def _voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """(n,) int64: each point's voxel, packed."""
    ijk = np.floor(points / voxel).astype(np.int64) & ((1 << _BITS) - 1)
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]


def check_rgb(rgb, shape: tuple[int, int] | None = None) -> np.ndarray:
    """`rgb` as given if it is an (H, W, 3) uint8 image (of `shape` (H, W) if given); else
    DataError."""
    if not isinstance(rgb, np.ndarray):
        raise DataError(f"rgb must be a numpy array, got {type(rgb).__name__}")
    if rgb.dtype != np.uint8:
        raise DataError(f"rgb has dtype {rgb.dtype}; expected uint8")
    if rgb.ndim != 3 or rgb.shape[2] != 3 or (shape is not None and rgb.shape[:2] != shape):
        want = "(H, W, 3)" if shape is None else str((*shape, 3))
        raise DataError(f"rgb has shape {rgb.shape}; expected {want}")
    return rgb


def colour_bins(rgb: np.ndarray, hue_bins: int, saturation_bins: int) -> np.ndarray:
    """(H, W) int64: each pixel's bin of a hue x saturation histogram, the last bin
    (hue_bins * saturation_bins) for grey pixels (saturation or value too low for a hue to
    mean anything). Brightness is left out: the same object is lit differently from
    different sides.

    Args:
        rgb: (H, W, 3) uint8, RGB order.

    Raises:
        DataError: rgb of another kind.
    """
    check_rgb(rgb)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL)
    # one lookup table per channel, then a sum: no wide temporaries per pixel
    level = np.arange(256)
    hue = (level * hue_bins // 256) * saturation_bins
    # saturation bins span the coloured range only; grey pixels get a code past every bin
    grey = hue_bins * saturation_bins
    sat = np.where(level < _GREY_SATURATION, grey,
                   np.minimum((level - _GREY_SATURATION) * saturation_bins
                              // (256 - _GREY_SATURATION), saturation_bins - 1))
    bins = (hue[hsv[..., 0]] + sat[hsv[..., 1]]).astype(np.int64)
    bins[(bins >= grey) | (hsv[..., 2] < _DARK)] = grey
    return bins


#: HSV (0-255 scale) below which a pixel has no meaningful hue
_GREY_SATURATION = 40
_DARK = 40
