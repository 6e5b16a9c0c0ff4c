"""Candidates checked against every object: objects explained, spread, ambiguity with the maps'
other alignments and with the robots' earlier maps; what a filter may take; object ids."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import grid_maps, overlapping_maps

from tcaff_gtsam import FrameAligner, FrameAlignerParams, ObjectMap
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.frame_aligner import MapMemory
from tcaff_gtsam.geometry import se2_error, se2_from_params
from tcaff_gtsam.identities import ObjectIdentities, recent_ids
from tcaff_gtsam.pairwise import admitted, unchecked
from tcaff_gtsam.registration import mutual_inliers, spread
from tcaff_gtsam.tcaff import AlignmentEstimate

CHECKED = FrameAlignerParams(min_inliers=6, min_spread=0.25, check_ambiguity=True)
poses = st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-math.pi, math.pi))


def object_map(xy, now: float = 10.0, size: float = 0.5) -> ObjectMap:
    n = len(xy)
    return ObjectMap(np.column_stack([xy, np.zeros(n)]), np.full(n, size), np.full(n, size),
                     np.full(n, now))


@settings(max_examples=50, deadline=None)
@given(poses, st.integers(1, 12), st.integers(0, 2**32 - 1))
def test_every_object_is_an_inlier_under_the_true_alignment(pose, n, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-10, 10, (n, 2)) * np.arange(1, n + 1)[:, None]  # well apart
    T = se2_from_params(pose)
    q = (p - T[:2, 2]) @ T[:2, :2]  # p = R q + t
    order = rng.permutation(n)
    pairs = mutual_inliers(T, p, q[order], np.ones((n, n), bool), 0.3)
    assert pairs.shape == (n, 2)
    np.testing.assert_array_equal(order[pairs[:, 1]], pairs[:, 0])


def test_inliers_are_mutual_and_size_compatible():
    p = np.array([[0.0, 0.0], [0.2, 0.0]])
    q = np.array([[0.1, 0.0]])
    # q is nearest to both: only one pair may claim it
    assert mutual_inliers(np.eye(3), p, q, np.ones((2, 1), bool), 0.3).shape == (1, 2)
    assert mutual_inliers(np.eye(3), p, q, np.zeros((2, 1), bool), 0.3).shape == (0, 2)
    assert mutual_inliers(np.eye(3), p, q + 1.0, np.ones((2, 1), bool), 0.3).shape == (0, 2)


@settings(max_examples=50, deadline=None)
@given(st.integers(2, 20), st.floats(-math.pi, math.pi), st.integers(0, 2**32 - 1))
def test_points_on_a_line_have_no_spread_whatever_their_direction(n, heading, seed):
    along = np.random.default_rng(seed).uniform(-5, 5, n)
    line = np.column_stack([np.cos(heading) * along, np.sin(heading) * along])
    assert spread(line) == pytest.approx(0.0, abs=1e-6)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    assert spread(square) == pytest.approx(0.5)


def test_a_correct_candidate_explains_the_overlap_and_passes_the_checks():
    for seed in range(5):
        pair = overlapping_maps(np.random.default_rng(seed), 40, 0.6, 0.1, clutter=10)
        found = FrameAligner(CHECKED).measurements(pair.ego, pair.other, pair.now)
        assert found and not found[0].ambiguous
        assert found[0].inliers >= 15  # of 24 shared objects, 0.1 m noise per axis
        dt, dtheta = se2_error(pair.T_oi_oj, found[0].T)
        assert dt < 1.0 and math.degrees(dtheta) < 5.0


def test_a_symmetric_world_gives_ambiguous_candidates_only():
    """A 2 x 4 grid of identical objects matches itself turned half a turn as well as it matches
    the truth: every candidate is flagged, the unchecked aligner reports them as unique."""
    pair = grid_maps()
    found = FrameAligner(CHECKED).measurements(pair.ego, pair.other, pair.now)
    assert found and all(m.ambiguous for m in found)
    plain = FrameAligner(unchecked(CHECKED)).measurements(pair.ego, pair.other, pair.now)
    assert plain and not any(m.ambiguous for m in plain)


def test_a_look_alike_in_an_earlier_map_makes_a_candidate_ambiguous():
    """The ego saw a copy of the shared cluster elsewhere before: the current maps alone look
    unique, the earlier map shows another place the other's objects fit as well."""
    rng = np.random.default_rng(3)
    cluster = rng.uniform(0, 4, (7, 2))
    T = se2_from_params([2.0, 1.0, 0.4])
    other = object_map((cluster - T[:2, 2]) @ T[:2, :2])
    ego = object_map(cluster)
    earlier = object_map(cluster + np.array([30.0, -12.0]), now=-40.0)
    aligner = FrameAligner(replace(CHECKED, memory_span=100.0))
    alone = aligner.measurements(ego, other, 10.0)
    assert alone and not alone[0].ambiguous
    with_memory = aligner.measurements(ego, other, 10.0, ego_past=[(-40.0, earlier)])
    assert with_memory and with_memory[0].ambiguous
    # the same place seen before is no rival: it gives the same alignment
    same = aligner.measurements(ego, other, 10.0, ego_past=[(-40.0, object_map(cluster, -40))])
    assert same and not same[0].ambiguous


