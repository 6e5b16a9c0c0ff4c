"""The partial-view size gate where it runs: which pairs only the partial-view rule passes
(`association.size_gates`), which of them enter the consistency graph
(`FrameAlignerParams.partial_pairs`: each the best pair of both its objects,
`association._partial_pairs_kept`) and when the aligner chooses among them
(`_partial_ranking_pays`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree
from test_priors import gate_reference, sized_map

import tcaff_gtsam.frame_aligner as fa
from tcaff_gtsam import FrameAligner, FrameAlignerParams, ObjectMap
from tcaff_gtsam import association as reg
from tcaff_gtsam.association import (
    _neighbour_distances,
    _partial_neighbours,
    _partial_pairs_kept,
    _partial_ranking_pays,
    neighbourhood_agreement,
    size_compatible,
    size_gates,
)
from tcaff_gtsam.geometry import invert, se2_error, se2_from_params, transform_points
from tcaff_gtsam.params import ParameterError
from tcaff_gtsam.registration import mutual_inliers

seeds = st.integers(0, 2**32 - 1)
extents = st.lists(st.tuples(st.floats(0.01, 3.0), st.floats(0.01, 3.0)), min_size=0,
                   max_size=8)


@settings(max_examples=80, deadline=None)
@given(ego=extents, other=extents, ratio=st.floats(1.0, 2.0), abs_diff=st.floats(0.0, 0.3),
       extra=st.none() | st.floats(0.0, 2.0))
def test_partial_pairs_are_exactly_those_only_the_partial_rule_passes(ego, other, ratio,
                                                                      abs_diff, extra):
    a = sized_map([w for w, _ in ego], [h for _, h in ego])
    b = sized_map([w for w, _ in other], [h for _, h in other])
    partial_ratio = None if extra is None else ratio + extra
    compatible, partial = size_gates(a, b, ratio, abs_diff, partial_ratio)
    paper = set(gate_reference(a, b, ratio, abs_diff, None))
    whole = set(gate_reference(a, b, ratio, abs_diff, partial_ratio))
    assert set(map(tuple, np.argwhere(compatible).tolist())) == whole
    assert set(map(tuple, np.argwhere(partial).tolist())) == whole - paper
    np.testing.assert_array_equal(compatible, size_compatible(a, b, ratio, abs_diff,
                                                              partial_ratio))
    if partial_ratio is None or partial_ratio <= ratio:
        assert not partial.any()


def test_a_partial_pair_is_one_extent_cut():
    ego = sized_map([0.5, 0.5, 0.5], [1.0, 1.0, 1.0])
    # complete; height cut; width cut by more than the partial ratio allows
    other = sized_map([0.5, 0.5, 0.2], [1.0, 0.55, 1.0])
    compatible, partial = size_gates(ego, other, 1.35, 0.1, 2.0)
    assert compatible[:, :2].all() and not compatible[:, 2].any()
    assert not partial[:, 0].any() and partial[:, 1].all()


def ranked_by_brute_force(p, q, compatible, ages_ego, ages_other, epsilon, neighbours):
    """(n, m) bool: the compatible pairs that rank first, by (agreement high, age sum low,
    index low), among the compatible pairs of both their objects."""
    n, m = compatible.shape
    pairs = np.argwhere(np.ones((n, m), bool))
    scores = neighbourhood_agreement(p, q, pairs, epsilon, neighbours).reshape(n, m)
    age = ages_ego[:, None] + ages_other[None, :]
    first_of_row = np.full(n, -1)
    first_of_col = np.full(m, -1)
    for i in range(n):
        js = np.flatnonzero(compatible[i])
        if js.size:
            first_of_row[i] = js[np.lexsort((js, age[i, js], -scores[i, js]))][0]
    for j in range(m):
        is_ = np.flatnonzero(compatible[:, j])
        if is_.size:
            first_of_col[j] = is_[np.lexsort((is_, age[is_, j], -scores[is_, j]))][0]
    best = np.zeros((n, m), bool)
    for i in range(n):
        j = first_of_row[i]
        if j >= 0 and first_of_col[j] == i:
            best[i, j] = True
    return best


@settings(max_examples=80, deadline=None)
@given(seeds, st.integers(0, 20), st.integers(0, 20), st.floats(0.0, 1.0),
       st.floats(0.0, 1.0), st.integers(1, 12))
def test_a_partial_pair_is_kept_exactly_when_it_is_the_best_pair_of_both_its_objects(
        seed, n, m, share, partial_share, neighbours):
    rng = np.random.default_rng(seed)
    # whole decimetres and whole seconds: ties in the agreement and in the ages
    p, q = rng.integers(0, 60, (n, 2)) / 10, rng.integers(0, 60, (m, 2)) / 10
    ages_ego, ages_other = rng.integers(0, 3, n) * 1.0, rng.integers(0, 3, m) * 1.0
    compatible = rng.random((n, m)) < share
    partial = compatible & (rng.random((n, m)) < partial_share)
    saved = reg.NEIGHBOURS
    reg.NEIGHBOURS = neighbours
    try:
        k = _partial_neighbours(int(np.count_nonzero(compatible)))
        kept = _partial_pairs_kept(compatible, partial, p, q, ages_ego, ages_other, 0.3)
    finally:
        reg.NEIGHBOURS = saved
    assert kept.dtype == np.bool_ and kept.shape == (n, m)
    expected = ranked_by_brute_force(p, q, compatible, ages_ego, ages_other, 0.3, k) & partial
    np.testing.assert_array_equal(kept, expected)
    assert (kept.sum(axis=1) <= 1).all() and (kept.sum(axis=0) <= 1).all()
    assert not (kept & ~partial).any()


@settings(max_examples=40, deadline=None)
@given(seeds, st.integers(1, 60), st.integers(1, 3), st.integers(1, 70))
def test_sorted_distance_rows_are_the_trees_nearest_neighbours(seed, n, d, neighbours):
    rng = np.random.default_rng(seed)
    points = rng.integers(0, 30, (n, d)) / 10.0  # duplicates and ties
    got = _neighbour_distances(points, neighbours)
    k = min(neighbours, n - 1)
    assert got.shape == (n, k + 1) and np.isinf(got[:, k]).all()
    if k:
        distances, _ = cKDTree(points).query(points, k + 1)
        np.testing.assert_allclose(got[:, :k], distances[:, 1:], rtol=0, atol=1e-12)
    saved = reg._DENSE_NEIGHBOURS
    reg._DENSE_NEIGHBOURS = 0  # the tree's path for large maps gives the same rows
    try:
        np.testing.assert_allclose(_neighbour_distances(points, neighbours), got, rtol=0,
                                   atol=1e-12)
    finally:
        reg._DENSE_NEIGHBOURS = saved


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 5000), st.integers(0, 5000))
def test_ranking_pays_only_where_it_costs_less_than_the_checks_it_saves(n_pairs, n_partial):
    n_partial = min(n_partial, n_pairs)
    pays = _partial_ranking_pays(n_pairs, n_partial)
    complete = n_pairs - n_partial
    steps = 2 * _partial_neighbours(n_pairs) * n_pairs
    added = (n_pairs**2 - complete**2) // 2
    assert pays == (added > steps and added > reg._PARTIAL_CHECKS)
    if n_partial == 0:
        assert not pays
    assert reg._PARTIAL_NEIGHBOURS <= _partial_neighbours(n_pairs) <= reg.NEIGHBOURS


def test_the_ranking_keeps_within_its_steps():
    assert _partial_neighbours(10) == reg.NEIGHBOURS
    big = 100_000
    assert _partial_neighbours(big) == reg._PARTIAL_NEIGHBOURS
    middle = reg._PARTIAL_STEPS // (2 * 20)
    assert 2 * _partial_neighbours(middle) * middle <= reg._PARTIAL_STEPS


# -- the aligner ------------------------------------------------------------------------------


def cut_world(seed: int, n: int, cut: float, clutter: int = 0):
    """Two maps of one world of n objects of assorted sizes, all in both, the other robot's
    heights cut to `cut` of the ego's (every object seen in part), plus `clutter` objects of
    random sizes in each. Returns (ego, other, T_oi_oj (3, 3), true pairs (n, 2))."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 30.0, (n, 2))
    widths = np.exp(rng.normal(np.log(0.7), 0.6, n))
    heights = np.exp(rng.normal(np.log(0.8), 0.6, n))
    T = se2_from_params([*rng.uniform(-10, 10, 2), rng.uniform(-math.pi, math.pi)])

    def seen(points, w, h):
        k = len(w)
        extra_xy = rng.uniform(0.0, 30.0, (clutter, 2))
        extra_w = np.exp(rng.normal(np.log(0.7), 0.6, clutter))
        extra_h = np.exp(rng.normal(np.log(0.8), 0.6, clutter))
        c = np.column_stack([np.r_[points, extra_xy], np.r_[h, extra_h] / 2])
        c += rng.normal(0.0, 0.05, c.shape)
        return ObjectMap(c, np.r_[w, extra_w], np.r_[h, extra_h],
                         np.full(k + clutter, 10.0))

    ego = seen(xy, widths, heights)
    other = seen(transform_points(invert(T), xy), widths, cut * heights)
    return ego, other, T, np.column_stack([np.arange(n), np.arange(n)])


