"""Packaging: the top-level `mapping/` and `eval/` folders ship as `tcaff_gtsam.mapping` and
`tcaff_gtsam.eval` (pyproject `[tool.setuptools.package-dir]`), never as top-level packages.

Two installs are checked: the editable install the virtualenv already has, and a normal wheel
install built from a copy of the repository. The wheel tests (`TestWheelInstall`, select with
`-k wheel`) build and install a wheel with pip and take a few seconds.
"""

from __future__ import annotations

import configparser
import importlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import NamedTuple

import pytest

REPO = Path(__file__).resolve().parents[1]  # the repository

PROBE = """
import importlib, importlib.util, json, sys
out = {"top": {name: importlib.util.find_spec(name) is not None for name in ("mapping", "eval")}}
for name in ("tcaff_gtsam", "tcaff_gtsam.mapping", "tcaff_gtsam.eval", "tcaff_gtsam.eval.sim",
             "tcaff_gtsam.eval.sim.maps", "tcaff_gtsam.eval.cli"):
    out[name] = importlib.import_module(name).__file__
print(json.dumps(out))
"""


#: prints the folders of installed packages (purelib, then platlib when it differs)
SITE_PACKAGES = ("import sysconfig; p = sysconfig.get_paths(); "
                 "print(*dict.fromkeys([p['purelib'], p['platlib']]))")


def clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.update(extra)
    return env


def run_probe(cwd: Path, env: dict[str, str]) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def is_under(path: str | Path, folder: Path) -> bool:
    return Path(path).resolve().is_relative_to(folder.resolve())


# ---------------------------------------------------------------------------------------------
# (a) the editable install in the virtualenv


@pytest.mark.parametrize(
    ("module", "folder"),
    [
        ("tcaff_gtsam.mapping", "mapping"),
        ("tcaff_gtsam.eval", "eval"),
        ("tcaff_gtsam.eval.sim", "eval/sim"),
        ("tcaff_gtsam.eval.sim.maps", "eval/sim"),
        ("tcaff_gtsam.eval.cli", "eval"),
    ],
)
def test_editable_subpackages_come_from_repo_folders(module, folder):
    mod = importlib.import_module(module)
    assert mod.__file__ is not None
    assert is_under(mod.__file__, REPO / folder), mod.__file__
    assert not is_under(mod.__file__, REPO / "tcaff_gtsam"), mod.__file__


def test_editable_core_package_comes_from_repo():
    import tcaff_gtsam

    assert Path(tcaff_gtsam.__file__).resolve() == (REPO / "tcaff_gtsam" / "__init__.py").resolve()


def test_editable_install_outside_repo_has_no_top_level_mapping_or_eval(tmp_path):
    out = run_probe(tmp_path, clean_env())
    assert out["top"] == {"mapping": False, "eval": False}
    assert is_under(out["tcaff_gtsam.mapping"], REPO / "mapping")
    assert is_under(out["tcaff_gtsam.eval"], REPO / "eval")
    assert is_under(out["tcaff_gtsam.eval.sim"], REPO / "eval" / "sim")
    assert is_under(out["tcaff_gtsam.eval.sim.maps"], REPO / "eval" / "sim")
    assert is_under(out["tcaff_gtsam"], REPO / "tcaff_gtsam")


def test_pyproject_declares_the_package_dir_mapping():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    setuptools_cfg = config["tool"]["setuptools"]
    assert setuptools_cfg["package-dir"]["tcaff_gtsam.mapping"] == "mapping"
    assert setuptools_cfg["package-dir"]["tcaff_gtsam.eval"] == "eval"
    assert {"tcaff_gtsam.mapping", "tcaff_gtsam.eval", "tcaff_gtsam.eval.sim"} <= set(
        setuptools_cfg["packages"])
    assert "mapping" not in setuptools_cfg["packages"]
    assert "eval" not in setuptools_cfg["packages"]
    assert config["project"]["scripts"]["tcaff"] == "tcaff_gtsam.eval.cli:main"


