"""Tests for tcaff_gtsam.mapping.mapper: tracking, confirmation, removal, merging, validation."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.mapping.mapper import MapperParams, ObjectMapper

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import FrameAlignerParams

DT = 0.1  # seconds between frames (10 Hz)


def observe(mapper: ObjectMapper, t: float, centroids, widths, heights) -> np.ndarray:
    ids = mapper.update(t, np.asarray(centroids, dtype=float).reshape(-1, 3), widths, heights)
    assert ids.dtype == np.int64
    assert ids.shape == (len(widths),)
    return ids


def one(mapper: ObjectMapper, t: float, xyz, w: float = 0.5, h: float = 1.0) -> int:
    return int(observe(mapper, t, [xyz], [w], [h])[0])


def static_world(n: int, seed: int):
    """n objects on a 3 m grid (well apart relative to the 1 m gate) with random sizes."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(25, size=n, replace=False)
    centroids = np.column_stack([3.0 * (cells % 5), 3.0 * (cells // 5), rng.uniform(0, 2, n)])
    return centroids, rng.uniform(0.3, 2.0, n), rng.uniform(0.3, 2.0, n)


# ---------------------------------------------------------------------------------------------
# tracking


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_static_world_gives_one_stable_track_per_object(seed):
    truth, widths, heights = static_world(10, seed)
    rng = np.random.default_rng(100 + seed)
    mapper = ObjectMapper()
    track_of = [set() for _ in range(len(truth))]
    for frame in range(30):
        order = rng.permutation(len(truth))
        noisy = truth[order] + rng.normal(0.0, 0.05, truth.shape)
        w = widths[order] * rng.uniform(0.95, 1.05, len(truth))
        h = heights[order] * rng.uniform(0.95, 1.05, len(truth))
        ids = observe(mapper, frame * DT, noisy, w, h)
        assert len(set(ids.tolist())) == len(truth)
        for obj, track in zip(order, ids, strict=True):
            track_of[obj].add(int(track))
    assert all(len(s) == 1 for s in track_of), track_of
    assert len(mapper) == len(truth)
    m = mapper.object_map()
    confirmed = mapper.confirmed_ids()
    assert len(m) == len(truth)
    assert confirmed.dtype == np.int64
    assert np.all(np.diff(confirmed) > 0)
    for obj, tracks in enumerate(track_of):
        (track,) = tracks
        row = int(np.flatnonzero(confirmed == track)[0])
        assert np.linalg.norm(m.centroids[row] - truth[obj]) < 0.05
        assert m.widths[row] == pytest.approx(widths[obj], rel=0.05)
        assert m.heights[row] == pytest.approx(heights[obj], rel=0.05)
        assert m.last_seen[row] == pytest.approx(29 * DT)


def test_first_observations_get_consecutive_ids_and_map_rows_follow_ids():
    mapper = ObjectMapper(MapperParams(nu=1))
    ids = observe(mapper, 0.0, [[10, 0, 0], [0, 0, 0], [5, 0, 0]], [1, 1, 1], [1, 1, 1])
    np.testing.assert_array_equal(ids, [0, 1, 2])
    np.testing.assert_array_equal(mapper.confirmed_ids(), [0, 1, 2])
    np.testing.assert_array_equal(mapper.object_map().centroids[:, 0], [10, 0, 5])


def test_running_mean_is_plain_mean_up_to_max_average_then_exponential():
    mapper = ObjectMapper(MapperParams(nu=1, max_average=3))
    xs = [0.0, 0.3, 0.6, 0.9]
    for i, x in enumerate(xs):
        one(mapper, i * DT, [x, 0, 0])
        if i == 2:
            assert mapper.object_map().centroids[0, 0] == pytest.approx(0.3)
    # Fourth hit: weight 1 / min(4, 3) = 1/3.
    assert mapper.object_map().centroids[0, 0] == pytest.approx(0.3 + (0.9 - 0.3) / 3)


def test_confirmation_after_nu_sightings():
    params = MapperParams(nu=4)
    mapper = ObjectMapper(params)
    for i in range(params.nu - 1):
        track = one(mapper, i * DT, [1, 2, 0.5])
        assert len(mapper.object_map()) == 0
        assert mapper.confirmed_ids().shape == (0,)
        assert len(mapper) == 1
    assert one(mapper, params.nu * DT, [1, 2, 0.5]) == track
    np.testing.assert_array_equal(mapper.confirmed_ids(), [track])
    assert len(mapper.object_map()) == 1


def test_track_removed_after_kappa_unseen_but_kept_at_exactly_kappa():
    params = MapperParams(nu=3, kappa=20.0, tentative_timeout=math.inf)
    mapper = ObjectMapper(params)
    for t in (0.0, 1.0, 2.0):
        track = one(mapper, t, [0, 0, 0])
    other = one(mapper, 2.0, [50, 0, 0])
    assert mapper.confirmed_ids().tolist() == [track]

    observe(mapper, 22.0, [], [], [])  # unseen for exactly kappa
    assert mapper.confirmed_ids().tolist() == [track]
    assert len(mapper) == 2
    observe(mapper, 22.25, [], [], [])
    assert mapper.confirmed_ids().tolist() == []
    assert len(mapper.object_map()) == 0
    assert len(mapper) == 0

    # Ids are never reused: the object seen again starts a new track.
    assert one(mapper, 23.0, [0, 0, 0]) not in (track, other)


def test_track_seen_again_at_exactly_kappa_keeps_its_id():
    mapper = ObjectMapper(MapperParams(nu=2, kappa=20.0, tentative_timeout=math.inf))
    track = one(mapper, 0.0, [0, 0, 0])
    assert one(mapper, 20.0, [0.1, 0, 0]) == track
    np.testing.assert_array_equal(mapper.confirmed_ids(), [track])
    assert one(mapper, 40.5, [0.1, 0, 0]) != track


def test_tentative_track_removed_after_its_timeout_confirmed_one_kept():
    mapper = ObjectMapper(MapperParams(nu=3, kappa=20.0, tentative_timeout=1.0))
    for t in (0.0, 0.1, 0.2):
        confirmed = one(mapper, t, [0, 0, 0])
    tentative = one(mapper, 0.5, [5, 0, 0])
    one(mapper, 0.6, [5, 0, 0])
    observe(mapper, 1.6, [], [], [])  # tentative unseen for exactly the timeout
    assert len(mapper) == 2
    observe(mapper, 1.7, [], [], [])
    assert len(mapper) == 1
    assert mapper.confirmed_ids().tolist() == [confirmed]
    assert one(mapper, 1.8, [5, 0, 0]) != tentative


def test_one_off_false_observation_never_reaches_the_map():
    truth, widths, heights = static_world(6, seed=3)
    rng = np.random.default_rng(7)
    mapper = ObjectMapper()
    false_id = None
    for frame in range(40):
        c = truth + rng.normal(0.0, 0.03, truth.shape)
        w, h = widths, heights
        if frame == 10:
            c = np.vstack([c, [7.5, 7.5, 1.0]])  # halfway between grid cells
            w, h = np.append(w, 0.4), np.append(h, 0.4)
        ids = observe(mapper, frame * DT, c, w, h)
        if frame == 10:
            false_id = int(ids[-1])
            assert false_id not in ids[:-1]
        if false_id is not None:
            assert false_id not in mapper.confirmed_ids()
    assert len(mapper.object_map()) == len(truth)
    # Unseen for longer than kappa, the false track is gone altogether.
    observe(mapper, 10 * DT + 20.5, truth, widths, heights)
    assert len(mapper) == len(truth)


@pytest.mark.parametrize("sizes", [((0.5, 0.5), (1.5, 1.5)), ((0.8, 1.0), (0.8, 1.0))],
                         ids=["different-sizes", "same-sizes"])
def test_two_objects_06m_apart_stay_two_tracks(sizes):
    truth = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 1.0]])
    widths = np.array([sizes[0][0], sizes[1][0]])
    heights = np.array([sizes[0][1], sizes[1][1]])
    rng = np.random.default_rng(11)
    mapper = ObjectMapper()
    seen = [set(), set()]
    for frame in range(50):
        order = rng.permutation(2)
        ids = observe(mapper, frame * DT, truth[order] + rng.normal(0, 0.05, (2, 3)),
                      widths[order], heights[order])
        for obj, track in zip(order, ids, strict=True):
            seen[obj].add(int(track))
    assert len(seen[0]) == len(seen[1]) == 1
    assert seen[0] != seen[1]
    assert len(mapper) == 2
    m = mapper.object_map()
    assert len(m) == 2
    for obj in range(2):
        row = int(np.flatnonzero(mapper.confirmed_ids() == next(iter(seen[obj])))[0])
        assert np.linalg.norm(m.centroids[row] - truth[obj]) < 0.1


