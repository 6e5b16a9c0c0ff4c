"""A team over ROS 2's default middleware: a `RobotNode` transport on rclpy, with whatever RMW
the environment selects (rmw_fastrtps_cpp from the wheels of the `ros2` extra), so that a node
is an ordinary ROS 2 node `/<robot>/tcaff` and a team needs nothing but ROS 2.

Topics (layouts in `node.ros2`; every message CDR-serialised by rosbags and published raw):

    /<robot>/tcaff/map                      MarkerArray, the robot's map; its neighbours align
                                            to it (the DELETEALL marker carries seq and boot)
                                            QoS: reliable, volatile, keep last 10
    /<robot>/tcaff/alignment/<neighbour>    PoseWithCovarianceStamped, each accepted alignment
    /<robot>/tcaff/team_alignment/<other>   the same, each accepted team alignment
                                            QoS: reliable, transient local, keep last 1 (a
                                            late subscriber gets the latest)
    /diagnostics                            DiagnosticArray, the node's health once per
                                            `health_period` s (pairs, latency, skipped maps)
subscribed: every member's map, with team consistency every other robot's alignments, and with
`NodeParams.ros2_objects` /<robot>/tcaff/objects (MarkerArray) and /<robot>/tcaff/object_cloud
(PointCloud2), reliable, keep last 10.

The node's settings are also ROS parameters of `/<robot>/tcaff` (read-only; `ros2 param get`),
and a parameters file (`--params-file`, ROS's YAML) overrides them: kappa, silence, queue,
team_consistency and health_period.

Every rclpy process of this project's tests and benchmarks runs inside a network namespace
holding only loopback (see docs/ros2.md): DDS discovery is multicast and reaches any interface
it is given.
"""

from __future__ import annotations

import logging
import os
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError, reason
from tcaff_gtsam.params import _finite, _int_at_least, _require

from .ros2 import (
    ALIGNMENT_TYPE,
    CLOUD_TYPE,
    HEALTH_TYPE,
    MAP_TYPE,
    alignment_of,
    alignment_topic,
    check_ros_name,
    cloud_message,
    cloud_topic,
    exchange_of,
    health_message,
    map_message,
    map_topic,
    object_map_of,
    object_map_of_cloud,
    objects_topic,
    pose_message,
    read_message,
    serialize,
    team_topic,
)
from .transport import ros2_output

if TYPE_CHECKING:
    from tcaff_gtsam.object_map import ObjectMap

    from .messages import AlignmentMessage, MapMessage, TeamMessage
    from .node import NodeParams, RobotNode

__all__ = ["HEALTH_TOPIC", "DdsTransport", "isolated", "namespace_problem", "ros2_available"]

log = logging.getLogger(__name__)

HEALTH_TOPIC = "/diagnostics"
#: the node's settings that are ROS parameters too
_PARAMETERS = ("kappa", "silence", "queue", "team_consistency")


def ros2_available() -> str | None:
    """None when rclpy and the message packages import; else why not (for messages)."""
    try:
        import diagnostic_msgs.msg  # noqa: F401
        import geometry_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import visualization_msgs.msg  # noqa: F401
    except ImportError as exc:
        return f"{exc} (pip install 'tcaff-gtsam[ros2]')"
    return None


def namespace_problem() -> str | None:
    """None when this process can make a network namespace holding only loopback (`unshare
    -n`, as root); else why not."""
    try:
        done = subprocess.run(isolated(["true"], 0)[0], capture_output=True, text=True,
                              timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"cannot run unshare: {exc}"
    if done.returncode != 0:
        return f"cannot make a network namespace: {done.stderr.strip() or done.returncode}"
    return None


def isolated(argv: list[str], domain_id: int) -> tuple[list[str], dict[str, str]]:
    """(command line, environment) running `argv` as ROS 2 processes on this machine alone:
    in a new network namespace holding only the loopback interface (`unshare -n`, then `ip
    link set lo up`), with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and ROS_DOMAIN_ID
    `domain_id`. Processes that `argv` starts share the namespace and see each other; no DDS
    packet leaves it."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain_id))
    return ["unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$@"', "sh", *argv], env


def _message_classes() -> dict[str, type]:
    """rclpy's classes of the message types (their type support is what rclpy needs)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    return {MAP_TYPE: MarkerArray, ALIGNMENT_TYPE: PoseWithCovarianceStamped,
            CLOUD_TYPE: PointCloud2, HEALTH_TYPE: DiagnosticArray}


