"""Tests for tcaff_gtsam.eval.sim.people: people walking between waypoints, the robots'
person detector, the people of a simulated run, and the pedestrians configuration."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from tcaff_gtsam.eval.config import (
    CONFIG_DIR,
    PedestriansConfig,
    PersonDetectorConfig,
    ScenarioConfig,
    load_scenario,
)
from tcaff_gtsam.eval.sim.people import PeopleRun, detect_people, walk
from tcaff_gtsam.eval.sim.simulate import simulate

from tcaff_gtsam.errors import ConfigError, DataError

FEW = settings(max_examples=25, deadline=None)

seeds = st.integers(0, 2**32 - 1)


def ideal_detector(**update) -> PersonDetectorConfig:
    """A detector that finds every person in its field of view exactly, and nothing else."""
    base = {"fov_deg": 90.0, "range_min": 0.5, "range_max": 8.0, "p_detect": 1.0,
            "noise": 0.0, "noise_per_m": 0.0, "false_per_frame": 0.0}
    return PersonDetectorConfig(**{**base, **update})


def se2(pose) -> np.ndarray:
    """(..., 3, 3) from (..., 3) (x, y, theta), written out here rather than taken from the
    code under test."""
    pose = np.asarray(pose, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    T = np.zeros((*pose.shape[:-1], 3, 3))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = c, -s, pose[..., 0]
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2] = s, c, pose[..., 1]
    T[..., 2, 2] = 1.0
    return T


def to_frame(T_a_b, xy_b) -> np.ndarray:
    """Points (F, n, 2) in frame b mapped into frame a by (F, 3, 3), one loop per frame."""
    return np.stack([xy @ T[:2, :2].T + T[:2, 2] for T, xy in zip(T_a_b, xy_b, strict=True)])


def random_scene(rng, n_frames=40, n_people=12):
    """People scattered around a robot, and unrelated true and odometry poses."""
    xy = rng.uniform(-10.0, 10.0, (n_frames, n_people, 2))
    poses_true = np.column_stack([rng.uniform(-3, 3, (n_frames, 2)),
                                  rng.uniform(-np.pi, np.pi, n_frames)])
    poses_odom = np.column_stack([rng.uniform(-3, 3, (n_frames, 2)),
                                  rng.uniform(-np.pi, np.pi, n_frames)])
    return xy, poses_true, poses_odom


def expected_in_view(xy, poses_true, detector) -> tuple[np.ndarray, np.ndarray]:
    """(in_view (F, n), body (F, n, 2)) worked out from the detector's definition."""
    body = to_frame(np.linalg.inv(se2(poses_true)), xy)
    r = np.hypot(body[..., 0], body[..., 1])
    bearing = np.degrees(np.abs(np.arctan2(body[..., 1], body[..., 0])))
    inside = ((r >= detector.range_min) & (r <= detector.range_max)
              & (bearing <= detector.fov_deg / 2))
    return inside, body


# -- walk ------------------------------------------------------------------------------------


@FEW
@given(seed=seeds, x0=st.floats(-20, 20), y0=st.floats(-20, 20),
       w=st.floats(0.5, 20), h=st.floats(0.5, 20), low=st.floats(0.1, 1.5),
       extra=st.floats(0.0, 1.0), pause=st.floats(0.0, 3.0))
def test_walk_stays_in_bounds_below_max_speed_and_repeats(seed, x0, y0, w, h, low, extra,
                                                          pause):
    """Walkers stay inside the bounds, never move faster than the highest speed between two
    samples, do move, and the same generator seed gives the same walk."""
    bounds = (x0, y0, x0 + w, y0 + h)
    speed = (low, low + extra)
    times = 0.2 * np.arange(200)
    xy = walk(np.random.default_rng(seed), 5, bounds, speed, (0.0, pause), times)
    assert xy.shape == (200, 5, 2)
    assert np.all(np.isfinite(xy))
    assert np.all(xy[..., 0] >= x0) and np.all(xy[..., 0] <= x0 + w)
    assert np.all(xy[..., 1] >= y0) and np.all(xy[..., 1] <= y0 + h)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=-1) / np.diff(times)[:, None]
    assert step.max() <= speed[1] * (1 + 1e-9) + 1e-9
    assert step.max() > 0
    again = walk(np.random.default_rng(seed), 5, bounds, speed, (0.0, pause), times)
    assert np.array_equal(xy, again)


def test_walk_moves_at_the_drawn_speed_between_waypoints():
    """With a single speed and no pauses, a walker is at that speed except where it turns at a
    waypoint (where the straight-line speed between samples is lower)."""
    times = 0.1 * np.arange(600)
    xy = walk(np.random.default_rng(7), 3, (0.0, 0.0, 10.0, 10.0), (0.8, 0.8), (0.0, 0.0),
              times)
    step = np.linalg.norm(np.diff(xy, axis=0), axis=-1) / 0.1
    assert np.all(step <= 0.8 + 1e-9)
    assert np.mean(np.abs(step - 0.8) < 1e-9) > 0.8


