"""`tcaff node`, `tcaff team`, `tcaff listen`: their refusals, and node/'s place in the layers."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval import cli

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
     "--scenario/--kimera/--replay [None, None, None]: give exactly one"),
    (["team", "--scenario", "four_robots", "--speed", "nan"], "--speed nan"),
    (["node", "--robot", "r0", "--scenario", "four_robots", "--stop-timeout", "0"],
     "--stop-timeout 0.0: must be a finite number > 0 (s)"),
    (["team", "--kimera", "missing"], "--kimera 'missing': must be a folder"),
    (["team", "--scenario", "four_robots", "--kimera", "."], "give exactly one"),
    (["listen", "--team", "a/b", "--connect", "127.0.0.1:7447"], "--team 'a/b'"),
])
def test_bad_options_end_in_one_line_and_status_2(tmp_path: Path, monkeypatch, capsys,
                                                  args: list[str], words: str) -> None:
    """Through the console entry point, in this process (a subprocess would only add the
    interpreter's start)."""
    argv = ["tcaff", *args, *(["--output", str(tmp_path)] if args[0] != "listen" else [])]
    monkeypatch.chdir(tmp_path)
    assert words in refused(argv, monkeypatch, capsys)


def refused(argv: list[str], monkeypatch, capsys) -> str:
    """The one line of stderr `tcaff` run with `argv` in this process ends with (status 2)."""
    monkeypatch.setattr(sys, "argv", argv)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exited:
        cli.main()
    stderr = capsys.readouterr().err
    assert exited.value.code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    return lines[0]


def test_a_node_whose_alignments_file_is_a_folder_is_refused_naming_it(
        tmp_path: Path, monkeypatch, capsys) -> None:
    """Before anything starts (it ended in a raw IsADirectoryError traceback)."""
    (tmp_path / "r0.csv").mkdir()
    argv = ["tcaff", "node", "--robot", "r0", "--scenario", "four_robots", "--listen",
            "127.0.0.1:7447", "--output", str(tmp_path)]
    assert refused(argv, monkeypatch, capsys) == (
        f"error: AlignmentCsv: {tmp_path / 'r0.csv'} is a folder, not a file")


def test_team_prints_each_failing_nodes_own_error(tmp_path: Path, monkeypatch, capsys) -> None:
    """A node's refusal went to its log only; the team's user saw just that it failed. Each
    node here is refused an option of its own (its drop seed), before it links."""
    from tcaff_gtsam.node import run

    node_argv = run.node_argv
    monkeypatch.setattr(run, "node_argv", lambda replay, robot, *args, **kwargs: [
        *node_argv(replay, robot, *args, **kwargs), "--drop-seed", str(-1 - robot)])
    monkeypatch.setattr(sys, "argv", ["tcaff", "team", "--scenario", "indoor_return",
                                      "--duration", "5", "--output", str(tmp_path)])
    with pytest.raises(SystemExit) as exited:
        cli.main()
    lines = capsys.readouterr().err.strip().splitlines()
    assert exited.value.code == 2
    assert lines == ["r0: --drop-seed -1: must be an int >= 0",
                     "r1: --drop-seed -2: must be an int >= 0",
                     f"error: nodes r0, r1 failed; see {tmp_path / 'logs'}"]


@pytest.mark.parametrize(("log", "code", "said"), [
    ("starting\nTraceback (most recent call last):\n  ...\nOSError: disk full\n\n", 1,
     "OSError: disk full"),
    ("error: --robot 'r9': the run's robots are r0, r1\nWARN zenoh: session closed\n", 2,
     "--robot 'r9': the run's robots are r0, r1"),
    ("", -9, "exit status -9, nothing written to"),
    (None, None, "still running when the run should have ended; stopped"),
])
def test_last_error_of_a_node_log(tmp_path: Path, log, code, said) -> None:
    path = tmp_path / "node0.log"
    if log is not None:
        path.write_text(log)
    assert cli.common._last_error(path, code).startswith(said)


def test_help_explains_the_team_commands() -> None:
    out = subprocess.run([TCAFF, "--help"], capture_output=True, text=True,
                         env={"COLUMNS": "200", "PATH": ""}, check=True).stdout
    for command in ("node", "team", "listen"):
        assert command in out


def test_a_listen_port_in_use_is_named_not_a_zenoh_error() -> None:
    import socket

    from tcaff_gtsam.node.link import Link

    from tcaff_gtsam.errors import ConfigError

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ConfigError, match=rf"--listen \['127.0.0.1:{port}'\] / --connect "
                                              rf"\[\]: Zenoh cannot open the session"):
            Link(listen=(f"127.0.0.1:{port}",)).open()


