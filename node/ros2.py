"""The team in ROS 2 terms, on the node's own Zenoh session, laid out as ROS 2's Zenoh middleware
(rmw_zenoh, Jazzy and later) lays out a ROS 2 graph; no ROS 2 installation is needed.

Topics a node with `NodeParams.ros2` publishes (robot names are ROS 2 name tokens there):
    /<robot>/tcaff/map                         visualization_msgs/msg/MarkerArray: the map it
                                               shares, one cylinder per object in <robot>/odom
    /<robot>/tcaff/alignment/<neighbour>       geometry_msgs/msg/PoseWithCovarianceStamped:
                                               each accepted alignment T_oi_oj
    /<robot>/tcaff/team_alignment/<other>      the same type: each accepted team-consistent
                                               alignment (chained through a third robot or not)
and, with `NodeParams.ros2_objects`, the node takes its robot's map from
    /<robot>/tcaff/objects                     visualization_msgs/msg/MarkerArray, as above
    /<robot>/tcaff/object_cloud                sensor_msgs/msg/PointCloud2, one point per
                                               object (`object_map_of_cloud`)
(the DDS node of `node.dds` publishes the same topics, and its health on /diagnostics).

An alignment's header.frame_id is `<robot>/odom`; its pose is the pose of `<neighbour>/odom` in
it (x, y, yaw; z = 0), the message type having no child frame. Its covariance is ROS's 6 x 6
(x, y, z, roll, pitch, yaw), row-major, holding the 3 x 3 one of (x, y, yaw) at rows and columns
0, 1 and 5, zero elsewhere (as ROS's 2-D localisation publishes a planar pose).

A map's markers carry each object's centroid (pose.position), width (scale.x = scale.y, m) and
height (scale.z, m), and in header.stamp the time the object was last seen; the array opens with
a DELETEALL marker stamped with the map's time, so that a viewer shows only the current map,
whose `id` is the sender's exchange counter (seq) and whose `text` its boot number (decimal):
robots that exchange maps over ROS 2 read a neighbour's map from it (`exchange_of`).

A PointCloud2 of objects holds one point per object with the float fields (FLOAT32 or FLOAT64
each, any offsets, either byte order) x, y, z (the centroid, m), width, height (m) and
last_seen (s, the clock of header.stamp; FLOAT64, as float32 holds epoch seconds to 2 min
only); header.stamp is the map's time.

On the wire (rmw_zenoh's design document): a message of topic T and type P/msg/N goes on the key
`<domain_id>/<T without its leading slash>/P::msg::dds_::N_/<RIHS01 type hash>` as CDR (rosbags'
serialiser, little-endian), with a 33-byte attachment: sequence number (int64), source time
(int64 ns since the epoch), 16 and the publisher's 16-byte GID. Each publisher and subscriber,
and the ROS node they belong to (`/<robot>/tcaff`), hold a liveliness token under `@ros2_lv`,
which is how `ros2 topic list` finds them.
"""

from __future__ import annotations

import logging
import os
import re
import struct
import time
from functools import cache

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.object_map import ObjectMap

from .messages import (
    MAX_OBJECTS,
    AlignmentMessage,
    MapMessage,
    MessageError,
    TeamMessage,
    check_usable,
)

__all__ = ["ALIGNMENT_TYPE", "CLOUD_FIELDS", "CLOUD_TYPE", "HEALTH_TYPE", "MAP_TYPE",
           "Ros2Bridge", "alignment_of", "alignment_topic", "attachment", "check_ros_name",
           "cloud_message", "cloud_topic", "decode_attachment", "entity_token", "exchange_of",
           "health_message", "map_message", "map_topic", "object_map_of", "object_map_of_cloud",
           "objects_topic", "pose_message", "read_message", "serialize", "team_topic",
           "topic_key", "type_hash"]

