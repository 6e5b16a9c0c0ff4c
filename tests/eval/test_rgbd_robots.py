"""Recorded RGB-D sequences as robots (`datasets.rgbd_robots`): walks through a sequence's
frames, the gravity-aligned odometry frames (exact and VIO-like), and the overlap of two maps
under the truth. Sequences are made in memory: nothing here reads an image."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from tcaff_gtsam.eval.config import load_methods
from tcaff_gtsam.eval.dataset_runs import evaluate_run, rgbd_name
from tcaff_gtsam.eval.datasets import rgbd_robots as rr
from tcaff_gtsam.eval.datasets.rgbd_sequence import RgbdSequence, read_sequence
from tcaff_gtsam.mapping.camera import PinholeCamera, T_body_camera

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import (
    invert,
    se2_from_params,
    se3_from_xyz_yaw,
    se3_to_se2,
    wrap_angle,
)
from tcaff_gtsam.object_map import ObjectMap

FAST = settings(max_examples=25, deadline=None)
DOWN = np.array([0.0, 0.0, -1.0])


def sequence(ids, fps: float = 30.0, poses=None, gravity=DOWN, name: str = "kitchen",
             times=None) -> RgbdSequence:
    """A sequence of frames `ids` taken at id / fps (or `times`), without image files."""
    ids = np.asarray(ids, dtype=np.int64)
    n = ids.size
    poses = np.tile(np.eye(4), (n, 1, 1)) if poses is None else np.asarray(poses, float)
    return RgbdSequence(
        name=name, folder=Path(f"/nowhere/{name}"), layout="7scenes",
        camera=PinholeCamera(64, 48, 58.5, 58.5, 32.0, 24.0), depth_scale=1000.0,
        times=ids / fps if times is None else np.asarray(times, float), frame_ids=ids,
        color_paths=(), depth_paths=(), T_world_camera=poses,
        gravity=np.asarray(gravity, float) / np.linalg.norm(gravity))


frame_ids = st.lists(st.integers(0, 400), min_size=2, max_size=60, unique=True).map(sorted)


# -- walks ------------------------------------------------------------------------------------


@FAST
@given(ids=frame_ids, start=st.none() | st.integers(-5, 420),
       stop=st.none() | st.integers(-5, 420), gaps=st.sets(st.integers(0, 59), max_size=5))
def test_a_walk_takes_the_frames_whose_ids_lie_in_its_range(ids, start, stop, gaps):
    poses = np.tile(np.eye(4), (len(ids), 1, 1))
    for k in gaps:  # frames without truth
        if k < len(ids):
            poses[k] = np.nan
    seq = sequence(ids, poses=poses)
    ids = np.array(ids)
    wanted = [k for k in range(len(ids))
              if (start is None or ids[k] >= start) and (stop is None or ids[k] < stop)
              and k not in gaps]
    if len(wanted) < 2:
        with pytest.raises(DataError, match="frames with ground truth in the range"):
            rr.walk(seq, start, stop)
        return
    route = rr.walk(seq, start, stop)
    assert route.positions.tolist() == wanted
    np.testing.assert_allclose(route.times, seq.times[wanted] - seq.times[wanted[0]])
    assert route.times[0] == 0.0 and route.duration == route.times[-1]
    assert route.label == f"kitchen[{'' if start is None else start}:" \
                          f"{'' if stop is None else stop}]"


@FAST
@given(n=st.integers(2, 200), fps=st.floats(5.0, 60.0), share=st.floats(0.01, 1.0),
       jitter=st.integers(0, 2**32 - 1))
def test_a_rate_keeps_frames_at_least_one_period_apart(n, fps, share, jitter):
    rng = np.random.default_rng(jitter)
    times = np.cumsum(rng.uniform(0.8, 1.2, n)) / fps  # a camera's uneven clock
    seq = sequence(np.arange(n), times=times)
    held = 1.0 / np.median(np.diff(times))
    rate = share * held
    route = rr.walk(seq, rate=rate)
    kept = route.positions
    assert kept[0] == 0
    gaps = np.diff(times[kept])
    assert np.all(gaps >= 1.0 / rate - 1e-9)
    # and greedily: each kept frame is the first at least a period after the one before it,
    # and no frame after the last kept one would have been
    for a, b in itertools.pairwise(kept):
        assert np.all(times[a + 1:b] - times[a] < 1.0 / rate - 1e-9)
    assert np.all(times[kept[-1] + 1:] - times[kept[-1]] < 1.0 / rate - 1e-9)
    np.testing.assert_allclose(route.times, times[kept] - times[0])


def test_every_frame_at_the_folders_rate_and_none_above_it():
    seq = sequence(np.arange(0, 100, 5), fps=30.0)  # every 5th frame: 6 Hz
    assert rr.walk(seq, rate=6.0).positions.size == 20
    assert rr.walk(seq, rate=3.0).positions.tolist() == list(range(0, 20, 2))
    with pytest.raises(DataError, match=r"rate = 12 Hz: .*kitchen holds frames at 6 Hz"):
        rr.walk(seq, rate=12.0)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(DataError, match="rate"):
            rr.walk(seq, rate=bad)


@FAST
@given(ids=frame_ids, fps=st.floats(1.0, 60.0))
def test_there_and_back_walks_back_with_the_time_running_on(ids, fps):
    seq = sequence(ids, fps)
    there = rr.walk(seq)
    both = rr.walk(seq, there_and_back=True)
    k = there.positions.size
    assert both.positions.size == 2 * k - 1
    assert both.positions[:k].tolist() == there.positions.tolist()
    assert both.positions[k:].tolist() == there.positions[-2::-1].tolist()
    np.testing.assert_array_equal(both.times[:k], there.times)
    T = there.duration
    # symmetric about the turn: the way back takes as long as the way there
    np.testing.assert_allclose(both.times[::-1], 2 * T - both.times, atol=1e-9)
    assert np.all(np.diff(both.times) > 0)
    assert both.duration == pytest.approx(2 * T)
    assert both.label == there.label + " there and back"


# -- gravity and odometry ---------------------------------------------------------------------


vectors = st.tuples(*[st.floats(-1e3, 1e3)] * 3).map(np.array).filter(
    lambda v: np.linalg.norm(v) > 1e-3)


@FAST
@given(g=vectors)
def test_level_rotation_takes_gravity_to_minus_z_by_the_smallest_turn(g):
    R = rr.level_rotation(g)
    unit = g / np.linalg.norm(g)
    np.testing.assert_allclose(R @ unit, DOWN, atol=1e-9)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0)
    angle = Rotation.from_matrix(R).magnitude()
    assert angle == pytest.approx(math.acos(np.clip(unit @ DOWN, -1, 1)), abs=1e-6)


@pytest.mark.parametrize("g", [DOWN, -DOWN, np.array([0.0, 0.0, -1e-3]),
                               np.array([1e-14, 0.0, 1.0]), np.array([0.0, 0.0, 1e300]),
                               np.array([0.0, 1.4916832686056252e-155, 397.0]),
                               np.array([1e-160, -1e-160, 1.0]), np.array([1e-120, 0.0, -1.0])])
def test_level_rotation_of_gravity_along_z(g):
    R = rr.level_rotation(g)
    np.testing.assert_allclose(R @ (g / np.abs(g).max()), DOWN, atol=1e-14)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    # no turn, or a half turn (symmetric) about a horizontal axis (z flipped, kept in-plane)
    np.testing.assert_allclose(R, R.T, atol=1e-13)
    assert R[2, 2] == pytest.approx(-1.0 if g[2] > 0 else 1.0, abs=1e-15)


@pytest.mark.parametrize("g", [np.zeros(3), np.array([0.0, np.nan, -1.0]),
                               np.array([0.0, 0.0, np.inf]), np.ones(2)])
def test_level_rotation_refuses_a_gravity_without_a_direction(g):
    with pytest.raises(DataError, match="level_rotation: gravity must be 3 finite numbers"):
        rr.level_rotation(g)


def smallest_turn(g: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation by acos(u . down) about u x down (u = g / |g|), by Rodrigues'
    formula; identity for g along -z (undefined along +z). Accurate to rounding near +z too:
    the axis comes from u's horizontal part exactly."""
    u = g / np.linalg.norm(g)
    axis = np.cross(u, DOWN)
    s, c = np.linalg.norm(axis), float(u @ DOWN)
    if s == 0.0:
        return np.eye(3)
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * K @ K