@pytest.mark.parametrize("times", [[0.0, float("nan"), 2.0], [0.0, 2.0, 1.0], [0.0, 1.0],
                                   [0.0, 1.0, 1e300],  # the wait overflowed
                                   np.array([-6e18, 0, 6e18], dtype=np.int64)])  # wraps
def test_a_replay_whose_times_cannot_be_a_schedule_is_refused_on_load(tmp_path, times) -> None:
    """Refused when read, not after a node has waited for its team and reached the first
    exchange due (it waited two minutes before)."""
    import numpy as np
    from tcaff_gtsam.node.replay import RobotReplay

    from tcaff_gtsam import ObjectMap
    from tcaff_gtsam.errors import DataError

    maps = [ObjectMap(np.zeros((1, 3)), np.ones(1), np.ones(1), np.zeros(1))] * 3
    good = RobotReplay(("r0", "r1"), 0, np.array([0.0, 1.0, 2.0]), maps, 20.0, None)
    good.save(tmp_path / "good.npz")
    RobotReplay.load(tmp_path / "good.npz")
    bad = RobotReplay(("r0", "r1"), 0, np.array(times), maps, 20.0, None)
    bad.save(tmp_path / "bad.npz")
    with pytest.raises(DataError, match="times must be finite and increasing, one per map"):
        RobotReplay.load(tmp_path / "bad.npz")
    # without exchanges: refused when saved (it was saved, then refused on load as a map
    # of the wrong shape)
    with pytest.raises(DataError, match="a robot replay needs at least one exchange"):
        RobotReplay(("r0", "r1"), 0, np.zeros(0), [], 20.0, None).save(tmp_path / "none.npz")
    assert not (tmp_path / "none.npz").exists()


@pytest.mark.parametrize("name", ["times", "sizes"])
def test_a_replay_of_boolean_numbers_is_refused_naming_the_array(tmp_path, name) -> None:
    """numpy took them as 0 and 1: times [False, True] made a schedule."""
    import numpy as np
    from tcaff_gtsam.node.replay import RobotReplay

    from tcaff_gtsam import ObjectMap
    from tcaff_gtsam.errors import DataError

    maps = [ObjectMap(np.zeros((1, 3)), np.ones(1), np.ones(1), np.zeros(1))] * 2
    RobotReplay(("r0", "r1"), 0, np.array([0.0, 1.0]), maps, 20.0, None).save(
        tmp_path / "good.npz")
    with np.load(tmp_path / "good.npz") as data:
        arrays = {key: data[key] for key in data.files}
    np.savez(tmp_path / "bad.npz", **{**arrays, name: arrays[name].astype(bool)})
    with pytest.raises(DataError, match=f"bad.npz: array '{name}' has dtype bool, not real"):
        RobotReplay.load(tmp_path / "bad.npz")


def _replay_arrays(tmp_path: Path) -> dict:
    """The arrays `RobotReplay.save` writes of a replay of three maps of 1, 2 and 3 objects."""
    from tcaff_gtsam.node.replay import RobotReplay

    from tcaff_gtsam import ObjectMap

    maps = [ObjectMap(np.full((k, 3), float(k)), np.ones(k), np.ones(k), np.full(k, float(k)))
            for k in (1, 2, 3)]
    RobotReplay(("r0", "r1", "r2"), 1, np.arange(3.0), maps, 20.0, 8).save(
        tmp_path / "good.npz")
    with np.load(tmp_path / "good.npz") as data:
        return {key: data[key] for key in data.files}