def test_slowly_drifting_object_stays_one_track_and_is_followed():
    rng = np.random.default_rng(5)
    mapper = ObjectMapper()
    ids = set()
    start = np.array([2.0, -1.0, 0.5])
    direction = np.array([0.6, 0.8, 0.0])
    for frame in range(100):
        truth = start + 0.02 * frame * direction
        ids.add(one(mapper, frame * DT, truth + rng.normal(0, 0.01, 3), 0.7, 1.2))
        assert len(mapper) == 1
    assert len(ids) == 1
    m = mapper.object_map()
    assert len(m) == 1
    assert np.linalg.norm(m.centroids[0] - truth) < 0.3
    # A tracker that averaged all 100 hits would lag by about 1 m.
    assert np.linalg.norm(m.centroids[0] - start) > 1.5


# ---------------------------------------------------------------------------------------------
# merging


def test_converging_tracks_seen_together_stay_apart_then_merge_into_the_lower_id():
    mapper = ObjectMapper()
    a0, b0, meet = np.array([0.0, 0, 1]), np.array([2.0, 0, 1]), np.array([1.0, 0, 1])
    ids_a = observe(mapper, 0.0, [a0], [0.5], [0.5])
    ids_b = observe(mapper, DT, [b0], [0.5], [0.5])
    a, b = int(ids_a[0]), int(ids_b[0])
    assert a < b
    # Both are seen in every frame, so they are two objects however close they come.
    for frame in range(2, 42):
        s = min(frame / 30.0, 1.0)
        obs = np.array([a0 + s * (meet - a0), b0 + s * (meet - b0)])
        ids = observe(mapper, frame * DT, obs, [0.5, 0.5], [0.5, 0.5])
        assert sorted(ids.tolist()) == [a, b]
    assert len(mapper) == 2
    # From now on one segment is seen where the two were: the tracks drift together and, once
    # within merge_distance in a frame that saw only one of them, merge into the lower id.
    for frame in range(42, 80):
        ids = observe(mapper, frame * DT, [meet], [0.5], [0.5])
    assert ids.tolist() == [a]
    assert len(mapper) == 1
    assert mapper.confirmed_ids().tolist() == [a]
    np.testing.assert_allclose(mapper.object_map().centroids[0], meet, atol=0.05)


