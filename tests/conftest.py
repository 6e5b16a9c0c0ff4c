"""Shared test set-up.

The suite mirrors the package: `core/` (tcaff_gtsam), `mapping/` and `eval/`. Helper modules
that several folders use (`rgbd_scenes.py`, `precompiled.py`) sit beside this file, whose
folder pytest puts on the import path. End-to-end tests that run whole studies, data sets or
bags are marked `slow`:

    make test                      # everything (what CI runs)
    .venv/bin/pytest -m "not slow"  # the quick subset for development
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import settings

#: the repository's root folder
REPO = Path(__file__).resolve().parents[1]


def _build_each_command_line_once() -> None:
    """typer builds the click command from the command functions' signatures on every call
    (about 0.1 s: typer reads every annotation again); a `tcaff` process builds it once, but
    the tests run the command line hundreds of times in one process. An app does not change
    once its modules are imported, so each is built once here, for `app()` and `CliRunner`."""
    import functools

    import typer.main
    import typer.testing

    typer.main.get_command = typer.testing._get_command = functools.cache(typer.main.get_command)


_build_each_command_line_once()

# no timing thresholds inside tests: hypothesis' default fails an example slower than 200 ms,
# which a loaded machine (or a kernel's first call in a fresh process) can make any example
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The `slow` tests first, each group in its collected order: spread over the workers
    (`make test`), the long end-to-end runs then start early instead of leaving one core
    running the last of them alone at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository's root folder."""
    return REPO


def made_once(tmp_path_factory, name: str, make):
    """`make(folder)` run once per test session, its return value pickled beside its files:
    the folder and the value. Under xdist the test processes share one run (the first to ask
    makes it, under a file lock; the others wait and read it), so a costly data set is not
    made once per process."""
    import fcntl
    import os
    import pickle

    base = tmp_path_factory.getbasetemp()
    if "PYTEST_XDIST_WORKER" in os.environ:
        base = base.parent  # the session's, shared by its processes
    folder, saved = base / name, base / f"{name}.pickle"
    with open(base / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not saved.exists():
            value = make(folder)
            saved.write_bytes(pickle.dumps(value))
        return folder, pickle.loads(saved.read_bytes())


@pytest.fixture(scope="session")
def kimera_like_sequence(tmp_path_factory):
    """Kimera-Multi-like bags of the two robots of the shipped test same_direction, rendered
    from the simulator: 30 s at 240 x 180 and 5 Hz. The folder (no test writes into it) and
    the simulation's truth. The robots first share objects after 9 s, so TCAFF answers only
    from about 17 s: the 30 s stay, the images are small (rendering and mapping cost by the
    pixel; at 160 x 120 TCAFF accepts nothing in 30 s)."""
    from tcaff_gtsam.eval.config import load_kimera_multi
    from tcaff_gtsam.eval.sim import kimera_bags

    robots = tuple(load_kimera_multi("same_direction").robots)
    return made_once(tmp_path_factory, "kimera_like", lambda folder: kimera_bags.write_sequence(
        folder, robots, 30.0, 5.0, 240, 180, seed=1,
        scenario=str(REPO / "tests" / "eval" / "data" / "small_room_rgbd.yaml")))


#: seconds an in-process command may take before the test process is stopped with every
#: thread's traceback (as a subprocess's timeout would stop the subprocess)
COMMAND_TIMEOUT = 300.0


@pytest.fixture
def tcaff_main(monkeypatch, capsys):
    """`tcaff ARGS` through its entry point `cli.main` in this process (a subprocess costs
    seconds of imports): the exit status, stdout and stderr as a `CompletedProcess`. Processes
    the command starts (Dask workers, nodes) are still processes of their own."""
    import faulthandler
    import subprocess
    import sys

    from tcaff_gtsam.eval import cli

    def run(*args: str) -> subprocess.CompletedProcess:
        monkeypatch.setattr(sys, "argv", ["tcaff", *args])
        monkeypatch.setenv("COLUMNS", "200")
        monkeypatch.setattr(cli, "_consoles", {})  # made again at that width
        capsys.readouterr()
        faulthandler.dump_traceback_later(COMMAND_TIMEOUT, exit=True, file=sys.__stderr__)
        try:
            with pytest.raises(SystemExit) as exited:
                cli.main()
        finally:
            faulthandler.cancel_dump_traceback_later()
        out = capsys.readouterr()
        return subprocess.CompletedProcess(args, exited.value.code or 0, out.out, out.err)

    return run
