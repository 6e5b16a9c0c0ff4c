"""Synthetic object-map pairs with a known alignment: two robots' maps of one world.

Used by the demo, the tests and the association benchmark. Object sizes follow a few classes
found in the paper's indoor and outdoor scenes so the size gate behaves as
on real maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import invert, se2_from_params, transform_points
from tcaff_gtsam.object_map import ObjectMap

from .sizes import count

__all__ = ["MAX_OBJECTS", "MAX_POINTS", "OBJECT_CLASSES", "MapPair", "grid_maps",
           "overlapping_maps", "random_sizes", "registration_problem"]

#: the most objects a generated map or world holds (`overlapping_maps`' n_objects and its
#: clutter each, `grid_maps`' rows x cols, the `world` builders'): a node's map message holds
#: at most as many (`node.messages.MAX_OBJECTS`), and two maps of clutter and objects compare
#: their labels in a (2 MAX_OBJECTS)^2 table of 400 MB
MAX_OBJECTS = 10_000

#: the most points of a `registration_problem`: it lists the n (n - 1) wrong pairs to draw
#: its outliers from, 64 MB of indices for 2000 points
MAX_POINTS = 2_000

#: (width range, height range) in metres per object class; sizes are log-uniform in a range.
OBJECT_CLASSES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "box": ((0.3, 1.0), (0.3, 1.0)),
    "pole": ((0.05, 0.3), (1.5, 4.0)),
    "tree": ((0.5, 3.0), (3.0, 10.0)),
    "furniture": ((0.4, 2.0), (0.4, 1.2)),
    "bin": ((0.2, 0.6), (0.5, 1.2)),
    "sign": ((0.3, 0.8), (1.8, 3.0)),
    "car": ((1.6, 2.0), (1.3, 1.9)),
    "rock": ((0.3, 1.5), (0.15, 0.6)),
    "bench": ((1.2, 2.2), (0.4, 0.9)),
}


@dataclass(frozen=True)
class MapPair:
    """Two maps of one world and the truth relating them.

    Attributes:
        ego, other: the two robots' maps, each in its own odometry frame.
        T_oi_oj: (3, 3) SE(2) true transform from the other's odometry frame into the ego's.
        true_pairs: (k, 2) int (ego index, other index) of objects that are the same object.
        now: seconds, the time at which the maps were exchanged.
    """

    ego: ObjectMap
    other: ObjectMap
    T_oi_oj: np.ndarray
    true_pairs: np.ndarray
    now: float


def random_sizes(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) widths and (n,) heights in metres drawn from `OBJECT_CLASSES` uniformly by class,
    n an int in [0, 2 MAX_OBJECTS] (the objects of two maps' world); DataError otherwise."""
    n = count("random_sizes", "n", n, 2 * MAX_OBJECTS, "2 MAX_OBJECTS")
    classes = list(OBJECT_CLASSES.values())
    kind = rng.integers(len(classes), size=n)
    lo_w, hi_w = np.array([c[0] for c in classes]).T
    lo_h, hi_h = np.array([c[1] for c in classes]).T

    def log_uniform(lo, hi):
        return np.exp(rng.uniform(np.log(lo[kind]), np.log(hi[kind])))

    return log_uniform(lo_w, hi_w), log_uniform(lo_h, hi_h)


def overlapping_maps(rng: np.random.Generator, n_objects: int = 50, overlap: float = 0.5,
                     noise: float = 0.1, size_noise: float = 0.1, clutter: int = 0,
                     spacing: float = 4.0, T_oi_oj: np.ndarray | None = None,
                     now: float = 100.0, max_age: float = 15.0) -> MapPair:
    """Two maps of `n_objects` objects each, sharing round(overlap * n_objects) of them.

    Args:
        rng: randomness; same generator state, same maps.
        n_objects: objects per map before clutter, an int in [0, MAX_OBJECTS].
        overlap: share of each map's objects that the other map also holds, in [0, 1].
        noise: metres, std of the centroid noise per axis, independent in each map.
        size_noise: relative std of the observed width and height.
        clutter: extra spurious small objects per map (false segments), not in the other map;
            an int in [0, MAX_OBJECTS].
        spacing: metres; the world is a square of side spacing * sqrt(number of objects).
        T_oi_oj: (3, 3) true alignment; None draws a random one (|t| up to 20 m, any heading).
        now: seconds; objects were last seen uniformly within max_age seconds before it.
    Raises:
        DataError: n_objects or clutter not an int in [0, MAX_OBJECTS], overlap not in [0, 1].
    """
    n_objects = count("overlapping_maps", "n_objects", n_objects, MAX_OBJECTS, "MAX_OBJECTS")
    clutter = count("overlapping_maps", "clutter", clutter, MAX_OBJECTS, "MAX_OBJECTS")
    if not 0 <= overlap <= 1:
        raise DataError(f"overlapping_maps: overlap = {overlap!r}: must be in [0, 1]")
    if T_oi_oj is None:
        T_oi_oj = se2_from_params([*rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)])
    shared = round(overlap * n_objects)
    n_world = 2 * n_objects - shared
    side = spacing * np.sqrt(max(n_world, 1))
    xy = rng.uniform(0.0, side, (n_world, 2))
    widths, heights = random_sizes(rng, n_world)
    centroids_w = np.column_stack([xy, heights / 2])
    ego_ids = np.arange(n_objects)
    other_ids = np.r_[np.arange(shared), np.arange(n_objects, n_world)]

    def observe(ids: np.ndarray, T_frame_world: np.ndarray) -> tuple[ObjectMap, np.ndarray]:
        k = ids.size
        c = centroids_w[ids].copy()
        c[:, :2] = transform_points(T_frame_world, c[:, :2])
        c += rng.normal(0.0, noise, c.shape)
        w = widths[ids] * np.clip(1 + size_noise * rng.standard_normal(k), 0.2, None)
        h = heights[ids] * np.clip(1 + size_noise * rng.standard_normal(k), 0.2, None)
        clutter_xy = transform_points(T_frame_world, rng.uniform(0.0, side, (clutter, 2)))
        clutter_h = rng.uniform(0.1, 0.6, clutter)
        c = np.vstack([c, np.column_stack([clutter_xy, clutter_h / 2])])
        w = np.r_[w, rng.uniform(0.1, 0.6, clutter)]
        h = np.r_[h, clutter_h]
        order = rng.permutation(k + clutter)
        last_seen = now - rng.uniform(0.0, max_age, k + clutter)
        labels = np.r_[ids, np.full(clutter, -1)][order]
        return ObjectMap(c[order], w[order], h[order], last_seen), labels

    ego, ego_labels = observe(ego_ids, np.eye(3))
    other, other_labels = observe(other_ids, invert(T_oi_oj))
    same = (ego_labels[:, None] == other_labels[None, :]) & (ego_labels[:, None] >= 0)
    true_pairs = np.argwhere(same).astype(np.int64).reshape(-1, 2)
    return MapPair(ego, other, T_oi_oj, true_pairs, now)