def test_merge_is_hits_weighted_and_reports_the_surviving_id():
    # max_average = 1: every track sits exactly on its latest observation.
    mapper = ObjectMapper(MapperParams(nu=3, max_average=1))
    low, high = observe(mapper, 0.0, [[0, 0, 0], [0.5, 0, 0]], [1, 1], [1, 1]).tolist()
    one(mapper, DT, [0.5, 0, 0], 1.0, 1.0)
    one(mapper, 2 * DT, [0.5, 0, 0], 1.0, 1.0)
    assert mapper.confirmed_ids().tolist() == [high]
    # low (2 hits) moves to 0.2, high (4 hits) to 0.3: 0.1 m apart, but both are seen in
    # this frame, so they stay two tracks with distinct ids.
    ids = observe(mapper, 3 * DT, [[0.3, 0, 0], [0.2, 0, 0]], [1.2, 0.9], [1, 1])
    assert ids.tolist() == [high, low]
    assert len(mapper) == 2
    # high alone (5 hits) moves to 0.27, 0.07 m from low (2 hits): they merge into low.
    ids = observe(mapper, 4 * DT, [[0.27, 0, 0]], [1.0], [1])
    assert ids.tolist() == [low]
    assert len(mapper) == 1
    assert mapper.confirmed_ids().tolist() == [low]
    m = mapper.object_map()
    np.testing.assert_allclose(m.centroids[0], [(2 * 0.2 + 5 * 0.27) / 7, 0, 0])
    assert m.widths[0] == pytest.approx((2 * 0.9 + 5 * 1.0) / 7)
    assert m.last_seen[0] == pytest.approx(4 * DT)
    # 7 hits: after the merge the running mean uses weight 1 / min(8, 1) = 1.
    one(mapper, 5 * DT, [0.25, 0, 0], 1.0, 1.0)
    np.testing.assert_allclose(mapper.object_map().centroids[0], [0.25, 0, 0])


def test_close_tracks_with_incompatible_sizes_do_not_merge():
    mapper = ObjectMapper(MapperParams(nu=1))
    ids = observe(mapper, 0.0, [[0, 0, 0], [0.1, 0, 0]], [0.3, 1.5], [1, 1])
    assert len(set(ids.tolist())) == 2
    assert len(mapper) == 2


def test_merge_distance_zero_disables_merging():
    mapper = ObjectMapper(MapperParams(nu=1, merge_distance=0.0))
    ids = observe(mapper, 0.0, [[0, 0, 0], [0.01, 0, 0]], [1, 1], [1, 1])
    assert len(set(ids.tolist())) == 2


def test_size_gate_blocks_association():
    mapper = ObjectMapper(MapperParams(nu=1, merge_distance=0.0))
    first = one(mapper, 0.0, [0, 0, 0], 0.5, 1.0)
    assert one(mapper, DT, [0, 0, 0], 1.0, 1.0) == first  # ratio exactly size_gate
    assert one(mapper, 2 * DT, [0, 0, 0], 0.5, 2.5) != first


def test_distance_gate_blocks_association():
    mapper = ObjectMapper(MapperParams(nu=1, merge_distance=0.0, max_average=1))
    first = one(mapper, 0.0, [0, 0, 0])
    assert one(mapper, DT, [0.6, 0.8, 0], 0.5, 1.0) == first  # 1 m: on the gate
    # 1.04 m away although within 1 m along every axis.
    assert one(mapper, 2 * DT, [1.2, 1.4, 0.6], 0.5, 1.0) != first
    assert len(mapper) == 2


def test_merge_with_an_unseen_track_keeps_the_latest_last_seen():
    mapper = ObjectMapper(MapperParams(nu=1, max_average=1))
    old = one(mapper, 0.0, [0, 0, 0])
    young = one(mapper, 1.0, [2.0, 0, 0])
    # young walks towards old, each observation nearer to young than to old.
    for t, x in ((2.0, 1.2), (3.0, 0.65), (4.0, 0.35)):
        assert one(mapper, t, [x, 0, 0]) == young
    assert len(mapper) == 2
    assert one(mapper, 5.0, [0.2, 0, 0]) == old  # 0.2 m from old: merged into the lower id
    assert mapper.confirmed_ids().tolist() == [old]
    m = mapper.object_map()
    assert m.last_seen.tolist() == [5.0]
    np.testing.assert_allclose(m.centroids[0], [5 * 0.2 / 6, 0, 0])


