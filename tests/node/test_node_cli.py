"""`tcaff node`, `tcaff team`, `tcaff listen`: their refusals, and node/'s place in the layers."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TCAFF = str(Path(sys.executable).parent / "tcaff")


def imported(folder: Path) -> set[str]:
    """Every absolute module name the .py files of `folder` import."""
    names = set()
    for file in folder.glob("*.py"):
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, ast.Import):
                names |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names.add(node.module)
    return names


@pytest.mark.parametrize(("folder", "above"), [
    ("tcaff_gtsam", ("mapping", "eval", "node")), ("mapping", ("eval", "node")),
    ("node", ("eval",))])
def test_layers_import_one_way(folder, above) -> None:
    """core <- mapping <- eval, node: no layer imports one above it."""
    upward = [m for m in imported(REPO / folder)
              if m.startswith(tuple(f"tcaff_gtsam.{layer}" for layer in above))]
    assert not upward


@pytest.mark.parametrize(("args", "words"), [
    (["node", "--robot", "r0", "--listen", "127.0.0.1:7447"],
     "--scenario/--replay [None, None]: give exactly one"),
    (["team", "--scenario", "four_robots", "--speed", "nan"], "--speed nan"),
    (["listen", "--team", "a/b", "--connect", "127.0.0.1:7447"], "--team 'a/b'"),
])
def test_bad_options_end_in_one_line_and_status_2(tmp_path: Path, args: list[str],
                                                  words: str) -> None:
    result = subprocess.run([TCAFF, *args, *(["--output", str(tmp_path)]
                                             if args[0] != "listen" else [])],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], result.stderr


def test_help_explains_the_team_commands() -> None:
    out = subprocess.run([TCAFF, "--help"], capture_output=True, text=True,
                         env={"COLUMNS": "200", "PATH": ""}, check=True).stdout
    for command in ("node", "team", "listen"):
        assert command in out
