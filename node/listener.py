"""TeamListener: every pair's latest alignment in a team, as a rich table."""

from __future__ import annotations

import math
import threading
import time
from collections import Counter
from collections.abc import Callable

import numpy as np

from tcaff_gtsam.geometry import se2_to_params, wrap_angle

from .link import Link, check_name, team_keys
from .messages import AlignmentMessage, MessageError, decode

__all__ = ["TeamListener"]


class TeamListener:
    """Subscribes to a team's alignments and keeps the latest of each directed pair.

    Args:
        truth: for runs with truth, T_true(i, j) -> (S, 3, 3) true T_oi_oj per exchange, robots
            named r<i>; the table then shows each alignment's error at its ego exchange.
    Attributes:
        latest: (robot, neighbour) -> the latest AlignmentMessage; counts: messages per pair;
        dropped: Counter of bad payloads by reason.
    """

    def __init__(self, team: str, link: Link,
                 truth: Callable[[int, int], np.ndarray] | None = None) -> None:
        self.team = check_name("--team", team)
        self.latest: dict[tuple[str, str], AlignmentMessage] = {}
        self.counts: Counter[tuple[str, str]] = Counter()
        self.dropped: Counter[str] = Counter()
        self._truth = truth
        self._lock = threading.Lock()
        self._started = time.monotonic()
        self._session = link.open()
        self._subscriber = self._session.declare_subscriber(team_keys(team)[1], self._arrived)

    def _arrived(self, sample) -> None:
        try:
            message = decode(sample.payload.to_bytes())
            if not isinstance(message, AlignmentMessage):
                raise MessageError("malformed", "a map on an alignment key")
        except MessageError as exc:
            self.dropped[exc.reason] += 1
            return
        pair = (message.sender, message.neighbour)
        with self._lock:
            self.latest[pair] = message
            self.counts[pair] += 1

    def elapsed(self) -> float:
        return time.monotonic() - self._started

    def error(self, m: AlignmentMessage) -> tuple[float, float] | None:
        """(m, deg) error of an accepted alignment against the truth, None without truth."""
        if self._truth is None or not m.accepted:
            return None
        try:
            i, j = int(m.sender[1:]), int(m.neighbour[1:])
            true = se2_to_params(self._truth(i, j)[m.seq])
        except (ValueError, IndexError):
            return None
        return (float(np.linalg.norm(m.x[:2] - true[:2])),
                math.degrees(abs(float(wrap_angle(m.x[2] - true[2])))))

    def table(self):
        """A rich Table of every pair seen so far."""
        from rich.table import Table

        table = Table(title=f"team {self.team}: latest alignment of each pair "
                            f"({self.elapsed():.0f} s)")
        for column in ("pair", "msgs", "exchange", "step", "hyp", "x [m]", "y [m]",
                       "theta [deg]", "sd [m, deg]", *(("error [m, deg]",) if self._truth
                                                      else ())):
            table.add_column(column, justify="left" if column == "pair" else "right")
        with self._lock:
            items = sorted(self.latest.items())
            counts = dict(self.counts)
        for (robot, neighbour), m in items:
            if m.accepted:
                sd = np.sqrt(np.clip(np.diag(m.P), 0, None))
                numbers = [f"{m.x[0]:.2f}", f"{m.x[1]:.2f}", f"{math.degrees(m.x[2]):.1f}",
                           f"{max(sd[0], sd[1]):.2f}, {math.degrees(sd[2]):.1f}"]
            else:
                numbers = ["-"] * 4
            row = [f"{robot}->{neighbour}", str(counts[(robot, neighbour)]), str(m.seq),
                   str(m.step), str(m.hypothesis) if m.accepted else "-", *numbers]
            if self._truth is not None:
                err = self.error(m)
                row.append("-" if err is None else f"{err[0]:.2f}, {err[1]:.1f}")
            table.add_row(*row)
        notes = [] if items else [f"no alignment of team {self.team!r} heard yet"]
        if self.dropped:
            notes.append("dropped: " + ", ".join(f"{k} {v}" for k, v in self.dropped.items()))
        table.caption = "; ".join(notes) or None
        return table

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> TeamListener:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
