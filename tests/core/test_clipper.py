"""CLIPPER: the consistency graph, the solver and MNO-CLIPPER."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import registration_problem

from tcaff_gtsam import (
    ClipperParams,
    ConfigError,
    DataError,
    clipper_solve,
    consistency_graph,
    mno_clipper,
)
from tcaff_gtsam.aligner_params import MIN_SIGMA
from tcaff_gtsam.geometry import invert, se2_from_params, transform_points
from tcaff_gtsam.registration import weighted_arun


def dense_reference(p, q, associations, epsilon, sigma):
    """The consistency graph by the definition, one pair at a time."""
    m = len(associations)
    W = np.zeros((m, m))
    for a in range(m):
        for b in range(m):
            (i, j), (k, ell) = associations[a], associations[b]
            if i == k or j == ell:
                continue
            c = abs(np.linalg.norm(p[i] - p[k]) - np.linalg.norm(q[j] - q[ell]))
            if c < epsilon:
                W[a, b] = np.exp(-(c**2) / (2 * sigma**2))
    return W


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), dim=st.sampled_from([2, 3]), m=st.integers(0, 60))
def test_graph_matches_definition(seed, dim, m):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 3, (12, dim))
    q = rng.uniform(0, 3, (10, dim))
    associations = np.column_stack([rng.integers(0, 12, m), rng.integers(0, 10, m)])
    graph = consistency_graph(p, q, associations, epsilon=0.4, sigma=0.2)
    expected = dense_reference(p, q, associations, 0.4, 0.2)
    affinity = graph.affinity().toarray()
    np.testing.assert_allclose(affinity - np.eye(m), expected, atol=1e-12)
    assert graph.n_edges == np.count_nonzero(expected) // 2
    # stored sparsely: exactly the consistent pairs, each once per direction, no self loops
    assert graph.indices.size == np.count_nonzero(expected)
    for row in range(m):
        cols = graph.indices[graph.indptr[row]:graph.indptr[row + 1]]
        assert len(np.unique(cols)) == len(cols) and row not in cols


def test_prior_weights_on_diagonal():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    associations = np.array([[0, 0], [1, 1], [2, 2]])
    graph = consistency_graph(p, p, associations, prior=np.array([0.5, 1.0, 2.0]))
    np.testing.assert_allclose(graph.affinity().diagonal(), [0.5, 1.0, 2.0])
    with pytest.raises(DataError, match="prior"):
        consistency_graph(p, p, associations, prior=np.array([1.0, -1.0, 1.0]))


def test_graph_bad_input():
    p = np.zeros((3, 2))
    with pytest.raises(DataError, match="out of range"):
        consistency_graph(p, p, np.array([[0, 3]]))
    with pytest.raises(DataError, match="finite"):
        consistency_graph(np.array([[np.nan, 0.0]]), p, np.array([[0, 0]]))
    with pytest.raises(DataError):
        consistency_graph(p, np.zeros((3, 3)), np.array([[0, 0]]))


def test_empty_graph_gives_empty_solution():
    graph = consistency_graph(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), int))
    assert graph.m == 0
    assert len(clipper_solve(graph)) == 0
    assert mno_clipper(graph, 4) == []


@pytest.mark.parametrize("dim", [2, 3])
def test_precision_and_recall_with_many_outliers(dim):
    """The original's sigma / epsilon, noise 0.05 m, 50-95 % outlier associations."""
    params = ClipperParams(sigma=0.15, epsilon=0.25)
    precision, recall = [], []
    for trial in range(24):
        rng = np.random.default_rng(trial)
        outlier_ratio = [0.5, 0.8, 0.9, 0.95][trial % 4]
        p, q, associations, inlier = registration_problem(rng, 20, outlier_ratio, 0.05, dim=dim)
        solution = clipper_solve(consistency_graph(p, q, associations, 0.25, 0.15), params)
        chosen = np.zeros(len(associations), bool)
        chosen[solution.nodes] = True
        precision.append((chosen & inlier).sum() / max(chosen.sum(), 1))
        recall.append((chosen & inlier).sum() / inlier.sum())
    assert np.mean(precision) >= 0.95
    assert np.mean(recall) >= 0.6


def test_deterministic_for_a_seed():
    p, q, associations, _ = registration_problem(np.random.default_rng(3), 15, 0.9, 0.05)
    graph = consistency_graph(p, q, associations)
    first = clipper_solve(graph, ClipperParams(seed=7))
    second = clipper_solve(graph, ClipperParams(seed=7))
    np.testing.assert_array_equal(first.nodes, second.nodes)
    np.testing.assert_array_equal(first.u, second.u)