def _warm_codecs() -> None:
    """Serialise and read one message of each type the node sends or reads: rosbags makes
    each type's code on first use (0.2 s on an idle core), which would otherwise fall on the
    run's first maps and put the node behind its neighbours'."""
    from tcaff_gtsam.object_map import ObjectMap

    one = ObjectMap(np.zeros((1, 3)), np.ones(1), np.ones(1), np.zeros(1))
    for message, msgtype in ((map_message(1.0, "warm", one, seq=0, boot=0), MAP_TYPE),
                             (pose_message(1.0, "warm", np.zeros(3), np.eye(3)),
                              ALIGNMENT_TYPE),
                             (cloud_message(1.0, "warm", one), CLOUD_TYPE),
                             (health_message(1.0, "warm", 0, "", {"k": "v"}), HEALTH_TYPE)):
        read_message(serialize(message, msgtype), msgtype)


#: Fast DDS's default participant profile for a node: its first discovery announcements 30
#: times 0.1 s apart instead of 5. With Fast DDS's own, 2 of 6 and 4 of 10 starts of a node
#: beside a watcher missed the first announcements and found each other only at the periodic
#: one 3 s later (spawn to first message 3.8-4.0 s instead of 1.2-1.9 s)
FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")


def _announce_often() -> None:
    """Point Fast DDS at `FASTDDS_PROFILE` before rclpy starts it, unless the middleware is
    another or the user gave Fast DDS profiles of their own."""
    if os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return
    if any(v in os.environ for v in ("FASTDDS_DEFAULT_PROFILES_FILE",
                                     "FASTRTPS_DEFAULT_PROFILES_FILE")):
        return
    os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)


def _qos(latched: bool):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1 if latched else 10,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                  else DurabilityPolicy.VOLATILE))


