"""`python -m tcaff_gtsam.eval.precompile`: the core's kernels, the people tracker's and the
mapping front end's are compiled (or loaded from the cache) before any run needs them."""

from __future__ import annotations

import subprocess
import sys

#: the kernels called from Python outside the core, and one of the core's (all of which
#: tests/core/test_precompile.py checks)
ENTRY_KERNELS = [("tcaff_gtsam.eval.tracker", "_advance"),
                 ("tcaff_gtsam.mapping.lift", "_calipers"),
                 ("tcaff_gtsam.clipper", "_mno")]


def test_compile_kernels_compiles_the_tracker_mapping_and_core_kernels():
    """In a fresh interpreter: none of the kernels has a compiled signature before
    `compile_kernels`, every one has after it; the module says what it did."""
    check = "; ".join([
        "import importlib",
        f"kernels = [getattr(importlib.import_module(m), n) for m, n in {ENTRY_KERNELS!r}]",
        "print([bool(k.signatures) for k in kernels])",
        "from tcaff_gtsam.eval.precompile import main",
        "main()",
        "print([bool(k.signatures) for k in kernels])"])
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    before, after = done.stdout.strip().splitlines()[-2:]
    assert before == str([False] * len(ENTRY_KERNELS))
    assert after == str([True] * len(ENTRY_KERNELS))
    assert "numba kernels compiled and cached, with the tracker's" in done.stderr