def test_level_rotation_is_the_smallest_turn_to_rounding():
    """2000 gravity directions of lengths 1e-3 to 1e3: over the sphere, and within 1e-16 to
    0.1 of -z (a level world) and of +z (upside down)."""
    rng = np.random.default_rng(0)

    def near(z: float, n: int) -> np.ndarray:
        return np.array([0.0, 0.0, z]) + 10 ** rng.uniform(-16, -1, (n, 1)) * rng.normal(
            size=(n, 3))

    gs = np.concatenate([rng.normal(size=(1400, 3)), near(-1.0, 300), near(1.0, 300)])
    gs *= 10 ** rng.uniform(-3, 3, (len(gs), 1))
    for g in gs:
        R = rr.level_rotation(g)
        u = g / np.linalg.norm(g)
        s2 = u[0] ** 2 + u[1] ** 2
        # near a half turn scipy's quaternion loses precision as 1 + cos(angle) (= s^2 / (1 -
        # cos), without the cancellation) goes to 0: at most 3 ulp / (1 + cos) measured
        tol = 1e-14 + 4e-16 * (1.0 + u[2]) / s2 if u[2] > 0 else 1e-14
        np.testing.assert_allclose(R, smallest_turn(g), rtol=0, atol=tol, err_msg=str(g))
        np.testing.assert_allclose(R @ u, DOWN, rtol=0, atol=1e-12, err_msg=str(g))