def test_pyproject_lists_every_package_folder():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    setuptools_cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = set()
    for folder, package in (("tcaff_gtsam", "tcaff_gtsam"), ("mapping", "tcaff_gtsam.mapping"),
                            ("eval", "tcaff_gtsam.eval"), ("node", "tcaff_gtsam.node")):
        for init in (REPO / folder).rglob("__init__.py"):
            parts = init.parent.relative_to(REPO / folder).parts
            on_disk.add(".".join((package, *parts)))
    # A package missing from the list is silently left out of the wheel.
    assert on_disk == set(setuptools_cfg["packages"])


def test_pyproject_ships_the_configs_as_package_data_only():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    setuptools_cfg = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    # With include-package-data on, setuptools takes each configs/ sub-folder for a package
    # and prints a page of warnings per folder on every install.
    assert setuptools_cfg["include-package-data"] is False
    assert "configs/*/*.yaml" in setuptools_cfg["package-data"]["tcaff_gtsam.eval"]


# ---------------------------------------------------------------------------------------------
# (b) a normal (non-editable) wheel install

_IGNORE = shutil.ignore_patterns(".venv", ".git", "build", "dist", "*.egg-info", "__pycache__",
                                 ".pytest_cache", ".hypothesis", ".ruff_cache", "results")


class Built(NamedTuple):
    wheel: Path
    site: Path
    log: str


@pytest.fixture(scope="module")
def wheel_install(tmp_path_factory):
    """Build a wheel from a copy of the repository and pip-install it into a --target folder.

    The copy keeps the build's `build/` and `*.egg-info` output out of the working tree.
    Returns the wheel path, the site folder and the build's output.
    """
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    shutil.copytree(REPO, src, ignore=_IGNORE)
    dist = base / "dist"
    # Absolute paths throughout: pip would read a bare word as a package name to download.
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
         "-v", "-w", str(dist), str(src)],
        capture_output=True, text=True, timeout=300, env=clean_env(),
    )
    assert build.returncode == 0, build.stdout + build.stderr
    wheels = list(dist.glob("tcaff_gtsam-*.whl"))
    assert len(wheels) == 1, list(dist.iterdir())
    site = base / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--target",
         str(site), str(wheels[0])],
        capture_output=True, text=True, timeout=300, env=clean_env(),
    )
    assert install.returncode == 0, install.stdout + install.stderr
    return Built(wheels[0], site, build.stdout + build.stderr)