@pytest.fixture
def graph_nodes(monkeypatch):
    """The nodes (k, 2) of every consistency graph the aligner builds, in order."""
    seen = []
    real = fa._graph

    def spy(p, q, assoc, *args):
        seen.append(assoc.copy())
        return real(p, q, assoc, *args)

    monkeypatch.setattr(fa, "_graph", spy)
    return seen


@pytest.mark.parametrize("mode", ["best", "auto"])
def test_the_graph_holds_the_papers_pairs_and_the_best_partial_ones(graph_nodes, mode):
    ego, other, _, _ = cut_world(1, 60, 0.6, clutter=20)
    params = FrameAlignerParams(partial_pairs=mode)
    compatible, partial = size_gates(ego, other, params.size_ratio, params.size_abs_diff,
                                     params.size_partial)
    assert _partial_ranking_pays(int(compatible.sum()), int(partial.sum()))  # so auto ranks
    FrameAligner(params).measurements(ego, other, 10.0)
    nodes = np.zeros(compatible.shape, bool)
    nodes[graph_nodes[0][:, 0], graph_nodes[0][:, 1]] = True
    kept = _partial_pairs_kept(compatible, partial, ego.centroids[:, :2],
                               other.centroids[:, :2], ego.ages(10.0), other.ages(10.0),
                               params.span_epsilon(params.kappa))
    np.testing.assert_array_equal(nodes, (compatible & ~partial) | kept)


