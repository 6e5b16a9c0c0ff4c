"""The text tables of the recorded data sets (`datasets.text_tables`): what is read, and a
DataError naming file and line for anything corrupt."""

from __future__ import annotations

import os
import re
import tempfile
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.datasets import text_tables
from tcaff_gtsam.eval.datasets.text_tables import data_lines, read_table

from tcaff_gtsam.errors import DataError

#: (what is written at a field, the error's words)
CORRUPTIONS = [("x1", "not a number: 'x1'"), ("1,5", "not a number: '1,5'"),
               ("nan", "non-finite value 'nan'"), ("-inf", "non-finite value '-inf'"),
               ("1e999", "non-finite value '1e999'"), ("\x00", "not a number"),
               ("0x1p3", "not a number: '0x1p3'")]


def test_comments_blank_lines_and_line_endings():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.txt"
        path.write_bytes(b"# header\r\n\r\n1 2 3\r\n  4\t5 6  # a note\r\n#\n\n7 8 9")
        rows, lines, texts = read_table(path, 3)
    np.testing.assert_array_equal(rows, [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    assert lines.tolist() == [3, 4, 7] and lines.dtype == np.int64
    assert texts == ["1 2 3", "4\t5 6", "7 8 9"]


def test_lines_are_counted_as_an_editor_counts_them():
    """A form feed or a vertical tab is no line break: the line named is the file's."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.txt"
        path.write_text("1 2\n3\x0c4\n5\x0b x\n")
        assert data_lines(path)[0] == [1, 2, 3]
        with pytest.raises(DataError, match=re.escape(f"{path}:3: not a number: 'x'")):
            read_table(path, 2)


@pytest.mark.parametrize(("content", "message"), [
    ("", ": no rows \\(expected lines of 'a b'\\)"),
    ("# only a comment\n\n", ": no rows"),
    ("1 2\n3\n", ":2: expected 2 columns \\(a b\\), got 1 \\('3'\\)"),
    ("1 2\n3 4 5\n", ":2: expected 2 columns \\(a b\\), got 3"),
])
def test_a_bad_shape_is_named(content, message):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.txt"
        path.write_text(content)
        with pytest.raises(DataError, match=re.escape(str(path)) + message):
            read_table(path, 2, "a b")


def test_an_empty_table_may_be_allowed():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.txt"
        path.write_text("# nothing yet\n")
        rows, lines, texts = read_table(path, 4, empty_ok=True)
    assert rows.shape == (0, 4) and lines.shape == (0,) and texts == []


def test_a_file_that_cannot_be_read_is_named(tmp_path):
    with pytest.raises(DataError, match=re.escape(f"{tmp_path / 'none.txt'}: no such file")):
        read_table(tmp_path / "none.txt", 2)
    with pytest.raises(DataError, match=re.escape(f"{tmp_path}: cannot read")):
        read_table(tmp_path, 2)
    binary = tmp_path / "binary.txt"
    binary.write_bytes(b"1 2\n\xff\xfe\x00\x89PNG\n")
    with pytest.raises(DataError, match=re.escape(f"{binary}: cannot read") + ".*utf-8"):
        read_table(binary, 2)


@settings(max_examples=60, deadline=None)
@given(table=st.lists(st.lists(st.floats(-1e9, 1e9), min_size=3, max_size=3), min_size=1,
                      max_size=30),
       comments=st.lists(st.booleans(), min_size=30, max_size=30),
       at=st.tuples(st.integers(0, 29), st.integers(0, 2)),
       corruption=st.sampled_from(CORRUPTIONS))
def test_a_corrupted_field_names_file_line_and_field(table, comments, at, corruption):
    """Random tables with comment lines among the rows read back exactly; one field
    corrupted gives the error of that field, on its line."""
    text, row_lines = [], []
    for k, row in enumerate(table):
        if comments[k]:
            text.append("# a comment")
        text.append(" ".join(repr(v) for v in row))
        row_lines.append(len(text))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "t.txt"
        path.write_text("\n".join(text) + "\n")
        rows, lines, _ = read_table(path, 3)
        np.testing.assert_array_equal(rows, table)
        assert lines.tolist() == row_lines
        r, c = at[0] % len(table), at[1]
        fields = text[row_lines[r] - 1].split()
        fields[c], words = corruption
        text[row_lines[r] - 1] = " ".join(fields)
        path.write_text("\n".join(text) + "\n")
        with pytest.raises(DataError) as info:
            read_table(path, 3)
    assert str(info.value).startswith(f"{path}:{row_lines[r]}: {words}")


@contextmanager
def fifo_holding(path: Path, text: str):
    """A FIFO at `path` that gives `text` to whatever opens it to read, as a file would: a
    reader that opens it reads `text` and then its end, instead of waiting for ever (a thread
    writes it once the reader is there). On exit a reader that never came is stood in for, so
    that the thread ends."""
    os.mkfifo(path)

    def write() -> None:
        with open(path, "w") as fifo:  # waits for a reader
            fifo.write(text)

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    try:
        yield path
    finally:
        stand_in = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        writer.join()
        os.close(stand_in)


def test_a_fifo_is_refused_before_it_is_opened(tmp_path):
    """A FIFO in place of a text file used to be opened and read: with no writer that waits for
    ever; here the FIFO gives a valid table to a reader, so that opening it is what is seen."""
    with fifo_holding(tmp_path / "table.txt", "1 2\n3 4\n") as fifo:
        with pytest.raises(DataError, match=re.escape(f"{fifo}: cannot read (not a regular "
                                                      "file (a folder, FIFO or device))")):
            read_table(fifo, 2)
    with fifo_holding(tmp_path / "value.json", "[1, 2]") as fifo:
        with pytest.raises(DataError, match="not a regular file"):
            text_tables.read_json(fifo)


@settings(max_examples=40, deadline=None)
@given(st.text(max_size=40), st.integers(0, 100_000))
def test_any_json_text_is_a_value_or_a_data_error_naming_the_file(text, depth):
    """Text that is not JSON, or JSON nested deeper than the parser's recursion (a
    RecursionError out of json.loads), is a DataError naming the file."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "v.json"
        path.write_text("[" * depth + text + "]" * depth, encoding="utf-8")
        try:
            text_tables.read_json(path, "thing")
        except DataError as exc:
            assert str(exc).startswith(f"{path}: not a thing: not JSON")