def test_the_search_of_earlier_maps_is_capped_and_takes_the_most_familiar_first():
    """Earlier maps that repeat the current one are searched before a map of elsewhere; at most
    `memory_searches` of them, so the look-alike elsewhere is found only when the cap leaves
    room for it."""
    rng = np.random.default_rng(3)
    cluster = rng.uniform(0, 4, (7, 2))
    T = se2_from_params([2.0, 1.0, 0.4])
    other = object_map((cluster - T[:2, 2]) @ T[:2, :2])
    ego = object_map(cluster)
    elsewhere = (-40.0, object_map(cluster + np.array([30.0, -12.0]), now=-40.0))
    familiar = [(t, object_map(cluster, now=t)) for t in (-20.0, 0.0)]
    past = [elsewhere, *familiar]
    for cap, flagged in ((0, False), (2, False), (3, True)):
        aligner = FrameAligner(replace(CHECKED, memory_span=100.0, memory_searches=cap))
        found = aligner.measurements(ego, other, 10.0, ego_past=past)
        assert found and found[0].ambiguous is flagged, cap


def test_a_candidate_on_a_line_of_objects_is_refused_by_its_spread():
    xy = np.column_stack([np.arange(8.0) * 1.3 + 0.2 * np.arange(8) ** 2, np.zeros(8)])
    pair_ego, pair_other = object_map(xy), object_map(xy - [1.0, 0.0])
    assert FrameAligner(FrameAlignerParams(min_spread=0.0)).measurements(pair_ego, pair_other,
                                                                       10.0)
    assert FrameAligner(FrameAlignerParams()).measurements(pair_ego, pair_other, 10.0) == []


def test_too_few_objects_explained_is_no_candidate():
    pair = overlapping_maps(np.random.default_rng(0), 40, 0.6, 0.1, clutter=10)
    found = FrameAligner(CHECKED).measurements(pair.ego, pair.other, pair.now)
    most = max(m.inliers for m in found)
    assert FrameAligner(replace(CHECKED, min_inliers=most + 1)).measurements(
        pair.ego, pair.other, pair.now) == []


def estimate(x) -> AlignmentEstimate:
    return AlignmentEstimate(np.asarray(x, float), np.eye(3), 0.0, 1, 1, 1, 0)


