"""A node's alignments CSV: written row by row, read back whole even after its writer was killed
mid-row, and every damaged file refused naming the file and the line."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from tcaff_gtsam.node.messages import AlignmentMessage, TeamMessage
from tcaff_gtsam.node.results import TEAM_COLUMNS, AlignmentCsv, read_alignments

from tcaff_gtsam.errors import DataError


def step(k: int, accepted: bool = True) -> AlignmentMessage:
    """The k-th alignment of r0 to r1 (x and P tell the rows apart)."""
    return AlignmentMessage("r0", 1, k, 10.0 + k, "r1", k, 9.0 + k, k, 1 if accepted else -1,
                            accepted, np.array([k + 0.25, -2.0, 0.3]) if accepted
                            else np.full(3, np.nan),
                            np.diag([0.1, 0.2, 0.01]) * (k + 1) if accepted
                            else np.full((3, 3), np.nan))


def written(path: Path, steps: range) -> None:
    rows = AlignmentCsv(path)
    for k in steps:
        rows.write(step(k, accepted=k % 3 != 1))
    rows.close()


def assert_rows(path: Path, steps: list[int]) -> None:
    got = read_alignments(path)
    np.testing.assert_array_equal(got["seq"], steps)
    np.testing.assert_array_equal(got["neighbour"], ["r1"] * len(steps))
    np.testing.assert_array_equal(got["x"], [k + 0.25 if k % 3 != 1 else np.nan
                                             for k in steps])


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 6), cut=st.floats(0, 1, exclude_max=True), more=st.integers(0, 3))
@example(n=3, cut=0.95, more=0)   # cut in the last row's last number
@example(n=3, cut=0.999, more=2)  # between its "\r" and "\n": the row is whole
def test_a_writer_killed_mid_row_loses_that_row_only_and_a_restarted_one_appends_whole_rows(
        tmp_path_factory, n, cut, more) -> None:
    """The writer appends and flushes row by row: a node killed mid-write leaves a row cut
    short at the end (read_alignments raised ValueError on it), and a node restarted on the
    same file ran its next row on from the cut one."""
    path = tmp_path_factory.mktemp("rows") / "r0.csv"
    written(path, range(n))
    raw = path.read_bytes()
    header = raw.index(b"\n") + 1
    at = header + int(cut * (len(raw) - header))  # the kill: anywhere after the header
    path.write_bytes(raw[:at])
    # the rows whose line end was written, or its carriage return (ending the last row)
    whole = raw[:at].count(b"\n") - 1 + raw[:at].endswith(b"\r")
    assert_rows(path, list(range(whole)))
    written(path, range(n, n + more))  # restarted
    assert_rows(path, [*range(whole), *range(n, n + more)])
    # a row cut between its "\r" and "\n" got its "\n": no lone carriage return that a
    # second cut would turn into the end of a whole row
    assert b"\r" not in path.read_bytes().replace(b"\r\n", b"")


@pytest.mark.parametrize(("edit", "words"), [
    (lambda b: b.replace(b"\r\n", b"\r\n\r\n", 2), "line 2 has 0 fields, the header 18"),
    (lambda b: b.replace(b"0.3", b"abc", 1), "line 2: theta = 'abc' is not a number"),
    (lambda b: b[:-10] + b"\xff\xfe\r\n", "line 4 is not UTF-8"),
    (lambda b: b + b"r0," + b"9" * 200_000 + b"\r\n", "line 5: field larger than field limit"),
    (lambda b: b.replace(b"r0,r1,1,", b"r0,r1,1,7,", 1), "line 3 has 19 fields"),
])
def test_a_damaged_alignments_csv_is_refused_naming_the_file_and_line(tmp_path, edit,
                                                                      words) -> None:
    written(tmp_path / "good.csv", range(3))
    (tmp_path / "bad.csv").write_bytes(edit((tmp_path / "good.csv").read_bytes()))
    with pytest.raises(DataError, match=f"^{tmp_path / 'bad.csv'}: ") as caught:
        read_alignments(tmp_path / "bad.csv")
    assert words in str(caught.value)


def test_a_fifo_in_place_of_the_csv_is_refused_without_waiting_for_a_writer(tmp_path) -> None:
    fifo = tmp_path / "r0.csv"
    os.mkfifo(fifo)
    outcome: list[BaseException] = []

    def read() -> None:
        try:
            read_alignments(fifo)
        except BaseException as exc:  # handed to the test's thread
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(60)  # catches a hang only
    if reader.is_alive():  # let the reader go: a writer opens and closes the FIFO
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
    assert not reader.is_alive() and isinstance(outcome[0], DataError)
    assert "not a regular file" in str(outcome[0])


def test_a_team_csv_reads_back_as_written(tmp_path) -> None:
    rows = AlignmentCsv(tmp_path / "r0.team.csv", TEAM_COLUMNS)
    rows.write(TeamMessage("r0", 1, 4, 14.0, "r2", ("r1",), True, np.array([1.0, 2.0, 0.5]),
                           np.eye(3)))
    rows.close()
    with open(tmp_path / "r0.team.csv", "ab") as file:  # killed in its second row
        file.write(b"r0,r2,5,15.0,r1,1,1.0")
    got = read_alignments(tmp_path / "r0.team.csv", TEAM_COLUMNS)
    assert (got["via"].tolist(), got["seq"].tolist(), got["P_tt"].tolist()) == (
        ["r1"], [4.0], [1.0])


def test_a_file_of_something_else_is_not_appended_to(tmp_path) -> None:
    """A file at the CSV's path that is no alignments CSV (no line end at all, or another
    header) was cut to nothing and given a header; it is left as it is."""
    for text in ("notes without a line end", "robot,neighbour,else\r\nr0,r1,3\r\n"):
        path = tmp_path / "r0.csv"
        path.write_text(text, newline="")
        with pytest.raises(DataError, match="holds something other than alignments"):
            AlignmentCsv(path)
        assert path.read_bytes().decode() == text
    written(tmp_path / "lf.csv", range(2))  # line ends made "\n" by a tool: appended to
    (tmp_path / "lf.csv").write_bytes((tmp_path / "lf.csv").read_bytes().replace(b"\r\n",
                                                                                  b"\n"))
    written(tmp_path / "lf.csv", range(2, 4))
    assert_rows(tmp_path / "lf.csv", [0, 1, 2, 3])
    written(tmp_path / "cut.csv", range(0))  # a header alone, its line end cut off
    (tmp_path / "cut.csv").write_bytes((tmp_path / "cut.csv").read_bytes()[:-1])
    written(tmp_path / "cut.csv", range(2))
    assert_rows(tmp_path / "cut.csv", [0, 1])


def test_a_writer_killed_before_its_first_row_leaves_a_csv_of_none(tmp_path) -> None:
    """The header waited in the buffer for the first row: the file of a node killed before it
    was empty, which reads as no alignments CSV at all."""
    rows = AlignmentCsv(tmp_path / "r0.csv")  # never closed: the process is killed
    got = read_alignments(tmp_path / "r0.csv")
    assert all(len(column) == 0 for column in got.values())
    rows.close()