def test_with_every_partial_pair_the_graph_holds_the_whole_gate(graph_nodes):
    ego, other, _, _ = cut_world(1, 60, 0.6, clutter=20)
    params = FrameAlignerParams(partial_pairs="all")
    FrameAligner(params).measurements(ego, other, 10.0)
    compatible = size_compatible(ego, other, params.size_ratio, params.size_abs_diff,
                                 params.size_partial)
    np.testing.assert_array_equal(graph_nodes[0], np.argwhere(compatible))


def test_small_maps_keep_every_partial_pair_by_default(graph_nodes):
    """A few tens of objects: keeping every partial pair costs the graph little."""
    ego, other, _, _ = cut_world(2, 30, 0.6, clutter=10)
    params = FrameAlignerParams()
    compatible, partial = size_gates(ego, other, params.size_ratio, params.size_abs_diff,
                                     params.size_partial)
    assert partial.any() and not _partial_ranking_pays(int(compatible.sum()),
                                                        int(partial.sum()))
    FrameAligner(params).measurements(ego, other, 10.0)
    np.testing.assert_array_equal(graph_nodes[0], np.argwhere(compatible))


def test_without_the_partial_rule_nothing_is_ranked(graph_nodes, monkeypatch):
    ego, other, _, _ = cut_world(1, 60, 0.6, clutter=20)
    monkeypatch.setattr(fa, "_partial_pairs_kept", lambda *a: pytest.fail("ranked"))
    params = FrameAlignerParams(size_partial=None, partial_pairs="best")
    FrameAligner(params).measurements(ego, other, 10.0)
    np.testing.assert_array_equal(
        graph_nodes[0], np.argwhere(size_compatible(ego, other, 1.35, 0.1)))


