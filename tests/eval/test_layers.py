"""eval/ imports one way: the run sources (`sim/`, `datasets/`) reach nothing of the runners,
the study, the tracking evaluation, the plots or the command line, statically or at run time."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

EVAL = Path(__file__).resolve().parents[2] / "eval"
PACKAGE = "tcaff_gtsam.eval"
#: what the run sources must not reach
ABOVE = ("methods", "study", "mot", "plots", "jobs", "results", "dataset_runs", "cli")


def module_file(name: str) -> Path | None:
    """The file of an eval module (`tcaff_gtsam.eval.sim.world`), None outside eval."""
    if name != PACKAGE and not name.startswith(PACKAGE + "."):
        return None
    parts = name.removeprefix(PACKAGE).strip(".").split(".") if name != PACKAGE else []
    folder = EVAL.joinpath(*parts)
    if (folder / "__init__.py").is_file():
        return folder / "__init__.py"
    file = folder.with_suffix(".py")
    return file if file.is_file() else None


def module_name(file: Path) -> str:
    parts = list(file.relative_to(EVAL).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGE, *parts])


def imports_of(file: Path) -> set[str]:
    """Every module an eval file imports, at any depth of the file (absolute names); `from X
    import y` counts both X and X.y, since y may be a module."""
    tree = ast.parse(file.read_text())
    name = module_name(file)
    package = name if file.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module
            found.add(target)
            found |= {f"{target}.{alias.name}" for alias in node.names}
    return found


def reached_from(roots: list[Path]) -> dict[str, str]:
    """eval module -> the module that first imported it, walking from the roots."""
    seen: dict[str, str] = {}
    todo = [(module_name(f), "(root)") for f in roots]
    while todo:
        name, parent = todo.pop()
        if name in seen:
            continue
        seen[name] = parent
        file = module_file(name)
        if file is None:
            continue
        # importing a.b.c runs a/__init__ and a/b/__init__ too
        parents = [name.rsplit(".", k)[0] for k in range(1, name.count(".") - 1)]
        todo += [(p, name) for p in parents if module_file(p) is not None]
        todo += [(m, name) for m in imports_of(file) if module_file(m) is not None]
    return seen


def forbidden(name: str) -> bool:
    rest = name.removeprefix(PACKAGE + ".").split(".")[0]
    return rest in ABOVE  # the command line: the cli package, with all its modules


SOURCES = sorted((EVAL / "sim").glob("*.py")) + sorted((EVAL / "datasets").glob("*.py"))


@pytest.mark.parametrize("file", SOURCES, ids=lambda f: f"{f.parent.name}/{f.name}")
def test_run_sources_do_not_import_the_layers_above(file):
    seen = reached_from([file])
    bad = {m: seen[m] for m in seen if forbidden(m)}
    assert not bad, f"{file.name} reaches {bad} (module: imported by)"


def test_the_walk_finds_an_upward_import():
    """The check itself: the study reaches the runners and the plots."""
    seen = reached_from([EVAL / "study.py"])
    assert f"{PACKAGE}.methods" in seen and f"{PACKAGE}.results" in seen
    assert any(forbidden(m) for m in seen)


def test_importing_the_run_sources_loads_nothing_above_them():
    code = ("import sys, tcaff_gtsam.eval.sim.simulate, tcaff_gtsam.eval.sim.kimera_bags, "
            "tcaff_gtsam.eval.datasets.kimera_multi, tcaff_gtsam.eval.datasets.mrclam\n"
            f"print(sorted(m for m in sys.modules if m.startswith('{PACKAGE}.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    loaded = ast.literal_eval(out)
    assert f"{PACKAGE}.sim.simulate" in loaded
    assert not [m for m in loaded if forbidden(m)], loaded


@pytest.mark.parametrize("module", [*sorted((EVAL / "cli").glob("*.py")),
                                    *sorted(EVAL.glob("config*.py"))],
                         ids=lambda path: path.relative_to(EVAL).as_posix())
def test_command_line_and_config_modules_stay_readable(module):
    """The command line and the configs are where new commands and settings land: each module
    stays small enough to take in at once."""
    lines = len(module.read_text().splitlines())
    assert lines <= 500, f"{module.name}: {lines} lines"


def test_a_study_worker_without_a_camera_or_people_loads_neither_open3d_nor_motmetrics():
    """A study's worker process starts (`executor._announce`, then the job's imports) and runs
    an object-level job of TCAFF and the ground truth: Open3D (1 s with the Dash it imports)
    and motmetrics (with pandas) are for rendered scenarios, ICP and people, and every worker
    would otherwise pay their imports at start."""
    code = ("import queue, sys\n"
            "from tcaff_gtsam.eval import executor\n"
            "from tcaff_gtsam.eval.config import load_methods, load_scenario\n"
            "executor._announce(queue.Queue(), 1)\n"
            "scenario = load_scenario('opposite_directions').model_copy(update={'duration': 8})\n"
            "job = executor.simulated_job(scenario, load_methods('tcaff_only'), 0)\n"
            "print(sorted(m for m in ('open3d', 'motmetrics', 'pandas') if m in sys.modules), "
            "len(job.metrics))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "4"], out.stdout  # 4: TCAFF, causal, smoothed, truth
