"""A node's alignments as CSV, one row per step of a pair, written as they are made."""

from __future__ import annotations

import csv
import io
import json
import logging
import os
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import NotRegularFile, open_regular, output_path, shown, write_whole

from .messages import AlignmentMessage, TeamMessage

__all__ = ["COLUMNS", "TEAM_COLUMNS", "AlignmentCsv", "read_alignments", "row_covariance",
           "write_counters"]

_ESTIMATE = ("accepted", "x", "y", "theta", "P_xx", "P_xy", "P_xt", "P_yy", "P_yt", "P_tt")
COLUMNS = ("robot", "neighbour", "seq", "stamp", "neighbour_seq", "neighbour_stamp", "step",
           "hypothesis", *_ESTIMATE)
#: a team alignment's row: `via` names the robots it is chained through, joined by "+"
TEAM_COLUMNS = ("robot", "neighbour", "seq", "stamp", "via", *_ESTIMATE)
_TEXT = ("robot", "neighbour", "via")
_UPPER = np.triu_indices(3)
_COVARIANCE = _ESTIMATE[4:]  # the upper triangle's columns, row by row
log = logging.getLogger(__name__)


class AlignmentCsv:
    """Appends each AlignmentMessage (or, given `TEAM_COLUMNS`, each TeamMessage) to a CSV
    file (x, y in metres, theta in radians, P the upper triangle of the covariance), flushed
    per row so that a killed node keeps its rows. A row a killed writer left cut short at the
    end of the file is taken off first (logged), so that a restarted node's rows do not run
    on from it; a file of something else is not appended to."""

    def __init__(self, path: str | Path, columns: tuple[str, ...] = COLUMNS) -> None:
        """Raises:
            DataError: naming the file: a folder, in a missing folder, not writable, or one
                that holds something other than these columns' rows (it is left as it is)."""
        path = output_path("AlignmentCsv", path)
        try:
            fresh = not path.exists() or path.stat().st_size == 0
            if not fresh:
                fresh = _ready_to_append(path, columns)
            self._file = open(path, "a", newline="")
        except OSError as exc:
            raise DataError(f"AlignmentCsv: cannot write {path} ({exc.strerror or exc})") from None
        self._rows = csv.writer(self._file)
        if fresh:  # on disk at once: a node killed before its first row leaves a CSV of none
            self._rows.writerow(columns)
            self._file.flush()

    def write(self, m: AlignmentMessage | TeamMessage) -> None:
        if isinstance(m, TeamMessage):
            head = [m.sender, m.neighbour, m.seq, repr(m.stamp), "+".join(m.via)]
        else:
            head = [m.sender, m.neighbour, m.seq, repr(m.stamp), m.neighbour_seq,
                    repr(m.neighbour_stamp), m.step, m.hypothesis]
        self._rows.writerow([*head, int(m.accepted), *map(repr, m.x.tolist()),
                             *map(repr, m.P[_UPPER].tolist())])
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def _whole(file, size: int) -> int:
    """How many of the `size` bytes of a CSV `AlignmentCsv` wrote (`file` open to read them)
    hold whole rows: up to its last line end, or all of them when they end in a row's carriage
    return (cut before its line feed). What follows is a row its writer had not finished."""
    at = size
    while at > 0:  # back from the end a block at a time: rows are short, files long
        start = max(at - 4096, 0)
        file.seek(start)
        block = file.read(at - start)
        if at == size and block.endswith(b"\r"):
            return size
        found = block.rfind(b"\n")
        if found >= 0:
            return start + found + 1
        at = start
    return 0