def test_walk_needs_room_to_walk():
    with pytest.raises(DataError, match="must span some distance"):
        walk(np.random.default_rng(0), 1, (2, 2, 2, 2), (0.5, 1.0), (0.0, 0.0),
             np.arange(3.0))


def test_walk_of_different_seeds_differ():
    times = 0.5 * np.arange(20)
    a = walk(np.random.default_rng(1), 2, (0, 0, 5, 5), (0.5, 1.0), (0.0, 1.0), times)
    b = walk(np.random.default_rng(2), 2, (0, 0, 5, 5), (0.5, 1.0), (0.0, 1.0), times)
    assert not np.allclose(a, b)


# -- detect_people ---------------------------------------------------------------------------


@FEW
@given(seed=seeds, fov=st.sampled_from([60.0, 90.0, 180.0, 270.0]))
def test_ideal_detections_are_the_people_in_view_in_the_odometry_frame(seed, fov):
    """With p_detect 1, no noise and no false detections: exactly the people within the field
    of view and range are detected, once each, at their world positions moved into the
    robot's odometry frame through T_w_o = T_w_b(true) T_o_b(odom)^-1."""
    rng = np.random.default_rng(seed)
    xy, poses_true, poses_odom = random_scene(rng)
    detector = ideal_detector(fov_deg=fov)
    (frame, found, person), in_view = detect_people(np.random.default_rng(seed), xy,
                                                    poses_true, poses_odom, detector)
    inside, _ = expected_in_view(xy, poses_true, detector)
    assert np.array_equal(in_view, inside)
    assert np.all(person >= 0)
    detected = np.zeros_like(inside)
    detected[frame, person] = True
    assert np.array_equal(detected, inside)               # everybody inside, nobody outside
    assert len(frame) == inside.sum()                    # and each once
    assert np.all(np.diff(frame) >= 0)
    T_w_o = se2(poses_true) @ np.linalg.inv(se2(poses_odom))
    truth = to_frame(np.linalg.inv(T_w_o), xy)
    assert np.allclose(found, truth[frame, person], atol=1e-9, rtol=0)
    run = PeopleRun(np.arange(len(xy)), xy, in_view, poses_true[None], poses_odom[None],
                    [(frame, found, person)])
    assert np.allclose(run.T_w_o(0), T_w_o, atol=1e-12)
    assert np.allclose(run.truth_in_odom(0), truth, atol=1e-9)


def test_false_detections_are_labelled_and_inside_the_field_of_view():
    """False detections carry label -1 and lie in the field of view and range in the body
    frame; the true detections among them are still exact."""
    rng = np.random.default_rng(11)
    xy, poses_true, poses_odom = random_scene(rng, n_frames=200, n_people=4)
    detector = ideal_detector(fov_deg=70.0, range_min=1.0, range_max=5.0, false_per_frame=2.0)
    (frame, found, person), _ = detect_people(rng, xy, poses_true, poses_odom, detector)
    false = person == -1
    assert np.all(person >= -1)
    assert 250 < false.sum() < 550                        # Poisson, mean 400
    assert np.all(np.diff(frame) >= 0)
    T_b_o = np.linalg.inv(se2(poses_odom[frame]))
    body = np.einsum("dij,dj->di", T_b_o[:, :2, :2], found) + T_b_o[:, :2, 2]
    r = np.hypot(body[false, 0], body[false, 1])
    bearing = np.degrees(np.abs(np.arctan2(body[false, 1], body[false, 0])))
    assert np.all(r >= 1.0 - 1e-9) and np.all(r <= 5.0 + 1e-9)
    assert np.all(bearing <= 35.0 + 1e-9)
    T_w_o = se2(poses_true) @ np.linalg.inv(se2(poses_odom))
    truth = to_frame(np.linalg.inv(T_w_o), xy)
    assert np.allclose(found[~false], truth[frame[~false], person[~false]], atol=1e-9)


def test_detection_noise_and_rate_follow_the_config():
    """Detections scatter around the truth with std noise + noise_per_m * range per axis, and
    a share p_detect of the people in view is detected."""
    rng = np.random.default_rng(5)
    xy, poses_true, poses_odom = random_scene(rng, n_frames=400, n_people=10)
    detector = ideal_detector(fov_deg=360.0, p_detect=0.6, noise=0.1, noise_per_m=0.05)
    (frame, found, person), in_view = detect_people(rng, xy, poses_true, poses_odom, detector)
    assert abs(len(frame) / in_view.sum() - 0.6) < 0.03
    _, body = expected_in_view(xy, poses_true, detector)
    distance = np.hypot(body[frame, person, 0], body[frame, person, 1])
    T_w_o = se2(poses_true) @ np.linalg.inv(se2(poses_odom))
    truth = to_frame(np.linalg.inv(T_w_o), xy)
    z = (found - truth[frame, person]) / (0.1 + 0.05 * distance)[:, None]
    assert abs(z.std() - 1.0) < 0.05 and abs(z.mean()) < 0.05