ALIGNMENT_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
MAP_TYPE = "visualization_msgs/msg/MarkerArray"
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
HEALTH_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
#: the fields of a PointCloud2 of objects, one point per object
CLOUD_FIELDS = ("x", "y", "z", "width", "height", "last_seen")
_FLOAT32, _FLOAT64 = 7, 8  # sensor_msgs/PointField datatypes
_INT32_MAX = 2**31 - 1
#: the QoS of every entity, in rmw_zenoh's key form: reliable, volatile, keep the last 10
#: (defaults left empty)
QOS = "::,10:,:,:,,"
#: a ROS 2 name token (topic names and namespaces are made of them)
_TOKEN = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
log = logging.getLogger(__name__)
_ATTACHMENT = struct.Struct("<qqB16s")
_MARKER_ADD, _MARKER_DELETEALL, _CYLINDER = 0, 3, 3
#: yaw's row and column in ROS's 6 x 6 pose covariance, after x and y
_XY_YAW = np.array([0, 1, 5])
#: how far a quaternion's squared norm may be from 1: tf2's tolerance, past which it refuses
#: a transform
_UNIT_TOLERANCE = 0.01


@cache
def _store():
    """rosbags' typestore of ROS 2 Jazzy's message definitions (the first with type hashes)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@cache
def type_hash(msgtype: str) -> str:
    """The RIHS01 hash of a message type (`RIHS01_<64 hex digits>`), as rosidl computes it."""
    return _store().hash_rihs01(msgtype)


def _dds_type(msgtype: str) -> str:
    package, kind, name = msgtype.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def check_ros_name(option: str, name: str) -> str:
    """`name` if it can be a token of a ROS 2 topic name (a letter, then letters, digits and
    `_`, no `__`); else ConfigError naming `option`."""
    if not isinstance(name, str) or not _TOKEN.match(name) or "__" in name:
        raise ConfigError(f"{option} {name!r}: with ROS 2 a robot name must be a letter, then "
                          f"letters, digits or single '_' (a ROS 2 name token)")
    return name


def map_topic(robot: str) -> str:
    return f"/{robot}/tcaff/map"


def objects_topic(robot: str) -> str:
    """Where a node with `ros2_objects` takes its robot's map from."""
    return f"/{robot}/tcaff/objects"


def cloud_topic(robot: str) -> str:
    """Where a node with `ros2_objects` takes its robot's map as a PointCloud2 from."""
    return f"/{robot}/tcaff/object_cloud"


def alignment_topic(robot: str, neighbour: str) -> str:
    return f"/{robot}/tcaff/alignment/{neighbour}"


def team_topic(robot: str, other: str) -> str:
    return f"/{robot}/tcaff/team_alignment/{other}"


def topic_key(domain_id: int, topic: str, msgtype: str) -> str:
    """The Zenoh key expression rmw_zenoh publishes a fully qualified topic of `msgtype` on."""
    return f"{domain_id}/{topic.lstrip('/')}/{_dds_type(msgtype)}/{type_hash(msgtype)}"


def _mangle(name: str) -> str:
    return name.replace("/", "%") or "%"


def entity_token(domain_id: int, session_id: str, node_id: int, entity_id: int, kind: str,
                 namespace: str, node: str, topic: str | None = None,
                 msgtype: str | None = None) -> str:
    """The liveliness token of a ROS 2 node (`kind` NN, `topic` None), publisher (MP) or
    subscriber (MS), as rmw_zenoh declares it (enclave unset)."""
    head = (f"@ros2_lv/{domain_id}/{session_id}/{node_id}/{entity_id}/{kind}/%/"
            f"{_mangle(namespace)}/{node}")
    if topic is None:
        return head
    return f"{head}/{_mangle(topic)}/{_dds_type(msgtype)}/{type_hash(msgtype)}/{QOS}"


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """rmw_zenoh's attachment of a published message."""
    return _ATTACHMENT.pack(seq, stamp_ns, 16, gid)


