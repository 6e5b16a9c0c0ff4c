"""Sizes a caller asks the simulators for are bounded: a count that decides how much a
generator allocates (objects of a map or world, steps and candidates of a stream, people,
waypoints, threads) is taken up to its limit and refused beyond it, or when it is not an int,
by a DataError naming the function, the argument and its value, never by numpy's "Maximum
allowed size exceeded", a MemoryError or a run without end. The scenario configuration bounds
what the builders are given."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from tcaff_gtsam.eval.config_methods import MAX_ICP_ITERATIONS, IcpConfig
from tcaff_gtsam.eval.config_scenario import (
    MAX_DURATION,
    MAX_FALSE_PER_FRAME,
    MAX_METRES,
    MAX_SPEED,
    GridLayout,
    IndoorReturnLayout,
    PathLayout,
    PersonDetectorConfig,
    RoomLayout,
    SensorConfig,
)
from tcaff_gtsam.eval.sim import maps, motion, people, streams, threads, world
from tcaff_gtsam.eval.sim.maps import MAX_OBJECTS, MAX_POINTS
from tcaff_gtsam.eval.sim.streams import MAX_PAIRS, MAX_PER_STEP, MAX_STEPS

from tcaff_gtsam.errors import DataError


def rng():
    return np.random.default_rng(0)


BOUNDS = (0.0, 0.0, 10.0, 10.0)

#: (owner, argument, limit, call with the count): every count argument of the generators
COUNTS = [
    ("random_sizes", "n", 2 * MAX_OBJECTS, lambda n: maps.random_sizes(rng(), n)),
    ("overlapping_maps", "n_objects", MAX_OBJECTS,
     lambda n: maps.overlapping_maps(rng(), n_objects=n)),
    ("overlapping_maps", "clutter", MAX_OBJECTS, lambda n: maps.overlapping_maps(rng(), clutter=n)),
    ("registration_problem", "n_points", MAX_POINTS,
     lambda n: maps.registration_problem(rng(), n_points=n)),
    ("grid_maps", "rows", MAX_OBJECTS, lambda n: maps.grid_maps(rows=n, cols=1)),
    ("grid_maps", "cols", MAX_OBJECTS, lambda n: maps.grid_maps(rows=1, cols=n)),
    ("scatter", "n", MAX_OBJECTS, lambda n: world.scatter(rng(), n, BOUNDS)),
    ("grid", "rows", MAX_OBJECTS, lambda n: world.grid(n, 1, 1.0, 0.5)),
    ("grid", "cols", MAX_OBJECTS, lambda n: world.grid(1, n, 1.0, 0.5)),
    ("wrong_alignments", "k", MAX_PER_STEP, lambda n: streams.wrong_alignments(rng(), n)),
    ("alignment_stream", "steps", MAX_STEPS, lambda n: streams.alignment_stream(rng(), n)),
    ("drifting_truth", "steps", MAX_STEPS,
     lambda n: streams.drifting_truth(rng(), n, (0.0, 0.0, 0.0), (0.1, 0.1, 0.1))),
    ("observe_alignments", r"outliers\[1\]", MAX_PER_STEP,
     lambda n: streams.observe_alignments(rng(), np.zeros((3, 3)), outliers=(0, n))),
    ("decoy_stream", "steps", MAX_STEPS, lambda n: streams.decoy_stream(rng(), steps=n)),
    ("decoy_stream", r"outliers\[1\]", MAX_PER_STEP,
     lambda n: streams.decoy_stream(rng(), outliers=(0, n))),
    ("decoy_stream", "objects_per_match", MAX_PAIRS // (120 * (2 + 2)),
     lambda n: streams.decoy_stream(rng(), objects_per_match=n)),
    ("robot_team_streams", "steps", MAX_STEPS,
     lambda n: streams.robot_team_streams(rng(), 1, n)),
    ("walk", "n", people.MAX_PEOPLE,
     lambda n: people.walk(rng(), n, BOUNDS, (0.5, 1.2), (0.0, 3.0), np.arange(3.0))),
    ("lawnmower", "lanes", motion.MAX_WAYPOINTS // 2, lambda n: motion.lawnmower(BOUNDS, n)),
    ("loop", "points_per_lap", motion.MAX_WAYPOINTS,
     lambda n: motion.loop((0.0, 0.0), 1.0, 0.0, points_per_lap=n)),
    ("cast_threads", "count", threads.MAX_THREADS, threads.cast_threads),
]
IDS = [f"{owner}-{name}" for owner, name, _, _ in COUNTS]


@pytest.fixture(autouse=True)
def _all_cores_after():
    yield
    threads.cast_threads(0)


@pytest.mark.parametrize(("owner", "name", "limit", "call"), COUNTS, ids=IDS)
@settings(max_examples=15, deadline=None)
@given(excess=st.one_of(st.integers(1, 10**6), st.integers(10**6, 2**80)))
def test_a_count_above_its_limit_is_refused(owner, name, limit, call, excess):
    with pytest.raises(DataError, match=rf"^{owner}: {name} = {limit + excess}: must be an "
                                        rf"int in \[\d+, {limit}\]"):
        call(limit + excess)


@pytest.mark.parametrize(("owner", "name", "limit", "call"), COUNTS, ids=IDS)
@pytest.mark.parametrize("bad", [-1, True, 2.0, math.nan, math.inf, "3", None])
def test_a_count_that_is_not_an_int_in_range_is_refused(owner, name, limit, call, bad):
    with pytest.raises(DataError, match=rf"^{owner}: {name} = "):
        call(bad)


@pytest.mark.parametrize(("call", "size"), [
    (lambda: maps.random_sizes(rng(), 2 * MAX_OBJECTS), lambda out: out[0].size),
    (lambda: maps.grid_maps(rows=1, cols=MAX_OBJECTS), lambda out: len(out.ego)),
    (lambda: maps.grid_maps(rows=MAX_OBJECTS, cols=1), lambda out: len(out.other)),
    (lambda: world.grid(MAX_OBJECTS // 100, 100, 1.0, 0.5), len),
    (lambda: maps.registration_problem(rng(), MAX_POINTS, n_points=MAX_POINTS),
     lambda out: out[0].shape[0]),
    (lambda: streams.wrong_alignments(rng(), MAX_PER_STEP), len),
    (lambda: streams.observe_alignments(rng(), np.zeros((1, 3)), 0.0, 0.0,
                                        (MAX_PER_STEP, MAX_PER_STEP)),
     lambda out: len(out.zs[0]) - 1),
    (lambda: motion.lawnmower(BOUNDS, 1000), lambda out: 2 * MAX_OBJECTS // 10),
], ids=["random_sizes", "grid_maps-cols", "grid_maps-rows", "grid", "registration_problem",
        "wrong_alignments", "observe_alignments", "lawnmower"])
def test_sizes_at_their_limit_are_made(call, size):
    out = call()
    assert size(out) in (2 * MAX_OBJECTS, MAX_OBJECTS, MAX_POINTS, MAX_PER_STEP,
                         2 * MAX_OBJECTS // 10)


def test_grid_rows_times_cols_is_at_most_max_objects():
    assert len(world.grid(100, MAX_OBJECTS // 100, 1.0, 0.5)) == MAX_OBJECTS
    for build in (lambda c: world.grid(100, c, 1.0, 0.5), lambda c: maps.grid_maps(100, c)):
        with pytest.raises(DataError, match=r"cols = 101: must be an int in \[1, 100\] "
                                            r"\(MAX_OBJECTS // rows\)"):
            build(MAX_OBJECTS // 100 + 1)


@settings(max_examples=40, deadline=None)
@given(steps=st.integers(0, 12), n_robots=st.integers(1, 12))
def test_robot_team_streams_hold_at_most_max_steps_of_all_pairs(steps, n_robots):
    """With MAX_STEPS at 60: a team is made exactly when its directed pairs' steps, counting
    a stream of no steps as one, are at most 60."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(streams, "MAX_STEPS", 60)
        if n_robots * (n_robots - 1) * max(steps, 1) > 60:
            with pytest.raises(DataError, match=rf"^robot_team_streams: n_robots = {n_robots}: "
                                                r"must be an int in \[1, \d+\] \(n \(n - 1\)"):
                streams.robot_team_streams(rng(), n_robots, steps)
            return
        team = streams.robot_team_streams(rng(), n_robots, steps)
    assert team.A.shape == (n_robots, steps, 3, 3)
    assert len(team.pairs) == n_robots * (n_robots - 1)