def random_walk(rng: np.random.Generator, k: int, g: np.ndarray) -> np.ndarray:
    """(k, 4, 4) camera poses in a world whose gravity is g: a hand-held camera that looks
    roughly level (pitch and roll within 40 deg), turning and moving at random."""
    R_world_level = rr.level_rotation(g).T
    level_optical = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    out = np.tile(np.eye(4), (k, 1, 1))
    for i in range(k):
        yaw, pitch, roll = rng.uniform([-np.pi, -0.7, -0.7], [np.pi, 0.7, 0.7])
        body = Rotation.from_euler("zyx", [yaw, pitch, roll]).as_matrix()
        out[i, :3, :3] = R_world_level @ body @ level_optical
        out[i, :3, 3] = rng.uniform(-5, 5, 3)
    return out


def camera_yaw(R: np.ndarray) -> np.ndarray:
    """Heading (..,) of the horizontal part of a camera's optical axis in a z-up frame."""
    return np.arctan2(R[..., 1, 2], R[..., 0, 2])


@FAST
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 12), g=vectors)
def test_exact_odometry_starts_level_at_the_first_camera_and_is_the_truth(seed, k, g):
    g = g / np.linalg.norm(g)
    rng = np.random.default_rng(seed)
    T_wc = random_walk(rng, k, g)
    times = np.cumsum(rng.uniform(0.05, 0.5, k))
    T_oc, T_wo = rr.odometry(T_wc, times, g, "exact")
    assert T_oc.shape == T_wo.shape == (k, 4, 4)
    np.testing.assert_allclose(T_oc[0, :3, 3], 0.0, atol=1e-9)
    assert camera_yaw(T_oc[0, :3, :3]) == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(T_wo, np.broadcast_to(T_wo[0], T_wo.shape), atol=1e-9)
    np.testing.assert_allclose(T_wo @ T_oc, T_wc, atol=1e-9)
    # the odometry frame is gravity aligned: its -z is the world's gravity
    np.testing.assert_allclose(T_wo[0, :3, :3] @ DOWN, g, atol=1e-9)
    np.testing.assert_allclose(T_wo[0, :3, :3] @ T_wo[0, :3, :3].T, np.eye(3), atol=1e-9)