def test_solution_is_consistent_and_u_on_the_sphere():
    p, q, associations, _ = registration_problem(np.random.default_rng(5), 20, 0.8, 0.05)
    graph = consistency_graph(p, q, associations)
    solution = clipper_solve(graph)
    assert np.all(solution.u >= 0)
    assert np.linalg.norm(solution.u) == pytest.approx(1.0)
    # every selected pair is an edge of the graph: the selection is a clique
    affinity = graph.affinity().toarray()
    sub = affinity[np.ix_(solution.nodes, solution.nodes)]
    assert np.all(sub > 0)
    # the score of a clique is its indicator's Rayleigh quotient
    x = np.zeros(graph.m)
    x[solution.nodes] = 1.0
    assert solution.score == pytest.approx(x @ affinity @ x / (x @ x))


def test_threshold_rounding_keeps_large_entries():
    p, q, associations, inlier = registration_problem(np.random.default_rng(11), 20, 0.9, 0.05)
    graph = consistency_graph(p, q, associations)
    solution = clipper_solve(graph, ClipperParams(rounding="threshold", threshold=0.5))
    assert len(solution) > 0
    assert np.all(solution.u[solution.nodes] > 0.5 * solution.u.max())
    assert inlier[solution.nodes].mean() >= 0.95


def rectangle(width=6.0, height=2.0):
    return np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])


def test_mno_returns_true_and_mirrored_alignment_on_a_symmetric_map():
    """A rectangle of identical objects: the truth and its 180 degree twin fit equally well."""
    T_true = se2_from_params([3.0, -1.0, 0.4])
    p = rectangle()
    q = transform_points(invert(T_true), p)
    associations = np.argwhere(np.ones((4, 4), bool))
    graph = consistency_graph(p, q, associations)
    solutions = mno_clipper(graph, 4)
    assert len(solutions) == 4
    found = []
    for solution in solutions:
        assert len(solution) == 4
        T = weighted_arun(p[solution.associations[:, 0]], q[solution.associations[:, 1]])
        found.append(T)
    # the rectangle turned 180 degrees about its centre maps onto itself: p -> S p
    turned = se2_from_params([6.0, 2.0, np.pi]) @ T_true
    assert any(np.allclose(T, T_true, atol=1e-9) for T in found)
    assert any(np.allclose(T, turned, atol=1e-9) for T in found)
    # solutions never repeat an association
    all_nodes = np.concatenate([s.nodes for s in solutions])
    assert len(np.unique(all_nodes)) == len(all_nodes)


def test_mno_downweight_keeps_nodes_available():
    p = rectangle()
    associations = np.argwhere(np.ones((4, 4), bool))
    graph = consistency_graph(p, p, associations)
    removed = mno_clipper(graph, 6, downweight=0.0)
    softened = mno_clipper(graph, 6, downweight=0.5)
    assert len(removed) == 4  # 16 associations, four disjoint cliques of four
    assert len(softened) == 6  # down-weighted cliques can be found again
    with pytest.raises(ConfigError, match=r"mno_clipper.downweight = 1.5: must be in \[0, 1\)"):
        mno_clipper(graph, 2, downweight=1.5)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"downweight": 1.0}, "downweight"), ({"downweight": "0"}, "downweight"),
    ({"downweight": None}, "downweight"), ({"n_solutions": 0}, "n_solutions"),
    ({"n_solutions": 2.0}, "n_solutions"),
])
def test_mno_parameters_are_config_errors(kwargs, name):
    graph = consistency_graph(rectangle(), rectangle(), np.argwhere(np.ones((4, 4), bool)))
    with pytest.raises(ConfigError, match=f"mno_clipper.{name} = "):
        mno_clipper(graph, **{"n_solutions": 2, **kwargs})


