"""The `tcaff` command line."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from tcaff_gtsam.eval.cli import app
from typer.testing import CliRunner

runner = CliRunner()
TCAFF = str(Path(sys.executable).parent / "tcaff")


def test_help_lists_the_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("align-maps", "make-maps", "demo"):
        assert command in result.output


def test_make_maps_then_align_maps_finds_the_truth(tmp_path):
    result = runner.invoke(app, ["make-maps", str(tmp_path), "--seed", "3"])
    assert result.exit_code == 0, result.output
    truth = json.loads((tmp_path / "truth.json").read_text())["T_oi_oj"]
    result = runner.invoke(app, ["align-maps", str(tmp_path / "ego.npz"),
                                 str(tmp_path / "other.npz"), "--json"])
    assert result.exit_code == 0, result.output
    candidates = json.loads(result.output)
    assert candidates
    best = candidates[0]
    assert math.hypot(best["x"] - truth["x"], best["y"] - truth["y"]) < 0.6
    assert abs(best["theta"] - truth["theta"]) < math.radians(1.5)
    assert len(best["associations"]) >= 5
    table = runner.invoke(app, ["align-maps", str(tmp_path / "ego.npz"),
                                str(tmp_path / "other.npz")])
    assert "candidate alignments" in table.output


def test_missing_map_is_a_clear_error(tmp_path):
    done = subprocess.run([TCAFF, "align-maps", str(tmp_path / "nope.npz"),
                           str(tmp_path / "nope2.npz")], capture_output=True, text=True)
    assert done.returncode == 2
    assert "no such map file" in done.stderr
    assert "Traceback" not in done.stderr


def test_bad_option_is_a_clear_error(tmp_path):
    runner.invoke(app, ["make-maps", str(tmp_path)])
    done = subprocess.run([TCAFF, "align-maps", str(tmp_path / "ego.npz"),
                           str(tmp_path / "other.npz"), "--dim", "5"],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert "dim" in done.stderr and "Traceback" not in done.stderr


def test_demo_shows_correct_candidates():
    result = runner.invoke(app, ["demo"])
    assert result.exit_code == 0, result.output
    assert "correct" in result.output
    assert "Ambiguous grid" in result.output
