"""The array hypothesis tree: Kalman children, costs, gating, child selection and pruning."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from tcaff_gtsam.hypothesis_tree import (
    BEFORE_ROOT,
    NO_MEASUREMENT,
    CostModel,
    Leaves,
    _children,
    best_per_tree,
    branch,
    extend,
    mahalanobis_to,
    measurement_costs,
    not_positive_definite,
    seed,
)


def model(d, angles=(), reference=False, use_box=False, gate_p=0.999, Q=None, nm=4.0):
    """gate_p=None disables the gate."""
    angular = np.zeros(d, bool)
    angular[list(angles)] = True
    gate = np.inf if gate_p is None else chi2.ppf(gate_p, d)
    return CostModel(Q=np.eye(d) * 0.01 if Q is None else Q, angular=angular,
                     reference=reference, use_box=use_box, gate_chi2=gate,
                     gate_box=np.full(d, 2.0), no_measurement_cost=nm)


def spd(rng, d, scale=1.0):
    A = rng.normal(size=(d, d))
    return scale * (A @ A.T + d * np.eye(d))


def one_leaf(x, P, columns=3):
    return seed(np.asarray(x, float)[None], P, np.zeros(1), np.zeros(1), columns)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_measurement_child_is_the_textbook_kalman_update(d, seed_value):
    rng = np.random.default_rng(seed_value)
    x, z = rng.normal(size=d), rng.normal(size=d)
    P, R, Q = spd(rng, d, 0.1), spd(rng, d, 0.1), spd(rng, d, 0.01)
    m = model(d, Q=Q, gate_p=None)
    out = extend(one_leaf(x, P), z[None], R[None], m, 1, lambda c, *_: np.arange(c.size))
    assert len(out) == 2  # the measurement child, then the no-measurement child
    Pp = P + Q
    S = Pp + R
    K = Pp @ np.linalg.inv(S)
    np.testing.assert_allclose(out.x[0], x + K @ (z - x), atol=1e-9)
    I_K = np.eye(d) - K
    np.testing.assert_allclose(out.P[0], I_K @ Pp @ I_K.T + K @ R @ K.T, atol=1e-9)
    r = z - x
    cost = 0.5 * (r @ np.linalg.solve(S, r) + np.linalg.slogdet(S)[1])
    assert out.edge[0, -1] == pytest.approx(cost, abs=1e-9)
    np.testing.assert_allclose(out.x[1], x)
    np.testing.assert_allclose(out.P[1], Pp)
    assert out.edge[1, -1] == 4.0
    assert list(out.choice[:, -1]) == [0, NO_MEASUREMENT]


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 4), st.integers(0, 2**32 - 1))
def test_reference_cost_and_gain_are_diagonal_only(d, seed_value):
    rng = np.random.default_rng(seed_value)
    x, z = rng.normal(size=d), rng.normal(size=d) * 0.5
    P, R, Q = spd(rng, d, 0.3), spd(rng, d, 0.3), spd(rng, d, 0.01)
    m = model(d, Q=Q, reference=True, gate_p=None)
    cost = measurement_costs(one_leaf(x, P), z[None], R[None], m)[0, 0]
    s = np.diag(P) + np.diag(R)  # P, not P + Q, and only the diagonal
    maha = np.sum((z - x) ** 2 / s)
    assert cost == pytest.approx(0.5 * (maha**2 + np.log(s).sum() + d * math.log(2 * math.pi)))
    out = extend(one_leaf(x, P), z[None], R[None], m, 1, lambda c, *_: np.arange(c.size))
    assert out.choice[0, -1] == 0
    K = (P + Q) / (np.diag(P + Q) + np.diag(R))[None, :]
    np.testing.assert_allclose(out.x[0], x + K @ (z - x), atol=1e-9)
    np.testing.assert_allclose(out.P[0], (np.eye(d) - K) @ (P + Q), atol=1e-9)


def test_angle_residuals_are_wrapped():
    m = model(3, angles=(2,))
    P = np.diag([0.1, 0.1, 0.01])
    R = np.diag([0.1, 0.1, 0.01])[None]
    near = one_leaf([0, 0, np.pi - 0.05], P)
    far = one_leaf([0, 0, 0.0], P)
    z = np.array([[0.0, 0.0, -np.pi + 0.05]])  # 0.1 rad from the first leaf across +-pi
    assert np.isfinite(measurement_costs(near, z, R, m)[0, 0])
    assert np.isinf(measurement_costs(far, z, R, m)[0, 0])
    out = extend(near, z, R, m, 1, lambda c, *_: np.arange(c.size))
    assert -np.pi <= out.x[0, 2] < np.pi
    assert abs(abs(out.x[0, 2]) - np.pi) < 0.05


def test_mahalanobis_gate_and_box_gate():
    P = np.eye(2) * 0.01
    R = np.eye(2)[None] * 0.01
    leaf = one_leaf([0.0, 0.0], P)
    m = model(2, Q=np.eye(2) * 1e-6)
    s = math.sqrt(0.02 + 1e-6)
    inside = np.array([[0.9 * s * math.sqrt(chi2.ppf(0.999, 2)), 0.0]])
    outside = np.array([[1.1 * s * math.sqrt(chi2.ppf(0.999, 2)), 0.0]])
    assert np.isfinite(measurement_costs(leaf, inside, R, m)[0, 0])
    assert np.isinf(measurement_costs(leaf, outside, R, m)[0, 0])
    box = model(2, use_box=True)
    costs = measurement_costs(leaf, np.array([[1.9, -1.9], [2.1, 0.0]]), R, box)
    assert np.isfinite(costs[0, 0]) and np.isinf(costs[0, 1])


def test_children_take_the_cheapest_gated_measurements_in_leaf_order():
    costs = np.array([[3.0, np.inf, 1.0, 2.0, 0.5],
                      [np.inf, np.inf, np.inf, np.inf, np.inf],
                      [1.0, 1.0, 1.0, 0.0, 5.0]])
    parent, meas, edge = _children(costs, 2, 9.0)
    assert parent.tolist() == [0, 0, 0, 1, 2, 2, 2]
    assert meas.tolist() == [4, 2, -1, -1, 3, 0, -1]  # ties go to the lower index
    assert edge.tolist() == [0.5, 1.0, 9.0, 9.0, 0.0, 1.0, 9.0]
    parent, meas, _ = _children(np.empty((2, 0)), 4, 9.0)
    assert parent.tolist() == [0, 1] and meas.tolist() == [-1, -1]


def test_best_per_tree_keeps_the_cheapest_of_each_adjacent_group():
    cost = np.array([5.0, 1.0, 3.0, 2.0, 9.0, 0.0, 4.0])
    tree = np.array([0, 0, 0, 0, 7, 8, 8])
    assert best_per_tree(cost, tree, 2).tolist() == [1, 3, 4, 5, 6]
    assert best_per_tree(cost, tree, 10).tolist() == list(range(7))


def test_branch_keeps_the_subtree_of_the_best_leaf():
    choice = np.array([[0, 1, 2], [0, 1, -1], [0, -1, 2], [0, 2, 0]], np.int32)
    assert branch(choice, 1, 1).tolist() == [0, 1]
    assert branch(choice, 2, 1).tolist() == [2]


def test_extend_shifts_the_window_and_counts_steps_without_measurement():
    m = model(1, Q=np.eye(1) * 1e-4, nm=3.0)
    leaves = seed(np.array([[0.0], [10.0]]), np.eye(1) * 0.1, np.array([5, 6]),
                  np.array([0, 1]), 4)
    assert leaves.choice.tolist() == [[BEFORE_ROOT] * 3 + [0], [BEFORE_ROOT] * 3 + [1]]
    keep_all = lambda c, *_: np.arange(c.size)  # noqa: E731
    R = np.eye(1)[None] * 0.1
    step1 = extend(leaves, np.array([[0.1]]), R, m, 2, keep_all)
    assert step1.tree.tolist() == [5, 5, 6]  # the far root only gets its no-measurement child
    assert step1.choice[:, -2:].tolist() == [[0, 0], [0, -1], [1, -1]]
    assert step1.since.tolist() == [0, 1, 1]
    step2 = extend(step1, np.empty((0, 1)), np.empty((0, 1, 1)), m, 2, keep_all)
    assert step2.since.tolist() == [1, 2, 2]
    assert step2.choice[:, -3:].tolist() == [[0, 0, -1], [0, -1, -1], [1, -1, -1]]
    # the window cost sums the edges below the root
    np.testing.assert_allclose(step2.cost, step2.edge[:, -2] + 3.0)
    assert Leaves.concat([step1, step2]).x.shape == (6, 1)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(0, 2**32 - 1), st.floats(0.01, 100.0))
def test_the_gate_is_the_chi_square_test_on_the_full_covariance(d, seed_value, spread):
    """Costs are finite exactly where r' S^-1 r is within the gate (the one-component test
    that skips most pairs only ever rejects what the full test rejects)."""
    rng = np.random.default_rng(seed_value)
    P, Q = spd(rng, d, 0.1), spd(rng, d, 0.01)
    Rs = np.array([spd(rng, d, 0.1) for _ in range(6)])
    x = rng.normal(size=d)
    zs = x + spread * rng.normal(size=(6, d)) * rng.uniform(0.0, 1.0, (6, 1))
    m = model(d, Q=Q)
    costs = measurement_costs(one_leaf(x, P), zs, Rs, m)[0]
    for j in range(6):
        r = zs[j] - x
        maha = r @ np.linalg.solve(P + Q + Rs[j], r)
        if abs(maha - m.gate_chi2) > 1e-9 * m.gate_chi2:
            assert np.isfinite(costs[j]) == (maha <= m.gate_chi2)
        if np.isfinite(costs[j]):
            full = 0.5 * (maha + np.linalg.slogdet(P + Q + Rs[j])[1])
            assert costs[j] == pytest.approx(full, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(1, 6), st.integers(0, 2**32 - 1))
def test_mahalanobis_to_one_state(d, n, seed_value):
    rng = np.random.default_rng(seed_value)
    x, x0 = rng.normal(size=(n, d)) * 4.0, rng.normal(size=d)
    P, P0 = np.array([spd(rng, d, 0.1) for _ in range(n)]), spd(rng, d, 0.1)
    angular = np.zeros(d, bool)
    angular[-1] = True
    got = mahalanobis_to(x, P, x0, P0, angular)
    for i in range(n):
        r = x[i] - x0
        r[-1] = (r[-1] + np.pi) % (2 * np.pi) - np.pi
        assert got[i] == pytest.approx(r @ np.linalg.solve(P[i] + P0, r), rel=1e-9, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 4), st.integers(1, 5), st.integers(0, 2**32 - 1), st.booleans())
def test_not_positive_definite_finds_the_first_indefinite_matrix(d, n, seed_value, spoil):
    rng = np.random.default_rng(seed_value)
    P = np.array([spd(rng, d) for _ in range(n)])
    first = -1
    if spoil:
        first = int(rng.integers(n))
        v = rng.normal(size=d)
        P[first] -= (np.linalg.eigvalsh(P[first])[-1] + 1.0) * np.outer(v, v) / (v @ v)
    assert not_positive_definite(P) == first