# -- simulate --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def mot_runs():
    """The shipped `mot` scenario cut to 30 s, with and without its people."""
    config = load_scenario("mot").model_copy(update={"duration": 30})
    return simulate(config, 2), simulate(config.model_copy(update={"pedestrians": None}), 2)


def test_simulate_mot_people_shapes(mot_runs):
    """run.people holds F = duration * rate tracking frames of six people and four robots."""
    run, _ = mot_runs
    people = run.people
    F = 30 * 5
    assert people.times.shape == (F,)
    assert np.allclose(people.times, 0.2 * np.arange(1, F + 1))
    assert people.xy.shape == (F, 6, 2)
    assert people.in_view.shape == (F, 6) and people.in_view.dtype == bool
    assert people.poses_true.shape == (4, F, 3) and people.poses_odom.shape == (4, F, 3)
    assert people.n_robots == 4 and len(people.detections) == 4
    for frame, found, person in people.detections:
        assert found.shape == (len(frame), 2) and person.shape == frame.shape
        assert np.all((frame >= 0) & (frame < F)) and np.all(np.diff(frame) >= 0)
        assert np.all((person >= -1) & (person < 6))
    # the 1 Hz exchanges fall on every fifth tracking frame
    assert np.array_equal(people.poses_true[:, 4::5], run.poses_true)
    assert np.array_equal(people.poses_odom[:, 4::5], run.poses_odom)
    assert people.in_view.any()


def test_people_do_not_change_the_object_maps(mot_runs):
    """The robots' object maps and their labels are the same with and without people."""
    run, plain = mot_runs
    assert plain.people is None
    assert np.array_equal(run.poses_true, plain.poses_true)
    assert np.array_equal(run.poses_odom, plain.poses_odom)
    for r in range(run.n_robots):
        assert len(run.maps[r]) == len(plain.maps[r]) == 30
        for s in range(len(run.maps[r])):
            assert np.array_equal(run.maps[r][s].centroids, plain.maps[r][s].centroids)
            assert np.array_equal(run.labels[r][s], plain.labels[r][s])


def test_simulated_ideal_detections_are_the_truth_in_odometry():
    """With an ideal detector, every robot's detections in a simulated run are the people's
    truth_in_odom positions, and in_view is the union of what the robots detect."""
    config = load_scenario("mot")
    people = config.pedestrians.model_copy(update={"detector": ideal_detector()})
    run = simulate(config.model_copy(update={"duration": 20, "pedestrians": people}), 0).people
    seen = np.zeros_like(run.in_view)
    for robot, (frame, found, person) in enumerate(run.detections):
        assert np.all(person >= 0)
        assert np.allclose(found, run.truth_in_odom(robot)[frame, person], atol=1e-9)
        seen[frame, person] = True
    assert np.array_equal(seen, run.in_view)


# -- configuration ---------------------------------------------------------------------------


def mot_data(**pedestrians) -> dict:
    data = yaml.safe_load((CONFIG_DIR / "scenarios" / "mot.yaml").read_text())
    data["pedestrians"].update(pedestrians)
    return data


def write(tmp_path, data) -> str:
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


@pytest.mark.parametrize("rate", [3.0, 4.0, 20.0, 7.5])
def test_pedestrian_rate_must_divide_the_frame_rate(tmp_path, rate):
    """A pedestrians.rate that does not divide mapping.frame_rate (10 Hz) is rejected, naming
    pedestrians.rate, through load_scenario and through model_validate."""
    data = mot_data(rate=rate)
    with pytest.raises(ConfigError, match=r"pedestrians\.rate"):
        load_scenario(write(tmp_path, data))
    with pytest.raises(ValidationError, match=r"pedestrians\.rate"):
        ScenarioConfig.model_validate(data)


@pytest.mark.parametrize("rate", [10.0, 5.0, 2.5, 2.0, 1.0])
def test_pedestrian_rates_that_divide_the_frame_rate_load(tmp_path, rate):
    config = load_scenario(write(tmp_path, mot_data(rate=rate)))
    assert config.pedestrians.rate == rate


def test_pedestrian_speed_range_low_above_high_is_rejected(tmp_path):
    """A speed range with low > high is rejected, naming pedestrians.speed."""
    data = mot_data(speed=[1.2, 0.5])
    with pytest.raises(ConfigError, match=r"pedestrians\.speed.*low <= high"):
        load_scenario(write(tmp_path, data))
    with pytest.raises(ValidationError, match="low <= high"):
        PedestriansConfig.model_validate(data["pedestrians"])


def test_people_that_cannot_walk_are_rejected(tmp_path):
    with pytest.raises(ConfigError, match=r"pedestrians\.speed: people must walk"):
        load_scenario(write(tmp_path, mot_data(speed=[0.0, 0.0])))


def test_shipped_mot_scenario_has_pedestrians():
    config = load_scenario("mot")
    assert config.pedestrians is not None and config.n_robots == 4
    assert config.pedestrians.count == 6 and config.pedestrians.rate == 5.0