@FAST
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 12), g=vectors)
def test_vio_drifts_in_heading_and_scale_only(seed, k, g):
    g = g / np.linalg.norm(g)
    rng = np.random.default_rng(seed)
    T_wc = random_walk(rng, k, g)
    times = np.cumsum(rng.uniform(0.5, 30.0, k))
    exact, _ = rr.odometry(T_wc, times, g, "exact")
    T_oc, T_wo = rr.odometry(T_wc, times, g, "vio", np.random.default_rng(seed),
                             heading_rw_deg_per_sqrt_min=20.0, scale_std=0.1)
    again, _ = rr.odometry(T_wc, times, g, "vio", np.random.default_rng(seed),
                           heading_rw_deg_per_sqrt_min=20.0, scale_std=0.1)
    np.testing.assert_array_equal(T_oc, again)  # seeded: the same drift
    other, _ = rr.odometry(T_wc, times, g, "vio", np.random.default_rng(seed + 1),
                           heading_rw_deg_per_sqrt_min=20.0, scale_std=0.1)
    assert not np.allclose(other[1:], T_oc[1:])
    np.testing.assert_allclose(T_oc[0], exact[0], atol=1e-12)  # the same first pose
    # gravity seen from the camera is exact: pitch and roll do not drift
    np.testing.assert_allclose(np.swapaxes(T_oc[:, :3, :3], 1, 2) @ DOWN,
                               np.swapaxes(exact[:, :3, :3], 1, 2) @ DOWN, atol=1e-9)
    # T_world_odom is where the truth puts the drifting frame: still gravity aligned
    np.testing.assert_allclose(T_wo @ T_oc, T_wc, atol=1e-9)
    np.testing.assert_allclose(T_wo[:, :3, :3] @ DOWN, np.broadcast_to(g, (k, 3)), atol=1e-9)
    # every step is scaled by one factor
    moved = np.linalg.norm(np.diff(T_oc[:, :3, 3], axis=0), axis=1)
    truth = np.linalg.norm(np.diff(exact[:, :3, 3], axis=0), axis=1)
    long = truth > 1e-3
    if long.sum() >= 2:
        ratio = moved[long] / truth[long]
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)


def test_vio_without_drift_is_exact_and_bad_kinds_are_refused():
    rng = np.random.default_rng(0)
    T_wc = random_walk(rng, 6, DOWN)
    times = np.arange(6.0)
    exact = rr.odometry(T_wc, times, DOWN, "exact")
    still = rr.odometry(T_wc, times, DOWN, "vio", np.random.default_rng(1), 0.0, 0.0)
    np.testing.assert_allclose(still[0], exact[0], atol=1e-12)
    np.testing.assert_allclose(still[1], exact[1], atol=1e-12)
    with pytest.raises(DataError, match="random generator"):
        rr.odometry(T_wc, times, DOWN, "vio")
    with pytest.raises(DataError, match="'exact' or 'vio'"):
        rr.odometry(T_wc, times, DOWN, "wheel")


def test_vio_heading_drift_grows_with_the_square_root_of_time():
    """Heading error std ~ 1 deg * sqrt(t / 60 s), distance scale std 1 %, over many seeds."""
    times = np.arange(0.0, 240.5, 0.5)
    k = times.size
    T_wc = np.tile(np.eye(4), (k, 1, 1))
    level_optical = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    yaw = 0.3 * np.sin(times / 7.0)
    for i in range(k):
        T_wc[i, :3, :3] = Rotation.from_euler("z", yaw[i]).as_matrix() @ level_optical
        T_wc[i, :3, 3] = [0.2 * times[i], np.sin(times[i] / 5.0), 0.0]
    exact, _ = rr.odometry(T_wc, times, DOWN, "exact")
    errors, scales = [], []
    length = np.linalg.norm(np.diff(exact[:, :3, 3], axis=0), axis=1).sum()
    for seed in range(400):
        T_oc, _ = rr.odometry(T_wc, times, DOWN, "vio", np.random.default_rng([seed, 0]))
        errors.append(wrap_angle(camera_yaw(T_oc[:, :3, :3]) - camera_yaw(exact[:, :3, :3])))
        scales.append(np.linalg.norm(np.diff(T_oc[:, :3, 3], axis=0), axis=1).sum() / length)
    errors = np.degrees(np.array(errors))
    assert np.all(errors[:, 0] == 0.0)
    for minutes in (0.5, 1.0, 2.0, 4.0):
        s = int(np.flatnonzero(times == 60.0 * minutes)[0])
        assert np.std(errors[:, s]) == pytest.approx(math.sqrt(minutes), rel=0.15), minutes
        assert abs(np.mean(errors[:, s])) < 0.25 * math.sqrt(minutes)
    assert np.std(scales) == pytest.approx(0.01, rel=0.15)
    assert np.mean(scales) == pytest.approx(1.0, abs=0.002)


# -- overlap ----------------------------------------------------------------------------------


