"""TeamConsistency: the pairwise alignments that agree around cycles, and chains through a
third robot."""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam import InterRobotGraph, TeamConsistency, TeamParams
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.tcaff import AlignmentEstimate
from tcaff_gtsam.team import _three_cycles

P = np.diag([0.05**2, 0.05**2, math.radians(1.0) ** 2])


def team_frames(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3, 3) each robot's odometry frame in a common world."""
    return se2_from_params(np.column_stack([rng.uniform(-20, 20, (n, 2)),
                                            rng.uniform(-math.pi, math.pi, n)]))


def true_estimates(frames: np.ndarray, pairs) -> dict:
    return {(i, j): SimpleNamespace(x=se2_to_params(np.linalg.inv(frames[i]) @ frames[j]),
                                    P=P) for i, j in pairs}


def close(est, frames, i, j, tol=1e-6) -> bool:
    true = se2_to_params(np.linalg.inv(frames[i]) @ frames[j])
    d = est.x - true
    d[2] = math.remainder(d[2], 2 * math.pi)
    return bool(np.all(np.abs(d) < tol))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 6))
def test_a_consistent_team_passes_whole(seed, n):
    frames = team_frames(np.random.default_rng(seed), n)
    pairs = list(itertools.permutations(range(n), 2))
    out = TeamConsistency(n).update(true_estimates(frames, pairs))
    assert set(out) == set(pairs)
    assert all(close(out[p], frames, *p) and out[p].path == p for p in pairs)


def test_a_wrong_alignment_inconsistent_with_two_others_is_rejected():
    """Robots 0, 1, 2 agree pairwise except 0-2, off by 3 m: the cycle fails, two of the three
    can stand together, and of those sets the most certain is kept (the wrong one is the least
    certain here). Its place is taken by the chain through robot 1."""
    frames = team_frames(np.random.default_rng(1), 3)
    estimates = true_estimates(frames, [(0, 1), (1, 2), (0, 2)])
    wrong = estimates[(0, 2)].x + np.array([3.0, 0.0, 0.0])
    estimates[(0, 2)] = SimpleNamespace(x=wrong, P=4 * P)
    team = TeamConsistency(3)
    out = team.update(estimates)
    assert team.rejected == [(0, 2)]
    assert out[(0, 2)].path == (0, 1, 2) and close(out[(0, 2)], frames, 0, 2, 1e-9)
    assert len(out) == 6


def test_the_majority_of_cycles_decides_which_alignment_goes():
    """With four robots, the wrong 0-2 fails both cycles it is in (0-1-2, 0-2-3); every other
    alignment fails at most one. The largest consistent set drops exactly 0-2, which is then
    chained through a robot whose alignments hold."""
    frames = team_frames(np.random.default_rng(2), 4)
    pairs = list(itertools.combinations(range(4), 2))
    estimates = true_estimates(frames, pairs)
    estimates[(0, 2)] = SimpleNamespace(x=estimates[(0, 2)].x + np.array([0.0, 2.5, 0.2]), P=P)
    team = TeamConsistency(4)
    out = team.update(estimates)
    assert team.rejected == [(0, 2)]
    assert out[(0, 2)].chained and close(out[(0, 2)], frames, 0, 2, 1e-9)
    assert out[(2, 0)].chained and close(out[(2, 0)], frames, 2, 0, 1e-9)


def test_pairs_without_an_alignment_are_chained_through_a_third_robot():
    frames = team_frames(np.random.default_rng(3), 4)
    out = TeamConsistency(4).update(true_estimates(frames, [(0, 1), (2, 1), (2, 3)]))
    assert out[(0, 2)].path == (0, 1, 2) and close(out[(0, 2)], frames, 0, 2, 1e-9)
    assert (0, 3) not in out  # three links: more than max_chain
    longer = TeamConsistency(4, TeamParams(max_chain=3)).update(
        true_estimates(frames, [(0, 1), (2, 1), (2, 3)]))
    assert longer[(0, 3)].path == (0, 1, 2, 3) and close(longer[(0, 3)], frames, 0, 3, 1e-9)
    # a chain is less certain than its links
    assert np.trace(out[(0, 2)].P) > np.trace(out[(0, 1)].P)


def fewest_links(n: int, links: set, i: int, j: int, max_chain: int) -> list[tuple[int, ...]]:
    """Every simple path of robots from i to j along `links` (both directions) with the fewest
    links, up to max_chain; [] when there is none."""
    for length in range(1, max_chain + 1):
        found = [(i, *middle, j) for middle in itertools.permutations(
                     [r for r in range(n) if r not in (i, j)], length - 1)
                 if all(tuple(sorted(link)) in links
                        for link in itertools.pairwise((i, *middle, j)))]
        if found:
            return found
    return []


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 7), max_chain=st.integers(1, 4),
       share=st.floats(0.1, 0.9))
