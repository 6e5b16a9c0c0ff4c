"""How many threads a rendered frame's ray cast uses: set by a study's worker processes at start
without importing the renderer (and Open3D) that reads it."""

from __future__ import annotations

from tcaff_gtsam.errors import DataError

__all__ = ["cast_threads"]

#: threads each ray cast uses; 0: Open3D's choice, every core (see `cast_threads`)
per_cast = 0


def cast_threads(count: int) -> None:
    """Cast every later frame's rays on `count` threads (0: on every core, the default).

    A process that shares the machine with others busy on the other cores (a study's pool of
    workers) casts on its share: the threads of one cast otherwise wait on each other while
    the other processes hold the cores, which costs CPU time and no pixel changes (each ray is
    cast alone).
    """
    global per_cast
    if isinstance(count, bool) or not (isinstance(count, int) and count >= 0):
        raise DataError(f"cast_threads: count must be an int >= 0, got {count!r}")
    per_cast = count