def test_an_ambiguous_candidate_only_confirms_the_estimate_held():
    pair = grid_maps()
    found = FrameAligner(CHECKED).measurements(pair.ego, pair.other, pair.now)
    assert admitted(found, None, CHECKED) == []
    near = found[0].z + np.array([0.3, -0.2, math.radians(2.0)])
    assert any(m is found[0] for m in admitted(found, estimate(near), CHECKED))
    far = found[0].z + np.array([0.6, 0.0, 0.0])
    assert all(m is not found[0] for m in admitted(found, estimate(far), CHECKED))
    clear = [replace(m, ambiguous=False) for m in found]
    assert admitted(clear, None, CHECKED) == clear


def test_the_memory_keeps_one_map_per_interval_within_its_span():
    memory = MapMemory(span=60.0, every=20.0)
    for t in range(0, 200):
        memory.add(float(t), ObjectMap.empty())
    times = [t for t, _ in memory.snapshots()]
    assert times == [140.0, 160.0, 180.0]
    off = MapMemory(span=0.0, every=20.0)
    off.add(0.0, ObjectMap.empty())
    assert off.snapshots() == []


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 30), st.integers(0, 2**32 - 1))
def test_objects_keep_their_ids_whatever_order_and_small_noise(n, seed):
    rng = np.random.default_rng(seed)
    xy = np.column_stack([np.arange(n) * 2.0, rng.uniform(-1, 1, n)])
    ids = ObjectIdentities()
    first = ids.update(xy)
    assert len(set(first.tolist())) == n
    order = rng.permutation(n)
    again = ids.update(xy[order] + rng.normal(0, 0.03, (n, 2)))
    np.testing.assert_array_equal(again, first[order])


def test_new_and_forgotten_objects_get_new_ids():
    ids = ObjectIdentities(gate=0.3, memory=2)
    a = ids.update([[0.0, 0.0]])
    b = ids.update([[0.0, 0.0], [5.0, 5.0]])
    assert b[0] == a[0] and b[1] != a[0]
    ids.update(np.empty((0, 2)))
    ids.update(np.empty((0, 2)))
    c = ids.update([[0.0, 0.0]])  # unseen for two exchanges: forgotten
    assert c[0] not in (a[0], b[1])
    assert ids.update([[0.0, 1.0]])[0] != c[0]  # beyond the gate


@pytest.mark.parametrize("bad", [[[np.nan, 0.0]], [[1.0, 2.0, 3.0]], "xy", [[None, 1.0]]])
def test_bad_positions_are_data_errors(bad):
    with pytest.raises(DataError, match=r"ObjectIdentities\.update"):
        ObjectIdentities().update(bad)


@pytest.mark.parametrize(("kwargs", "field"), [({"gate": 0}, "gate"), ({"memory": 0}, "memory"),
                                               ({"gate": math.inf}, "gate")])
def test_bad_identity_settings_are_config_errors(kwargs, field):
    with pytest.raises(ConfigError, match=rf"ObjectIdentities\.{field}"):
        ObjectIdentities(**kwargs)


def test_checks_off_give_the_unchecked_candidates_less_the_residual_check():
    """With the checks off, the aligner reports exactly the released code's candidates that
    pass `max_rmse`, counting no objects and flagging nothing, also where the checks would
    refuse or flag candidates (a symmetric grid, a line of objects)."""
    off = replace(CHECKED, min_inliers=None, min_spread=0.0, check_ambiguity=False)
    line = np.column_stack([np.arange(8.0) * 1.3 + 0.2 * np.arange(8) ** 2, np.zeros(8)])
    pair = overlapping_maps(np.random.default_rng(1), 40, 0.6, 0.1, clutter=10)
    cases = [(pair.ego, pair.other, pair.now), (grid_maps().ego, grid_maps().other, 100.0),
             (object_map(line), object_map(line - [1.0, 0.0]), 10.0)]
    for ego, other, now in cases:
        released = FrameAligner(FrameAlignerParams.reference()).measurements(ego, other, now)
        assert released
        expected = [m.z.tolist() for m in released if m.rmse <= off.max_rmse]
        found = FrameAligner(off).measurements(ego, other, now)
        assert [m.z.tolist() for m in found] == expected
        assert all(m.inliers == 0 and not m.ambiguous for m in found)


