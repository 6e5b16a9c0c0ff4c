"""Compile every numba kernel of the package into its on-disk cache:
`python -m tcaff_gtsam.eval.precompile`.

The core's alignment kernels (`tcaff_gtsam.precompile`, which a user of the core alone runs),
the people tracker's frame and whole run (`tracker`), the mapping front end's footprint calipers
(`mapping.objects`) and the depth segmenter's and mask filter's kernels (`mapping.segment`).
`make install` runs it once, so that no study, demo or mapping run pays seconds of
compilation in its first process. Source changes are noticed by numba, which
compiles again on the next call.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from tcaff_gtsam.mapping.lift import _footprint_widths
from tcaff_gtsam.mapping.segment import _compile_kernels as compile_segmenter_kernels

from tcaff_gtsam.precompile import compile_kernels as compile_core_kernels

from .tracker import MultiObjectTracker

__all__ = ["compile_kernels"]


def compile_kernels() -> float:
    """The core's kernels, then two tracker frames (tracks spawned, then associated and
    updated) a call each and both in one call, the footprint of one cloud and the segmenter on
    a small frame, so that each kernel is compiled or loaded from the cache.

    Returns:
        seconds taken.
    """
    start = time.perf_counter()
    compile_core_kernels()
    tracker = MultiObjectTracker()
    tracker.step(0.0, [np.array([[0.0, 0.0], [3.0, 1.0]])])
    tracker.step(0.2, [np.array([[0.1, 0.0]]), np.zeros((0, 2))])
    # a whole run's frames in one call, as the study tracks (two sets a frame, one empty)
    MultiObjectTracker().run(np.array([0.0, 0.2]), np.array([[0.0, 0.0], [0.1, 0.0]]),
                             np.array([[0, 1, 1], [1, 2, 2]]))
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    _footprint_widths(square, np.array([0]), np.array([4]))
    compile_segmenter_kernels()
    return time.perf_counter() - start


def main() -> None:
    seconds = compile_kernels()
    print(f"tcaff_gtsam: numba kernels compiled and cached, with the tracker's and the mapping "
          f"front end's ({seconds:.1f} s)", file=sys.stderr)


if __name__ == "__main__":
    main()