def test_chains_have_the_fewest_links_and_the_least_spread_among_those(seed, n, max_chain,
                                                                       share):
    """A consistent team with some alignments missing: every pair gets the chain a brute-force
    search over simple paths finds (fewest links, then smallest translation covariance), and
    the composed alignment is the true one."""
    rng = np.random.default_rng(seed)
    frames = team_frames(rng, n)
    links = {pair for pair in itertools.combinations(range(n), 2) if rng.random() < share}
    estimates = true_estimates(frames, links)
    for pair in links:  # covariances of different sizes, so that the spread decides
        estimates[pair].P = P * rng.uniform(0.5, 4.0)
    out = TeamConsistency(n, TeamParams(max_chain=max_chain)).update(estimates)
    for i, j in itertools.permutations(range(n), 2):
        paths = fewest_links(n, links, i, j, max_chain)
        if not paths:
            assert (i, j) not in out
            continue
        assert len(out[(i, j)].path) == len(paths[0]) and out[(i, j)].path in paths
        assert close(out[(i, j)], frames, i, j, 1e-9)
        if len(paths) > 1:
            least = min(np.trace(chain_covariance(estimates, path)[:2, :2]) for path in paths)
            assert np.trace(out[(i, j)].P[:2, :2]) <= least * (1 + 1e-6)


def chain_covariance(estimates: dict, path: tuple[int, ...]) -> np.ndarray:
    """First-order covariance of the composition of the alignments along `path`, by numerical
    differentiation of the composed parameters (independent of the code under test)."""
    def composed(params: list[np.ndarray]) -> np.ndarray:
        T = np.eye(3)
        for x in params:
            T = T @ se2_from_params(x)
        return se2_to_params(T)

    links, covs = [], []
    for a, b in itertools.pairwise(path):
        est = estimates.get((a, b))
        if est is None:
            T = np.linalg.inv(se2_from_params(estimates[(b, a)].x))
            links.append(se2_to_params(T))
            J = numeric_jacobian(lambda x: se2_to_params(np.linalg.inv(se2_from_params(x))),
                                 estimates[(b, a)].x)
            covs.append(J @ estimates[(b, a)].P @ J.T)
        else:
            links.append(est.x)
            covs.append(est.P)
    total = np.zeros((3, 3))
    for k, cov in enumerate(covs):
        def moved(x, k=k):
            return composed([*links[:k], x, *links[k + 1:]])
        J = numeric_jacobian(moved, links[k])
        total += J @ cov @ J.T
    return total


def numeric_jacobian(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        diff = f(x + d) - f(x - d)
        diff[2] = math.remainder(diff[2], 2 * math.pi)
        cols.append(diff / (2 * h))
    return np.column_stack(cols)


def test_the_two_directions_of_a_pair_must_agree():
    frames = team_frames(np.random.default_rng(4), 2)
    estimates = true_estimates(frames, [(0, 1), (1, 0)])
    assert set(TeamConsistency(2).update(estimates)) == {(0, 1), (1, 0)}
    estimates[(1, 0)] = SimpleNamespace(x=estimates[(1, 0)].x + np.array([1.0, 0.0, 0.0]), P=P)
    assert TeamConsistency(2).update(estimates) == {}


def test_the_greedy_search_of_a_large_team_drops_the_same_alignment():
    frames = team_frames(np.random.default_rng(5), 6)
    estimates = true_estimates(frames, itertools.combinations(range(6), 2))
    estimates[(1, 4)] = SimpleNamespace(x=estimates[(1, 4)].x + np.array([0.0, 0.0, 0.5]), P=P)
    exact, greedy = TeamConsistency(6), TeamConsistency(6, TeamParams(exact_up_to=0))
    exact.update(estimates)
    greedy.update(estimates)
    assert exact.rejected == greedy.rejected == [(1, 4)]


@pytest.mark.parametrize(("estimates", "match"), [
    ({(0, 0): SimpleNamespace(x=np.zeros(3), P=P)}, "two different robots"),
    ({(0, 5): SimpleNamespace(x=np.zeros(3), P=P)}, "two different robots"),
    ({(True, 1): SimpleNamespace(x=np.zeros(3), P=P)}, "two different robots"),
    ({(0, 1): SimpleNamespace(x=np.array([np.nan, 0, 0]), P=P)}, "finite"),
    ({(0, 1): SimpleNamespace(x=np.zeros(2), P=P)}, "finite"),
])
def test_bad_input_is_a_data_error(estimates, match):
    with pytest.raises(DataError, match=match):
        TeamConsistency(3).update(estimates)


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"cycle_probability": 1.0}, "cycle_probability"), ({"max_chain": 0}, "max_chain"),
    ({"exact_up_to": 40}, "exact_up_to"), ({"cycle_probability": "x"}, "cycle_probability")])
def test_bad_parameters_are_config_errors(kwargs, field):
    with pytest.raises(ConfigError, match=field):
        TeamParams(**kwargs)
    with pytest.raises(ConfigError, match="n_robots"):
        TeamConsistency(1)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 6), data=st.data())