def test_only_objects_seen_within_kappa_get_ids():
    objects = ObjectMap(np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [6.0, 0.0, 0.0]]),
                        np.ones(3), np.ones(3), np.array([9.0, -30.0, 10.0]))
    identities = ObjectIdentities()
    first = recent_ids(identities, objects, 10.0, 20.0)
    assert first[1] == -1 and first[0] >= 0 and first[2] >= 0
    np.testing.assert_array_equal(recent_ids(identities, objects, 11.0, 20.0), first)


# candidates need 5 associations here, so that three shared objects are only tracked
TRACKING = FrameAlignerParams(track_min=3, min_associations=5)


def three_shared(T: np.ndarray, noise: float = 0.0, seed: int = 0):
    """An ego map of 3 objects and the other robot's view of them through T (plus 2 objects
    of its own): too few for a MNO-CLIPPER candidate (5 associations), enough to track."""
    rng = np.random.default_rng(seed)
    shared = np.array([[0.0, 0.0], [3.0, 0.5], [1.0, 2.5]])
    in_other = (shared - T[:2, 2]) @ T[:2, :2] + rng.normal(0, noise, (3, 2))
    return object_map(shared), object_map(np.vstack([in_other, [[40.0, 40.0], [-40.0, 5.0]]]))


@settings(max_examples=30, deadline=None)
@given(st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-math.pi, math.pi)),
       st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-0.015, 0.015))
def test_a_held_alignment_is_tracked_on_fewer_objects_than_a_candidate_needs(pose, dx, dy,
                                                                             dtheta):
    """Held within 0.28 m and 0.9 deg of the truth, objects at most 9 m from the other's
    origin: each lies within confirm_translation (0.5 m) of its match."""
    T = se2_from_params(pose)
    ego, other = three_shared(T)
    aligner = FrameAligner(TRACKING)
    assert aligner.measurements(ego, other, 10.0) == []
    held = np.array(pose) + np.array([dx, dy, dtheta])
    found = aligner.measurements(ego, other, 10.0, held=held)
    assert len(found) == 1 and found[0].tracked and found[0].inliers == 3
    assert sorted(map(tuple, found[0].associations)) == [(0, 0), (1, 1), (2, 2)]
    dt, dth = se2_error(T, found[0].T)
    assert dt < 1e-6 and dth < 1e-6  # re-registered on the objects, not the held value
    assert admitted(found, None, TRACKING) == []  # it never starts a hypothesis
    assert admitted(found, estimate(held), TRACKING) == found


def test_nothing_is_tracked_when_the_held_alignment_pairs_too_few_or_is_off():
    T = se2_from_params([2.0, -1.0, 0.7])
    ego, other = three_shared(T)
    z = np.array([2.0, -1.0, 0.7])
    assert FrameAligner(FrameAlignerParams(min_associations=5)).measurements(
        ego, other, 10.0, held=z) == []
    assert FrameAligner(replace(TRACKING, track_min=4)).measurements(ego, other, 10.0,
                                                                     held=z) == []
    # one metre off pairs nothing within confirm_translation
    off = z + np.array([1.0, 0.0, 0.0])
    assert FrameAligner(TRACKING).measurements(ego, other, 10.0, held=off) == []
    # objects on a line fix no rotation: refused by min_spread like a candidate
    line = object_map(np.array([[0.0, 0.0], [1.0, 0.0], [2.5, 0.0]]))
    assert FrameAligner(TRACKING).measurements(line, line, 10.0, held=np.zeros(3)) == []
    assert FrameAligner(replace(TRACKING, min_spread=0.0)).measurements(line, line, 10.0,
                                                                       held=np.zeros(3))


@pytest.mark.parametrize("bad", [1, 0, -3, 2.5, "3", True])
def test_bad_track_min_is_a_config_error(bad):
    with pytest.raises(ConfigError, match="track_min"):
        FrameAlignerParams(track_min=bad)