def _ready_to_append(path: Path, columns: tuple[str, ...]) -> bool:
    """Make the non-empty file `path` end with a whole row of `columns` (its writer killed
    mid-row left one cut short: taken off, logged; one cut before its line feed is ended),
    so that the rows appended next do not run on from it. Returns whether it is empty now.

    Raises:
        DataError: the file does not begin with the header of `columns` (left as it is).
    """
    header = ",".join(columns).encode()
    try:
        file, info = open_regular(path)
    except NotRegularFile as exc:
        raise DataError(f"AlignmentCsv: {path}: {exc}") from None
    with file:
        head = file.read(len(header) + 2)
        # the header with its line end as the writer writes it or as a tool that turned it
        # into "\n" left it, or cut short
        if not (head.startswith(header + b"\n") or (header + b"\r\n").startswith(head)):
            raise DataError(f"AlignmentCsv: {path} holds something other than alignments "
                            f"(it begins {shown(head[:80])}); not appended to")
        whole = _whole(file, info.st_size)
        if whole == info.st_size:
            file.seek(whole - 1)
            ended = file.read(1) == b"\n"  # else its last row's "\r" is there, not its "\n"
    if whole < info.st_size:
        log.warning("%s: its last line was a row cut short (its writer stopped mid-row); "
                    "taken off before appending", path)
        os.truncate(path, whole)
    elif not ended:
        with open(path, "ab") as file:
            file.write(b"\n")
    return whole == 0


def read_alignments(path: str | Path, columns: tuple[str, ...] = COLUMNS
                    ) -> dict[str, np.ndarray]:
    """The columns of an alignments CSV as arrays (names as text, the rest numbers).

    A last line without its line end is a row its writer had not finished (a node killed
    mid-write: `AlignmentCsv` appends and flushes row by row); it is left out, with a
    warning, and the rows before it are read.

    Raises:
        DataError: naming the file: missing, or not a regular file (a FIFO would block the
            read), or its header not `columns`; and the line: bytes that are not UTF-8, a
            row of another number of fields (a blank line), a number column that holds no
            number, a field past csv's limit (128 KiB).
    """
    raw = _read_regular(path)
    end = _whole(io.BytesIO(raw), len(raw))
    if end < len(raw):
        log.warning("%s: its last line is a row cut short (its writer stopped mid-row); "
                    "left out", path)
    try:
        text = raw[:end].decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataError(f"{path}: line {line} is not UTF-8 text, not an alignments CSV"
                        ) from None
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, [])
    if tuple(header) != columns:
        raise DataError(f"{path}: not an alignments CSV (header {shown(header, 200)})")
    numbers = [c for c, name in enumerate(columns) if name not in _TEXT]
    rows = []
    try:
        for row in reader:
            line = reader.line_num
            if len(row) != len(columns):
                raise DataError(f"{path}: line {line} has {len(row)} fields, the header "
                                f"{len(columns)}")
            for c in numbers:
                try:
                    row[c] = float(row[c])
                except ValueError:
                    raise DataError(f"{path}: line {line}: {columns[c]} = {shown(row[c])} is "
                                    f"not a number") from None
            rows.append(row)
    except csv.Error as exc:  # a field past the limit
        raise DataError(f"{path}: line {reader.line_num}: {exc}") from None
    return {name: np.array([row[c] for row in rows], dtype=str if name in _TEXT else float)
            for c, name in enumerate(columns)}


def _read_regular(path: str | Path) -> bytes:
    """The bytes of `path`, refused (DataError) unless it is a regular file
    (`inputs.open_regular`: a FIFO would make a reader wait for a writer forever)."""
    try:
        file, _ = open_regular(path)
        with file:
            return file.read()
    except NotRegularFile as exc:
        raise DataError(f"{path}: {exc}, not an alignments CSV") from None
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read alignments ({exc.strerror or exc})") from None


def write_counters(path: str | Path, counters: dict[str, float]) -> None:
    """The node's counters (and timings) as JSON, written aside (`<path>.partial`) and renamed
    over `path`: a process killed while writing (SIGKILL) leaves the previous file whole."""
    write_whole(Path(path), json.dumps(dict(sorted(counters.items())), indent=1) + "\n")


def row_covariance(rows: dict[str, np.ndarray], k: int) -> np.ndarray:
    """(3, 3) the covariance of row k of `read_alignments`' columns (x, y in m, theta in rad)."""
    P = np.zeros((3, 3))
    P[_UPPER] = [rows[c][k] for c in _COVARIANCE]
    return P + np.triu(P, 1).T
