"""Processes that leave Ctrl-C to the process that started them (a study's pool workers, its
queue's manager, a local Dask cluster's workers).

A module of its own that imports only the standard library: a spawned process imports the
module defining its class before it runs anything, so the manager, which runs no job, starts
in a fraction of a second instead of importing the whole stack with the executor.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from multiprocessing.context import SpawnContext, SpawnProcess

__all__ = ["QuietSpawnContext", "sigint"]


@contextmanager
def sigint(deferred: bool) -> Iterator[None]:
    """Ctrl-C in this process during the block: ignored (`deferred` False), or held back and
    raised once the block is done (True). Only the main thread can do either.

    Ignored, for the moment this process starts a process (a few ms): an ignored SIGINT stays
    ignored in the new process, which then never raises KeyboardInterrupt, not even while it
    starts (imports the stack, before the executor's `_announce`). Deferred, while the manager
    starts: cut short, its process, left without a reader, prints a traceback."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, (lambda signum, frame: caught.append(signum)) if deferred
                      else signal.SIG_IGN)
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class QuietSpawnProcess(SpawnProcess):
    """A spawned process that ignores Ctrl-C from its very start (see `sigint`)."""

    @staticmethod
    def _Popen(process_obj):
        with sigint(deferred=False):
            return SpawnProcess._Popen(process_obj)


class QuietSpawnContext(SpawnContext):
    """The spawn context, its processes (the pool's workers, the manager) ignoring Ctrl-C: the
    study's process handles it and ends them."""

    Process = QuietSpawnProcess