def test_global_nearest_neighbour_beats_greedy():
    mapper = ObjectMapper(MapperParams(nu=1, merge_distance=0.0, size_weight=0.0))
    a, b = observe(mapper, 0.0, [[0, 0, 0], [1.0, 0, 0]], [1, 1], [1, 1]).tolist()
    # Greedy would give the observation at 0.45 to a (0.45 < 0.55) and leave 1.5 unmatched;
    # the global assignment matches both.
    ids = observe(mapper, DT, [[0.45, 0, 0], [-0.5, 0, 0]], [1, 1], [1, 1])
    assert ids.tolist() == [b, a]


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_frames=st.integers(1, 15),
    max_k=st.integers(0, 12),
    nu=st.integers(1, 4),
)
def test_invariants_hold_for_random_observation_streams(seed, n_frames, max_k, nu):
    params = MapperParams(nu=nu, kappa=0.5)
    mapper = ObjectMapper(params)
    rng = np.random.default_rng(seed)
    t = 0.0
    issued: set[int] = set()
    for _ in range(n_frames):
        t += rng.choice([0.0, 0.1, 0.3, 1.0])
        k = int(rng.integers(0, max_k + 1))
        c = rng.uniform(0, 3, (k, 3))
        w, h = rng.uniform(0, 2, k), rng.uniform(0, 2, k)
        before = set(mapper._ids.tolist())
        ids = observe(mapper, t, c, w, h)
        assert len(set(ids.tolist())) == ids.size  # one frame's observations stay apart
        live = mapper._ids
        assert np.all(np.diff(live) > 0)
        assert set(ids.tolist()) <= set(live.tolist())
        newly = set(live.tolist()) - before
        assert not newly & issued  # ids are never reused
        issued |= set(live.tolist())
        # No two live tracks are left that should have been merged.
        d = np.linalg.norm(mapper._centroids[:, None] - mapper._centroids[None], axis=2)
        ratio_w = np.maximum(mapper._widths, 1e-3)
        ratio_h = np.maximum(mapper._heights, 1e-3)
        rw = np.maximum(ratio_w[:, None] / ratio_w[None], ratio_w[None] / ratio_w[:, None])
        rh = np.maximum(ratio_h[:, None] / ratio_h[None], ratio_h[None] / ratio_h[:, None])
        bad = (d < params.merge_distance) & (rw <= params.size_gate) & (rh <= params.size_gate)
        # only tracks last seen in one frame together may stay closer than merge_distance
        bad &= mapper._last_seen[:, None] != mapper._last_seen[None]
        np.fill_diagonal(bad, False)
        assert not bad.any()
        assert np.all(t - mapper._last_seen <= params.kappa)
        m = mapper.object_map()
        assert len(m) == int((mapper._hits >= nu).sum()) == mapper.confirmed_ids().size
        assert len(mapper) == live.size


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_observation_order_changes_only_the_labels(seed):
    truth, widths, heights = static_world(8, seed % 1000)
    rng = np.random.default_rng(seed)
    noise = rng.normal(0, 0.05, (6, *truth.shape))
    ordered, shuffled = ObjectMapper(), ObjectMapper()
    relabel: dict[int, int] = {}
    for frame in range(6):
        c = truth + noise[frame]
        perm = rng.permutation(len(truth))
        ids_a = observe(ordered, frame * DT, c, widths, heights)[perm]
        ids_b = observe(shuffled, frame * DT, c[perm], widths[perm], heights[perm])
        for a, b in zip(ids_a.tolist(), ids_b.tolist(), strict=True):
            assert relabel.setdefault(a, b) == b
    assert len(set(relabel.values())) == len(relabel) == len(truth)
    map_a, map_b = ordered.object_map(), shuffled.object_map()
    rows_b = {int(i): r for r, i in enumerate(shuffled.confirmed_ids())}
    for row_a, a in enumerate(ordered.confirmed_ids().tolist()):
        row_b = rows_b[relabel[a]]
        np.testing.assert_allclose(map_a.centroids[row_a], map_b.centroids[row_b])
        assert map_a.widths[row_a] == pytest.approx(map_b.widths[row_b])


# ---------------------------------------------------------------------------------------------
# empty input and validation


def test_empty_update_returns_empty_int64_array():
    mapper = ObjectMapper()
    for centroids in ([], np.zeros((0, 3))):
        ids = mapper.update(0.0, centroids, [], np.zeros(0))
        assert ids.dtype == np.int64
        assert ids.shape == (0,)
    assert len(mapper) == 0
    m = mapper.object_map()
    assert isinstance(m, ObjectMap)
    assert len(m) == 0
    assert mapper.confirmed_ids().dtype == np.int64


def test_empty_update_with_live_tracks_keeps_them():
    mapper = ObjectMapper(MapperParams(nu=1))
    track = one(mapper, 0.0, [0, 0, 0])
    assert mapper.update(1.0, np.zeros((0, 3)), [], []).shape == (0,)
    assert mapper.confirmed_ids().tolist() == [track]


def update_error(field: str) -> str:
    return re.escape("ObjectMapper.update: ") + r".*\b" + re.escape(field) + r"\b"


GOOD_C = np.array([[0.0, 0, 0], [1, 1, 1]])
GOOD_S = np.array([0.5, 0.5])