@settings(max_examples=30, deadline=None)
@given(steps=st.integers(1, MAX_STEPS), outliers=st.integers(0, MAX_PER_STEP),
       per_match=st.integers(0, 10**7))
def test_decoy_evidence_holds_at_most_max_pairs(steps, outliers, per_match):
    """Only whether the evidence's size is refused: a stream short enough to build
    (decoy_alone < steps) is not asked for above the limit."""
    most = MAX_PAIRS // (steps * (outliers + 2))
    if per_match <= most:
        return
    with pytest.raises(DataError, match=rf"^decoy_stream: objects_per_match = {per_match}: "
                                        rf"must be an int in \[0, {most}\] \(MAX_PAIRS"):
        streams.decoy_stream(rng(), steps=steps, outliers=(0, outliers),
                             objects_per_match=per_match)


@pytest.mark.parametrize("outliers", [(3, 2), (0,), 5, (0.0, 2), (-1, 2)])
def test_outliers_must_be_a_range_of_ints(outliers):
    for call in (lambda: streams.observe_alignments(rng(), np.zeros((2, 3)), outliers=outliers),
                 lambda: streams.decoy_stream(rng(), outliers=outliers)):
        with pytest.raises(DataError, match=r"^(observe_alignments|decoy_stream): outliers"):
            call()


