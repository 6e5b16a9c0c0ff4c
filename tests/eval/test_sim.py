"""Tests for tcaff_gtsam.eval.sim: the scenario builders and the simulator that turns them into
per-robot object maps."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from sim_helpers import (
    INDOOR,
    SCENARIOS,
    SHORT,
    angle_diff,
    ideal_sensor,
    run_of,
    short,
)
from tcaff_gtsam.eval.config import (
    MappingConfig,
    OdometryDrift,
    RoomLayout,
    ScenarioConfig,
    load_methods,
    load_scenario,
)
from tcaff_gtsam.eval.jobs import evaluate_simulated
from tcaff_gtsam.eval.sim.motion import (
    poses_along,
)
from tcaff_gtsam.eval.sim.rgbd import clear_paths
from tcaff_gtsam.eval.sim.scenarios import build_scene
from tcaff_gtsam.eval.sim.simulate import SimRun, simulate
from tcaff_gtsam.eval.sim.world import scatter

from tcaff_gtsam.geometry import (
    se2_error,
    se2_from_params,
    transform_points,
)
from tcaff_gtsam.object_map import ObjectMap

# =============================================================================================
# scenarios


def test_indoor_return_robot_leaves_and_comes_back():
    cfg = load_scenario("indoor_return")
    lay = cfg.layout
    scene = build_scene(cfg, np.random.default_rng(0))
    assert len(scene.knots) == 2
    t = np.arange(0.0, cfg.duration + 1.0, 1.0)
    home = [poses_along(*k, t)[:, :2] for k in scene.knots]
    in_home = np.all((home[1] > 0) & (home[1] < lay.room), axis=1)
    in_away = home[1][:, 0] > lay.room + 6.0
    assert np.all(np.all((home[0] > 0) & (home[0] < lay.room), axis=1))  # robot 0 stays
    assert np.all(in_home[t < lay.leave_at])
    assert np.all(in_away[(t > lay.leave_at + 30) & (t < lay.return_at - 30)])
    assert np.all(in_home[t > lay.return_at + 10])
    # both rooms' boxes are in the world: the home ones inside the home room
    n_home = lay.boxes
    assert len(scene.world) == lay.boxes + lay.away_boxes
    assert np.all((scene.world.xy[:n_home] >= 1.0) & (scene.world.xy[:n_home] <= lay.room - 1))
    assert np.all(scene.world.xy[n_home:, 0] > lay.room + 4.0)


@pytest.mark.parametrize("name", ["same_direction", "opposite_directions"])
def test_outdoor_robots_start_separated_along_the_path(name):
    cfg = load_scenario(name)
    lay = cfg.layout
    scene = build_scene(cfg, np.random.default_rng(3))
    start = [k[1][0] for k in scene.knots]
    # the path winds gently, so the straight distance is a little under the arc length
    gap = np.linalg.norm(start[1] - start[0])
    assert 0.9 * lay.separation < gap <= lay.separation + 1e-9
    for k in scene.knots:
        np.testing.assert_allclose(np.linalg.norm(np.diff(k[1], axis=0), axis=1) / lay.speed,
                                   np.diff(k[0]), rtol=1e-9)
    t = np.array([0.0, 10.0])
    p = [poses_along(*k, t) for k in scene.knots]
    if name == "same_direction":  # robot 1 follows robot 0
        assert start[0][0] > start[1][0]
        assert p[0][1, 0] > p[0][0, 0] and p[1][1, 0] > p[1][0, 0]
    else:  # they drive towards each other
        assert start[0][0] < start[1][0]
        assert p[0][1, 0] > p[0][0, 0] and p[1][1, 0] < p[1][0, 0]
        assert np.linalg.norm(p[1][1, :2] - p[0][1, :2]) < gap - 20.0


def test_grid_formations():
    """abreast: half a lane apart all the time; opposite: from the end of the sweep, back."""
    abreast = load_scenario("ambiguous_grid")
    opposite = load_scenario("ambiguous_grid_opposite")
    assert (abreast.layout.formation, opposite.layout.formation) == ("abreast", "opposite")
    t = np.arange(0.0, abreast.duration, 1.0)
    scene = build_scene(abreast, np.random.default_rng(0))
    p0, p1 = (poses_along(*k, t) for k in scene.knots)
    np.testing.assert_allclose(p1[:, :2] - p0[:, :2], np.tile([0.0, 1.25], (len(t), 1)),
                               atol=1e-9)
    scene = build_scene(opposite, np.random.default_rng(0))
    p0, p1 = (poses_along(*k, t) for k in scene.knots)
    assert np.linalg.norm(p0[0, :2] - p1[0, :2]) > 5.0  # the last lane's end
    assert np.mean(np.linalg.norm(p0[:, :2] - p1[:, :2], axis=1) > 0.5) > 0.5


# =============================================================================================
# simulate


@pytest.mark.parametrize("name", SCENARIOS)
def test_shipped_scenarios_simulate(name):
    run = run_of(name)
    cfg = run.scenario
    assert isinstance(run, SimRun) and run.seed == 0
    n, S = cfg.n_robots, int(SHORT)
    assert run.n_robots == n
    np.testing.assert_allclose(run.times, np.arange(1.0, SHORT + 1.0))
    assert run.poses_true.shape == run.poses_odom.shape == (n, S, 3)
    assert len(run.maps) == len(run.labels) == n
    for r in range(n):
        assert len(run.maps[r]) == len(run.labels[r]) == S
        for s in range(S):
            m, lab = run.maps[r][s], run.labels[r][s]
            assert isinstance(m, ObjectMap)
            assert lab.dtype == np.int64 and lab.shape == (len(m),)
            assert np.all((lab >= -1) & (lab < len(run.world)))
            assert np.all(m.last_seen <= run.times[s] + 1e-9)
        assert len(run.maps[r][-1]) > 0 and np.any(run.labels[r][-1] >= 0)
    for i in range(n):
        for j in range(n):
            assert run.T_true(i, j).shape == (S, 3, 3)
            assert run.overlap(i, j).shape == (S,)


@pytest.mark.parametrize("name", SCENARIOS)
def test_same_seed_same_run_other_seed_other_run(name):
    a, b = run_of(name, 0), simulate(short(name), 0)
    np.testing.assert_array_equal(a.poses_true, b.poses_true)
    np.testing.assert_array_equal(a.poses_odom, b.poses_odom)
    np.testing.assert_array_equal(a.world.xy, b.world.xy)
    for r in range(a.n_robots):
        for s in range(len(a.times)):
            np.testing.assert_array_equal(a.maps[r][s].centroids, b.maps[r][s].centroids)
            np.testing.assert_array_equal(a.maps[r][s].widths, b.maps[r][s].widths)
            np.testing.assert_array_equal(a.maps[r][s].last_seen, b.maps[r][s].last_seen)
            np.testing.assert_array_equal(a.labels[r][s], b.labels[r][s])
    c = run_of(name, 1)
    assert not np.array_equal(a.poses_odom, c.poses_odom)
    last_a, last_c = a.maps[0][-1].centroids, c.maps[0][-1].centroids
    assert last_a.shape != last_c.shape or not np.allclose(last_a, last_c)


def shared_residuals(run: SimRun) -> np.ndarray:
    """Distances (metres, x-y) between robot i's map entries and robot j's entries of the same
    world object mapped through T_true(i, j), over all ordered pairs and exchanges."""
    out = []
    for i in range(run.n_robots):
        for j in range(run.n_robots):
            if i == j:
                continue
            T = run.T_true(i, j)
            for s in range(len(run.times)):
                li, lj = run.labels[i][s], run.labels[j][s]
                common = np.intersect1d(li[li >= 0], lj[lj >= 0])
                for label in common.tolist():
                    ci = run.maps[i][s].centroids[li == label, :2]
                    cj = run.maps[j][s].centroids[lj == label, :2]
                    mapped = transform_points(T[s], cj)
                    out.append(np.min(np.linalg.norm(ci[:, None] - mapped[None], axis=2)))
    return np.asarray(out)


@pytest.mark.parametrize("name", SCENARIOS)
def test_true_alignment_maps_shared_objects_onto_each_other(name):
    run = run_of(name)
    res = shared_residuals(run)
    assert len(res) >= 50  # the robots do map common objects
    limit = 0.3 if name in INDOOR else 0.6
    assert np.median(res) < limit, np.median(res)
    assert np.quantile(res, 0.9) < 3 * limit
    # T_true(j, i) is the inverse of T_true(i, j)
    np.testing.assert_allclose(run.T_true(1, 0) @ run.T_true(0, 1),
                               np.broadcast_to(np.eye(3), (len(run.times), 3, 3)), atol=1e-9)


@pytest.mark.parametrize("name", SCENARIOS)
def test_true_poses_follow_the_scene_knots(name):
    run = run_of(name, 2)
    scene = build_scene(run.scenario, np.random.default_rng(2))
    np.testing.assert_array_equal(run.world.xy, scene.world.xy)
    for r, knots in enumerate(scene.knots):
        expected = poses_along(*knots, run.times)
        np.testing.assert_allclose(run.poses_true[r, :, :2], expected[:, :2], atol=1e-9)
        assert np.all(angle_diff(run.poses_true[r, :, 2], expected[:, 2]) < 1e-9)
        # the odometry frame is the true pose at t = 0, up to the drift
        T_w_o = run.T_w_o(r)
        start = se2_from_params(poses_along(*knots, np.array([0.0]))[0])
        err = se2_error(np.broadcast_to(start, T_w_o.shape), T_w_o)
        assert err[:, 0].max() < 2.0 and err[:, 1].max() < np.radians(5)


def test_without_drift_the_odometry_frame_is_the_first_pose_and_maps_are_exact():
    cfg = short("indoor_return", odometry=OdometryDrift(heading_rw_deg=0.0, position_rw=0.0),
                sensor=ideal_sensor(range_max=5.0))
    run = simulate(cfg, 4)
    scene = build_scene(cfg, np.random.default_rng(4))
    for r in range(2):
        start = se2_from_params(poses_along(*scene.knots[r], np.array([0.0]))[0])
        err = se2_error(np.broadcast_to(start, (len(run.times), 3, 3)), run.T_w_o(r))
        assert err.max() < 1e-9
        # an exact sensor and no drift: every map entry sits on its world object
        for s in range(len(run.times)):
            m, lab = run.maps[r][s], run.labels[r][s]
            assert np.all(lab >= 0)
            world_xy = transform_points(run.T_w_o(r)[s], m.centroids[:, :2])
            np.testing.assert_allclose(world_xy, run.world.xy[lab], atol=1e-9)
    res = shared_residuals(run)
    assert len(res) > 0 and res.max() < 1e-9


def hand_overlap(run: SimRun, i: int, j: int, s: int, need: int) -> bool:
    t, kappa = run.times[s], run.scenario.mapping.kappa
    a = {int(x) for x, seen in zip(run.labels[i][s], run.maps[i][s].last_seen, strict=True)
         if x >= 0 and t - seen < kappa}
    b = {int(x) for x, seen in zip(run.labels[j][s], run.maps[j][s].last_seen, strict=True)
         if x >= 0 and t - seen < kappa}
    return len(a & b) >= need


@pytest.mark.parametrize("name", SCENARIOS)
def test_overlap_is_sharing_enough_recent_labelled_objects(name):
    run = run_of(name)
    n = run.n_robots
    for i in range(n):
        for j in range(n):
            got = run.overlap(i, j)
            expected = [hand_overlap(run, i, j, s, run.scenario.min_shared)
                        for s in range(len(run.times))]
            assert got.tolist() == expected
            np.testing.assert_array_equal(got, run.overlap(j, i))
    # with a short kappa only what was just seen counts; with min_shared = 1 more steps overlap
    for update in ({"min_shared": 1}, {"min_shared": 12},
                   {"mapping": run.scenario.mapping.model_copy(update={"kappa": 2.0})}):
        other = SimRun(run.scenario.model_copy(update=update), run.seed, run.times,
                       run.poses_true, run.poses_odom, run.maps, run.labels, run.world)
        need = other.scenario.min_shared
        for s in range(len(run.times)):
            assert other.overlap(0, 1)[s] == hand_overlap(other, 0, 1, s, need)
    loose = SimRun(run.scenario.model_copy(update={"min_shared": 1}), run.seed, run.times,
                   run.poses_true, run.poses_odom, run.maps, run.labels, run.world)
    assert np.all(loose.overlap(0, 1) >= run.overlap(0, 1))


def test_overlap_is_not_trivial():
    run = run_of("indoor_return")
    ov = run.overlap(0, 1)
    assert ov.any() and not ov.all()
    assert run.overlap(0, 0)[-1]  # a robot overlaps with itself once it has mapped enough


@pytest.mark.parametrize("robots", [3, 4, 6])
def test_room_layout_gives_every_robot_its_data(robots):
    cfg = ScenarioConfig(name="room", duration=15.0,
                         layout=RoomLayout(kind="room", robots=robots, room=12.0, objects=20),
                         mapping=MappingConfig(frame_rate=5.0))
    assert cfg.n_robots == robots
    done = []
    run = simulate(cfg, 0, progress=done.append)
    assert done == pytest.approx([(r + 1) / robots for r in range(robots)])
    assert run.n_robots == robots
    assert run.poses_true.shape == run.poses_odom.shape == (robots, 15, 3)
    assert len(run.maps) == len(run.labels) == robots
    assert all(len(m) == 15 for m in run.maps)
    assert all(len(run.maps[r][-1]) > 0 for r in range(robots))
    # everybody drives inside the room, and not all along the same path
    assert np.all((run.poses_true[:, :, :2] > 0) & (run.poses_true[:, :, :2] < 12.0))
    starts = run.poses_true[:, 0, :2]
    d = np.linalg.norm(starts[:, None] - starts[None], axis=2)
    assert d[~np.eye(robots, dtype=bool)].min() > 0.1
    assert run.T_true(robots - 1, 0).shape == (15, 3, 3)


def test_per_robot_odometry_drift_is_used():
    cfg = short("indoor_return", odometry=[
        OdometryDrift(heading_rw_deg=0.0, position_rw=0.0),
        OdometryDrift(heading_rw_deg=2.0, position_rw=0.1)])
    run = simulate(cfg, 0)
    first = run.T_w_o(0)
    assert se2_error(np.broadcast_to(first[0], first.shape), first).max() < 1e-9
    second = run.T_w_o(1)
    assert se2_error(np.broadcast_to(second[0], second.shape), second)[:, 0].max() > 0.05


def test_frame_rate_below_the_map_exchange_rate_is_refused():
    # every 1 Hz map exchange needs a frame at or before it
    with pytest.raises(ValidationError, match="frame_rate"):
        MappingConfig(nu=1, kappa=20.0, frame_rate=0.5)
    cfg = short("indoor_return", duration=10.0,
                mapping=MappingConfig(nu=1, kappa=20.0, frame_rate=1.0))
    run = simulate(cfg, 0)
    assert all(len(run.maps[r]) == len(run.times) for r in range(run.n_robots))


# -- rendered RGB-D perception -------------------------------------------------------------------


def test_clear_paths_moves_objects_off_the_paths_and_keeps_them_apart():
    rng = np.random.default_rng(3)
    world = scatter(rng, 12, (0.0, 0.0, 10.0, 10.0), ("box", "bin"), min_gap=1.2)
    path = np.column_stack([np.linspace(0, 10, 400), np.full(400, 5.0)])
    cleared = clear_paths(rng, world, [path], clearance=0.4)
    assert len(cleared) == len(world)  # a 10 x 10 m room has room for all of them
    reach = 0.4 + cleared.widths / np.sqrt(2)
    assert np.all(np.abs(cleared.xy[:, 1] - 5.0) > reach - 1e-9)
    untouched = np.abs(world.xy[:, 1] - 5.0) > 0.4 + world.widths / np.sqrt(2)
    np.testing.assert_array_equal(cleared.xy[untouched], world.xy[untouched])


@pytest.mark.slow
def test_rendered_scenario_maps_only_real_objects_and_tcaff_aligns_them():
    """The indoor RGB-D scenario runs the real front end: every map entry is a real object
    (nothing from the floor or walls), few are duplicates, and TCAFF's alignment is right."""
    shipped = load_scenario("indoor_rgbd")
    # 32 s at 280 x 210 instead of 120 s at 320 x 240: ray casting and mapping cost by the
    # frame and the pixel. The robots share objects from about 17 s and TCAFF aligns both
    # directions from 25 s, 7 steps each; smaller images leave too few objects to align
    config = shipped.model_copy(update={"duration": 32.0, "camera": shipped.camera.model_copy(
        update={"width": 280, "height": 210})})
    run = simulate(config, seed=0)
    final = [run.labels[r][-1] for r in range(run.n_robots)]
    for labels in final:
        assert labels.size >= 4
        assert np.all(labels >= 0)
        assert np.unique(labels).size >= labels.size - 1  # at most one duplicate per map
    job = evaluate_simulated(run, load_methods("tcaff_only"))
    tcaff = job.metrics["tcaff"]["all"]
    assert tcaff["false_accept"] == 0.0
    assert tcaff["translation_error_m_mean"] < 0.35