@pytest.mark.parametrize(
    ("field", "t", "centroids", "widths", "heights", "detail"),
    [
        ("centroids", 0.0, [[0, 0, 0], [1, math.nan, 1]], GOOD_S, GOOD_S, "nan"),
        ("centroids", 0.0, np.zeros((2, 2)), GOOD_S, GOOD_S, "(2, 2)"),
        ("centroids", 0.0, np.zeros(3), GOOD_S, GOOD_S, "(3,)"),
        ("centroids", 0.0, "abc", GOOD_S, GOOD_S, "str"),
        ("widths", 0.0, GOOD_C, np.ones(3), GOOD_S, "(3,)"),
        ("heights", 0.0, GOOD_C, GOOD_S, np.ones((2, 1)), "(2, 1)"),
        ("widths", 0.0, GOOD_C, [0.5, -0.1], GOOD_S, "-0.1"),
        ("heights", 0.0, GOOD_C, GOOD_S, [-2.0, 0.5], "-2.0"),
        ("widths", 0.0, GOOD_C, [0.5, math.inf], GOOD_S, "inf"),
        ("t", math.nan, GOOD_C, GOOD_S, GOOD_S, "nan"),
        ("t", "now", GOOD_C, GOOD_S, GOOD_S, "now"),
    ],
)
def test_bad_input_raises_data_error_naming_the_field(field, t, centroids, widths, heights,
                                                      detail):
    mapper = ObjectMapper()
    with pytest.raises(DataError, match=update_error(field)) as info:
        mapper.update(t, centroids, widths, heights)
    assert detail in str(info.value)
    assert len(mapper) == 0


def test_shape_error_message_is_exact():
    with pytest.raises(DataError) as info:
        ObjectMapper().update(0.0, np.zeros((4, 2)), np.ones(4), np.ones(4))
    assert str(info.value) == "ObjectMapper.update: centroids must have shape (k, 3), got (4, 2)"


def test_time_going_backwards_raises_and_leaves_state_alone():
    mapper = ObjectMapper(MapperParams(nu=1))
    track = one(mapper, 5.0, [0, 0, 0])
    one(mapper, 5.0, [0, 0, 0])  # the same time again is fine
    with pytest.raises(DataError, match=update_error("t")) as info:
        mapper.update(4.9, GOOD_C, GOOD_S, GOOD_S)
    assert "4.9" in str(info.value)
    assert len(mapper) == 1
    assert one(mapper, 5.1, [0, 0, 0]) == track


def test_bad_input_is_rejected_before_any_change():
    mapper = ObjectMapper(MapperParams(nu=1))
    one(mapper, 0.0, [0, 0, 0])
    with pytest.raises(DataError):
        mapper.update(100.0, [[0, 0, 0]], [-1.0], [1.0])
    assert len(mapper) == 1  # no forgetting happened at t = 100
    assert one(mapper, 1.0, [0, 0, 0]) == 0


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("nu", 0),
        ("nu", 2.5),
        ("nu", True),
        ("kappa", 0.0),
        ("kappa", -1.0),
        ("kappa", math.nan),
        ("gate", 0.0),
        ("gate", math.inf),
        ("size_gate", 0.9),
        ("size_weight", -0.1),
        ("max_average", 0),
        ("max_average", 3.0),
        ("merge_distance", -0.01),
        ("merge_distance", math.nan),
        ("tentative_timeout", 0.0),
    ],
)
def test_bad_params_raise_config_error_naming_field_and_value(field, value):
    with pytest.raises(ConfigError, match=re.escape(f"MapperParams.{field} = {value!r}")):
        MapperParams(**{field: value})


@pytest.mark.parametrize("field", [f for f in vars(MapperParams())])
@pytest.mark.parametrize("value", [None, "1", [1.0], True, math.nan], ids=repr)
def test_params_refuse_junk_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=f"^MapperParams.{field} = "):
        MapperParams(**{field: value})


def test_kappa_defaults_to_the_frame_aligners():
    """One kappa (the paper's 20 s): the map keeps what the aligner uses."""
    assert MapperParams().kappa == FrameAlignerParams().kappa == 20.0


def test_mapper_rejects_wrong_params_type():
    with pytest.raises(ConfigError, match="params"):
        ObjectMapper({"nu": 3})  # type: ignore[arg-type]


def test_default_params_and_edge_values_are_accepted():
    p = MapperParams()
    assert (p.nu, p.kappa, p.gate, p.size_gate, p.size_weight, p.max_average,
            p.merge_distance) == (3, 20.0, 1.0, 2.0, 0.5, 10, 0.3)
    MapperParams(nu=1, size_gate=1.0, size_weight=0.0, max_average=1, merge_distance=0.0,
                 kappa=math.inf)


# ---------------------------------------------------------------------------------------------
# observations with their point clouds (and colours)

VOXEL = MapperParams().cloud_voxel  # 0.02 m