class TestWheelInstall:
    """Slow-ish (a few seconds): builds and installs a real wheel with pip."""

    def test_wheel_build_is_quiet(self, wheel_install):
        # `pip wheel -v` shows the build backend's warnings, as an install does.
        for warning in ("Package would be ignored", "is absent from the `packages`",
                        "as data is deprecated"):
            assert warning not in wheel_install.log, wheel_install.log

    def test_wheel_ships_every_config(self, wheel_install):
        with zipfile.ZipFile(wheel_install.wheel) as zf:
            names = set(zf.namelist())
        configs = sorted((REPO / "eval" / "configs").rglob("*.yaml"))
        assert configs
        for path in configs:
            rel = path.relative_to(REPO / "eval").as_posix()
            assert f"tcaff_gtsam/eval/{rel}" in names, f"{path} missing from the wheel"

    def test_wheel_file_list(self, wheel_install):
        wheel = wheel_install.wheel
        with zipfile.ZipFile(wheel) as zf:
            names = set(zf.namelist())
        for required in ("tcaff_gtsam/__init__.py", "tcaff_gtsam/geometry.py",
                         "tcaff_gtsam/mapping/__init__.py", "tcaff_gtsam/eval/__init__.py",
                         "tcaff_gtsam/eval/cli/__init__.py", "tcaff_gtsam/eval/sim/__init__.py",
                         "tcaff_gtsam/eval/sim/maps.py"):
            assert required in names, sorted(names)
        top_level = {name.split("/", 1)[0] for name in names}
        assert "mapping" not in top_level
        assert "eval" not in top_level
        assert not any(n.startswith(("mapping/", "eval/", "tests/", "scripts/")) for n in names)
        # Everything in the source folders made it in, under the mapped names.
        for folder, package in (("mapping", "tcaff_gtsam/mapping"), ("eval", "tcaff_gtsam/eval"),
                                ("tcaff_gtsam", "tcaff_gtsam")):
            for py in (REPO / folder).rglob("*.py"):
                rel = py.relative_to(REPO / folder).as_posix()
                assert f"{package}/{rel}" in names, f"{py} missing from the wheel"

    def test_wheel_entry_points_and_top_level(self, wheel_install):
        wheel = wheel_install.wheel
        with zipfile.ZipFile(wheel) as zf:
            names = zf.namelist()
            entry = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
            assert len(entry) == 1, names
            parser = configparser.ConfigParser()
            parser.read_string(zf.read(entry[0]).decode())
            top = [n for n in names if n.endswith(".dist-info/top_level.txt")]
            top_names = set(zf.read(top[0]).decode().split()) if top else set()
        assert parser["console_scripts"]["tcaff"].strip() == "tcaff_gtsam.eval.cli:main"
        assert "mapping" not in top_names and "eval" not in top_names

    def test_wheel_install_imports_from_target(self, wheel_install, tmp_path):
        site = wheel_install.site
        assert not (site / "mapping").exists()
        assert not (site / "eval").exists()
        out = run_probe(tmp_path, clean_env(PYTHONPATH=str(site)))
        for name in ("tcaff_gtsam", "tcaff_gtsam.mapping", "tcaff_gtsam.eval",
                     "tcaff_gtsam.eval.sim", "tcaff_gtsam.eval.sim.maps", "tcaff_gtsam.eval.cli"):
            assert out[name].startswith(str(site)), (name, out[name])
        assert out["tcaff_gtsam.eval.sim.maps"] == str(
            site / "tcaff_gtsam" / "eval" / "sim" / "maps.py")
        assert out["tcaff_gtsam.mapping"] == str(site / "tcaff_gtsam" / "mapping" / "__init__.py")
        assert out["top"] == {"mapping": False, "eval": False}

    def test_wheel_console_script_runs(self, wheel_install, tmp_path):
        site = wheel_install.site
        script = site / "bin" / "tcaff"
        assert script.is_file()
        proc = subprocess.run([sys.executable, str(script), "--help"], cwd=tmp_path,
                              env=clean_env(PYTHONPATH=str(site)), capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        assert "Usage" in proc.stdout
        assert "align" in proc.stdout.lower()


# ---------------------------------------------------------------------------------------------
# (c) outside the Makefile: `pip install .` into a fresh virtual environment


@pytest.mark.slow
def test_fresh_venv_pip_install_aligns_two_maps(tmp_path):
    """A new user's first steps: a fresh virtual environment, `pip install .` (not editable),
    then `tcaff make-maps` and `tcaff align-maps`, `tcaff study --help` and `python -m
    tcaff_gtsam --help`, run from a folder outside the repository; and numba compiles the
    installed package's kernels into a cache beside its modules, which the user's later
    processes load.

    The new environment borrows the dependencies this one installed from pyproject.toml (a
    .pth file puts this environment's site-packages after its own), so that pip installs the
    package alone instead of downloading and unpacking a gigabyte of wheels again (`make
    install` resolves them from the package index in every fresh clone); `pip check` then
    proves that the package's declared dependencies are what it is given.

    The two commands run their kernels as plain Python (`NUMBA_DISABLE_JIT`), and one small
    kernel is compiled to show where the cache goes: compiling the 17 kernels that aligning two
    maps calls into the new package took 20 s of the suite, and compilation is tested
    elsewhere (`make install` compiles every kernel in every clean clone, and
    tests/core/test_precompile.py checks what it compiles). What a study adds is tested
    elsewhere too: the wheel tests above check that every config ships, and `tcaff demo`'s
    every table and figure is checked in tests/eval/test_cli.py. `tcaff study --help` listing
    the shipped studies shows that the installed package finds its configs."""
    src = tmp_path / "src"
    shutil.copytree(REPO, src, ignore=_IGNORE)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=300)
    python = venv / "bin" / "python"
    own_site = subprocess.run([str(python), "-c", SITE_PACKAGES], capture_output=True,
                              text=True, check=True, timeout=120).stdout.split()
    lent = subprocess.run([sys.executable, "-c", SITE_PACKAGES], capture_output=True,
                          text=True, check=True, timeout=120).stdout.split()
    Path(own_site[0], "_dependencies.pth").write_text("\n".join(lent) + "\n")

    def pip(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "pip", "--python", str(python), *args],
                              capture_output=True, text=True, timeout=600, env=clean_env())

    def tcaff(*args: str) -> subprocess.CompletedProcess:
        done = subprocess.run([str(venv / "bin" / "tcaff"), *args], cwd=work,
                              capture_output=True, text=True, timeout=600,
                              env=clean_env(NUMBA_DISABLE_JIT="1"))
        assert done.returncode == 0, done.stdout + done.stderr
        return done

    # --ignore-installed: the editable install this environment lends is left alone
    install = pip("install", "-q", "--no-deps", "--no-index", "--no-build-isolation",
                  "--ignore-installed", str(src))
    assert install.returncode == 0, install.stdout + install.stderr
    checked = pip("check")
    assert checked.returncode == 0, checked.stdout + checked.stderr
    work = tmp_path / "work"
    work.mkdir()
    shutil.rmtree(src)  # nothing may come from the source tree
    installed = Path(own_site[0], "tcaff_gtsam")
    assert not list(installed.rglob("*.nbi"))
    tcaff("make-maps", "maps")
    truth = json.loads((work / "maps" / "truth.json").read_text())["T_oi_oj"]
    best = json.loads(tcaff("align-maps", "maps/ego.npz", "maps/other.npz", "--json").stdout)[0]
    assert abs(best["x"] - truth["x"]) < 0.5 and abs(best["y"] - truth["y"]) < 0.5
    assert not list(installed.rglob("*.nbi"))  # nothing compiled without the JIT
    compiled = subprocess.run(
        [str(python), "-c", "import numpy as np; from tcaff_gtsam.clipper import _gathered; "
                            "print(_gathered(np.arange(3.0), np.array([2, 0])))"],
        cwd=work, capture_output=True, text=True, timeout=300,
        env={k: v for k, v in clean_env(NUMBA_DISABLE_JIT="0").items()
             if k != "NUMBA_CACHE_DIR"})
    assert compiled.stdout.split() == ["[2.", "0.]"], compiled.stdout + compiled.stderr
    # the kernel went into the installed package's cache, not the source tree's
    assert [p.name.split("-")[0] for p in installed.rglob("__pycache__/*.nbi")] == [
        "clipper._gathered"]
    for study in ("demo", "limits", "paper"):
        assert study in tcaff("study", "--help").stdout
    helped = subprocess.run([str(python), "-m", "tcaff_gtsam", "--help"], cwd=work,
                            capture_output=True, text=True, timeout=300, env=clean_env())
    assert helped.returncode == 0, helped.stderr
    for command in ("study", "demo", "export", "mrclam", "kimera-multi"):
        assert command in helped.stdout
    where = subprocess.run([str(python), "-c", "import tcaff_gtsam; print(tcaff_gtsam.__file__)"],
                           cwd=work, capture_output=True, text=True, timeout=300,
                           env=clean_env())
    assert Path(where.stdout.strip()).is_relative_to(venv), where.stdout
