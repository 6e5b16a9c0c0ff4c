"""The command line fuzzed: every command with junk and plausible values for its options and
arguments. Each call ends in exit status 0, or 2 with one line on stderr that starts with
"error:"; never a traceback or another status.

Commands that would start long work (a study, a sweep, a data set) are given an input that
cannot be read (a missing file, a folder, a binary file) where their configuration or data
goes, so what is fuzzed is everything checked before the work starts."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import pytest
import typer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval import cli

COMMANDS = typer.main.get_command(cli.app).commands
#: what each long-running command is given where its input goes, so it cannot start work
UNREADABLE = ("missing.yaml", "folder", "binary.yaml", "/dev/null/x")
#: argument or option taking the unreadable input, per command
SPOILED = {"study": "config", "sweep": "config", "kimera-multi": "data", "mrclam": "data",
           "view": "results", "export": "results"}
FUZZED = sorted(set(SPOILED) | {"align-maps", "make-maps"})

values = st.one_of(
    st.sampled_from(["", "-1", "0", "1", "2", "3.5", "nan", "inf", "-inf", "1e400", "x", "é",
                     "--", "tum", "g2o", "vio", "raw", "residual", "0,1", "paper", "default",
                     "ego.npz", "other.npz", "out", "run.rrd", "tcp://127.0.0.1:1"]),
    st.sampled_from(UNREADABLE),
    st.text(max_size=6),
)


def one_line_or_success(code: int, stderr: str) -> None:
    assert "Traceback" not in stderr, stderr
    if code == 0:
        return
    lines = stderr.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, stderr)


@pytest.fixture(scope="module")
def workspace():
    """A folder holding two real maps, a folder, a binary file; the fuzz runs inside it."""
    with tempfile.TemporaryDirectory() as folder:
        here = Path(folder)
        (here / "folder").mkdir()
        (here / "binary.yaml").write_bytes(b"\xff\xfe\x00 not text")
        with pytest.raises(SystemExit):
            sys.argv = ["tcaff", "make-maps", str(here)]
            cli.main()
        yield here


@pytest.mark.parametrize("command", FUZZED)
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_any_arguments_end_in_success_or_one_line(workspace, monkeypatch, capsys, command,
                                                  data):
    params = COMMANDS[command].params
    argv: list[str] = []
    for param in params:
        if param.name == SPOILED.get(command):
            value = data.draw(st.sampled_from(UNREADABLE), label=param.name)
        elif param.param_type_name == "argument":
            value = data.draw(values, label=param.name)
        elif not data.draw(st.booleans(), label=f"give {param.name}"):
            continue
        elif param.is_flag:
            argv.append(param.opts[0])
            continue
        else:
            value = data.draw(values, label=param.name)
        argv.extend([value] if param.param_type_name == "argument" else [param.opts[0], value])
    monkeypatch.chdir(workspace)
    monkeypatch.setattr(sys, "argv", ["tcaff", command, *argv])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exited:
        cli.main()
    code = exited.value.code
    one_line_or_success(0 if code is None else code, capsys.readouterr().err)


@pytest.mark.parametrize("name", ["\x85", "a\u2028b", "line\nbreak", "x\x1cy"])
def test_a_file_name_with_a_line_break_is_reported_on_one_line(monkeypatch, capsys, name):
    """Every character str.splitlines breaks at is shown escaped in the error."""
    monkeypatch.setattr(sys, "argv", ["tcaff", "align-maps", name, "other.npz"])
    with pytest.raises(SystemExit) as done:
        cli.main()
    stderr = capsys.readouterr().err
    one_line_or_success(done.value.code, stderr)
    assert repr(name)[1:-1] in stderr  # the name, escaped, still says which file
