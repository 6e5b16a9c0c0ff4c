"""A node's alignments as CSV, one row per step of a pair, written as they are made."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.inputs import output_path, write_whole

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


class AlignmentCsv:
    """Appends each AlignmentMessage (or, given `TEAM_COLUMNS`, each TeamMessage) to a CSV
    file (x, y in metres, theta in radians, P the upper triangle of the covariance), flushed
    per row so that a killed node keeps its rows."""

    def __init__(self, path: str | Path, columns: tuple[str, ...] = COLUMNS) -> None:
        """Raises:
            DataError: naming the file: a folder, in a missing folder, or not writable."""
        path = output_path("AlignmentCsv", path)
        try:
            fresh = not path.exists() or path.stat().st_size == 0
            self._file = open(path, "a", newline="")
        except OSError as exc:
            raise DataError(f"AlignmentCsv: cannot write {path} ({exc.strerror or exc})") from None
        self._rows = csv.writer(self._file)
        if fresh:
            self._rows.writerow(columns)

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


def read_alignments(path: str | Path, columns: tuple[str, ...] = COLUMNS
                    ) -> dict[str, np.ndarray]:
    """The columns of an alignments CSV as arrays (names as text, the rest numbers).

    Raises:
        DataError: the file is missing or its header is not `columns`.
    """
    try:
        with open(path, newline="") as file:
            rows = list(csv.reader(file))
    except OSError as exc:
        raise DataError(f"{path}: cannot read alignments ({exc.strerror})") from None
    if not rows or tuple(rows[0]) != columns:
        raise DataError(f"{path}: not an alignments CSV (header {rows[:1]})")
    table = np.array(rows[1:], dtype=object).reshape(-1, len(columns))
    out: dict[str, np.ndarray] = {}
    for c, name in enumerate(columns):
        column = table[:, c]
        out[name] = column.astype(str) if name in _TEXT else column.astype(float)
    return out


def write_counters(path: str | Path, counters: dict[str, float]) -> None:
    """The node's counters (and timings) as JSON, written aside (`<path>.partial`) and renamed
    over `path`: a process killed while writing (SIGKILL) leaves the previous file whole."""
    write_whole(Path(path), json.dumps(dict(sorted(counters.items())), indent=1) + "\n")


def row_covariance(rows: dict[str, np.ndarray], k: int) -> np.ndarray:
    """(3, 3) the covariance of row k of `read_alignments`' columns (x, y in m, theta in rad)."""
    P = np.zeros((3, 3))
    P[_UPPER] = [rows[c][k] for c in _COVARIANCE]
    return P + np.triu(P, 1).T