@pytest.mark.parametrize(("field", "value", "words"), [
    ("robot", 5, "robot = 5: must be an int in [0, 2]"),      # IndexError when its node ran
    ("robot", -1, "robot = -1"),                               # silently the last robot
    ("robot", 1.0, "robot = 1.0"),
    ("kappa", np.nan, "kappa = nan"), ("kappa", 0.0, "kappa = 0.0"),
    ("kappa", -2.0, "kappa = -2.0"), ("kappa", np.array("10"), "kappa = '10'"),
    ("window", 0, "window = 0"), ("window", 8.0, "window = 8.0"),
    ("robots", np.array(["r0", "r1", "r0"]), "robots = array(['r0', 'r1', 'r0']"),
    ("robots", np.array(["r0", "", "r2"]), "robots holds robot name ''"),
    ("times", np.array(["0", "1", "2"]), "times = array(['0', '1', '2']"),
    ("sizes", np.array([-1, 5, 2]), "sizes = array([-1, 5, 2])"),      # regrouped objects
    ("sizes", np.array([2, 3, 100]), "sizes = array([ 2, 3, 100])"),   # cut the last short
    ("sizes", np.array([1.0, 2.0, 3.0]), "sizes = array([1., 2., 3.])"),
    # sizes whose sum wraps round to the objects' count (loaded as maps of 6, 0 and 2)
    ("sizes", np.array([2**63 - 1, 2**63 - 1, 8]), "sizes = array(["),
    ("centroids", np.zeros(18), "centroids = array of shape (18,)"),
    ("widths", np.ones(5), "widths = array([1., 1., 1., 1., 1.])"),
])
def test_a_broken_replay_is_refused_on_load_naming_the_file_and_field(
        tmp_path, field, value, words) -> None:
    from tcaff_gtsam.node.replay import RobotReplay

    from tcaff_gtsam.errors import DataError

    np.savez(tmp_path / "bad.npz", **{**_replay_arrays(tmp_path), field: value})
    with pytest.raises(DataError) as caught:
        RobotReplay.load(tmp_path / "bad.npz")
    said = str(caught.value)
    assert said.startswith(f"{tmp_path / 'bad.npz'}: not a robot replay") and words in said
    assert said.count("not a robot replay") == 1  # not wrapped twice


#: values a damaged or hand-made replay may hold in place of a field's
_stored = st.one_of(
    st.integers(-3, 8), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=3),
    st.lists(st.integers(-3, 8), max_size=7).map(np.array),
    st.lists(st.floats(-5, 30), max_size=7).map(lambda v: np.array(v, dtype=float)),
    st.lists(st.text(max_size=3), max_size=4).map(np.array))


@settings(max_examples=150, deadline=None)
@given(field=st.sampled_from(["robots", "robot", "times", "sizes", "kappa", "window",
                              "centroids", "widths", "heights", "last_seen"]),
       value=_stored)
def test_a_replay_loads_as_what_it_stores_or_is_refused_naming_its_file(tmp_path_factory,
                                                                        field, value) -> None:
    """What loads is a replay a node can run: a robot of its team, each object in the map
    the sizes say, a kappa and window the aligner takes."""
    from tcaff_gtsam.node.replay import MAX_TEAM, RobotReplay

    from tcaff_gtsam.errors import DataError
    from tcaff_gtsam.filter_params import MAX_WINDOW

    folder = tmp_path_factory.mktemp("replay")
    arrays = {**_replay_arrays(folder), field: value}
    np.savez(folder / "bad.npz", **arrays)
    try:
        r = RobotReplay.load(folder / "bad.npz")
    except DataError as exc:
        assert str(exc).startswith(f"{folder / 'bad.npz'}: not a robot replay"), exc
        return
    assert 2 <= len(r.robots) <= MAX_TEAM and len(set(r.robots)) == len(r.robots)
    assert all(r.robots) and 0 <= r.robot < len(r.robots) and r.robot == arrays["robot"]
    assert r.kappa > 0 and r.kappa == arrays["kappa"]
    assert r.window is None or 1 <= r.window <= MAX_WINDOW
    assert len(r.times) == len(r.maps) >= 1 and np.all(np.diff(r.times) > 0)
    np.testing.assert_array_equal([len(m) for m in r.maps], arrays["sizes"])
    np.testing.assert_array_equal(np.concatenate([m.centroids for m in r.maps]),
                                  arrays["centroids"])


#: in a process of its own: a node's stop event (`node.run._node_files`, what `tcaff node`
#: waits on) is waited on again and again, and SIGTERM arrives at the k-th line the wait runs
#: (of the wait and what it calls), for every k; prints the wait's answer for each
SIGNAL_IN_THE_WAIT = """
import signal, sys
from pathlib import Path
from tcaff_gtsam.node.run import _node_files

answers = []
for k in range(1000):
    with _node_files("r0", Path(sys.argv[1]), False, 2.0) as (stop, _, _):
        wait, lines = type(stop).wait.__code__, []

        def tracer(frame, event, arg):
            if frame.f_code is not wait and not lines:
                return None  # outside the wait
            def line(frame, event, arg):
                if event == "line":
                    lines.append(frame.f_lineno)
                    if len(lines) == k + 1:
                        signal.raise_signal(signal.SIGTERM)  # handled here and now
                return line
            return line

        sys.settrace(tracer)
        try:
            answers.append(stop.wait(1.0))
        finally:
            sys.settrace(None)
        if len(lines) <= k:  # every line of the wait has had its signal
            break
print(answers[:-1])
"""


