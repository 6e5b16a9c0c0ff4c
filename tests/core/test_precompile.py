"""`python -m tcaff_gtsam.precompile`: every kernel a pair aligner calls from Python is compiled
(or loaded from the cache) before the first real step."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from precompiled import signatures_around

from tcaff_gtsam.inputs import kernel_array

#: the kernels the alignment path calls from Python (the others are called only by these)
ENTRY_KERNELS = [("clipper_graph", "_graph_csr"), ("clipper", "_mno"),
                 ("hypothesis_tree", "_measurement_costs"),
                 ("hypothesis_tree", "_kalman_children"), ("hypothesis_tree", "_children"),
                 ("hypothesis_tree", "_best_per_group"),
                 ("hypothesis_tree", "_mahalanobis_to"),
                 ("hypothesis_tree", "_first_not_positive_definite"),
                 ("registration", "_mutual_nearest"),
                 ("association", "_best_per_object"),
                 ("association", "_best_pair_of_each"),
                 ("association", "_size_gate"), ("association", "_nearest_rows"),
                 ("association", "_true_pairs"), ("association", "_mutual_best"),
                 ("twins", "_self_motions")]


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


READ_ONLY_INPUTS = """
import numpy as np
from tcaff_gtsam import TCAFF, association, clipper_graph, hypothesis_tree
from tcaff_gtsam.frame_aligner import FrameAligner
from tcaff_gtsam.params import FrameAlignerParams
from tcaff_gtsam.precompile import _maps, compile_kernels
kernels = [clipper_graph._graph_csr, hypothesis_tree._measurement_costs,
           hypothesis_tree._kalman_children, hypothesis_tree._first_not_positive_definite,
           association._agreement, association._size_gate]
compile_kernels()
print([len(k.signatures) for k in kernels])
ego, other = _maps(np.random.default_rng(3), 0.0)
FrameAligner(FrameAlignerParams(dim=3)).measurements(ego, other, 0.0)  # the maps' own arrays
zs, Rs = np.zeros((2, 3)), np.stack([np.eye(3) * 0.1] * 2)
zs.setflags(write=False)
Rs.setflags(write=False)
filter = TCAFF()
for _ in range(6):
    filter.update(zs, Rs)
hypothesis_tree.not_positive_definite(np.broadcast_to(np.eye(3), (2, 3, 3)))
print([len(k.signatures) for k in kernels])
"""


def test_read_only_inputs_use_the_kernels_compile_kernels_compiled():
    """ObjectMaps' arrays and a caller's read-only measurements reach the kernels as the
    writeable arrays `compile_kernels` compiled them for: no process compiles them again."""
    done = subprocess.run([sys.executable, "-c", READ_ONLY_INPUTS], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    after_compile, after_read_only = done.stdout.strip().splitlines()[-2:]
    assert after_compile == after_read_only
    assert "0" not in after_compile.strip("[]").split(", ")


@given(st.sampled_from([np.float64, np.float32, np.int64]), st.booleans(), st.booleans(),
       st.integers(1, 5), st.integers(1, 4))
def test_kernel_array_is_writeable_contiguous_and_copies_only_when_it_must(
        dtype, read_only, transposed, rows, cols):
    value = np.arange(rows * cols, dtype=dtype).reshape(rows, cols)
    if transposed:
        value = value.T
    value.setflags(write=not read_only)
    array = kernel_array(value)
    assert array.dtype == np.float64 and array.flags.c_contiguous and array.flags.writeable
    assert np.array_equal(array, value)
    reused = dtype is np.float64 and not read_only and value.flags.c_contiguous
    assert np.shares_memory(array, value) == reused