def mutual_pairs(a: np.ndarray, b_moved: np.ndarray, radius: float) -> int:
    d = np.linalg.norm(a[:, None] - b_moved[None], axis=-1)
    count = 0
    for i in range(len(a)):
        j = int(np.argmin(d[i]))
        if int(np.argmin(d[:, j])) == i and d[i, j] <= radius:
            count += 1
    return count


def flat_map(xy: np.ndarray) -> ObjectMap:
    n = len(xy)
    return ObjectMap(np.column_stack([xy, np.full(n, 0.5)]), np.full(n, 0.5), np.full(n, 0.5),
                     np.zeros(n))


@FAST
@given(seed=st.integers(0, 2**32 - 1), n_a=st.integers(0, 9), n_b=st.integers(0, 9),
       min_shared=st.integers(1, 6), radius=st.floats(0.05, 1.0))
def test_overlap_counts_mutual_nearest_neighbours_under_the_truth(seed, n_a, n_b, min_shared,
                                                                   radius):
    rng = np.random.default_rng(seed)
    z = rng.uniform([-5, -5, -np.pi], [5, 5, np.pi])
    T = se2_from_params(z)
    a = rng.uniform(-4, 4, (n_a, 2))
    # the other map: some of a's objects (moved into its frame, with noise) and others
    shared = a[: min(n_a, n_b)] + rng.normal(0, 0.3, (min(n_a, n_b), 2))
    b_world = np.vstack([shared, rng.uniform(-4, 4, (n_b - len(shared), 2))])
    T_inv = invert(T)
    b = b_world @ T_inv[:2, :2].T + T_inv[:2, 2]
    got = rr.overlap([flat_map(a), flat_map(a)], [flat_map(b), flat_map(b_world)],
                     np.stack([T, np.eye(3)]), min_shared, radius)
    assert got.dtype == bool and got.shape == (2,)
    expected = min(n_a, n_b) >= min_shared and mutual_pairs(a, b_world, radius) >= min_shared
    assert got[0] == expected and got[1] == expected


def test_overlap_needs_mutual_pairs_not_mere_neighbours():
    """Three objects of one map crowd round one of the other's: one pair, not three."""
    a = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [5.0, 5.0]])
    b = np.array([[0.02, 0.02], [5.0, 5.1]])
    T = np.eye(3)[None]
    assert rr.overlap([flat_map(a)], [flat_map(b)], T, 2, 0.3).tolist() == [True]
    assert rr.overlap([flat_map(a)], [flat_map(b)], T, 3, 0.3).tolist() == [False]
    assert rr.overlap([flat_map(a)], [flat_map(b)], T, 2, 0.05).tolist() == [False]


# -- runs -------------------------------------------------------------------------------------


def test_load_run_refuses_what_cannot_be_a_run():
    seq = sequence(np.arange(0, 90), fps=30.0)  # three seconds
    long = rr.walk(seq)
    short = rr.walk(seq, 0, 20)  # 0.63 s
    with pytest.raises(DataError, match="two or more"):
        rr.load_run([long], "exact", None, 20.0)
    with pytest.raises(DataError, match="seed"):
        rr.load_run([long, long], "vio", None, 20.0)
    with pytest.raises(DataError, match=r"shortest walk lasts 0\.63 s"):
        rr.load_run([long, short], "exact", None, 20.0)


def test_result_names_say_the_sequences_the_odometry_and_the_seed():
    kitchen, office = sequence(np.arange(60)), sequence(np.arange(60), name="office")
    assert rr.halves(kitchen.frame_ids) == [(0, 30), (30, 60)]
    halves = [rr.walk(kitchen, 0, 30), rr.walk(kitchen, 30, 60)]
    assert rgbd_name(halves, "exact", None) == "kitchen-exact"
    assert rgbd_name(halves, "vio", 3) == "kitchen-vio-seed3"
    back = [rr.walk(kitchen, 0, 30, there_and_back=True),
            rr.walk(kitchen, 30, 60, there_and_back=True)]
    assert rgbd_name(back, "vio", 0) == "kitchen-back-vio-seed0"
    assert rgbd_name([rr.walk(kitchen), rr.walk(office)], "exact", None) == \
        "kitchen+office-exact"