def test_the_wanted_pairs_are_those_of_the_whole_team(seed, n, data):
    """Asked for some pairs only, the team gives exactly what it gives them when asked for
    all, and leaves out the same pairs (one pair is wrong and some have no estimate)."""
    rng = np.random.default_rng(seed)
    frames = team_frames(rng, n)
    every = list(itertools.permutations(range(n), 2))
    known = [p for p in every if rng.random() < 0.6]
    estimates = true_estimates(frames, known)
    if known:
        estimates[known[0]] = SimpleNamespace(x=estimates[known[0]].x + np.array([3.0, 0, 0]), P=P)
    whole = TeamConsistency(n)
    full = whole.update(estimates)
    wanted = data.draw(st.lists(st.sampled_from(every), unique=True))
    some = TeamConsistency(n)
    part = some.update(estimates, wanted)
    assert some.rejected == whole.rejected
    assert set(part) == {p for p in wanted if p in full}
    for p in part:
        assert part[p].path == full[p].path
        np.testing.assert_array_equal(part[p].x, full[p].x)


@pytest.mark.parametrize("pairs", [[(0, 0)], [(0, 3)], [(0,)], [(True, 1)], ["01"]])
def test_a_wanted_pair_outside_the_team_is_refused(pairs):
    with pytest.raises(DataError, match="wanted pair"):
        TeamConsistency(3).update({}, pairs)


@pytest.mark.parametrize("pairs", [5, np.array(0.0), object()])
def test_wanted_pairs_that_cannot_be_listed_are_refused(pairs):
    """Not an iterable, or one that cannot be iterated (a 0-d array is an Iterable)."""
    with pytest.raises(DataError, match="pairs must be ordered pairs of robots"):
        TeamConsistency(3).update({(0, 1): None}, pairs)


@pytest.mark.parametrize("n_robots", [TeamConsistency.MAX_ROBOTS + 1, 10**9])
def test_a_team_too_large_for_the_update_is_refused_at_once(n_robots):
    with pytest.raises(ConfigError, match="n_robots"):
        TeamConsistency(n_robots)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 12), data=st.data())
def test_the_cycles_of_three_are_every_triple_of_known_pairs_in_order(n, data):
    """Found from the pairs, they are the triples i < j < k with all three pairs known, in
    the order of visiting every triple (which 1024 robots took minutes to do)."""
    possible = list(itertools.combinations(range(n), 2))
    known = data.draw(st.lists(st.sampled_from(possible), unique=True)) if possible else []
    edges = dict.fromkeys(known)
    assert _three_cycles(edges) == [
        (i, j, k) for i, j, k in itertools.combinations(range(n), 3)
        if (i, j) in edges and (j, k) in edges and (i, k) in edges]


def test_the_largest_team_keeps_a_closed_cycle_and_a_lone_pair():
    """Robots 0, 1, 2 close a cycle, 500 and 700 share one alignment, among 1024 robots."""
    team = TeamConsistency(TeamConsistency.MAX_ROBOTS)
    P = np.diag([0.01, 0.01, 1e-4])

    def estimate(x):
        return SimpleNamespace(x=np.array(x, float), P=P.copy())

    out = team.update({(0, 1): estimate([1.0, 0.0, 0.0]), (1, 2): estimate([1.0, 0.0, 0.0]),
                       (0, 2): estimate([2.0, 0.0, 0.0]), (500, 700): estimate([0.0, 3.0, 0.0])},
                      pairs=[(0, 2), (2, 0), (500, 700)])
    assert team.rejected == []
    assert sorted(out) == [(0, 2), (2, 0), (500, 700)]
    np.testing.assert_allclose(out[(2, 0)].x, [-2.0, 0.0, 0.0], atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 7))
def test_what_the_graph_asks_leaves_out_what_update_does(seed, n):
    """The graph's cycle check reads `_rejected` on the estimates `add_tcaff_estimate`
    checked, numbered over the robots they name: it holds out the same pairs as `update`
    leaves out, on teams with some alignments wrong and some pairs given in one direction,
    both, or neither."""
    rng = np.random.default_rng(seed)
    frames = team_frames(rng, n)
    pairs = [p for p in itertools.permutations(range(n), 2) if rng.random() < 0.6]
    estimates = true_estimates(frames, pairs)
    for key in pairs:
        if rng.random() < 0.2:
            estimates[key].x = estimates[key].x + rng.normal(0, [2.0, 2.0, 0.5])
    team = TeamConsistency(n)
    team.update(estimates)
    graph = InterRobotGraph(n)
    for (i, j), e in estimates.items():  # held estimates: the check without factors
        graph.add_tcaff_estimate(0, i, j, AlignmentEstimate(e.x, e.P, 0.0, 1, 1, 8, -1),
                                 None, None)
    graph.update(0)
    assert {(min(pair), max(pair)) for pair in graph._suspended} == set(team.rejected)