@pytest.mark.parametrize("seed", range(3))
def test_objects_seen_in_part_are_still_aligned_beside_clutter(seed, graph_nodes):
    """Every object of the other map has its height cut to 60 %: none passes the paper's
    gate, and the best partial pairs, one per object, hold most of the true ones."""
    ego, other, T, true = cut_world(seed, 50, 0.6, clutter=25)
    found = FrameAligner(FrameAlignerParams(partial_pairs="best")).measurements(ego, other,
                                                                              10.0)
    assert found
    dt, dtheta = se2_error(T, found[0].T)
    assert dt < 0.3 and math.degrees(dtheta) < 1.0
    nodes = set(map(tuple, graph_nodes[0].tolist()))
    truth = set(map(tuple, true.tolist()))
    compatible, partial = size_gates(ego, other, 1.35, 0.1, 2.0)
    true_partial = {t for t in truth if partial[t]}
    assert true_partial, "the test needs objects whose sizes only the partial rule matches"
    assert len(nodes & true_partial) >= 0.5 * len(true_partial)
    # nothing else of the partial rule's many pairs but one per object at most
    assert len(nodes - set(map(tuple, np.argwhere(compatible & ~partial).tolist()))) <= 75


def test_a_guided_search_keeps_every_partial_pair_that_agrees(graph_nodes):
    ego, other, T, _ = cut_world(0, 50, 0.6, clutter=25)
    params = FrameAlignerParams(partial_pairs="best")
    held = np.array([T[0, 2], T[1, 2], math.atan2(T[1, 0], T[0, 0])])
    FrameAligner(params).measurements(ego, other, 10.0, held=held, guided=True)
    compatible = size_compatible(ego, other, 1.35, 0.1, 2.0)
    agree = FrameAligner(params)._agree(ego.centroids[:, :2], other.centroids[:, :2], held)
    np.testing.assert_array_equal(graph_nodes[0], np.argwhere(compatible & agree))


def test_lookalike_share_and_the_explained_objects_take_the_whole_gate():
    ego, other, _, _ = cut_world(1, 60, 0.6, clutter=20)
    compatible = size_compatible(ego, other, 1.35, 0.1, 2.0)
    for mode in ("all", "best", "auto"):
        params = FrameAlignerParams(partial_pairs=mode)
        aligner = FrameAligner(params)
        assert aligner.lookalike_share(ego, other, 10.0) == pytest.approx(compatible.mean())
        found = aligner.measurements(ego, other, 10.0)
        assert found
        for candidate in found:
            explained = mutual_inliers(candidate.T, ego.centroids[:, :2],
                                       other.centroids[:, :2], compatible,
                                       params.inlier_radius)
            assert candidate.inliers == len(explained)


@pytest.mark.parametrize("value", ["some", "", None, 1, True, "Best"])
def test_partial_pairs_takes_its_three_values_only(value):
    with pytest.raises(ParameterError, match=r"FrameAlignerParams\.partial_pairs = ") as info:
        FrameAlignerParams(partial_pairs=value)
    assert info.value.name == "partial_pairs"
    for good in ("all", "best", "auto"):
        assert FrameAlignerParams(partial_pairs=good).partial_pairs == good
    assert FrameAlignerParams().partial_pairs == "auto"


def test_thinning_past_the_cap_names_the_gates_pairs_and_those_searched(caplog, graph_nodes):
    ego, other, _, _ = cut_world(1, 60, 0.6, clutter=20)
    params = FrameAlignerParams(partial_pairs="best", max_associations=100)
    compatible, partial = size_gates(ego, other, params.size_ratio, params.size_abs_diff,
                                     params.size_partial)
    searched = (compatible & ~partial) | _partial_pairs_kept(
        compatible, partial, ego.centroids[:, :2], other.centroids[:, :2], ego.ages(10.0),
        other.ages(10.0), params.span_epsilon(params.kappa))
    assert searched.sum() > 100
    aligner = FrameAligner(params)
    with caplog.at_level("WARNING", logger="tcaff_gtsam.frame_aligner"):
        aligner.measurements(ego, other, 10.0)
    assert aligner.thinned == 1
    message = caplog.records[0].getMessage()
    assert (f"passed {int(compatible.sum())} pairs of 80 x 80 recent objects "
            f"({int(searched.sum())} of them searched)") in message
    assert len(graph_nodes[0]) <= 100
