"""`python -m tcaff_gtsam.precompile`: every kernel a pair aligner calls from Python is compiled
(or loaded from the cache) before the first real step."""

from __future__ import annotations

import subprocess
import sys

from precompiled import signatures_around

#: the kernels the alignment path calls from Python (the others are called only by these)
ENTRY_KERNELS = [("clipper", "_graph_csr"), ("clipper", "_mno"),
                 ("hypothesis_tree", "_measurement_costs"),
                 ("hypothesis_tree", "_kalman_children"), ("hypothesis_tree", "_children"),
                 ("hypothesis_tree", "_best_per_group"),
                 ("hypothesis_tree", "_mahalanobis_to"),
                 ("hypothesis_tree", "_first_not_positive_definite"),
                 ("registration", "_mutual_nearest"),
                 ("registration", "_best_per_object")]


def test_compile_kernels_compiles_every_entry_kernel():
    """In a fresh interpreter, where nothing else has run the aligner: no entry kernel has a
    compiled signature before `compile_kernels`, every one has after it."""
    kernels = [(f"tcaff_gtsam.{module}", name) for module, name in ENTRY_KERNELS]
    before, after, _ = signatures_around(
        kernels, "from tcaff_gtsam.precompile import compile_kernels; compile_kernels()")
    assert before == [False] * len(kernels)
    assert after == [True] * len(kernels)


def test_the_module_runs_and_says_what_it_did():
    done = subprocess.run([sys.executable, "-m", "tcaff_gtsam.precompile"], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "numba kernels compiled and cached" in done.stderr