def registration_problem(rng: np.random.Generator, n_inliers: int = 20,
                         outlier_ratio: float = 0.9, noise: float = 0.05, n_points: int = 50,
                         side: float = 20.0, dim: int = 2
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A point registration problem with a known share of outlier associations (CLIPPER's test).

    `n_points` points uniform in a square (cube for dim 3) of `side` metres, seen by the ego;
    the other holds the same points moved by a random rigid transform plus Gaussian noise of
    `noise` metres per axis. Associations: `n_inliers` correct pairs plus enough random wrong
    pairs that they make up `outlier_ratio` of all associations.

    Returns:
        (ego points (n, dim), other points (n, dim), associations (m, 2), inlier mask (m,)).
    Raises:
        DataError: n_points not an int in [1, MAX_POINTS], n_inliers not one in [1, n_points],
            outlier_ratio not in [0, 1), dim not 2 or 3.
    """
    o = "registration_problem"
    n_points = count(o, "n_points", n_points, MAX_POINTS, "MAX_POINTS", low=1)
    n_inliers = count(o, "n_inliers", n_inliers, n_points, "n_points", low=1)
    if not 0 <= outlier_ratio < 1 or dim not in (2, 3):
        raise DataError(f"{o}: need outlier_ratio in [0, 1) and dim in (2, 3), got "
                        f"{outlier_ratio}, {dim}")
    p = rng.uniform(0.0, side, (n_points, dim))
    R = np.linalg.qr(rng.standard_normal((dim, dim)))[0]
    R *= np.sign(np.linalg.det(R))
    q = (p - rng.uniform(-side, side, dim)) @ R + rng.normal(0.0, noise, (n_points, dim))
    n_outliers = round(n_inliers * outlier_ratio / (1 - outlier_ratio))
    inlier_ids = rng.choice(n_points, n_inliers, replace=False)
    wrong = np.argwhere(~np.eye(n_points, dtype=bool))
    wrong = wrong[rng.choice(len(wrong), min(n_outliers, len(wrong)), replace=False)]
    associations = np.vstack([np.column_stack([inlier_ids, inlier_ids]), wrong])
    inlier = np.r_[np.ones(n_inliers, bool), np.zeros(len(wrong), bool)]
    order = rng.permutation(len(associations))
    return p, q, associations[order], inlier[order]


def _grid_size(owner: str, rows, cols) -> tuple[int, int]:
    """(rows, cols) of a grid of objects, ints >= 1 with rows x cols at most MAX_OBJECTS;
    DataError naming `owner` otherwise."""
    rows = count(owner, "rows", rows, MAX_OBJECTS, "MAX_OBJECTS", low=1)
    return rows, count(owner, "cols", cols, MAX_OBJECTS // rows, "MAX_OBJECTS // rows", low=1)


def grid_maps(rows: int = 2, cols: int = 4, spacing: float = 3.0, size: float = 0.5,
              T_oi_oj: np.ndarray | None = None, now: float = 100.0) -> MapPair:
    """Both robots see the same rows x cols grid of identical objects: an ambiguous world.

    Any symmetry of the grid (the 180 degree turn of a rectangle, for one) aligns the maps as
    well as the truth does, so single-shot matching cannot tell them apart. Noise-free.

    Raises:
        DataError: rows or cols not an int >= 1, rows x cols more than MAX_OBJECTS, spacing
            or size not > 0.
    """
    rows, cols = _grid_size("grid_maps", rows, cols)
    if not (spacing > 0 and size > 0):
        raise DataError(f"grid_maps: need spacing, size > 0, got {spacing}, {size}")
    if T_oi_oj is None:
        T_oi_oj = se2_from_params([4.0, -2.0, 0.6])
    xy = spacing * np.argwhere(np.ones((rows, cols))).astype(float)
    n = len(xy)
    sizes = np.full(n, size)
    ego = ObjectMap(np.column_stack([xy, sizes / 2]), sizes, sizes, np.full(n, now))
    other_xy = transform_points(invert(T_oi_oj), xy)
    other = ObjectMap(np.column_stack([other_xy, sizes / 2]), sizes, sizes, np.full(n, now))
    return MapPair(ego, other, T_oi_oj, np.column_stack([np.arange(n), np.arange(n)]), now)
