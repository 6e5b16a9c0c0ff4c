"""Ranking the pairs of look-alike objects by their neighbourhoods, when the size gate passes
more pairs than `max_associations`."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import maximum_bipartite_matching

from tcaff_gtsam import FrameAligner, FrameAlignerParams, ObjectMap
from tcaff_gtsam import association as reg
from tcaff_gtsam.association import _neighbourhood_pairs, neighbourhood_agreement
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_error, se2_from_params, transform_points

seeds = st.integers(0, 2**32 - 1)
poses = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-math.pi, math.pi))


def clustered(rng: np.random.Generator, n: int, shared: int):
    """Two maps of n look-alike objects (1 x 1 m) in clusters of about eight, `shared` of them
    in both; the other's frame turned and moved. Returns the maps, the true pairs (k, 2) and
    T_oi_oj."""
    n_world = 2 * n - shared
    centres = rng.uniform(0.0, 4.0 * math.sqrt(n_world), (max(1, n_world // 8), 2))
    xy = centres[rng.integers(len(centres), size=n_world)] + rng.normal(0, 1.0, (n_world, 2))
    T_oi_oj = se2_from_params([*rng.uniform(-20, 20, 2), rng.uniform(-math.pi, math.pi)])
    ego_ids = rng.permutation(n)
    other_ids = rng.permutation(np.r_[np.arange(shared), np.arange(n, n_world)])

    def seen(ids, T):
        c = transform_points(T, xy[ids]) + rng.normal(0, 0.1, (len(ids), 2))
        return ObjectMap(np.column_stack([c, np.zeros(len(ids))]), np.ones(len(ids)),
                         np.ones(len(ids)), rng.uniform(0, 15, len(ids)))

    ego = seen(ego_ids, np.eye(3))
    other = seen(other_ids, np.linalg.inv(T_oi_oj))
    true = np.argwhere(ego_ids[:, None] == other_ids[None, :])
    return ego, other, true, T_oi_oj


@settings(max_examples=40, deadline=None)
@given(seeds, st.integers(1, 40), st.integers(1, 40), poses, poses, st.integers(1, 12))
def test_agreement_is_the_same_in_any_frame(seed, n, m, pose_ego, pose_other, neighbours):
    rng = np.random.default_rng(seed)
    p, q = rng.uniform(0, 20, (n, 2)), rng.uniform(0, 20, (m, 2))
    pairs = np.argwhere(np.ones((n, m), bool))
    before = neighbourhood_agreement(p, q, pairs, 0.25, neighbours)
    moved_p = transform_points(se2_from_params(pose_ego), p)
    moved_q = transform_points(se2_from_params(pose_other), q)
    np.testing.assert_array_equal(
        neighbourhood_agreement(moved_p, moved_q, pairs, 0.25, neighbours), before)
    # and the order of the objects in their maps does not matter either
    order_p, order_q = rng.permutation(n), rng.permutation(m)
    shuffled = neighbourhood_agreement(p[order_p], q[order_q], pairs, 0.25, neighbours)
    back = np.empty((n, m), np.int64)
    back[np.ix_(order_p, order_q)] = shuffled.reshape(n, m)
    np.testing.assert_array_equal(back.ravel(), before)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(1, 15), st.integers(1, 15), st.integers(1, 10),
       st.floats(0.05, 3.0))
def test_agreement_is_the_largest_matching_of_neighbour_distances(seed, n, m, neighbours,
                                                                  epsilon):
    rng = np.random.default_rng(seed)
    # whole decimetres: many equal distances, which the greedy matching must not miscount
    p, q = rng.integers(0, 40, (n, 2)) / 10, rng.integers(0, 40, (m, 2)) / 10
    pairs = np.argwhere(np.ones((n, m), bool))
    got = neighbourhood_agreement(p, q, pairs, epsilon, neighbours)

    def nearest(points, i):
        d = np.sort(np.delete(np.hypot(*(points - points[i]).T), i))
        return d[:neighbours]

    for s, (i, j) in enumerate(pairs):
        a, b = nearest(p, i), nearest(q, j)
        close = csr_matrix(np.abs(a[:, None] - b[None, :]) < epsilon)
        assert got[s] == np.count_nonzero(maximum_bipartite_matching(close) >= 0)


def best_by_brute_force(scores, ages_ego, ages_other, compatible, per_object):
    """(n, m) bool: per row and per column the per_object best compatible pairs by (score
    high, age sum low, index low)."""
    n, m = scores.shape
    age = ages_ego[:, None] + ages_other[None, :]
    keep = np.zeros((n, m), bool)
    for i in range(n):
        js = np.flatnonzero(compatible[i])
        best = js[np.lexsort((js, age[i, js], -scores[i, js]))][:per_object]
        keep[i, best] = True
    for j in range(m):
        is_ = np.flatnonzero(compatible[:, j])
        best = is_[np.lexsort((is_, age[is_, j], -scores[is_, j]))][:per_object]
        keep[best, j] = True
    return keep


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(0, 25), st.integers(0, 25), st.integers(1, 4), st.integers(1, 200),
       st.integers(1, 8))
def test_each_object_keeps_its_best_pairs_up_to_the_cap(seed, n, m, per_object, cap,
                                                         neighbours):
    rng = np.random.default_rng(seed)
    p, q = rng.uniform(0, 10, (n, 2)), rng.uniform(0, 10, (m, 2))
    compatible = rng.random((n, m)) < 0.7
    # whole seconds: ties in the age sum as well as in the score
    ages_ego, ages_other = rng.integers(0, 3, n).astype(float), rng.integers(0, 3, m) * 1.0
    saved = reg.NEIGHBOURS
    reg.NEIGHBOURS = neighbours
    try:
        kept = _neighbourhood_pairs(compatible, p, q, ages_ego, ages_other, 0.3, per_object, cap)
    finally:
        reg.NEIGHBOURS = saved
    pairs = np.argwhere(np.ones((n, m), bool))
    scores = neighbourhood_agreement(p, q, pairs, 0.3, neighbours).reshape(n, m)
    best = np.argwhere(best_by_brute_force(scores, ages_ego, ages_other, compatible,
                                           per_object))
    if len(best) > cap:
        age = ages_ego[best[:, 0]] + ages_other[best[:, 1]]
        best = best[np.sort(np.lexsort((best[:, 1], best[:, 0], age,
                                        -scores[best[:, 0], best[:, 1]]))[:cap])]
    np.testing.assert_array_equal(kept, best)
    assert kept.dtype == np.int64 and kept.shape[1] == 2 and len(kept) <= cap
    assert compatible[kept[:, 0], kept[:, 1]].all()


def test_neighbourhoods_keep_the_true_pairs_where_recency_does_not():
    rng = np.random.default_rng(7)
    ego, other, true, _ = clustered(rng, 150, 75)
    compatible = np.ones((150, 150), bool)
    ages_ego, ages_other = ego.ages(20.0), other.ages(20.0)
    kept = _neighbourhood_pairs(compatible, ego.centroids[:, :2], other.centroids[:, :2],
                               ages_ego, ages_other, 0.25, 2, 10000)
    # the same number of pairs, those whose objects were seen most recently
    pairs = np.argwhere(compatible)
    recent = pairs[np.argsort(ages_ego[pairs[:, 0]] + ages_other[pairs[:, 1]],
                              kind="stable")[: len(kept)]]

    def share_kept(chosen):
        return len(set(map(tuple, chosen.tolist())) & set(map(tuple, true.tolist()))) / len(true)

    assert len(kept) <= 2 * 300
    assert share_kept(kept) >= 0.8
    assert share_kept(recent) <= 0.2


def test_an_aligner_over_the_cap_finds_the_alignment_of_look_alike_clusters():
    rng = np.random.default_rng(3)
    ego, other, true, T_oi_oj = clustered(rng, 120, 60)
    aligner = FrameAligner(FrameAlignerParams(max_associations=2000))
    found = aligner.measurements(ego, other, 20.0)
    assert aligner.thinned == 1
    assert found and se2_error(found[0].T, T_oi_oj)[0] < 0.3
    right = set(map(tuple, true.tolist()))
    best = found[0].associations
    assert sum(tuple(a) in right for a in best.tolist()) >= 0.8 * len(best)


@pytest.mark.parametrize("value", [0, -1, 1.5, None, True, "2"])
def test_pairs_per_object_is_an_int_at_least_one(value):
    with pytest.raises(ConfigError, match="pairs_per_object"):
        FrameAlignerParams(pairs_per_object=value)


@pytest.mark.parametrize(("kwargs", "error", "named"), [
    ({"epsilon": 0.0}, ConfigError, "epsilon"),
    ({"epsilon": math.nan}, ConfigError, "epsilon"),
    ({"neighbours": 0}, ConfigError, "neighbours"),
    ({"neighbours": 2.0}, ConfigError, "neighbours"),
    ({"ego_points": np.full((3, 2), np.nan)}, DataError, "ego_points"),
    ({"other_points": np.zeros((3, 3))}, DataError, "other_points"),
    ({"pairs": np.array([[0, 3]])}, DataError, "out of range"),
    ({"pairs": np.array([[0.5, 1]])}, DataError, "pairs"),
    ({"pairs": np.zeros((2, 3), int)}, DataError, "pairs"),
])
def test_agreement_refuses_bad_input_by_name(kwargs, error, named):
    args = {"ego_points": np.zeros((3, 2)), "other_points": np.ones((3, 2)),
            "pairs": np.array([[0, 1]]), "epsilon": 0.25, "neighbours": 2} | kwargs
    with pytest.raises(error, match=named):
        neighbourhood_agreement(**args)


def test_agreement_of_maps_of_one_object_is_zero():
    got = neighbourhood_agreement(np.zeros((1, 2)), np.zeros((1, 2)), np.array([[0, 0]]))
    np.testing.assert_array_equal(got, [0])
    assert neighbourhood_agreement(np.zeros((1, 2)), np.zeros((1, 2)),
                                   np.empty((0, 2), int)).shape == (0,)
