"""Shared by the simulator tests: hypothesis settings and strategies, an ideal sensor, worlds
placed around a robot, and the shipped scenarios cut short and cached."""

from __future__ import annotations

import numpy as np
from hypothesis import settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.config import (
    ScenarioConfig,
    SensorConfig,
    load_scenario,
)
from tcaff_gtsam.eval.sim.simulate import SimRun, simulate
from tcaff_gtsam.eval.sim.world import World

from tcaff_gtsam.geometry import (
    invert,
    se2_from_params,
    transform_points,
    wrap_angle,
)

PROPS = settings(max_examples=40, deadline=None)
FEW = settings(max_examples=15, deadline=None)

SCENARIOS = ("indoor_return", "same_direction", "opposite_directions", "four_robots",
             "ambiguous_grid")
INDOOR = ("indoor_return", "four_robots", "ambiguous_grid")
SHORT = 20.0  # seconds: every shipped scenario is cut to this for the simulator tests

coord = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False, allow_infinity=False)
seeds = st.integers(0, 2**32 - 1)


def angle_diff(a, b) -> np.ndarray:
    return np.abs(wrap_angle(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)))


def ideal_sensor(**update) -> SensorConfig:
    """A sensor that sees every object in its field of view exactly, and nothing else."""
    base = {"fov_deg": 90.0, "range_min": 0.5, "range_max": 5.0, "p_detect": 1.0,
            "centroid_noise": 0.0, "centroid_noise_per_m": 0.0, "size_noise": 0.0,
            "partial_view": 1.0, "false_per_frame": 0.0}
    return SensorConfig(**{**base, **update})


def world_from_body(pose, body_xy, widths, heights) -> World:
    """A world whose objects sit at body-frame positions `body_xy` of a robot at `pose`."""
    body_xy = np.asarray(body_xy, dtype=float).reshape(-1, 2)
    n = len(body_xy)
    xy = transform_points(se2_from_params(pose), body_xy)
    return World(xy, np.asarray(widths, dtype=float), np.asarray(heights, dtype=float),
                 np.full(n, "box"))


def to_body(pose, points_xy) -> np.ndarray:
    """(n, 2) points of the frame `pose` is expressed in, mapped into that body frame."""
    return transform_points(invert(se2_from_params(pose)), np.asarray(points_xy).reshape(-1, 2))


def segment_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(n,) distance of each point to a polyline (m, 2)."""
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.einsum("nmk,mk->nm", points[:, None, :] - a[None], ab) / np.einsum("mk,mk->m", ab, ab)
    foot = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.min(np.linalg.norm(points[:, None, :] - foot, axis=2), axis=1)


def short(name: str, **update) -> ScenarioConfig:
    return load_scenario(name).model_copy(update={"duration": SHORT, **update})


_RUNS: dict[tuple[str, int], SimRun] = {}


def run_of(name: str, seed: int = 0) -> SimRun:
    """The shortened shipped scenario simulated with `seed` (cached: runs are deterministic)."""
    key = (name, seed)
    if key not in _RUNS:
        _RUNS[key] = simulate(short(name), seed)
    return _RUNS[key]