@settings(max_examples=40, deadline=None)
@given(per_100m=st.floats(0.0, 1e300, allow_nan=False))
def test_along_path_draws_at_most_max_objects_on_average(per_100m):
    path = np.array([[0.0, 0.0], [1000.0, 0.0]])  # 1 km: per_100m x 10 objects
    if per_100m * 10 > MAX_OBJECTS:
        with pytest.raises(DataError, match=r"^along_path: per_100m = .* more than "
                                            rf"MAX_OBJECTS = {MAX_OBJECTS}"):
            world.along_path(rng(), path, per_100m, (1.0, 2.0), ("box",))
        return
    if per_100m <= 100:  # cheap enough to draw
        assert len(world.along_path(rng(), path, per_100m, (1.0, 2.0), ("box",))) >= 0


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf, True, "3"])
def test_along_path_refuses_a_density_that_is_not_a_finite_number(bad):
    with pytest.raises(DataError, match=r"^along_path: per_100m = "):
        world.along_path(rng(), np.array([[0.0, 0.0], [10.0, 0.0]]), bad, (1.0, 2.0), ("box",))


@settings(max_examples=40, deadline=None)
@given(laps=st.floats(0.0, 1e300, allow_nan=False), per_lap=st.integers(1, 1000))
def test_loop_makes_at_most_max_waypoints(laps, per_lap):
    if laps * per_lap > motion.MAX_WAYPOINTS:
        with pytest.raises(DataError, match=r"^loop: laps = .*\(MAX_WAYPOINTS / points_per_lap"):
            motion.loop((0.0, 0.0), 1.0, laps, points_per_lap=per_lap)
    elif laps * per_lap < 10_000:
        way = motion.loop((0.0, 0.0), 1.0, laps, points_per_lap=per_lap)
        assert way.shape == (max(round(per_lap * laps), 1) + 1, 2)


@pytest.mark.parametrize("bad", [-0.5, math.nan, math.inf, True, None])
def test_loop_refuses_laps_that_are_not_a_finite_number(bad):
    with pytest.raises(DataError, match=r"^loop: laps = "):
        motion.loop((0.0, 0.0), 1.0, bad)