@pytest.mark.parametrize("name", ["epsilon", "sigma"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf"), "0.2", None, True])
def test_graph_parameters_are_config_errors(name, value):
    p = np.zeros((3, 2))
    with pytest.raises(ConfigError, match=f"consistency_graph.{name} = "):
        consistency_graph(p, p, np.array([[0, 0]]), **{name: value})


@pytest.mark.parametrize("sigma", [1e-10, 1e-156, 1e-170, 5e-324])
def test_a_kernel_too_narrow_to_compute_is_refused_by_name(sigma):
    """sigma below MIN_SIGMA (a nanometre): from about 1e-154 m the kernel's 1 / (2 sigma^2)
    overflowed and pairs that agree exactly got NaN weights (52 of this graph's
    weights, and CLIPPER a clique of one), from about 1e-162 m consistency_graph and every
    FrameAligner search raised ZeroDivisionError."""
    p = np.random.default_rng(0).uniform(0.0, 5.0, (6, 2))
    pairs = np.argwhere(np.ones((6, 6), bool))
    with pytest.raises(ConfigError, match=r"^consistency_graph\.sigma = "):
        consistency_graph(p, p + 1.0, pairs, sigma=sigma)
    with pytest.raises(ConfigError, match=r"^ClipperParams\.sigma = "):
        ClipperParams(sigma=sigma)
    graph = consistency_graph(p, p + 1.0, pairs, sigma=MIN_SIGMA)
    assert np.isfinite(graph.weights).all() and len(clipper_solve(graph)) == 6
    assert ClipperParams(sigma=MIN_SIGMA).sigma == MIN_SIGMA


def test_mno_scores_use_the_original_affinity():
    p, q, associations, _ = registration_problem(np.random.default_rng(2), 20, 0.8, 0.05)
    graph = consistency_graph(p, q, associations)
    affinity = graph.affinity().toarray()
    for solution in mno_clipper(graph, 4, downweight=0.3):
        x = np.zeros(graph.m)
        x[solution.nodes] = 1.0
        assert solution.score == pytest.approx(x @ affinity @ x / (x @ x))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_edges_within_a_node_set(seed):
    from tcaff_gtsam.clipper import _edges_within

    rng = np.random.default_rng(seed)
    p, q, associations, _ = registration_problem(rng, 15, 0.8, 0.05)
    graph = consistency_graph(p, q, associations)
    nodes = np.sort(rng.choice(graph.m, rng.integers(1, graph.m), replace=False))
    member = np.zeros(graph.m, bool)
    member[nodes] = True
    rows = np.repeat(np.arange(graph.m), np.diff(graph.indptr))
    expected = np.flatnonzero(member[rows] & member[graph.indices])
    scratch = np.zeros(graph.m, bool)
    edges = _edges_within(graph.indptr, graph.indices, nodes, scratch)
    np.testing.assert_array_equal(edges, expected)  # row by row, in CSR order
    assert not scratch.any()  # the scratch is handed back cleared


# ---------------------------------------------------------------------------------------------
# bad graphs and arguments: clear errors, never a crash inside the compiled solver


def small_graph():
    p = rectangle()
    return consistency_graph(p, p, np.argwhere(np.ones((4, 4), bool)))


@pytest.mark.parametrize(("field", "bad", "message"), [
    ("indices", lambda g: np.where(np.arange(g.indices.size) == 0, 10**9, g.indices),
     r"indices must be node numbers in \[0, 16\), got 1000000000"),
    ("indices", lambda g: np.where(np.arange(g.indices.size) == 3, -1, g.indices),
     r"indices must be node numbers in \[0, 16\), got -1"),
    ("indices", lambda g: g.indices.astype(float), "indices must be a 1-D integer array"),
    ("indptr", lambda g: g.indptr[:-1], r"indptr must have shape \(17,\)"),
    ("indptr", lambda g: g.indptr + 1, "indptr must rise from 0"),
    ("indptr", lambda g: g.indptr[::-1].copy(), "indptr must rise from 0"),
    ("weights", lambda g: np.where(np.arange(g.weights.size) == 2, np.nan, g.weights),
     "weights must be finite numbers >= 0, got nan at index 2"),
    ("weights", lambda g: -g.weights, "weights must be finite numbers >= 0"),
    ("weights", lambda g: g.weights[:-1], "weights must have shape"),
    ("weights", lambda g: g.weights + 1j, "weights must be real numbers"),
    ("diag", lambda g: np.full(g.m, np.inf), "diag must be finite numbers >= 0, got inf"),
    ("diag", lambda g: np.ones(3), r"diag must have shape \(16,\)"),
    ("associations", lambda g: np.column_stack([g.associations, g.associations[:, :1]]),
     r"associations must be an \(m, 2\) array of index pairs, got shape \(16, 3\)"),
    ("associations", lambda g: g.associations - 1, "associations must be indices >= 0"),
])
def test_a_graph_with_bad_arrays_is_refused_before_the_solver_runs(field, bad, message):
    """Indices past the nodes used to make the compiled solver read (and write) out of bounds:
    a segmentation fault."""
    graph = small_graph()
    with pytest.raises(DataError, match=rf"^ConsistencyGraph: {message}"):
        replace(graph, **{field: bad(graph)})


def test_a_graph_cannot_be_changed_after_its_checks():
    graph = small_graph()
    with pytest.raises(ValueError, match="read-only"):
        graph.indices[0] = 10**9
    # the caller's own arrays stay writeable
    indices = graph.indices.copy()
    replace(graph, indices=indices)
    indices[0] = indices[0]
    assert len(clipper_solve(graph)) == 4


@pytest.mark.parametrize("solve", [clipper_solve, mno_clipper])
@pytest.mark.parametrize("graph", [None, "graph", np.zeros((4, 4)), {"indices": [0]}])
def test_solvers_refuse_what_is_not_a_graph(solve, graph):
    with pytest.raises(DataError, match=rf"^{solve.__name__}: graph must be a "
                                        rf"ConsistencyGraph, got {type(graph).__name__}"):
        solve(graph)


@pytest.mark.parametrize("solve", [clipper_solve, mno_clipper])
@pytest.mark.parametrize("params", ["default", 0, {"seed": 1}])
def test_solvers_refuse_params_that_are_not_clipper_params(solve, params):
    with pytest.raises(ConfigError, match=rf"^{solve.__name__}\.params = "):
        solve(small_graph(), params=params)


@pytest.mark.parametrize("n", [-1, 0, 2.5, "2", None, True])
def test_mno_solution_count_must_be_a_positive_int(n):
    with pytest.raises(ConfigError, match=rf"^mno_clipper\.n_solutions = {re.escape(repr(n))}"):
        mno_clipper(small_graph(), n)


@pytest.mark.parametrize(("associations", "message"), [
    (np.array([[0, 1, 2], [1, 2, 3]]), r"must be an \(m, 2\) array of index pairs, got shape "
                                        r"\(2, 3\)"),
    (np.array([0, 1, 2, 3]), r"got shape \(4,\)"),
    (np.array([[0.5, 1.0], [1.0, 2.0]]), r"must hold whole numbers, got 0.5 at \[0, 0\]"),
    (np.array([[0.0, np.nan]]), "must hold whole numbers, got nan"),
    (np.array([[0, -1]]), "must be indices >= 0, got -1"),
    (np.array([[True, False]]), "integer indices"),
    ([["0", "1"]], "integer indices"),
    (np.array([[2**63 + 5, 0]], dtype=np.uint64), "beyond int64"),
])
def test_graph_associations_are_never_reshaped_or_rounded(associations, message):
    """An (m, 3) array used to be reshaped into scrambled pairs and 0.5 truncated to 0."""
    p = np.random.default_rng(0).uniform(0, 5, (4, 2))
    with pytest.raises(DataError, match=rf"^consistency_graph: associations .*{message}"):
        consistency_graph(p, p, associations)


def test_whole_float_associations_are_still_accepted():
    p = rectangle()
    ints = np.argwhere(np.ones((4, 4), bool))
    a, b = consistency_graph(p, p, ints), consistency_graph(p, p, ints.astype(float))
    np.testing.assert_array_equal(a.associations, b.associations)
    np.testing.assert_array_equal(a.weights, b.weights)


@pytest.mark.parametrize("points", [np.ones((3, 2)) * (1 + 1j), [["a", "b"]] * 3, None])
def test_graph_points_must_be_real_numbers(points):
    with pytest.raises(DataError, match=r"^consistency_graph: ego_points must be real numbers"):
        consistency_graph(points, np.zeros((3, 2)), np.array([[0, 0]]))


@pytest.mark.parametrize("seed", [0, 1, 2**32, 2**64 + 1, 2**200, np.uint64(2**64 - 1)])
def test_every_seed_clipper_params_accepts_solves(seed):
    """ClipperParams takes the seeds the solver's generator takes: any int >= 0."""
    solution = clipper_solve(small_graph(), ClipperParams(seed=seed))
    assert len(solution) == 4


@pytest.mark.parametrize("seed", [-1, np.int64(-5), 1.0, "0", None, True])
def test_seeds_the_solver_cannot_take_are_config_errors(seed):
    with pytest.raises(ConfigError, match=r"^ClipperParams\.seed = .*must be an int >= 0"):
        ClipperParams(seed=seed)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1e6, allow_nan=False), max_size=600))
def test_compiled_sum_adds_in_numpys_order(values):
    """Scores are summed in compiled code; they must equal numpy's sums to the last bit."""
    from tcaff_gtsam.clipper import _sum

    a = np.array(values, dtype=float)
    assert _sum(a) == a.sum()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5), max_size=80))
def test_largest_first_is_numpys_stable_descending_order(values):
    """Rounding keeps the largest entries of u, ties to the lower node, as a stable sort does."""
    from tcaff_gtsam.clipper import _largest_first

    u = np.array(values, dtype=float)
    support = np.flatnonzero(u > 0)
    expected = support[np.argsort(-u[support], kind="stable")]
    np.testing.assert_array_equal(_largest_first(u, support), expected)