def voxel_grid(lo, hi) -> np.ndarray:
    """(n, 3) the centres of the cloud voxels with integer indices lo <= (i, j, k) < hi: a
    cloud a track's `ObjectCloud` keeps exactly as it is (one point per voxel)."""
    axes = [VOXEL * (np.arange(a, b) + 0.5) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


#: a 0.6 x 0.4 x 0.5 m box, in voxels: x 2.0 to 2.6 m, y -1.0 to -0.6 m, z 0 to 0.5 m
BOX_LO, BOX_HI = (100, -50, 0), (130, -30, 25)
BOX_CENTRE = VOXEL * (np.array(BOX_LO) + BOX_HI) / 2  # (2.3, -0.8, 0.25)


def box_face(side: str) -> np.ndarray:
    """The voxels of one face of the box, one voxel thick: "-y" (the long face in front, 750
    voxels), "+x" (the short face on its right, 475 voxels: the edge is the front's) or
    "-x" (on its left)."""
    (x0, y0, z0), (x1, y1, z1) = BOX_LO, BOX_HI
    if side == "-y":
        return voxel_grid((x0, y0, z0), (x1, y0 + 1, z1))
    x = x1 - 1 if side == "+x" else x0
    return voxel_grid((x, y0 + 1, z0), (x + 1, y1, z1))


def observe_clouds(mapper: ObjectMapper, t: float, clouds, colours=None) -> np.ndarray:
    """Observations whose centroids and sizes are junk (far off, huge): with clouds, the
    track's centroid and sizes must come from the merged cloud, never from these."""
    k = len(clouds)
    return mapper.update(t, np.full((k, 3), 50.0), np.full(k, 9.0), np.full(k, 9.0),
                         clouds=clouds, colours=colours)


def test_faces_seen_apart_then_together_are_one_track_with_the_whole_box():
    """The front face, then the right face (they share an edge, nothing else), then both (a
    view from the corner): the corner view lands on the track of the face it shares most with
    and the other face's track is merged into it, the lower id surviving. The map's object
    is the whole box: its centre, width (longer side) and height, from the merged cloud,
    whatever the observations' own centroids and sizes said."""
    mapper = ObjectMapper(MapperParams(nu=1))
    front, right = box_face("-y"), box_face("+x")
    a = int(observe_clouds(mapper, 0.0, [front])[0])
    b = int(observe_clouds(mapper, 0.1, [right])[0])
    assert a != b  # nothing but an edge in common: two tracks until a view holds both
    corner = int(observe_clouds(mapper, 0.2, [np.vstack([front, right])])[0])
    assert corner == min(a, b) == a
    assert len(mapper) == 1 and mapper.confirmed_ids().tolist() == [a]
    om = mapper.object_map()
    assert len(om) == 1
    np.testing.assert_allclose(om.centroids[0], BOX_CENTRE, atol=0.02)
    assert om.widths[0] == pytest.approx(0.6, abs=0.03)
    assert om.heights[0] == pytest.approx(0.5, abs=0.03)
    assert om.last_seen[0] == pytest.approx(0.2)
    # later views of either face stay on it
    assert observe_clouds(mapper, 0.3, [right])[0] == a
    assert observe_clouds(mapper, 0.4, [front])[0] == a
    assert len(mapper) == 1


def test_a_fragment_lying_on_a_coarser_cloud_is_merged_into_it():
    mapper = ObjectMapper(MapperParams(nu=1, cloud_points=600))
    front, right = box_face("-y"), box_face("+x")
    a = int(observe_clouds(mapper, 0.0, [front])[0])
    observe_clouds(mapper, 0.1, [right])
    assert observe_clouds(mapper, 0.2, [np.vstack([front, right])])[0] == a
    assert len(mapper) == 1


def test_clouds_far_from_the_origin_are_kept_apart_and_joined_as_near_it():
    """30 km out along x (a long drive): two cubes 0.1 m apart stay two tracks and a second
    view of one joins it, as they do at the origin; voxels are not clipped into one cell."""
    for x0 in (0.0, 30_000.0, -30_000.0):
        left = voxel_grid((0, 0, 0), (10, 10, 10)) + np.array([x0, 0.0, 0.0])
        right = left + np.array([0.3, 0.0, 0.0])
        mapper = ObjectMapper(MapperParams(nu=1))
        a, b = observe_clouds(mapper, 0.0, [left, right]).tolist()
        assert a != b
        assert observe_clouds(mapper, 0.1, [left + 0.005])[0] == a
        assert observe_clouds(mapper, 0.2, [right])[0] == b
        assert len(mapper) == 2
        np.testing.assert_allclose(mapper.object_map().widths, [0.2, 0.2], atol=0.02)


def test_neighbouring_objects_03m_apart_stay_two_tracks_with_clouds():
    """Two 0.2 m cubes 0.3 m apart (0.1 m gap), seen alone and together: with their clouds
    they are two tracks throughout. By centroids alone (the old rule) the second cube's
    first sighting joins the first cube's track (0.3 m, inside the 1 m gate)."""
    left = voxel_grid((0, 0, 0), (10, 10, 10))
    right = voxel_grid((15, 0, 0), (25, 10, 10))
    sequence = [[left], [right], [left, right], [right, left], [left], [right]]
    mapper = ObjectMapper(MapperParams(nu=1))
    ids = {}
    for i, clouds in enumerate(sequence):
        got = observe_clouds(mapper, 0.1 * i, clouds)
        for cloud, track in zip(clouds, got, strict=True):
            name = "left" if cloud is left else "right"
            assert ids.setdefault(name, int(track)) == track, f"frame {i}: {name} moved"
    assert ids["left"] != ids["right"] and len(mapper) == 2
    om = mapper.object_map()
    np.testing.assert_allclose(om.centroids, [[0.1, 0.1, 0.1], [0.4, 0.1, 0.1]], atol=0.02)

    old = ObjectMapper(MapperParams(nu=1))
    c_left, c_right = left.mean(axis=0), right.mean(axis=0)
    assert one(old, 0.0, c_left, 0.2, 0.2) == one(old, 0.1, c_right, 0.2, 0.2)


def bhattacharyya(p: np.ndarray, q: np.ndarray) -> float:
    return float(np.sum(np.sqrt(p * q)))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 1.0))