def test_runs_of_other_frames_have_other_names():
    kitchen = sequence(np.arange(0, 300, 5))  # every 5th frame, 6 Hz
    assert rr.halves(kitchen.frame_ids) == [(0, 150), (150, 296)]
    default = rgbd_name([rr.walk(kitchen, 0, 150), rr.walk(kitchen, 150, 296)], "exact", None)
    assert default == "kitchen-exact"
    others = {
        "kitchen-0to100+100to200-exact": [rr.walk(kitchen, 0, 100), rr.walk(kitchen, 100, 200)],
        "kitchen-0to150+100to300-exact": [rr.walk(kitchen, 0, 150), rr.walk(kitchen, 100, 300)],
        "kitchen-to150+150to-exact": [rr.walk(kitchen, None, 150), rr.walk(kitchen, 150)],
        "kitchen-all+all-exact": [rr.walk(kitchen), rr.walk(kitchen)],
        "kitchen-0to100+100to200+200to300-exact": [rr.walk(kitchen, 0, 100),
                                                   rr.walk(kitchen, 100, 200),
                                                   rr.walk(kitchen, 200, 300)],
        "kitchen-3hz-exact": [rr.walk(kitchen, 0, 150, 3.0), rr.walk(kitchen, 150, 296, 3.0)],
        "kitchen-2.5hz-exact": [rr.walk(kitchen, 0, 150, 2.5),
                                rr.walk(kitchen, 150, 296, 2.5)],
        "kitchen-all+3hz-exact": [rr.walk(kitchen, 0, 150), rr.walk(kitchen, 150, 296, 3.0)],
        "kitchen-0to100+100to200-3hz-back-exact": [
            rr.walk(kitchen, 0, 100, 3.0, True), rr.walk(kitchen, 100, 200, 3.0, True)],
        "kitchen-back1-exact": [rr.walk(kitchen, 0, 150),
                                rr.walk(kitchen, 150, 296, there_and_back=True)],
        "kitchen+office-all+0to30-exact": [rr.walk(kitchen),
                                           rr.walk(sequence(np.arange(60), name="office"),
                                                   0, 30)],
    }
    for name, walks in others.items():
        assert rgbd_name(walks, "exact", None) == name
    assert len({default, *others}) == len(others) + 1
    # there and back is what the walk was asked for, not what its label says
    renamed = rr.walk(kitchen, 0, 150)
    renamed = rr.Walk(renamed.sequence, renamed.positions, renamed.times,
                      "kitchen there and back", 0, 150)
    assert rgbd_name([renamed, rr.walk(kitchen, 150, 296)], "exact", None) == "kitchen-exact"


def uniform_folder(folder: Path, frames: int, poses: np.ndarray | None = None,
                   gravity: np.ndarray = DOWN) -> Path:
    """A 7-Scenes folder of `frames` uniform 64 x 48 frames at `poses` (k, 4, 4)
    (T_world_camera; None: the identity), the world's gravity `gravity`."""
    folder.mkdir()
    color = cv2.imencode(".png", np.full((48, 64, 3), 90, np.uint8))[1].tobytes()
    depth = cv2.imencode(".png", np.full((48, 64), 2000, np.uint16))[1].tobytes()
    for k in range(frames):
        stem = folder / f"frame-{k:06d}"
        Path(f"{stem}.color.png").write_bytes(color)
        Path(f"{stem}.depth.png").write_bytes(depth)
        T = np.eye(4) if poses is None else poses[k]
        Path(f"{stem}.pose.txt").write_text(
            "".join(" ".join(f"{v:.17g}" for v in row) + "\n" for row in T))
    (folder / "camera-intrinsics.txt").write_text("58.5 0 32\n0 58.5 24\n0 0 1\n")
    (folder / "gravity-direction.txt").write_text(" ".join(f"{v:.17g}" for v in gravity))
    return folder


@pytest.fixture
def unequal_run(tmp_path):
    """Two robots on 90 uniform frames at 30 Hz: one walks 1.47 s, the other 2.97 s."""
    seq = read_sequence(uniform_folder(tmp_path / "plain", 90))
    walks = [rr.walk(seq, 0, 45), rr.walk(seq)]
    return walks, rr.load_run(walks, "exact", None, 20.0)


