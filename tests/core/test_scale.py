"""Large maps: the descriptor gate by blocks, the cap on associations (each object's pairs whose
neighbourhoods agree best), mutual inliers by k-d tree, and a FrameAligner step on maps whose
gate passes far more pairs than the cap."""

from __future__ import annotations

import logging
import math
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import FrameAligner, FrameAlignerParams, ObjectMap, association
from tcaff_gtsam import frame_aligner as fa
from tcaff_gtsam import registration as reg
from tcaff_gtsam.association import putative_associations, size_compatible
from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.geometry import se2_error, se2_from_params
from tcaff_gtsam.registration import mutual_inliers

seeds = st.integers(0, 2**32 - 1)


@contextmanager
def gate_block(pairs: int):
    """The descriptor gate evaluated by blocks of `pairs` object pairs for the duration."""
    saved = association._GATE_BLOCK
    association._GATE_BLOCK = pairs
    try:
        yield
    finally:
        association._GATE_BLOCK = saved


def random_map(rng: np.random.Generator, n: int, sizes: int = 4) -> ObjectMap:
    """n objects in a 30 m square; sizes from a few classes, so gates pass many pairs."""
    return ObjectMap(np.column_stack([rng.uniform(0, 30, (n, 2)), np.zeros(n)]),
                     rng.integers(1, sizes + 1, n) * 0.5, rng.integers(1, sizes + 1, n) * 0.5,
                     rng.integers(0, 5, n).astype(float))


@settings(max_examples=40, deadline=None)
@given(seeds, st.integers(0, 40), st.integers(0, 40), st.integers(1, 60))
def test_the_gate_by_blocks_is_the_whole_gate(seed, n_ego, n_other, block):
    rng = np.random.default_rng(seed)

    def described(objects: ObjectMap) -> ObjectMap:
        d = np.abs(rng.normal(size=(len(objects), 8)))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return replace(objects, descriptors=d)

    ego, other = described(random_map(rng, n_ego)), described(random_map(rng, n_other))
    whole = putative_associations(ego, other)
    compatible = size_compatible(ego, other, 1.35, 0.1)
    np.testing.assert_array_equal(np.argwhere(compatible), whole)
    gated = association._descriptor_gate(ego, other, compatible, 0.7)
    similar = ego.descriptors @ other.descriptors.T >= 0.7
    np.testing.assert_array_equal(gated, compatible & similar)
    with gate_block(block):
        np.testing.assert_array_equal(association._descriptor_gate(ego, other, compatible, 0.7),
                                      gated)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(0, 40), st.integers(0, 40),
       st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-math.pi, math.pi)),
       st.floats(0.05, 3.0))
