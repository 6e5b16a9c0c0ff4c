"""A live team: one process per robot, maps and alignments exchanged over Zenoh.

`RobotNode` publishes its robot's object map and aligns to every neighbour's with one
`PairwiseAligner` each; `messages` is the wire format; `link` the Zenoh endpoints (TCP or mutual
TLS); `replay` feeds a node one robot of a recorded or simulated run.
"""

from .link import Link, TlsFiles
from .messages import AlignmentMessage, MapMessage, MessageError, decode, encode
from .node import NodeParams, RobotNode

__all__ = ["AlignmentMessage", "Link", "MapMessage", "MessageError", "NodeParams", "RobotNode",
           "TlsFiles", "decode", "encode"]