def test_load_run_exchanges_while_every_robot_walks(unequal_run):
    _, (run, seconds) = unequal_run
    np.testing.assert_array_equal(run.times, [1.0])  # the shorter walk's whole seconds
    assert [len(m) for m in run.maps] == [1, 1]
    assert run.robot_names == ("plain[0:45]", "plain[:]")
    assert run.shared.shape == (2, 2, 1)
    np.testing.assert_allclose(run.T_world_odom, np.broadcast_to(np.eye(4), (2, 1, 4, 4)),
                               atol=1e-12)  # exact odometry from the identity
    assert [s.shape for s in seconds] == [(31, 5), (31, 5)]  # the frames up to t = 1 s


def test_load_run_times_only_the_frames_it_maps(unequal_run):
    _, (_, seconds) = unequal_run
    for per_frame in seconds:
        assert np.all(per_frame.sum(axis=1) > 0)


#: 7-Scenes kitchen's gravity in its world frame: the world's y axis points mostly down
KITCHEN_GRAVITY = np.array([-0.00887460355, 0.904425621, 0.426539183])


def test_a_camera_walking_ahead_in_a_tilted_world_walks_along_x(tmp_path):
    """A hand-held camera (1.2 m up, 15 deg down, rolled 8 deg) walks 0.5 m/s straight along
    the level world's x at y = 0.7 in a world frame turned away from gravity: the paths are
    of a level body, heading 0 at constant y in the level world and in each odometry frame."""
    fps, frames = 5.0, 60
    g = KITCHEN_GRAVITY / np.linalg.norm(KITCHEN_GRAVITY)
    T_world_level = np.eye(4)
    T_world_level[:3, :3] = rr.level_rotation(g).T
    T_world_level[:3, 3] = [1.0, -2.0, 0.5]
    roll = np.eye(4)
    roll[:3, :3] = Rotation.from_euler("z", 8.0, degrees=True).as_matrix()  # about the optics
    poses = np.array([T_world_level @ se3_from_xyz_yaw(0.5 * k / fps, 0.7, 0.0, 0.0)
                      @ T_body_camera(1.2, 15.0) @ roll for k in range(frames)])
    seq = read_sequence(uniform_folder(tmp_path / "tilted", frames, poses, g), None, fps)
    walks = [rr.walk(seq, 0, 30), rr.walk(seq, 30, 60)]
    methods = load_methods("tcaff_only").model_copy(update={"methods": ["ground_truth"]})
    paths = {}
    for kind, seed in (("exact", None), ("vio", 2)):
        run, _ = rr.load_run(walks, kind, seed, 20.0)
        job, _ = evaluate_run(run, methods)
        true, odom = job.arrays["poses_true"], job.arrays["poses_odom"]
        assert true.shape == odom.shape == (2, 5, 3)
        paths[kind] = true
        # the truth of a pair is the odometry frames' relative pose in any one world frame
        for i, j in ((0, 1), (1, 0)):
            T_wo = [rr.odometry(seq.T_world_camera[w.positions], w.times, seq.gravity, kind,
                                None if seed is None else np.random.default_rng([seed, r]))[1]
                    for r, w in enumerate(walks)]
            at = [np.searchsorted(w.times, run.times, side="right") - 1 for w in walks]
            np.testing.assert_allclose(
                run.T_true(i, j), se3_to_se2(invert(T_wo[i][at[i]]) @ T_wo[j][at[j]]),
                atol=1e-9)
        if kind == "exact":
            np.testing.assert_allclose(odom[..., 2], 0.0, atol=1e-9)
            np.testing.assert_allclose(odom[..., 1], 0.0, atol=1e-9)
            assert np.all(np.diff(odom[..., 0], axis=1) > 0.4)
    # the truth does not depend on the odometry
    np.testing.assert_allclose(paths["vio"], paths["exact"], atol=1e-9)
    true = paths["exact"]
    # the level world keeps the sequence world's origin: the walk is offset by it
    origin = rr.level_rotation(g) @ T_world_level[:3, 3]
    np.testing.assert_allclose(true[..., 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(true[..., 1], 0.7 + origin[1], atol=1e-9)
    # at the last frame of each whole second: robot 1 started 30 frames (6 s) later
    s = np.arange(1, 6)
    np.testing.assert_allclose(true[0, :, 0], origin[0] + 0.5 * s, atol=1e-9)
    np.testing.assert_allclose(true[1, :, 0], origin[0] + 3.0 + 0.5 * s, atol=1e-9)
