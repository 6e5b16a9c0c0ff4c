"""A live team: one process per robot, maps and alignments exchanged over Zenoh.

`RobotNode` publishes its robot's object map and aligns to every neighbour's with one
`PairwiseAligner` each; `messages` is the wire format; `link` the Zenoh endpoints (TCP or mutual
TLS); `replay` feeds a node one robot of a recorded or simulated run; `listener` watches a team.

The names below load their module on first use, so that the wire format and the endpoints
(numpy and zenoh only) do not pull in the aligner's numba and scipy.
"""

import importlib as _importlib

__all__ = ["AlignmentMessage", "Link", "MapMessage", "MessageError", "NodeParams", "RobotNode",
           "TeamListener", "TeamMessage", "TlsFiles", "decode", "encode"]

_LAZY = {"AlignmentMessage": "messages", "MapMessage": "messages", "MessageError": "messages",
         "TeamMessage": "messages", "decode": "messages", "encode": "messages", "Link": "link",
         "TlsFiles": "link",
         "NodeParams": "node", "RobotNode": "node", "TeamListener": "listener"}


def __getattr__(name: str) -> object:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
