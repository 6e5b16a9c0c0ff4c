"""Start-up: importing the package, its sub-packages or the CLI, and `tcaff --help`, load none
of the heavy libraries; the core's public names load their module on first use (PEP 562).

Each check runs in a fresh interpreter, since this test process has long imported everything.
What is asserted is which modules are loaded, not how long it takes (that is
scripts/bench_startup.py's job).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

import tcaff_gtsam

# Each of these takes from a tenth of a second to a second to import on a small machine.
HEAVY = ("gtsam", "open3d", "matplotlib", "numba", "scipy", "cv2", "onnxruntime", "pandas",
         "motmetrics", "rosbags")


def loaded_after(code: str) -> dict:
    """Run `code` in a fresh interpreter; return the heavy modules it loaded and what it printed
    as JSON into the variable `out` (a dict)."""
    probe = (f"import json, sys\nout = {{}}\n{code}\n"
             f"out['heavy'] = sorted(m for m in {HEAVY!r} if m in sys.modules)\n"
             f"print(json.dumps(out))")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("module", ["tcaff_gtsam", "tcaff_gtsam.mapping", "tcaff_gtsam.eval",
                                    "tcaff_gtsam.eval.sim", "tcaff_gtsam.eval.datasets",
                                    "tcaff_gtsam.params", "tcaff_gtsam.eval.cli"])
def test_import_loads_no_heavy_library(module):
    assert loaded_after(f"import {module}")["heavy"] == []


def test_cli_help_loads_no_heavy_library():
    out = loaded_after(
        "from tcaff_gtsam.eval.cli import app\n"
        "for args in (['--help'], ['align-maps', '--help'], ['study', '--help'],\n"
        "             ['kimera-multi', '--help'], ['mrclam', '--help']):\n"
        "    try:\n"
        "        app(args, prog_name='tcaff')\n"
        "    except SystemExit as exc:\n"
        "        assert exc.code == 0, (args, exc.code)\n"
        "out['eval'] = sorted(m for m in sys.modules if m.startswith('tcaff_gtsam.eval.'))")
    assert out["heavy"] == []
    # The config loader, study and the rest are imported by the commands that run.
    # (the command line is the cli package, nothing else of eval)
    assert out["eval"] and all(m == "tcaff_gtsam.eval.cli" or m.startswith(
        "tcaff_gtsam.eval.cli.") for m in out["eval"])


def test_first_use_of_a_name_loads_its_module():
    out = loaded_after(
        "import tcaff_gtsam\n"
        "out['before'] = 'gtsam' in sys.modules\n"
        "graph = tcaff_gtsam.InterRobotGraph\n"
        "out['after'] = 'gtsam' in sys.modules\n"
        "out['where'] = graph.__module__\n"
        "out['cached'] = 'InterRobotGraph' in vars(tcaff_gtsam)")
    assert (out["before"], out["after"]) == (False, True)
    assert out["where"] == "tcaff_gtsam.graph"
    assert out["cached"]


def test_star_import_gives_every_public_name():
    out = loaded_after("ns = {}\nexec('from tcaff_gtsam import *', ns)\n"
                       "import tcaff_gtsam\n"
                       "out['missing'] = sorted(set(tcaff_gtsam.__all__) - set(ns))")
    assert out["missing"] == []


def test_public_api_is_unchanged():
    assert set(tcaff_gtsam.__all__) == {
        "TCAFF", "AlignmentEstimate", "AlignmentMeasurement", "ClipperParams", "ClipperSolution",
        "ConfigError", "ConsistencyGraph", "DataError", "FrameAligner", "FrameAlignerParams",
        "GraphParams", "InterRobotGraph", "ModelError", "ObjectMap", "PairwiseAligner",
        "TCAFFParams", "TcaffError", "clipper_solve", "consistency_graph", "mno_clipper",
        "putative_associations", "weighted_arun",
        "TeamConsistency", "TeamEstimate", "TeamParams", "MapMemory", "ObjectIdentities"}
    for name in tcaff_gtsam.__all__:
        value = getattr(tcaff_gtsam, name)
        assert value.__name__ == name
        assert value.__module__.startswith("tcaff_gtsam.")
    assert set(tcaff_gtsam.__all__) <= set(dir(tcaff_gtsam))
    assert tcaff_gtsam.__version__


def test_submodules_stay_reachable_as_attributes():
    from tcaff_gtsam import geometry

    assert tcaff_gtsam.geometry is geometry
    assert "geometry" in dir(tcaff_gtsam)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="module 'tcaff_gtsam' has no attribute 'Nope'"):
        tcaff_gtsam.Nope  # noqa: B018