class DdsTransport:
    """A node's team over rclpy (see the module docstring).

    Args:
        params_file: a ROS 2 parameters YAML whose values for `/<robot>/tcaff` override the
            node's settings; None: the settings as given.
        health_period: s between two health messages (overridden by the parameter of that
            name).
    Raises (from `RobotNode`):
        ConfigError: rclpy or the message packages are not installed, a parameters file that
            does not exist or whose values are refused, a bad health_period.
    """

    def __init__(self, params_file: str | Path | None = None, health_period: float = 1.0
                 ) -> None:
        _require(_finite(health_period) and health_period > 0, "DdsTransport",
                 "health_period", health_period, "must be a number > 0 (s)")
        if params_file is not None and not Path(params_file).is_file():
            raise ConfigError(f"--params-file {str(params_file)!r}: no such file")
        self.params_file = params_file
        self.health_period = float(health_period)
        self._context = None
        self._lock = threading.Lock()  # rclpy entities are made on two threads
        self._publishers: dict[str, object] = {}
        self._maps: dict[str, object] = {}  # member -> the subscription of its map
        self._reported: dict[str, int] = {}

    # -- set-up -------------------------------------------------------------------------------

    def start(self, robot: str, domain_id: int = 0) -> None:
        """Start the ROS node `/<robot>/tcaff` in `domain_id` and its map publisher, before
        the rest of the node is made (`RobotNode` does it if nothing did): DDS discovery runs
        on Fast DDS's own threads, so a process that starts this first finds its team and
        its subscribers while it loads the aligner. Again with the same robot and domain:
        nothing.

        Raises:
            ConfigError: rclpy or the message packages not installed, a robot name that is
                not a ROS 2 name token, a domain not in 0..232, or started already as
                another robot or in another domain.
        """
        if self._context is not None:
            if (robot, domain_id) != (self.robot, self.domain_id):
                raise ConfigError(f"--robot {robot!r}, --domain-id {domain_id!r}: the ROS "
                                  f"node was started as {self.robot!r} in domain "
                                  f"{self.domain_id}")
            return
        why = ros2_available()
        if why is not None:
            raise ConfigError(f"--ros2 dds needs ROS 2's Python packages: {why}")
        _require(_int_at_least(domain_id, 0) and domain_id <= 232, "DdsTransport.start",
                 "domain_id", domain_id, "must be an int in 0..232")
        _announce_often()
        import rclpy
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions

        self.robot = check_ros_name("--robot", robot)
        self.domain_id = domain_id
        self._classes = _message_classes()
        context = rclpy.Context()
        args = [] if self.params_file is None else ["--ros-args", "--params-file",
                                                    str(self.params_file)]
        # the node's process handles SIGINT / SIGTERM itself (and closes the node)
        try:
            rclpy.init(args=args, context=context, domain_id=domain_id,
                       signal_handler_options=SignalHandlerOptions.NO)
        except _rclpy.RCLError as exc:  # a params file rcl cannot parse, say
            raise ConfigError(f"--params-file {str(self.params_file)!r}: ROS 2 refused to start "
                              f"with it ({reason(exc)})") from None
        self._context = context
        try:
            self._ros = Node("tcaff", namespace=f"/{robot}", context=context)
            self._publisher(map_topic(robot), MAP_TYPE, False)  # discovered from the start
            _warm_codecs()
        except BaseException:
            self.close()
            raise

    def configure(self, robot: str, params: NodeParams) -> NodeParams:
        """Start the ROS node (`start`, unless started) and declare the node's settings as
        its parameters; returns them as the parameters file leaves them (with `ros2` on:
        robot names are ROS 2 name tokens)."""
        self.start(robot, params.domain_id)
        from rcl_interfaces.msg import ParameterDescriptor
        from rclpy.executors import SingleThreadedExecutor

        try:
            read_only = ParameterDescriptor(read_only=True)
            values = {}
            for name in (*_PARAMETERS, "health_period"):
                default = self.health_period if name == "health_period" else getattr(params,
                                                                                      name)
                values[name] = self._ros.declare_parameter(name, default, read_only).value
            self.health_period = values.pop("health_period")
            params = replace(params, ros2=True, **values)
            _require(_finite(self.health_period) and self.health_period > 0, "--params-file",
                     "health_period", self.health_period, "must be a number > 0 (s)")
        except BaseException as exc:
            self.close()
            if isinstance(exc, (ConfigError, DataError)) or not isinstance(exc, Exception):
                raise
            raise ConfigError(f"--params-file {str(self.params_file)!r}: {exc}") from None
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._ros)
        return params

    def open(self, node: RobotNode) -> None:
        self._node = node
        params = node.params
        for member in sorted(node.members):
            self._maps[member] = self._subscribe(map_topic(member), MAP_TYPE, False,
                                                 self._arrived_map(member))
            if params.team_consistency:
                for other in sorted(node.members | {node.robot}):
                    if other != member:
                        self._subscribe(alignment_topic(member, other), ALIGNMENT_TYPE, True,
                                        self._arrived_alignment(member, other))
        if params.ros2_objects:
            self._subscribe(objects_topic(node.robot), MAP_TYPE, False,
                            self._objects(object_map_of))
            self._subscribe(cloud_topic(node.robot), CLOUD_TYPE, False,
                            self._objects(object_map_of_cloud))
        self._health = self._publisher(HEALTH_TOPIC, HEALTH_TYPE, False)
        self._ros.create_timer(self.health_period, self._report)
        from rclpy.task import Future

        # done by `close`: the executor's wait wakes for it, whatever the spin thread is doing
        self._closing = Future()
        self._spinner = threading.Thread(target=self._spin, name=f"tcaff-dds-{node.robot}",
                                         daemon=True)
        self._spinner.start()

    def _spin(self) -> None:
        """Run the callbacks until `close` (or the context is shut down)."""
        from rclpy.executors import ExternalShutdownException

        try:
            self._executor.spin_until_future_complete(self._closing)
        except ExternalShutdownException:  # the context was shut down: the node is closing
            pass

    def _subscribe(self, topic: str, msgtype: str, latched: bool, callback):
        return self._ros.create_subscription(self._classes[msgtype], topic, callback, _qos(latched),
                                      raw=True)

    def _publisher(self, topic: str, msgtype: str, latched: bool):
        with self._lock:
            if topic not in self._publishers:
                self._publishers[topic] = self._ros.create_publisher(
                    self._classes[msgtype], topic, _qos(latched))
            return self._publishers[topic]

    # -- what arrives (on the executor's thread) ----------------------------------------------

    def _arrived_map(self, member: str):
        topic = map_topic(member)

        def arrived(data: bytes) -> None:
            self._node.arrived("map", topic,
                               lambda: exchange_of(read_message(data, MAP_TYPE), member))
        return arrived

    def _arrived_alignment(self, sender: str, neighbour: str):
        topic = alignment_topic(sender, neighbour)

        def arrived(data: bytes) -> None:
            self._node.arrived("alignment", topic, lambda: alignment_of(
                read_message(data, ALIGNMENT_TYPE), sender, neighbour))
        return arrived

    def _objects(self, read):
        """A callback taking the robot's map from its objects topic with `read`."""
        msgtype = CLOUD_TYPE if read is object_map_of_cloud else MAP_TYPE
        topic = (cloud_topic if msgtype == CLOUD_TYPE else objects_topic)(self.robot)

        def arrived(data: bytes) -> None:
            try:
                t, object_map = read(read_message(data, msgtype))
                self._node.ros2_map(t, object_map)
            except Exception as exc:  # nothing may escape into rclpy's executor
                self._node.drop("malformed", f"on {topic}: {exc}")
        return arrived

    # -- what goes out ------------------------------------------------------------------------

    def put_map(self, message: MapMessage, recent: ObjectMap) -> None:
        """Publish the map; a time or counter ROS 2 cannot carry is a DataError, before
        anything is sent."""
        data = serialize(map_message(message.stamp, f"{self.robot}/odom", recent,
                                     seq=message.seq, boot=message.boot), MAP_TYPE)
        self._publisher(map_topic(self.robot), MAP_TYPE, False).publish(data)

    def put_alignment(self, message: AlignmentMessage) -> None:
        self._put(alignment_topic, message)

    def put_team(self, message: TeamMessage) -> None:
        self._put(team_topic, message)

    def _put(self, topic, message: AlignmentMessage | TeamMessage) -> None:
        """Publish an accepted alignment; one ROS 2 cannot stamp is counted in
        `ros2_errors` and logged, the node goes on."""
        if not message.accepted:
            return

        def publish() -> None:
            data = serialize(pose_message(message.stamp, f"{self.robot}/odom", message.x,
                                          message.P), ALIGNMENT_TYPE)
            self._publisher(topic(self.robot, message.neighbour), ALIGNMENT_TYPE,
                            True).publish(data)

        ros2_output(self._node, f"alignment to {message.neighbour}", publish)

    def _report(self) -> None:
        """The node's health on /diagnostics: WARN when maps were dropped, skipped or lost,
        or steps failed, since the last report; OK otherwise."""
        node = self._node
        counters = dict(node.counters)
        latest = dict(node.latest)
        latency = np.array(node.latencies)
        pairs = {name: ("accepted" if m.accepted else "none") + f" at step {m.step}"
                 for name, m in sorted(latest.items())}
        accepted = sum(m.accepted for m in latest.values())
        troubles = {k: v for k, v in counters.items()
                    if (k.startswith("dropped_") or k in ("skipped", "lost", "errors",
                                                          "ros2_errors"))
                    and v > self._reported.get(k, 0)}
        self._reported = counters
        values = {"pairs_accepted": f"{accepted}/{len(node.members)}",
                  **{f"pair {name}": text for name, text in pairs.items()},
                  "latency_median_ms": f"{1e3 * np.median(latency):.1f}" if latency.size
                  else "-",
                  "latency_p95_ms": f"{1e3 * np.percentile(latency, 95):.1f}" if latency.size
                  else "-",
                  **{k: str(counters.get(k, 0)) for k in ("maps_sent", "maps_received",
                                                          "aligned", "skipped", "lost")},
                  "dropped": str(sum(v for k, v in counters.items()
                                     if k.startswith("dropped_")))}
        summary = f"{accepted} of {len(node.members)} pairs aligned" + (
            "; since the last report: " + ", ".join(f"{k} {v}" for k, v in troubles.items())
            if troubles else "")
        try:
            self._health.publish(serialize(health_message(time.time(), self.robot,
                                                          1 if troubles else 0, summary,
                                                          values), HEALTH_TYPE))
        except Exception as exc:  # a closing context: the next report would say the same
            log.debug("%s: health not published: %s", self.robot, exc)

    # -- the graph ----------------------------------------------------------------------------

    def present(self, timeout: float) -> set[str]:
        """The members linked both ways: this node's subscription of the member's map is
        matched with its publisher, and the member's node subscribes to this node's map, with
        this node's map publisher matched with as many subscriptions; waits up to `timeout` s
        for all of them."""
        own = self._publishers[map_topic(self.robot)]
        deadline = time.monotonic() + timeout
        while True:
            # the ROS graph names the nodes subscribing; the publisher's matched count says
            # that DDS has matched them (the graph alone can list a node before that)
            hearing = {info.node_namespace.strip("/") for info in
                       self._ros.get_subscriptions_info_by_topic(map_topic(self.robot))}
            up = {m for m in self._node.members
                  if m in hearing and self._maps[m].get_publisher_count() > 0}
            if own.get_subscription_count() < len(up):
                up = set()
            if up == self._node.members or time.monotonic() >= deadline:
                return up
            time.sleep(0.05)

    def close(self) -> None:
        """Stop the spin thread, then destroy the ROS node and the context (and with it the
        DDS participant); again: nothing.

        The spin thread ends first, with the executor whole: rclpy's `Executor.shutdown`
        destroys the executor's wake-up at once, without waiting for the thread, whose next
        wait could then end only when the health timer fired (past the join's bound with a
        `health_period` over 5 s)."""
        if self._context is None:
            return
        context, self._context = self._context, None
        try:
            if hasattr(self, "_spinner"):
                self._closing.set_result(None)
                self._spinner.join(timeout=5)
            if hasattr(self, "_executor"):
                self._executor.shutdown(timeout_sec=5)
            if hasattr(self, "_ros"):
                self._ros.destroy_node()
        finally:
            context.try_shutdown()
            context.destroy()
        # a later `start` makes everything anew, none of it on the closed context
        self._publishers.clear()
        self._maps.clear()
        self._reported.clear()
        for name in ("_executor", "_ros", "_spinner", "_closing"):
            self.__dict__.pop(name, None)