def test_descriptors_are_unit_and_weigh_colour_and_shape(seed, colour_weight):
    """Two objects of different shape (a pole and a board) with random colour histograms:
    the map's descriptors are unit rows sqrt(w c / sum c) and sqrt((1 - w) s) (s the merged
    cloud's shape features), so their dot product is w BC(colour) + (1 - w) BC(shape). A
    second sighting averages the histograms (running mean)."""
    from tcaff_gtsam.mapping.objects import shape_features

    rng = np.random.default_rng(seed)
    p = MapperParams(nu=1, colour_weight=colour_weight)
    bins = p.hue_bins * p.saturation_bins + 1
    pole = voxel_grid((0, 0, 0), (2, 2, 50))  # 0.04 x 0.04 x 1 m
    board = voxel_grid((50, 0, 0), (75, 1, 30))  # 0.5 x 0.02 x 0.6 m
    first = rng.random((2, bins)) * (rng.random((2, bins)) < 0.5)
    first[:, 0] += 0.01  # never all zero
    second = rng.random((2, bins))
    mapper = ObjectMapper(p)
    observe_clouds(mapper, 0.0, [pole, board], colours=first)
    observe_clouds(mapper, 0.1, [pole, board], colours=second)
    d = mapper.object_map().descriptors
    assert d is not None and d.shape == (2, bins + 3)
    assert np.all(d >= 0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    mean = (first + second) / 2  # hits 1 then 2: weight 1/2
    colours = mean / mean.sum(axis=1, keepdims=True)
    shapes = np.array([shape_features(pole), shape_features(board)])
    assert shapes[0, 0] > 0.9 and shapes[1, 1] > 0.5  # a pole is linear, a board planar
    w = colour_weight
    np.testing.assert_allclose(d[:, :bins], np.sqrt(w * colours), atol=1e-12)
    np.testing.assert_allclose(d[:, bins:], np.sqrt((1 - w) * shapes), atol=1e-12)
    expected = (w * bhattacharyya(colours[0], colours[1])
                + (1 - w) * bhattacharyya(shapes[0], shapes[1]))
    assert float(d[0] @ d[1]) == pytest.approx(expected, abs=1e-12)


def test_descriptors_need_colours_and_clouds_for_every_confirmed_track():
    assert ObjectMapper().object_map().descriptors is None  # an empty map has none
    cloud = voxel_grid((0, 0, 0), (10, 10, 10))
    mapper = ObjectMapper(MapperParams(nu=1))
    observe_clouds(mapper, 0.0, [cloud])
    assert mapper.object_map().descriptors is None  # no colours
    plain = ObjectMapper(MapperParams(nu=1))
    plain.update(0.0, [[0.1, 0.1, 0.1]], [0.2], [0.2], colours=np.ones((1, 37)))
    assert plain.object_map().descriptors is None  # no cloud
    both = ObjectMapper(MapperParams(nu=1))
    observe_clouds(both, 0.0, [cloud], colours=np.ones((1, 37)))
    observe_clouds(both, 0.1, [cloud + 5.0])  # a second track without colours
    assert len(both) == 2 and both.object_map().descriptors is None
    observe_clouds(both, 0.2, [cloud + 5.0], colours=np.ones((1, 37)))
    assert both.object_map().descriptors.shape == (2, 40)


def test_an_all_zero_colour_histogram_is_refused_and_changes_nothing():
    mapper = ObjectMapper(MapperParams(nu=1))
    cloud = voxel_grid((0, 0, 0), (10, 10, 10))
    with pytest.raises(DataError, match=r"colours\[0\] is all zeros"):
        observe_clouds(mapper, 0.0, [cloud], colours=np.zeros((1, 37)))
    assert len(mapper) == 0
    observe_clouds(mapper, 0.0, [cloud], colours=np.ones((1, 37)))
    assert len(mapper.object_map()) == 1


def test_clouds_are_given_in_every_update_or_in_none():
    """A track without a cloud could never be assigned by overlap: its object, seen again
    with a cloud, would start a second track. So the first update with observations fixes
    whether they come with clouds; an empty update may leave them out."""
    cloud = voxel_grid((0, 0, 0), (10, 10, 10))
    centroid, size = cloud.mean(axis=0), [0.2]
    with_clouds = ObjectMapper(MapperParams(nu=1))
    with_clouds.update(0.0, np.zeros((0, 3)), [], [])
    observe_clouds(with_clouds, 0.1, [cloud])
    with_clouds.update(0.2, np.zeros((0, 3)), [], [])
    with pytest.raises(DataError, match=r"clouds = None, but this mapper's earlier "
                                        r"observations came with clouds"):
        with_clouds.update(0.3, [centroid], size, size)
    observe_clouds(with_clouds, 0.3, [cloud])
    assert len(with_clouds) == 1 and with_clouds._hits.tolist() == [2]
    without = ObjectMapper(MapperParams(nu=1))
    without.update(0.0, [centroid], size, size)
    with pytest.raises(DataError, match=r"clouds = a list, but .* came without clouds"):
        observe_clouds(without, 0.1, [cloud])
    assert len(without) == 1 and without._hits.tolist() == [1]


GOOD_CLOUD = voxel_grid((0, 0, 0), (5, 5, 5))  # 125 points, 0.1 m cube


def with_nan(cloud: np.ndarray) -> np.ndarray:
    out = cloud.copy()
    out[3, 1] = np.nan
    return out


@pytest.mark.parametrize(
    ("clouds", "colours", "match"),
    [
        (GOOD_CLOUD[None], None, r"clouds must be None or a list of 1"),
        ([], None, r"clouds must be None or a list of 1 .* of 0"),
        ([GOOD_CLOUD, GOOD_CLOUD], None, r"list of 1 .* of 2"),
        ([GOOD_CLOUD[:, :2]], None, r"clouds\[0\] must have shape \(n, 3\) .* \(125, 2\)"),
        ([np.zeros((0, 3))], None, r"clouds\[0\] must have shape \(n, 3\) with n >= 1"),
        ([with_nan(GOOD_CLOUD)], None, r"clouds\[0\] holds non-finite"),
        ([GOOD_CLOUD + 2e9], None, r"clouds\[0\] holds coordinates beyond 1e\+09 m"),
        ([[*GOOD_CLOUD.tolist(), ["a", "b", "c"]]], None, r"clouds\[0\]"),
        ([GOOD_CLOUD], -np.ones((1, 37)), r"colours must be finite numbers >= 0"),
        ([GOOD_CLOUD], np.full((1, 37), np.nan), r"colours must be finite"),
        ([GOOD_CLOUD], np.ones((2, 37)), r"colours must have shape \(1, B\)"),
        ([GOOD_CLOUD], np.ones(37), r"colours must have shape \(1, B\)"),
        ([GOOD_CLOUD], np.ones((1, 36)), r"colours has 36 bins; the histograms of "
                                         r"hue_bins = 12 x saturation_bins = 3 have 37"),
        ([GOOD_CLOUD], [["x"] * 37], r"colours"),
    ],
    ids=["array", "none", "two", "xy", "empty", "nan", "far", "strings", "negative", "nan-colour",
         "rows", "1-d", "bins", "str-colour"],
)
def test_bad_clouds_and_colours_are_refused_naming_them_and_change_nothing(clouds, colours,
                                                                           match):
    mapper = ObjectMapper(MapperParams(nu=1))
    track = int(observe_clouds(mapper, 0.0, [GOOD_CLOUD], colours=np.ones((1, 37)))[0])
    before = mapper.object_map()
    with pytest.raises(DataError, match=r"^ObjectMapper.update: .*" + match):
        mapper.update(100.0, [[0.05, 0.05, 0.05]], [0.1], [0.1], clouds=clouds,
                      colours=colours)
    assert len(mapper) == 1  # nothing forgotten at t = 100, nothing added
    after = mapper.object_map()
    np.testing.assert_array_equal(after.centroids, before.centroids)
    np.testing.assert_array_equal(after.descriptors, before.descriptors)
    # a later good update (earlier than the refused one's t) still works, on the same track
    got = observe_clouds(mapper, 1.0, [GOOD_CLOUD + 0.01], colours=np.ones((1, 37)))
    assert got.tolist() == [track] and len(mapper) == 1


@pytest.mark.parametrize(
    ("field", "value"),
    [("cloud_voxel", 0.0), ("cloud_voxel", math.inf), ("cloud_points", 15),
     ("cloud_points", 100.0), ("cloud_span", 0.0), ("hue_bins", 0), ("hue_bins", 65),
     ("saturation_bins", 0), ("colour_weight", -0.1), ("colour_weight", 1.5),
     ("overlap_cell", 0.0), ("overlap_cell", math.inf), ("min_overlap", 0.0),
     ("min_overlap", 1.01), ("merge_overlap", 0.0), ("merge_overlap", 2.0),
     ("extent_pad", -0.01), ("extent_pad", math.nan), ("extent_pad", math.inf)],
)
def test_bad_cloud_params_raise_config_error_naming_field_and_value(field, value):
    with pytest.raises(ConfigError, match=re.escape(f"MapperParams.{field} = {value!r}")):
        MapperParams(**{field: value})


def test_cloud_params_accept_their_edge_values():
    MapperParams(cloud_points=16, colour_weight=0.0, min_overlap=1.0, merge_overlap=1.0,
                 hue_bins=64, saturation_bins=1, cloud_span=math.inf)
    MapperParams(colour_weight=1.0)
