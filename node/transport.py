"""How a node's messages travel: the part of a `RobotNode` that differs between a team over the
project's Zenoh session (`ZenohTransport`) and one over ROS 2's default middleware
(`node.dds.DdsTransport`). The aligning is the node's, the same over both.

A transport is opened by the node with itself (`open(node)`) and hands it each message that
arrives as `node.arrived(kind, source, read, perf_counter_time)`: `kind` "map" or "alignment",
`source` a name of the sender and kind (a map newer than another of the same source waiting
makes the node skip the older), `read()` the decoded, checked message or a `MessageError`
(called on the node's worker thread, so decoding never holds up the network's thread). With
`NodeParams.ros2_objects` it hands maps from the robot's ROS 2 objects topic to
`node.ros2_map(t, object_map)` and refusals to `node.drop(reason, detail)`.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Protocol

from .link import Link, alignment_key, alive_key, map_key, team_key, team_keys
from .messages import AlignmentMessage, MapMessage, MessageError, TeamMessage, decode, encode

if TYPE_CHECKING:
    from tcaff_gtsam.object_map import ObjectMap

    from .node import NodeParams, RobotNode

__all__ = ["Transport", "ZenohTransport", "ros2_output"]

log = logging.getLogger(__name__)


class Transport(Protocol):
    """What a node needs of the network (see the module docstring)."""

    def configure(self, robot: str, params: NodeParams) -> NodeParams:
        """The node's parameters as this transport runs them (before anything is opened)."""

    def open(self, node: RobotNode) -> None:
        """Declare the node's publishers and subscribers and start delivering to it."""

    def put_map(self, message: MapMessage, recent: ObjectMap) -> None:
        """Send the robot's map (`recent`: its objects, on the robot's clock)."""

    def put_alignment(self, message: AlignmentMessage) -> None:
        """Send one step of a pair's alignment."""

    def put_team(self, message: TeamMessage) -> None:
        """Send one step of a pair's team-consistent alignment."""

    def present(self, timeout: float) -> set[str]:
        """The robots of the team whose nodes this one can reach now."""

    def close(self) -> None:
        """Withdraw everything; again: nothing."""


def ros2_output(node: RobotNode, what: str, publish, *args) -> None:
    """Publish on the ROS 2 side, after the team's own message: a failure there (a time ROS
    cannot stamp, a closed session) is logged and counted (`ros2_errors`), never lost to the
    team; a success is counted as `ros2_sent`."""
    try:
        publish(*args)
        node.counters["ros2_sent"] += 1
    except Exception as exc:  # the team's own messages are out already
        node.counters["ros2_errors"] += 1
        log.warning("%s: ROS 2 %s not published: %s", node.robot, what, exc)


class ZenohTransport:
    """A team over the project's Zenoh session (`Link`): the keys of `node.link`, and with
    `NodeParams.ros2` the same session's ROS 2 topics laid out as rmw_zenoh does
    (`node.ros2.Ros2Bridge`)."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self._session = None
        self._bridge = None

    def configure(self, robot: str, params: NodeParams) -> NodeParams:
        self.link = self.link.for_robot(robot)
        return params

    def open(self, node: RobotNode) -> None:
        self._node = node
        team, robot = node.team, node.robot
        self._session = self.link.open(team, tuple(sorted(node.members | {robot})))
        try:
            self._map_pub = self._session.declare_publisher(map_key(team, robot))
            self._align_pubs: dict[str, object] = {}
            self._team_pubs: dict[str, object] = {}
            keys = team_keys(team)[:1 + node.params.team_consistency]
            self._subscribers = [self._session.declare_subscriber(key, self._arrived)
                                 for key in keys]
            self._alive = self._session.liveliness().declare_token(alive_key(team, robot))
            if node.params.ros2:
                from .ros2 import Ros2Bridge

                self._bridge = Ros2Bridge(
                    self._session, robot, node.params.domain_id,
                    node.ros2_map if node.params.ros2_objects else None, node.drop)
        except BaseException:  # nothing left open by a node that could not start
            session, self._session = self._session, None
            session.close()
            raise

    def _arrived(self, sample) -> None:
        """Zenoh's callback: hand the payload to the node (never block the network thread)."""
        key = str(sample.key_expr)
        if key.split("/")[2] == self._node.robot:
            return  # our own message, delivered back by the local session
        kind, what = ("map", MapMessage) if key.endswith("/map") else ("alignment",
                                                                      AlignmentMessage)
        payload = sample.payload.to_bytes()
        self._node.arrived(kind, key, lambda: _sent_on(key, payload, what))

    def put_map(self, message: MapMessage, recent: ObjectMap) -> None:
        self._map_pub.put(encode(message))
        if self._bridge is not None:
            ros2_output(self._node, "map", self._bridge.object_map, message.stamp, recent,
                        message.seq, message.boot)

    def put_alignment(self, message: AlignmentMessage) -> None:
        self._put(self._align_pubs, alignment_key, message)

    def put_team(self, message: TeamMessage) -> None:
        self._put(self._team_pubs, team_key, message)

    def _put(self, publishers: dict, key, message: AlignmentMessage | TeamMessage) -> None:
        name = message.neighbour
        if name not in publishers:
            publishers[name] = self._session.declare_publisher(
                key(self._node.team, self._node.robot, name))
        publishers[name].put(encode(message))
        if self._bridge is not None and message.accepted:
            ros2_output(self._node, "alignment", self._bridge.alignment, message)

    def present(self, timeout: float) -> set[str]:
        """The members whose nodes hold their liveliness token on a linked session."""
        replies = self._session.liveliness().get(alive_key(self._node.team, "*"),
                                                 timeout=timeout)
        return {str(r.ok.key_expr).split("/")[2] for r in replies if r.ok is not None}

    def close(self) -> None:
        """Withdraw the ROS 2 side and close the session; again: nothing.

        Zenoh's close gives up after some 10 s on a link it cannot flush (a peer frozen with
        the link's buffers full: 12.7 s on loopback) and raises: that is logged, and the
        node's stop goes on and writes its results. The ROS 2 side failing to close leaves the
        session closed all the same."""
        if self._session is None:
            return
        import zenoh

        session, self._session = self._session, None
        try:
            if self._bridge is not None:
                self._bridge.close()
        finally:
            try:
                session.close()
            except zenoh.ZError as exc:
                log.warning("%s: the Zenoh session did not close cleanly: %s",
                            self._node.robot, exc)


def _sent_on(key: str, payload: bytes, kind: type):
    """The message of `payload`, received on `key` (tcaff/<team>/<robot>/...): a `kind` sent by
    the robot of its key.

    Raises:
        MessageError: a payload that does not decode, of another kind, or from another robot.
    """
    what = "a map" if kind is MapMessage else "an alignment"
    message = decode(payload)
    if not isinstance(message, kind):
        raise MessageError("malformed", f"not {what} on {what}'s key")
    key_robot = key.split("/")[2]
    if message.sender != key_robot:
        raise MessageError("mismatch", f"sender {message.sender!r} on the key of "
                                       f"{key_robot!r}")
    return message
