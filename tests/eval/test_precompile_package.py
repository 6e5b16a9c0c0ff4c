"""`python -m tcaff_gtsam.eval.precompile`: the core's kernels, the people tracker's and the
mapping front end's are compiled (or loaded from the cache) before any run needs them."""

from __future__ import annotations

from precompiled import signatures_around

#: the kernels called from Python outside the core, and one of the core's (all of which
#: tests/core/test_precompile.py checks)
ENTRY_KERNELS = [("tcaff_gtsam.eval.tracker", "_advance"),
                 ("tcaff_gtsam.eval.tracker", "_run"),
                 ("tcaff_gtsam.mapping.objects", "footprint_rectangles"),
                 ("tcaff_gtsam.mapping.depth_grid", "_expand"),
                 ("tcaff_gtsam.mapping.structure", "_ransac_round"),
                 ("tcaff_gtsam.mapping.masks", "_mask_moments"),
                 ("tcaff_gtsam.mapping.masks", "_edge_band"),
                 ("tcaff_gtsam.mapping.masks", "_label_moments"),
                 ("tcaff_gtsam.mapping.structure", "_restore_slices"),
                 ("tcaff_gtsam.clipper", "_mno")]


def test_compile_kernels_compiles_the_tracker_mapping_and_core_kernels():
    """In a fresh interpreter: none of the kernels has a compiled signature before
    `compile_kernels`, every one has after it; the module says what it did."""
    before, after, stderr = signatures_around(
        ENTRY_KERNELS, "from tcaff_gtsam.eval.precompile import main; main()")
    assert before == [False] * len(ENTRY_KERNELS)
    assert after == [True] * len(ENTRY_KERNELS)
    assert "numba kernels compiled and cached, with the tracker's" in stderr
