"""How many threads a rendered frame's ray cast uses: set by a study's worker processes at start
without importing the renderer (and Open3D) that reads it."""

from __future__ import annotations

from .sizes import count as _count

__all__ = ["MAX_THREADS", "cast_threads"]

#: the most threads a ray cast may be told to use, far more than a machine's cores
MAX_THREADS = 1024

#: threads each ray cast uses; 0: Open3D's choice, every core (see `cast_threads`)
per_cast = 0


def cast_threads(count: int) -> None:
    """Cast every later frame's rays on `count` threads (0: on every core, the default).

    A process that shares the machine with others busy on the other cores (a study's pool of
    workers) casts on its share: the threads of one cast otherwise wait on each other while
    the other processes hold the cores, which costs CPU time and no pixel changes (each ray is
    cast alone).

    Raises:
        DataError: count not an int in [0, MAX_THREADS].
    """
    global per_cast
    per_cast = _count("cast_threads", "count", count, MAX_THREADS, "MAX_THREADS")
