"""The variables of `InterRobotGraph` and what it takes: the keys of its poses (one gtsam
symbol, kind, robot and index packed into its index), the record it keeps of each factor, the
checks of the transforms and covariances given to it, and the groups and blocks of robots its
factors link."""

from __future__ import annotations

import math
from collections import defaultdict
from typing import NamedTuple

import gtsam
import numpy as np

from .errors import DataError
from .inputs import real_array, shown

__all__ = ["alignment_key", "keyframe_key"]

# what the solver can take: beyond these, gtsam's elimination fails ("indeterminate linear
# system") and, without the roll-back, the graph stayed broken
_MAX_CONDITION = 1e10  # of a factor's covariance
_MAX_TRANSLATION = 1e4  # metres, of an alignment: far beyond any map two robots share

# One symbol character; kind, robot and index share the symbol's index, which is all that g2o
# files keep, so exported vertex ids stay unique. gtsam.symbol(c, index) is ord(c) << 56 | index,
# so keys are made and taken apart with integer arithmetic (no gtsam call in the update's loops).
_ROBOT_SHIFT, _KIND_SHIFT = 36, 52
_INDEX_MASK = (1 << _ROBOT_SHIFT) - 1
_SYMBOL = ord("r") << 56
_SYMBOL_INDEX = (1 << 56) - 1
_KEYFRAME = _SYMBOL | 1 << _KIND_SHIFT


def _check_index(name: str, value, bits: int) -> int:
    if (not isinstance(value, (int, np.integer)) or isinstance(value, bool)
            or not 0 <= value < 1 << bits):
        raise DataError(f"{name} = {shown(value)} must be an int in [0, 2^{bits})")
    return int(value)


def _key_list(keys) -> gtsam.KeyList:
    out = gtsam.KeyList()
    for key in keys:
        out.push_back(key)
    return out


def _components(nodes, links):
    """Union-find over `nodes` joined by the links, pairs (a, b); returns the function mapping
    a node to its group's root. Links to other nodes are ignored."""
    parent = {n: n for n in nodes}

    def root(n):
        while parent[n] != n:
            parent[n] = parent[parent[n]]
            n = parent[n]
        return n

    for a, b in links:
        if a in parent and b in parent:
            parent[root(a)] = root(b)
    return root


def _blocks(pairs: list[tuple]) -> list[int]:
    """The block (biconnected component) of each pair of a graph whose edges are `pairs`
    (distinct (a, b), a != b): pairs share a block when a cycle runs through both; a pair on
    no cycle is a block alone. Hopcroft and Tarjan's depth-first search, without recursion."""
    neighbours = defaultdict(list)
    for e, (a, b) in enumerate(pairs):
        neighbours[a].append((b, e))
        neighbours[b].append((a, e))
    order: dict = {}  # node -> its depth-first index
    low: dict = {}  # node -> the lowest index its subtree reaches by one back edge
    block, open_edges, n_blocks = [-1] * len(pairs), [], 0
    for root in neighbours:
        if root in order:
            continue
        order[root] = low[root] = len(order)
        path = [(root, -1, iter(neighbours[root]))]
        while path:
            v, entered_by, rest = path[-1]
            for w, e in rest:
                if e == entered_by:
                    continue
                if w not in order:
                    order[w] = low[w] = len(order)
                    open_edges.append(e)
                    path.append((w, e, iter(neighbours[w])))
                    break
                if order[w] < order[v]:  # a back edge, met from its lower end
                    open_edges.append(e)
                    low[v] = min(low[v], order[w])
            else:
                path.pop()
                if path:
                    u = path[-1][0]
                    low[u] = min(low[u], low[v])
                    if low[v] >= order[u]:  # nothing below v reaches above u: a block ends
                        while True:
                            e = open_edges.pop()
                            block[e] = n_blocks
                            if e == entered_by:
                                break
                        n_blocks += 1
    return block


def _a_key(robot: int, step: int) -> int:
    """gtsam key of A_robot(step) for a robot and step already checked."""
    return _SYMBOL | robot << _ROBOT_SHIFT | step


def _x_key(robot: int, index: int) -> int:
    """gtsam key of X_robot(index) for a robot and index already checked."""
    return _KEYFRAME | robot << _ROBOT_SHIFT | index


def alignment_key(robot: int, step: int) -> int:
    """gtsam key of A_robot(step); robot < 2^16, step < 2^36."""
    robot = _check_index("robot", robot, _KIND_SHIFT - _ROBOT_SHIFT)
    return _a_key(robot, _check_index("step", step, _ROBOT_SHIFT))


def keyframe_key(robot: int, index: int) -> int:
    """gtsam key of X_robot(index); robot < 2^16, index < 2^36."""
    robot = _check_index("robot", robot, _KIND_SHIFT - _ROBOT_SHIFT)
    return _x_key(robot, _check_index("keyframe index", index, _ROBOT_SHIFT))


def _step_of(key: int) -> int | None:
    """The alignment step of an A key; None for a keyframe key."""
    index = key & _SYMBOL_INDEX
    return None if index >> _KIND_SHIFT else index & _INDEX_MASK


def _keyframe_of(key: int) -> tuple[int, int]:
    """(robot, index) of a keyframe key."""
    return (key >> _ROBOT_SHIFT) & 0xFFFF, key & _INDEX_MASK


def _chain(key: int) -> tuple[str, int]:
    """("A", robot) or ("X", robot): the chain a key belongs to."""
    return ("X" if key >> _KIND_SHIFT & 1 else "A", (key >> _ROBOT_SHIFT) & 0xFFFF)


class _Factor(NamedTuple):
    """A factor and what the graph needs to know about it (a tuple: one is made for every
    factor, 16 per step for 4 robots).

    Attributes:
        keys: the factor's variables.
        tag: ("alignment" | "keyframe", i, j, hypothesis), ("free", chain) or None.
        step: the alignment step an alignment factor refers to.
        link: (chain, chain) when the factor connects two chains.
    """

    factor: gtsam.NonlinearFactor
    keys: tuple[int, ...]
    tag: tuple | None = None
    step: int | None = None
    link: tuple | None = None


def _check_finite(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    arr = real_array("InterRobotGraph", name, value)
    if arr.shape != shape:
        raise DataError(f"{name} must have shape {shape}, got {arr.shape}")
    if not math.isfinite(arr.sum()):  # one reduction: this runs for every factor
        raise DataError(f"{name} has non-finite values: {arr.tolist()}")
    return arr


def _check_translation(name: str, t: np.ndarray) -> None:
    if np.abs(t).max() > _MAX_TRANSLATION:
        raise DataError(f"{name}: translation {t.tolist()} m is beyond {_MAX_TRANSLATION:.0e} m")


def _check_cov(name: str, cov, n: int) -> np.ndarray:
    C = _check_finite(name, cov, (n, n))
    if np.abs(C - C.T).max() > 1e-9 * (1.0 + np.abs(C).max()):
        raise DataError(f"{name} must be symmetric positive definite, got {C.tolist()}")
    C = 0.5 * (C + C.T)
    eig = np.linalg.eigvalsh(C)
    if eig[0] <= 0:
        raise DataError(f"{name} must be symmetric positive definite, got {C.tolist()}")
    if eig[-1] > _MAX_CONDITION * eig[0]:
        raise DataError(f"{name} is too ill-conditioned for the solver (eigenvalues "
                        f"{eig[0]:.3g} to {eig[-1]:.3g}, condition number above "
                        f"{_MAX_CONDITION:.0e}): {C.tolist()}")
    return C
