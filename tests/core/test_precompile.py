"""`python -m tcaff_gtsam.precompile`: every kernel a pair aligner calls from Python is compiled
(or loaded from the cache) before the first real step."""

from __future__ import annotations

import subprocess
import sys

from tcaff_gtsam import clipper, hypothesis_tree
from tcaff_gtsam.precompile import compile_kernels

#: the kernels the alignment path calls from Python (the others are called only by these)
ENTRY_KERNELS = [(clipper, "_graph_csr"), (clipper, "_mno"),
                 (hypothesis_tree, "_measurement_costs"), (hypothesis_tree, "_kalman_children"),
                 (hypothesis_tree, "_children"), (hypothesis_tree, "_best_per_group")]


def test_compile_kernels_compiles_every_entry_kernel():
    seconds = compile_kernels()
    assert seconds >= 0
    for module, name in ENTRY_KERNELS:
        assert getattr(module, name).signatures, f"{module.__name__}.{name} not compiled"


def test_the_module_runs_and_says_what_it_did():
    done = subprocess.run([sys.executable, "-m", "tcaff_gtsam.precompile"], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "numba kernels compiled and cached" in done.stderr
