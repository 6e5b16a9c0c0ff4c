"""Whitespace-separated text tables of numbers, as recorded data sets ship them (TUM RGB-D's
groundtruth.txt and accelerometer.txt, 7-Scenes' camera-intrinsics.txt, MRCLAM's .dat files).

A `#` starts a comment that runs to the end of its line; lines left blank by that are skipped;
every other line is one row. Lines are counted as an editor counts them (by "\\n" only), so the
line numbers in errors are the ones a reader opens the file at. `read_text` and `read_json`
read a whole file of other text.

Anything wrong is a `DataError` naming the file, and the line for a bad row: a missing or
unreadable file (a folder, FIFO or device; not UTF-8 text: a binary or truncated download), a
row with the wrong number of columns, a field that is not a number, a non-finite value, and no
rows where some are needed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import open_regular

__all__ = ["TextTable", "data_lines", "number", "read_json", "read_table", "read_text"]


class TextTable(NamedTuple):
    """The rows of a text table.

    Attributes:
        rows: (k, columns) float64, every value finite.
        lines: (k,) int64, each row's line number in the file (1-based).
        texts: (k,) each row as written (its comment cut, stripped), to quote in errors.
    """

    rows: np.ndarray
    lines: np.ndarray
    texts: list[str]


def read_text(path: Path, what: str = "file") -> str:
    """The text of `path`; `what` names it in the error ("file", "image list", ...).

    Raises:
        DataError: no such file; a folder, FIFO or device (refused before it is opened: a
            FIFO would block the read forever), an unreadable or a non-UTF-8 file.
    """
    path = Path(path)
    try:
        file, _ = open_regular(path)
        with file:
            data = file.read()
        return data.decode("utf-8")
    except FileNotFoundError:
        raise DataError(f"{path}: no such {what}") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # ValueError: a NUL in the path
        raise DataError(f"{path}: cannot read ({exc})") from None


def read_json(path: Path, what: str = "file"):
    """The JSON value `path` holds; `what` names it in the error.

    Raises:
        DataError: as `read_text`; not JSON, or nested too deep for the parser.
    """
    text = read_text(path, what)
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise DataError(f"{path}: not a {what}: not JSON ({type(exc).__name__}: {exc})"
                        ) from None


def data_lines(path: Path) -> tuple[list[int], list[str]]:
    """Line numbers (1-based) and texts (comments cut, stripped) of the lines of `path` that
    hold something besides a comment.

    Raises:
        DataError: as `read_text`.
    """
    lines, texts = [], []
    for k, line in enumerate(read_text(path).split("\n"), start=1):
        content = line.split("#", 1)[0].strip()
        if content:
            lines.append(k)
            texts.append(content)
    return lines, texts


def read_table(path: Path, columns: int, header: str | None = None,
               empty_ok: bool = False) -> TextTable:
    """The numeric rows of a text table of `columns` columns.

    Args:
        header: the columns' names ("timestamp tx ty tz qx qy qz qw"), quoted in errors.
        empty_ok: a table without rows is returned as (0, columns) rows instead of refused.
    Raises:
        DataError: missing or unreadable file; a row with the wrong number of columns, a
            non-number or a non-finite value (naming file and line); no rows, unless
            `empty_ok`.
    """
    lines, texts = data_lines(path)
    if not texts and not empty_ok:
        expected = f" (expected lines of '{header}')" if header else ""
        raise DataError(f"{path}: no rows{expected}")
    rows = None
    # one conversion for the whole file; only a bad file is checked row by row
    if all(len(t.split()) == columns for t in texts):
        try:
            rows = np.array(" ".join(texts).split(), dtype=float).reshape(len(texts), columns)
        except ValueError:
            rows = None
    if rows is None or not np.all(np.isfinite(rows)):
        for line, text in zip(lines, texts, strict=True):
            _check_row(path, line, text, columns, header)
        rows = np.array([[float(f) for f in t.split()] for t in texts]).reshape(-1, columns)
    return TextTable(rows, np.array(lines, dtype=np.int64), texts)


def _check_row(path: Path, line: int, text: str, columns: int, header: str | None) -> None:
    """Raise the DataError of one row of a numeric table, if it has one."""
    fields = text.split()
    if len(fields) != columns:
        named = f" ({header})" if header else ""
        raise DataError(f"{path}:{line}: expected {columns} columns{named}, got "
                        f"{len(fields)} ({text!r})")
    for f in fields:
        number(path, line, f, text)


def number(path: Path, line: int, field: str, text: str) -> float:
    """The finite number `field` of line `line` (text `text`) of `path`; DataError naming the
    file and line when it is not one."""
    try:
        value = float(field)
    except ValueError:
        raise DataError(f"{path}:{line}: not a number: {field!r} in {text!r}") from None
    if not math.isfinite(value):
        raise DataError(f"{path}:{line}: non-finite value {field!r} in {text!r}")
    return value