def test_walk_stops_at_max_legs():
    """Times far in the future (or bounds with no room to walk) would take legs without end:
    refused at once where even the longest legs would be too many, else once the walk has
    taken MAX_LEGS."""
    times = np.array([0.0, 1e300])
    with pytest.raises(DataError, match=r"^walk: 2 people .* more than MAX_LEGS = "):
        people.walk(rng(), 2, BOUNDS, (0.5, 1.2), (0.0, 3.0), times)
    x0, y0, x1, y1 = BOUNDS
    longest = math.hypot(x1 - x0, y1 - y0) / 0.5 + 3.0  # the slowest leg and longest pause
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(people, "MAX_LEGS", 50)
        with pytest.raises(DataError, match="MAX_LEGS = 50 legs"):
            people.walk(rng(), 2, BOUNDS, (0.5, 1.2), (0.0, 3.0), np.array([0.0, 1e4]))
        # within the up-front bound, but the legs actually walked are shorter and more
        with pytest.raises(DataError, match="MAX_LEGS = 50 legs"):
            people.walk(rng(), 2, BOUNDS, (0.5, 1.2), (0.0, 3.0),
                        np.array([0.0, 24.0 * longest]))
        assert people.walk(rng(), 2, BOUNDS, (0.5, 1.2), (0.0, 3.0), np.arange(5.0)).shape == (
            5, 2, 2)


@pytest.mark.parametrize("times", [np.array([0.0, math.nan]), np.array([0.0, math.inf]),
                                   np.zeros((2, 2)), "soon"])
def test_walk_refuses_times_that_are_not_finite_seconds(times):
    with pytest.raises(DataError, match=r"^walk: times"):
        people.walk(rng(), 2, BOUNDS, (0.5, 1.2), (0.0, 3.0), times)


# -- the scenario configuration ----------------------------------------------------------------

#: (model, fields that make it, field, its upper bound)
LIMITS = [
    (IcpConfig, {}, "max_iterations", MAX_ICP_ITERATIONS),
    (SensorConfig, {}, "false_per_frame", MAX_FALSE_PER_FRAME),
    (PersonDetectorConfig, {}, "false_per_frame", MAX_FALSE_PER_FRAME),
    (IndoorReturnLayout, {"kind": "indoor_return"}, "boxes", MAX_OBJECTS),
    (IndoorReturnLayout, {"kind": "indoor_return"}, "away_boxes", MAX_OBJECTS),
    (IndoorReturnLayout, {"kind": "indoor_return", "leave_at": 0.0}, "return_at", MAX_DURATION),
    (IndoorReturnLayout, {"kind": "indoor_return"}, "speed", MAX_SPEED),
    (IndoorReturnLayout, {"kind": "indoor_return"}, "room", MAX_METRES),
    (PathLayout, {"kind": "same_direction", "objects_per_100m": 1.0}, "length", MAX_METRES),
    (PathLayout, {"kind": "same_direction"}, "speed", MAX_SPEED),
    (PathLayout, {"kind": "same_direction", "length": 100.0}, "objects_per_100m",
     float(MAX_OBJECTS)),
    (RoomLayout, {"kind": "room"}, "objects", MAX_OBJECTS),
    (RoomLayout, {"kind": "room"}, "speed", MAX_SPEED),
    (RoomLayout, {"kind": "room"}, "room", MAX_METRES),
    (GridLayout, {"kind": "grid"}, "rows", 100),
    (GridLayout, {"kind": "grid"}, "cols", 100),
    (GridLayout, {"kind": "grid"}, "landmarks", MAX_OBJECTS),
    (GridLayout, {"kind": "grid"}, "spacing", MAX_METRES),
    (GridLayout, {"kind": "grid"}, "size", MAX_METRES),
    (GridLayout, {"kind": "grid"}, "speed", MAX_SPEED),
]


@pytest.mark.parametrize(("model", "base", "field", "limit"), LIMITS,
                         ids=[f"{m.__name__}-{f}" for m, _, f, _ in LIMITS])
def test_config_sizes_are_bounded(model, base, field, limit):
    assert getattr(model(**base, **{field: limit}), field) == limit
    above = limit + 1 if isinstance(limit, int) else limit * (1 + 1e-9)
    for bad in (above, 10**12, math.inf):
        with pytest.raises(ValidationError, match=field):
            model(**base, **{field: bad})


def test_path_layout_holds_at_most_max_objects():
    assert PathLayout(kind="same_direction", length=1000.0, objects_per_100m=1000.0)
    with pytest.raises(ValidationError, match="more than MAX_OBJECTS"):
        PathLayout(kind="same_direction", length=1000.1, objects_per_100m=1000.0)