def decode_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time in ns, publisher GID) of an attachment.

    Raises:
        MessageError: not 33 bytes, or a GID length other than 16.
    """
    if len(data) != _ATTACHMENT.size:
        raise MessageError("malformed", f"a ROS 2 attachment is {_ATTACHMENT.size} bytes, "
                                        f"got {len(data)}")
    seq, stamp_ns, size, gid = _ATTACHMENT.unpack(data)
    if size != 16:
        raise MessageError("malformed", f"a ROS 2 attachment's GID is 16 bytes, says {size}")
    return seq, stamp_ns, gid


def _time(t: float):
    """builtin_interfaces/msg/Time of `t` s (whole seconds floored, so nanosec is in range).

    Raises:
        DataError: t not finite or outside ROS's int32 seconds.
    """
    if not np.isfinite(t) or not -2**31 <= np.floor(t) < 2**31:
        raise DataError(f"time {t!r} s: a ROS 2 stamp holds int32 seconds")
    sec = int(np.floor(t))
    nanosec = min(round((float(t) - sec) * 1e9), 999_999_999)
    return _store().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def _header(t: float, frame_id: str):
    return _store().types["std_msgs/msg/Header"](stamp=_time(t), frame_id=frame_id)


def pose_message(t: float, frame_id: str, x: np.ndarray, P: np.ndarray):
    """A PoseWithCovarianceStamped of the planar pose x = (x [m], y [m], yaw [rad]) with the
    3 x 3 covariance P, in `frame_id` at `t` s."""
    types = _store().types
    covariance = np.zeros((6, 6))
    covariance[np.ix_(_XY_YAW, _XY_YAW)] = P
    half = 0.5 * float(x[2])
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=float(x[0]), y=float(x[1]), z=0.0),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(half),
                                                          w=np.cos(half)))
    return types[ALIGNMENT_TYPE](
        header=_header(t, frame_id),
        pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                           covariance=covariance.ravel()))


def _marker(types, t: float, frame_id: str, marker_id: int, action: int, centroid=(0, 0, 0),
            scale=(0.0, 0.0, 0.0), rgba=(0.0, 0.0, 0.0, 0.0), text=""):
    g = types
    return g["visualization_msgs/msg/Marker"](
        header=_header(t, frame_id), ns="tcaff_objects", id=marker_id, type=_CYLINDER,
        action=action,
        pose=g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](x=float(centroid[0]), y=float(centroid[1]),
                                                  z=float(centroid[2])),
            orientation=g["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)),
        scale=g["geometry_msgs/msg/Vector3"](x=float(scale[0]), y=float(scale[1]),
                                             z=float(scale[2])),
        color=g["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        lifetime=g["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
        points=[], colors=[], texture_resource="",
        texture=g["sensor_msgs/msg/CompressedImage"](header=_header(0.0, ""), format="",
                                                     data=np.zeros(0, np.uint8)),
        uv_coordinates=[], text=text, mesh_resource="",
        mesh_file=g["visualization_msgs/msg/MeshFile"](filename="",
                                                       data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False)


def map_message(t: float, frame_id: str, object_map: ObjectMap,
                rgba: tuple[float, float, float, float] = (0.2, 0.6, 1.0, 0.7), seq: int = 0,
                boot: int = 0):
    """A MarkerArray of `object_map` at `t` s: a DELETEALL marker stamped t (its id the
    exchange counter `seq`, its text the sender's `boot` number), then one cylinder per object
    (centroid, width as diameter, height; stamped with its last sighting).

    Raises:
        DataError: seq outside 0..2**31 - 1 (a marker's int32 id).
    """
    if not 0 <= seq <= _INT32_MAX:
        raise DataError(f"exchange counter {seq}: a ROS 2 map carries it in an int32 marker id")
    types = _store().types
    markers = [_marker(types, t, frame_id, seq, _MARKER_DELETEALL, text=str(boot))]
    for k in range(len(object_map)):
        w = float(object_map.widths[k])
        markers.append(_marker(types, float(object_map.last_seen[k]), frame_id, k + 1,
                               _MARKER_ADD, object_map.centroids[k],
                               (w, w, float(object_map.heights[k])), rgba))
    return types[MAP_TYPE](markers=markers)


def object_map_of(message) -> tuple[float, ObjectMap]:
    """(t, map) of a MarkerArray written as `map_message` writes it: the objects are its ADD
    markers (pose.position, scale.x as width, scale.z as height, header.stamp as last seen);
    t is the DELETEALL marker's stamp, or the latest object's without one.

    Raises:
        DataError: no marker to take a time from, or sizes or positions that no ObjectMap
            holds (NaN, negative sizes).
    """
    def seconds(stamp) -> float:
        return stamp.sec + 1e-9 * stamp.nanosec

    objects = [m for m in message.markers if m.action == _MARKER_ADD]
    cleared = [seconds(m.header.stamp) for m in message.markers if m.action == _MARKER_DELETEALL]
    if not objects and not cleared:
        raise DataError("a MarkerArray without markers: no map time")
    centroids = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z]
                          for m in objects], dtype=float).reshape(-1, 3)
    widths = np.array([m.scale.x for m in objects], dtype=float)
    heights = np.array([m.scale.z for m in objects], dtype=float)
    last_seen = np.array([seconds(m.header.stamp) for m in objects], dtype=float)
    t = cleared[-1] if cleared else float(last_seen.max())
    return t, ObjectMap(centroids, widths, heights, last_seen)


def exchange_of(message, sender: str) -> MapMessage:
    """A neighbour's map as the team exchanges it, from the MarkerArray `sender` published
    (`map_message`): seq the DELETEALL marker's id, boot its text (0 when not a decimal
    number of ASCII digits below 2**32: a map of another publisher, which has none), the
    objects' ages from their stamps.

    Raises:
        MessageError: no DELETEALL marker (no exchange counter) or a negative id, too many
            objects, or objects no ObjectMap holds ("malformed", "oversized").
    """
    cleared = [m for m in message.markers if m.action == _MARKER_DELETEALL]
    if not cleared:
        raise MessageError("malformed", "a map without its DELETEALL marker: no exchange "
                                        "counter")
    if len(message.markers) > MAX_OBJECTS + 1:
        raise MessageError("oversized", f"{len(message.markers)} markers, at most "
                                        f"{MAX_OBJECTS} objects")
    try:
        t, object_map = object_map_of(message)
    except DataError as exc:
        raise MessageError("malformed", str(exc)) from None
    seq = int(cleared[-1].id)
    if seq < 0:
        raise MessageError("malformed", f"a map whose DELETEALL marker's id, its exchange "
                                        f"counter, is {seq}")
    text = cleared[-1].text
    # ASCII only: str.isdigit() is true of '²', which int() refuses
    boot = int(text) if text.isascii() and text.isdigit() and int(text) < 2**32 else 0
    return MapMessage(sender, boot, seq, t, object_map.centroids,
                      object_map.widths, object_map.heights,
                      np.maximum(t - object_map.last_seen, 0.0))


def cloud_message(t: float, frame_id: str, object_map: ObjectMap):
    """A PointCloud2 of `object_map` at `t` s in the layout `object_map_of_cloud` reads, all
    six fields FLOAT64 (48 bytes per object, little-endian), as a pipeline may publish it."""
    types = _store().types
    points = np.column_stack([object_map.centroids, object_map.widths, object_map.heights,
                              object_map.last_seen]).astype("<f8")
    fields = [types["sensor_msgs/msg/PointField"](name=name, offset=8 * k, datatype=_FLOAT64,
                                                   count=1)
              for k, name in enumerate(CLOUD_FIELDS)]
    return types[CLOUD_TYPE](
        header=_header(t, frame_id), height=1, width=len(points), fields=fields,
        is_bigendian=False, point_step=48, row_step=48 * len(points),
        data=np.frombuffer(points.tobytes(), np.uint8), is_dense=True)


def object_map_of_cloud(message) -> tuple[float, ObjectMap]:
    """(t, map) of a PointCloud2 of objects (see the module docstring): t its header.stamp.

    Raises:
        DataError: a field missing or not FLOAT32 / FLOAT64, a point_step or data size that
            does not hold the points, or values no ObjectMap holds.
    """
    n = int(message.width) * int(message.height)
    step = int(message.point_step)
    fields = {f.name: f for f in message.fields}
    order = ">" if message.is_bigendian else "<"
    columns = []
    for name in CLOUD_FIELDS:
        field = fields.get(name)
        if field is None or field.datatype not in (_FLOAT32, _FLOAT64):
            raise DataError(f"a PointCloud2 of objects needs a FLOAT32 or FLOAT64 field "
                            f"{name!r}; fields: {sorted(fields)}")
        size = 4 if field.datatype == _FLOAT32 else 8
        if field.offset + size > step:
            raise DataError(f"PointCloud2 field {name!r} at offset {field.offset} lies "
                            f"outside point_step {step}")
        columns.append((name, f"{order}f{size}", field.offset))
    data = np.asarray(message.data, dtype=np.uint8)
    if n > MAX_OBJECTS or data.size < n * step or (n and step <= 0):
        raise DataError(f"a PointCloud2 of {n} objects of {step} bytes needs {n * step} "
                        f"bytes (at most {MAX_OBJECTS} objects); it has {data.size}")
    dtype = np.dtype({"names": [c[0] for c in columns], "formats": [c[1] for c in columns],
                      "offsets": [c[2] for c in columns], "itemsize": max(step, 1)})
    points = np.frombuffer(data[:n * step].tobytes(), dtype=dtype, count=n)
    t = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
    column = {name: points[name].astype(float) for name in CLOUD_FIELDS}
    return t, ObjectMap(np.column_stack([column["x"], column["y"], column["z"]]),
                        column["width"], column["height"], column["last_seen"])


def alignment_of(message, sender: str, neighbour: str) -> AlignmentMessage:
    """Another robot's accepted alignment as the team consistency takes it, from the
    PoseWithCovarianceStamped it published on `alignment_topic(sender, neighbour)`: x = (x
    [m], y [m], yaw [rad] of the pose), P (3, 3) its covariance's rows and columns 0, 1 and 5;
    boot, seq, step, hypothesis and the neighbour's map are not on the topic (0; its stamp
    NaN).

    Raises:
        MessageError ("malformed"): an orientation that is not a unit quaternion (within
            tf2's tolerance), or an estimate `TeamConsistency` would refuse
            (`tcaff_gtsam.team.usable_estimates`: x within 1e9, P symmetric positive
            definite with entries within 1e18).
    """
    pose = message.pose.pose
    o = pose.orientation
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    # bounded first: squares of huge components overflow
    if not (np.all(np.abs(q) <= 2.0) and abs(q @ q - 1.0) <= _UNIT_TOLERANCE):
        raise MessageError("malformed", f"an alignment of {sender} to {neighbour} whose "
                                        f"orientation {q.tolist()} (x, y, z, w) is not a unit "
                                        f"quaternion")
    qx, qy, qz, qw = q
    # the yaw of the rotation q / |q|: both arguments scale with |q|^2
    x = np.array([pose.position.x, pose.position.y,
                  np.arctan2(2 * (qw * qz + qx * qy), qw**2 + qx**2 - qy**2 - qz**2)],
                 dtype=float)
    P = np.asarray(message.pose.covariance, dtype=float).reshape(6, 6)[np.ix_(_XY_YAW, _XY_YAW)]
    check_usable(x, P, f"an alignment of {sender} to {neighbour}")
    stamp = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
    return AlignmentMessage(sender, 0, 0, stamp, neighbour, 0, np.nan, 0, 0, True, x, P)


def health_message(t: float, robot: str, level: int, summary: str,
                   values: dict[str, str]):
    """A DiagnosticArray at `t` s with one status `tcaff: /<robot>/tcaff` (hardware_id the
    robot) of `level` (0 OK, 1 WARN, 2 ERROR), `summary` and the key-value `values`."""
    types = _store().types
    status = types["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level, name=f"tcaff: /{robot}/tcaff", message=summary, hardware_id=robot,
        values=[types["diagnostic_msgs/msg/KeyValue"](key=k, value=v)
                for k, v in values.items()])
    return types[HEALTH_TYPE](header=_header(t, ""), status=[status])


def serialize(message, msgtype: str) -> bytes:
    """The CDR bytes of a message (rosbags' serialiser; little-endian, with its header)."""
    return bytes(_store().serialize_cdr(message, msgtype))


def read_message(data: bytes, msgtype: str):
    """The message of CDR bytes.

    Raises:
        MessageError: bytes that are not a `msgtype`.
    """
    try:
        return _store().deserialize_cdr(data, msgtype)
    except Exception as exc:  # rosbags raises assorted errors on foreign bytes
        raise MessageError("malformed", f"not a {msgtype} ({type(exc).__name__}: {exc})"
                           ) from None


class _Publisher:
    """One ROS 2 publisher: a Zenoh publisher on the topic's key, its liveliness token, its
    GID and sequence numbers."""

    def __init__(self, bridge: Ros2Bridge, topic: str, msgtype: str) -> None:
        self.msgtype = msgtype
        session = bridge.session
        self._pub = session.declare_publisher(topic_key(bridge.domain_id, topic, msgtype))
        self.token = session.liveliness().declare_token(bridge.token("MP", topic, msgtype))
        self._gid = os.urandom(16)
        self._seq = 0

    def put(self, message) -> None:
        self._seq += 1
        self._pub.put(serialize(message, self.msgtype),
                      attachment=attachment(self._seq, time.time_ns(), self._gid))


class Ros2Bridge:
    """A node's ROS 2 side on its Zenoh session: the ROS node `/<robot>/tcaff`, its publishers
    (declared on first use) and, when given `on_objects`, its subscriber of
    `/<robot>/tcaff/objects`.

    `on_objects(t, object_map)` is called on Zenoh's thread with each map that arrives; a
    message that is not a MarkerArray of objects, or that `on_objects` fails on, is handed to
    `on_refused(reason, detail)` (the node counts and logs it) or, without one, logged.
    """

    def __init__(self, session, robot: str, domain_id: int = 0, on_objects=None,
                 on_refused=None) -> None:
        self.session = session
        self.robot = check_ros_name("--robot", robot)
        self.domain_id = domain_id
        self._session_id = str(session.info.zid())
        self._entities = 0
        self._publishers: dict[str, _Publisher] = {}
        self._tokens = [session.liveliness().declare_token(self.token("NN"))]
        self._subscriber = None
        if on_objects is not None:
            self._on_objects, self._on_refused = on_objects, on_refused
            topic = objects_topic(robot)
            self._subscriber = session.declare_subscriber(
                topic_key(domain_id, topic, MAP_TYPE), self._objects)
            self._tokens.append(session.liveliness().declare_token(
                self.token("MS", topic, MAP_TYPE)))

    def token(self, kind: str, topic: str | None = None, msgtype: str | None = None) -> str:
        """The liveliness token of the next entity of this node (the node itself: NN)."""
        entity = 0 if kind == "NN" else self._entities + 1
        self._entities = max(self._entities, entity)
        return entity_token(self.domain_id, self._session_id, 0, entity, kind,
                            f"/{self.robot}", "tcaff", topic, msgtype)

    def _publish(self, topic: str, msgtype: str, message) -> None:
        if topic not in self._publishers:
            self._publishers[topic] = _Publisher(self, topic, msgtype)
        self._publishers[topic].put(message)

    def object_map(self, t: float, object_map: ObjectMap, seq: int = 0, boot: int = 0
                   ) -> None:
        """Publish the robot's shared map at `t` s (exchange `seq` of boot `boot`)."""
        self._publish(map_topic(self.robot), MAP_TYPE,
                      map_message(t, f"{self.robot}/odom", object_map, seq=seq, boot=boot))

    def alignment(self, message: AlignmentMessage | TeamMessage) -> None:
        """Publish an accepted alignment (a TeamMessage on the team topic); others are not
        published."""
        if not message.accepted:
            return
        topic = (team_topic if isinstance(message, TeamMessage) else alignment_topic)(
            self.robot, check_ros_name("neighbour", message.neighbour))
        self._publish(topic, ALIGNMENT_TYPE,
                      pose_message(message.stamp, f"{self.robot}/odom", message.x, message.P))

    def _objects(self, sample) -> None:
        try:
            message = read_message(sample.payload.to_bytes(), MAP_TYPE)
            t, object_map = object_map_of(message)
            self._on_objects(t, object_map)
        except Exception as exc:  # nothing may escape into Zenoh's thread
            detail = f"on {objects_topic(self.robot)}: {exc}"
            if self._on_refused is not None:
                self._on_refused("malformed", detail)
            else:
                log.warning("dropped a ROS 2 map %s", detail)

    def close(self) -> None:
        """Withdraw the tokens and undeclare the subscriber (the session stays open); again:
        nothing."""
        if self._subscriber is not None:
            self._subscriber.undeclare()
            self._subscriber = None
        for publisher in self._publishers.values():
            self._tokens.append(publisher.token)
        self._publishers = {}
        for token in self._tokens:
            token.undeclare()
        self._tokens = []