def test_inliers_by_tree_are_the_dense_inliers(seed, n, m, pose, radius):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 10, (n, 2))
    q = np.vstack([p[: m // 2] + rng.normal(0, 0.2, (min(m // 2, n), 2)),
                   rng.uniform(0, 10, (m - min(m // 2, n), 2))])
    compatible = rng.random((n, m)) < 0.8
    T = se2_from_params(pose)
    dense = mutual_inliers(T, p, q, compatible, radius)
    moved = q @ T[:2, :2].T + T[:2, 2]
    by_tree = reg._mutual_inliers_by_tree(p, moved, compatible, radius)
    np.testing.assert_array_equal(by_tree, dense)


def test_large_maps_take_the_tree_path_and_agree(monkeypatch):
    rng = np.random.default_rng(3)
    p = rng.uniform(0, 50, (300, 2))
    q = p + rng.normal(0, 0.05, p.shape)
    compatible = rng.random((300, 300)) < 0.9
    dense = mutual_inliers(np.eye(3), p, q, compatible, 0.3)
    monkeypatch.setattr(reg, "_DENSE_INLIERS", 0)
    calls = []
    tree = reg._mutual_inliers_by_tree
    monkeypatch.setattr(reg, "_mutual_inliers_by_tree", lambda *a: calls.append(1) or tree(*a))
    np.testing.assert_array_equal(mutual_inliers(np.eye(3), p, q, compatible, 0.3), dense)
    assert calls and len(dense) > 200


def big_pair(n: int, seed: int = 0):
    """Maps of n objects each, half shared, the shared ones seen within the last second and
    the others up to 15 s ago."""
    pair = overlapping_maps(np.random.default_rng(seed), n, overlap=0.5, max_age=15.0)
    now = pair.now
    ages = []
    for objects in (pair.ego, pair.other):
        shared = np.isin(np.arange(len(objects)), pair.true_pairs[:, 0 if objects is pair.ego
                                                                    else 1])
        last_seen = np.where(shared, now - 0.5, objects.last_seen)
        ages.append(replace(objects, last_seen=last_seen))
    return pair, ages[0], ages[1]


def test_a_step_whose_gate_passes_more_than_the_cap_keeps_the_true_pairs(caplog):
    pair, ego, other = big_pair(300)
    n_pairs = len(putative_associations(ego, other,
                                        partial_ratio=FrameAlignerParams().size_partial))
    cap = n_pairs // 4
    aligner = FrameAligner(FrameAlignerParams(max_associations=cap))
    with caplog.at_level(logging.DEBUG, logger="tcaff_gtsam.frame_aligner"):
        first = aligner.measurements(ego, other, pair.now)
        aligner.measurements(ego, other, pair.now)
    records = [r for r in caplog.records if "max_associations" in r.getMessage()]
    assert [r.levelno for r in records] == [logging.WARNING, logging.DEBUG]
    assert f"passed {n_pairs} pairs" in records[0].getMessage()
    assert aligner.thinned == 2
    assert first and len(first[0].associations) >= 5
    assert se2_error(first[0].T, pair.T_oi_oj)[0] < 0.5  # the kept pairs hold the truth
    untouched = FrameAligner(FrameAlignerParams(max_associations=n_pairs))
    untouched.measurements(ego, other, pair.now)
    assert untouched.thinned == 0


def test_the_cap_bounds_the_graph(monkeypatch):
    pair, ego, other = big_pair(200)
    seen = []
    real = fa._graph
    monkeypatch.setattr(fa, "_graph",
                        lambda p, q, assoc, *a: seen.append(len(assoc)) or real(p, q, assoc, *a))
    FrameAligner(FrameAlignerParams(max_associations=500)).measurements(ego, other, pair.now)
    assert len(seen) == 1 and 0 < seen[0] <= 500


@pytest.mark.parametrize("value", [2, 1, 2.5, None, True])
def test_the_cap_is_an_int_at_least_min_associations(value):
    with pytest.raises(ConfigError, match="max_associations"):
        FrameAlignerParams(max_associations=value)


def reference_mutual_inliers(T, p, q, compatible, radius):
    """Mutual nearest compatible neighbours within the radius, ties to the lower index, by
    direct differences: what the compiled pass must give."""
    moved = q @ T[:2, :2].T + T[:2, 2]
    d2 = ((p[:, None, :] - moved[None, :, :]) ** 2).sum(axis=2)
    d2[~compatible] = np.inf
    out = []
    for i in range(len(p)):
        if not np.isfinite(d2[i]).any():
            continue
        j = int(np.argmin(d2[i]))
        if int(np.argmin(d2[:, j])) == i and d2[i, j] <= radius**2:
            out.append((i, j))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(0, 12), st.integers(0, 12), st.sampled_from([0, 1, 2]),
       st.sampled_from([0, 1, 1.5]))
def test_inliers_on_a_grid_of_ties_take_the_lower_index(seed, n, m, turns, radius):
    """Points on an integer grid, a quarter turn apart: many exact ties and distances exactly
    at the radius."""
    rng = np.random.default_rng(seed)
    p = rng.integers(0, 4, (n, 2)).astype(float)
    q = rng.integers(0, 4, (m, 2)).astype(float)
    compatible = rng.random((n, m)) < 0.7
    T = se2_from_params([1.0, 0.0, turns * math.pi / 2])
    T[:2, :2] = np.round(T[:2, :2])  # exact quarter turns
    np.testing.assert_array_equal(mutual_inliers(T, p, q, compatible, radius),
                                  reference_mutual_inliers(T, p, q, compatible, radius))


def test_any_layout_and_radius_type_use_the_one_compiled_inlier_pass():
    """A strided mask, float32 points and an int radius give the same inliers through the
    signature that installation compiled, not a new compilation on a user's first step."""
    rng = np.random.default_rng(4)
    p, q = rng.uniform(0, 5, (9, 2)), rng.uniform(0, 5, (7, 2))
    wide = rng.random((9, 14)) < 0.8
    T = se2_from_params([0.3, -0.2, 0.4])
    expected = mutual_inliers(T, p, q, np.ascontiguousarray(wide[:, ::2]), 2.0)
    got = reg._mutual_inliers(T, p.astype(np.float32), q, wide[:, ::2], 2)
    np.testing.assert_array_equal(got, expected)
    frozen = np.ascontiguousarray(wide[:, ::2])
    frozen.flags.writeable = False
    np.testing.assert_array_equal(reg._mutual_inliers(T, p, q, frozen, 2.0), expected)
    assert len(reg._mutual_nearest.signatures) == 1
