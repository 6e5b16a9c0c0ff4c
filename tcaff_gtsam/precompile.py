"""Compile the core's numba kernels into their on-disk cache: `python -m tcaff_gtsam.precompile`.

The kernels (consistency graph, MNO-CLIPPER, mutual inliers, the ranking of look-alike pairs
and of the partial-view rule's, the TCAFF hypothesis trees, a map's fits of itself) are
compiled with `cache=True`: the machine code is written next to each module (in its
`__pycache__`, or numba's user cache when that is not writable) and loaded by later processes.
The first process to use them otherwise pays the compilation, seconds, on its first alignment
step; `make install` runs this once so that no user process does. Source changes are noticed
by numba, which compiles again on the next call.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .association import _neighbourhood_pairs, _partial_pairs_kept, neighbourhood_agreement
from .hypothesis_tree import best_per_tree, mahalanobis_to, not_positive_definite
from .object_map import ObjectMap
from .pairwise import PairwiseAligner
from .twins import self_motions

__all__ = ["compile_kernels"]

def _maps(rng: np.random.Generator, t: float) -> tuple[ObjectMap, ObjectMap]:
    """Two maps of 12 objects of assorted sizes, the second the first turned and moved."""
    n = 12
    xy = rng.uniform(0.0, 15.0, (n, 2))
    sizes = rng.uniform(0.3, 2.0, n)
    c, s = np.cos(0.7), np.sin(0.7)
    moved = (xy - [3.0, -2.0]) @ np.array([[c, -s], [s, c]])  # the other's frame
    seen = np.full(n, t)

    def one(points: np.ndarray) -> ObjectMap:
        return ObjectMap(np.column_stack([points, sizes / 2]), sizes, sizes, seen)

    return one(xy), one(moved)


def compile_kernels() -> float:
    """Run the default and the reference pair aligner through a few steps (every kernel of the
    alignment path: graph, MNO-CLIPPER, the TCAFF filter), prune a large hypothesis tree, rank
    the pairs of look-alike maps past the association cap and those of the partial-view
    rule, score their neighbourhoods' agreement, and fit a map to itself, so that each kernel
    is compiled, or loaded from the cache. The kernels are given writeable arrays only
    (`inputs.kernel_array`), the ones compiled here.

    Returns:
        seconds taken.
    """
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    pairs = (PairwiseAligner(), PairwiseAligner.reference())  # both filters' gates and costs
    for step in range(5):
        maps = _maps(rng, float(step))
        for pair in pairs:
            pair.update(float(step), *maps)
    best_per_tree(rng.uniform(0.0, 1.0, 8), np.zeros(8, np.int64), 2)  # a tree past its bound
    # a rival weighed against the main hypothesis; covariances checked
    mahalanobis_to(np.zeros((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)), np.zeros(3),
                   np.eye(3), np.array([False, False, True]))
    not_positive_definite(np.eye(3)[None])
    # look-alike maps past max_associations: each object's best pairs, cut to a cap
    xy = rng.uniform(0.0, 15.0, (12, 2))
    _neighbourhood_pairs(np.ones((12, 12), bool), xy, xy, np.zeros(12), np.zeros(12), 0.25, 2, 5)
    neighbourhood_agreement(xy, xy, np.array([[0, 0], [1, 1], [2, 2]]), 0.25, 2)
    # the partial-view rule's pairs of maps of many objects: each object's best pair
    _partial_pairs_kept(np.ones((12, 12), bool), np.eye(12, dtype=bool), xy, xy, np.zeros(12),
                        np.zeros(12), 0.25)
    # a map's objects fitting the map itself turned (an alignment's twins)
    self_motions(xy[:4], xy, np.ones((4, 12), bool), 0.3, (1.0, 0.1))
    return time.perf_counter() - start


def main() -> None:
    seconds = compile_kernels()
    print(f"tcaff_gtsam: numba kernels compiled and cached ({seconds:.1f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
