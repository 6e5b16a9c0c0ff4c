"""Whether numba kernels get compiled: the helper of tests/core/test_precompile.py and
tests/eval/test_precompile_package.py."""

from __future__ import annotations

import ast
import subprocess
import sys


def signatures_around(kernels: list[tuple[str, str]], statement: str
                      ) -> tuple[list[bool], list[bool], str]:
    """In a fresh interpreter: whether each kernel (module, name) has a compiled signature
    before and after `statement` runs, and the interpreter's stderr."""
    check = "; ".join([
        "import importlib",
        f"kernels = [getattr(importlib.import_module(m), n) for m, n in {kernels!r}]",
        "print([bool(k.signatures) for k in kernels])",
        statement,
        "print([bool(k.signatures) for k in kernels])"])
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    before, after = done.stdout.strip().splitlines()[-2:]
    return ast.literal_eval(before), ast.literal_eval(after), done.stderr