def test_a_node_stops_on_sigterm_wherever_its_main_thread_is_in_the_wait(tmp_path: Path
                                                                         ) -> None:
    """A signal handler runs on the main thread between two of its bytecodes, inside the wait
    for the stop event too: the handler must not take a lock that the wait holds (a
    `threading.Event`'s did, and the node then ignored SIGTERM for good)."""
    done = subprocess.run([sys.executable, "-c", SIGNAL_IN_THE_WAIT, str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    answers = ast.literal_eval(done.stdout)
    assert answers and all(answers), answers


def test_the_node_command_stops_within_the_library_s_default() -> None:
    """--stop-timeout's default is `replay_node`'s (written twice to keep the CLI's start
    light)."""
    import inspect

    from tcaff_gtsam.eval.cli.team import node
    from tcaff_gtsam.node.run import STOP_TIMEOUT

    assert inspect.signature(node).parameters["stop_timeout"].default == STOP_TIMEOUT


def test_a_team_run_sets_the_previous_runs_results_aside(tmp_path: Path, monkeypatch,
                                                         capsys) -> None:
    """The nodes append to their CSVs (to carry on after a restart): a second run into the
    folder added its rows to the first's, and one of more exchanges crashed the table. The
    run's nodes fail at once here (a bad drop seed), so what is left is what the team kept."""
    from tcaff_gtsam.node import run

    old = ["r0.csv", "r0.json", "r12.team.csv", "r3.json", "logs/node3.log", "replay/r3.npz"]
    # what a team run does not write: near misses of its names, and the Kimera maps it reuses
    kept = ["maps/r0.npz", "notes.csv", "r2d2_notes.csv", "r1-old.json", "r3_summary.team.csv",
            "replay/r1_backup.npz", "logs/node1.log.1", "previous/notes.txt"]
    for name in [*old, *kept, "previous/r9.csv"]:
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(f"{name} of a previous run\n")
    node_argv = run.node_argv
    monkeypatch.setattr(run, "node_argv", lambda *args, **kwargs: [
        *node_argv(*args, **kwargs), "--drop-seed", "-1"])
    monkeypatch.setattr(sys, "argv", ["tcaff", "team", "--scenario", "indoor_return",
                                      "--duration", "5", "--output", str(tmp_path)])
    with pytest.raises(SystemExit):
        cli.main()
    said = " ".join(capsys.readouterr().out.split())
    assert f"the previous run's results ({len(old)} files) moved to {tmp_path / 'previous'}" in said
    assert not any((tmp_path / name).exists() for name in old)
    assert all((tmp_path / "previous" / name).read_text() == f"{name} of a previous run\n"
               for name in old)
    assert not (tmp_path / "previous" / "r9.csv").exists()  # an older run's, replaced
    assert all((tmp_path / name).exists() for name in kept)


def test_a_team_run_refuses_a_previous_that_is_no_folder(tmp_path: Path, monkeypatch,
                                                         capsys) -> None:
    (tmp_path / "r0.csv").write_text("a previous run's\n")
    (tmp_path / "previous").write_text("not a folder\n")
    argv = ["tcaff", "team", "--scenario", "indoor_return", "--duration", "5", "--output",
            str(tmp_path)]
    assert refused(argv, monkeypatch, capsys) == (
        f"error: --output '{tmp_path}': holds {tmp_path / 'previous'}, which is no folder: the "
        f"previous run's results are moved there")
    assert (tmp_path / "r0.csv").read_text() == "a previous run's\n"


def test_the_team_table_leaves_out_rows_of_another_run(tmp_path: Path) -> None:
    """Rows of exchanges the run does not have crashed the table (IndexError) after the nodes
    had run; they are left out, and the caption says so."""
    from tcaff_gtsam.eval.cli.team import _simulated
    from tcaff_gtsam.eval.cli.team_table import _team_table
    from tcaff_gtsam.node.messages import AlignmentMessage
    from tcaff_gtsam.node.results import AlignmentCsv

    sim = _simulated("indoor_return", 0, 5.0)
    for robot, seq in (("r0", len(sim.times)), ("r1", 0)):
        rows = AlignmentCsv(tmp_path / f"{robot}.csv")
        rows.write(AlignmentMessage(robot, 0, seq, 1.0, "r1" if robot == "r0" else "r0", 0,
                                    1.0, 0, -1, False, np.full(3, np.nan),
                                    np.full((3, 3), np.nan)))
        rows.close()
    table = _team_table(sim, tmp_path, ("r0", "r1"))
    assert table.row_count == 1  # r1 -> r0
    assert table.caption == (f"left out r0.csv: exchanges beyond this run's {len(sim.times)} "
                             f"(another run's rows)")
