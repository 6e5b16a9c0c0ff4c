"""The wire format of a team: object maps and alignments, versioned, compact and checked.

Every message is little-endian and starts with the same header:

    magic  b"TCAF"      4 bytes
    version u8          `VERSION`; any other is refused
    kind    u8          1: map, 2: alignment, 3: team alignment
    sender  u8 + UTF-8  the robot that sent it (1 to 64 bytes)
    boot    u32         a number the sender draws when it starts (tells a restart from a replay)
    seq     u32         the sender's exchange counter (a map's, or the ego map an alignment used)
    stamp   f64         s, on the sender's own clock

A map then holds `n u32` and n objects of six float32 each, 24 bytes per object: centroid x, y,
z [m] in the sender's odometry frame, width, height [m], age [s] (stamp - last_seen, never
negative). Ages instead of stamps make a map independent of the sender's clock: the receiver
puts the objects on its own clock. float32 keeps 1e-6 relative precision, below any object's
measurement noise.

An alignment then holds: neighbour u8 + UTF-8, neighbour_seq u32 (the neighbour's map it used),
neighbour_stamp f64 (that map's stamp on the neighbour's clock), step i32 (the pair's filter
updates so far, >= 0), hypothesis i32 (the main tree's id, >= 0; -1 exactly when there is no
estimate), accepted u8 (0 or 1), x, y, theta f64 (T_oi_oj) and the six upper-triangle entries
of its 3x3 covariance, f64. A not accepted alignment has no estimate: its nine numbers are NaN
(any other is refused, not ignored: only a damaged or forged message holds one).

A team alignment (what the node's team consistency selects for a pair) then holds: neighbour
u8 + UTF-8, via u8 (the robots it is chained through, 0 for the pair's own alignment) and as
many names (u8 + UTF-8 each), accepted u8, x, y, theta f64 and the covariance's upper triangle
(NaN when not accepted, as an alignment's).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.object_map import ObjectMap

__all__ = ["BYTES_PER_OBJECT", "MAX_OBJECTS", "VERSION", "AlignmentMessage", "MapMessage",
           "MessageError", "TeamMessage", "decode", "encode"]

VERSION = 1
MAGIC = b"TCAF"
MAP, ALIGNMENT, TEAM = 1, 2, 3
BYTES_PER_OBJECT = 24
#: the most objects a map message may hold; a larger one is refused before it is read
MAX_OBJECTS = 10_000
MAX_NAME = 64

_HEAD = struct.Struct("<4sBB")
_COUNTERS = struct.Struct("<IId")  # boot, seq, stamp
_N = struct.Struct("<I")
_ALIGN = struct.Struct("<Idii B 3d 6d")  # neighbour_seq, neighbour_stamp, step, hypothesis, ...
_ESTIMATE = struct.Struct("<B 3d 6d")  # accepted, x, upper triangle of P
_OBJECT = np.dtype("<f4")
_UPPER = np.triu_indices(3)
#: the largest message: a map of MAX_OBJECTS objects from a robot with the longest name
MAX_BYTES = _HEAD.size + 1 + MAX_NAME + _COUNTERS.size + _N.size + MAX_OBJECTS * BYTES_PER_OBJECT


class MessageError(DataError):
    """A payload that is not a message this node accepts.

    Attributes:
        reason: the counter it is counted under: "malformed", "version", "oversized",
            "outsider" (a robot outside the team), "mismatch" (sender and key disagree).
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason} message: {detail}")
        self.reason = reason


@dataclass(frozen=True, eq=False)
class MapMessage:
    """A robot's object map as sent.

    Attributes:
        sender: robot name; boot, seq: see the module docstring; stamp: s, sender's clock.
        centroids: (n, 3) m, sender's odometry frame; widths, heights: (n,) m;
        ages: (n,) s since each object was last seen, at `stamp`.
    """

    sender: str
    boot: int
    seq: int
    stamp: float
    centroids: np.ndarray
    widths: np.ndarray
    heights: np.ndarray
    ages: np.ndarray

    @classmethod
    def of(cls, sender: str, boot: int, seq: int, stamp: float, object_map: ObjectMap
           ) -> MapMessage:
        """The message of `object_map` at time `stamp` (the clock of its `last_seen`)."""
        return cls(sender, boot, seq, stamp, object_map.centroids, object_map.widths,
                   object_map.heights, object_map.ages(stamp))

    def object_map(self, now: float) -> ObjectMap:
        """The objects as an ObjectMap with `last_seen` on the receiver's clock, now = `now`."""
        return ObjectMap(self.centroids, self.widths, self.heights, now - self.ages)


@dataclass(frozen=True, eq=False)
class AlignmentMessage:
    """One step of a robot's alignment to a neighbour.

    Attributes:
        sender: the ego robot i; neighbour: robot j; seq: the ego map's seq; stamp: s, ego clock.
        neighbour_seq, neighbour_stamp: the neighbour's map used (stamp on its clock).
        step: the pair's filter updates so far; hypothesis: the filter's main tree (-1: none,
            exactly when not accepted).
        accepted: the filter holds an estimate; x: (3,) (x [m], y [m], theta [rad]) of T_oi_oj;
        P: (3, 3) its covariance (both NaN when not accepted: `encode` sends NaN).
    """

    sender: str
    boot: int
    seq: int
    stamp: float
    neighbour: str
    neighbour_seq: int
    neighbour_stamp: float
    step: int
    hypothesis: int
    accepted: bool
    x: np.ndarray
    P: np.ndarray


@dataclass(frozen=True, eq=False)
class TeamMessage:
    """A team-consistent alignment of a robot to another (see `tcaff_gtsam.TeamConsistency`).

    Attributes:
        sender: the ego robot i; neighbour: robot j (any robot of the team); seq: the ego map's
            seq; stamp: s, ego clock.
        via: the robots between i and j of a chained alignment, () for the pair's own.
        accepted: the team has an alignment of the pair; x: (3,) (x [m], y [m], theta [rad])
            of T_oi_oj; P: (3, 3) its covariance (both NaN when not accepted: `encode` sends
            NaN).
    """

    sender: str
    boot: int
    seq: int
    stamp: float
    neighbour: str
    via: tuple[str, ...]
    accepted: bool
    x: np.ndarray
    P: np.ndarray


def _name(name: str) -> bytes:
    raw = name.encode()
    if not 1 <= len(raw) <= MAX_NAME:
        raise DataError(f"robot name {name!r}: must be 1 to {MAX_NAME} bytes of UTF-8")
    return bytes([len(raw)]) + raw


def _u32(name: str, value: int) -> int:
    if not 0 <= value < 2**32:
        raise DataError(f"{name} = {value}: must fit in 32 bits unsigned")
    return value


def _i32(name: str, value: int) -> int:
    if not 0 <= value < 2**31:
        raise DataError(f"{name} = {value}: must be in [0, 2**31 - 1] (32 bits signed)")
    return value


def encode(message: MapMessage | AlignmentMessage | TeamMessage) -> bytes:
    """The bytes of a message.

    A message that is not accepted is sent without its estimate: NaN for x and P.

    Raises:
        DataError: a name longer than 64 bytes (or empty), counters beyond 32 bits (a step
            below 0, an accepted alignment's hypothesis below 0), a stamp that is not finite,
            or a map of more than `MAX_OBJECTS` objects.
    """
    kind = {MapMessage: MAP, AlignmentMessage: ALIGNMENT, TeamMessage: TEAM}[type(message)]
    if not math.isfinite(message.stamp):
        raise DataError(f"stamp = {message.stamp}: must be a finite number of seconds")
    head = (_HEAD.pack(MAGIC, VERSION, kind) + _name(message.sender)
            + _COUNTERS.pack(_u32("boot", message.boot), _u32("seq", message.seq),
                             message.stamp))
    if kind == MAP:
        n = len(message.centroids)
        if n > MAX_OBJECTS:
            raise DataError(f"a map message holds at most {MAX_OBJECTS} objects, got {n}")
        body = np.column_stack([message.centroids, message.widths, message.heights,
                                message.ages]).astype(_OBJECT)
        return head + _N.pack(n) + body.tobytes()
    if message.accepted:
        x, P = np.asarray(message.x, dtype=float), np.asarray(message.P, dtype=float)[_UPPER]
    else:
        x, P = np.full(3, np.nan), np.full(6, np.nan)
    if kind == TEAM:
        if len(message.via) > 255:
            raise DataError(f"via holds {len(message.via)} robots, at most 255")
        return (head + _name(message.neighbour) + bytes([len(message.via)])
                + b"".join(map(_name, message.via))
                + _ESTIMATE.pack(int(message.accepted), *x, *P))
    if not math.isfinite(message.neighbour_stamp):
        raise DataError(f"neighbour_stamp = {message.neighbour_stamp}: must be a finite number "
                        f"of seconds")
    hypothesis = -1 if not message.accepted else _i32("hypothesis", message.hypothesis)
    return (head + _name(message.neighbour)
            + _ALIGN.pack(_u32("neighbour_seq", message.neighbour_seq),
                          message.neighbour_stamp, _i32("step", message.step), hypothesis,
                          int(message.accepted), *x, *P))


class _Reader:
    """Reads a payload front to back; every shortfall is a `malformed` MessageError."""

    def __init__(self, payload: bytes) -> None:
        self.payload, self.at = payload, 0

    def take(self, size: int, what: str) -> bytes:
        end = self.at + size
        if end > len(self.payload):
            raise MessageError("malformed", f"truncated in {what} ({len(self.payload)} bytes)")
        chunk, self.at = self.payload[self.at:end], end
        return chunk

    def unpack(self, fmt: struct.Struct, what: str) -> tuple:
        return fmt.unpack(self.take(fmt.size, what))

    def name(self, what: str) -> str:
        (length,) = self.take(1, what)
        if not 1 <= length <= MAX_NAME:
            raise MessageError("malformed", f"{what} of {length} bytes")
        try:
            return self.take(length, what).decode()
        except UnicodeDecodeError:
            raise MessageError("malformed", f"{what} is not UTF-8") from None


def decode(payload: bytes, max_bytes: int | None = None
           ) -> MapMessage | AlignmentMessage | TeamMessage:
    """The message in `payload`, fully checked.

    Raises:
        MessageError: `oversized` beyond `max_bytes` (refused before it is read); `version`
            for another version of this format; `malformed` for anything else: another magic,
            kind, a truncated or overlong payload, a name that is not UTF-8, non-finite
            numbers, negative sizes or ages, a negative step, a hypothesis other than -1
            without an estimate or below 0 with one, a not accepted alignment whose x or P
            is not NaN; an accepted alignment whose estimate
            `TeamConsistency` would refuse (`tcaff_gtsam.team.usable_estimates`: x within
            1e9, P symmetric positive definite with entries within 1e18), an accepted team
            alignment whose x is not finite or whose P is not symmetric positive
            semi-definite. `max_bytes` None: `MAX_BYTES`.
    """
    if max_bytes is None:
        max_bytes = MAX_BYTES
    if len(payload) > max_bytes:
        raise MessageError("oversized", f"{len(payload)} bytes, at most {max_bytes}")
    read = _Reader(payload)
    magic, version, kind = read.unpack(_HEAD, "header")
    if magic != MAGIC:
        raise MessageError("malformed", f"magic {magic!r}, expected {MAGIC!r}")
    if version != VERSION:
        raise MessageError("version", f"format version {version}, this node reads {VERSION}")
    if kind not in (MAP, ALIGNMENT, TEAM):
        raise MessageError("malformed", f"kind {kind}")
    sender = read.name("sender")
    boot, seq, stamp = read.unpack(_COUNTERS, "header")
    if not math.isfinite(stamp):
        raise MessageError("malformed", f"stamp {stamp}")
    if kind == MAP:
        (n,) = read.unpack(_N, "object count")
        if n > MAX_OBJECTS:
            raise MessageError("oversized", f"{n} objects, at most {MAX_OBJECTS}")
        body = read.take(n * BYTES_PER_OBJECT, "objects")
        _finished(read)
        values = np.frombuffer(body, dtype=_OBJECT).reshape(n, 6).astype(float)
        if not np.isfinite(values).all():
            raise MessageError("malformed", "non-finite object values")
        if (values[:, 3:] < 0).any():
            raise MessageError("malformed", "negative size or age")
        return MapMessage(sender, boot, seq, stamp, values[:, :3], values[:, 3], values[:, 4],
                          values[:, 5])
    neighbour = read.name("neighbour")
    if kind == TEAM:
        (n_via,) = read.take(1, "via")
        via = tuple(read.name("via") for _ in range(n_via))
        accepted, *numbers = read.unpack(_ESTIMATE, "team alignment")
        _finished(read)
        if accepted not in (0, 1):
            raise MessageError("malformed", f"accepted {accepted}")
        x, P = _estimate(bool(accepted), numbers, team=True)
        return TeamMessage(sender, boot, seq, stamp, neighbour, via, bool(accepted), x, P)
    nseq, nstamp, step, hypothesis, accepted, *numbers = read.unpack(_ALIGN, "alignment")
    _finished(read)
    if (accepted not in (0, 1) or step < 0 or not math.isfinite(nstamp)
            or (hypothesis < 0 if accepted else hypothesis != -1)):
        raise MessageError("malformed", f"accepted {accepted}, step {step}, hypothesis "
                                        f"{hypothesis}, neighbour stamp {nstamp}")
    x, P = _estimate(bool(accepted), numbers, team=False)
    return AlignmentMessage(sender, boot, seq, stamp, neighbour, nseq, nstamp, step,
                            hypothesis, bool(accepted), x, P)


def _estimate(accepted: bool, numbers: list[float], team: bool
              ) -> tuple[np.ndarray, np.ndarray]:
    """x (3,) and the symmetric P (3, 3) of an alignment's nine numbers, checked: an accepted
    alignment's as `TeamConsistency` checks its input (the node hands it to it), an accepted
    team alignment's (`team`, composed along a chain: beyond those bounds by rights) finite
    and positive semi-definite."""
    x = np.array(numbers[:3])
    P = np.zeros((3, 3))
    P[_UPPER] = numbers[3:]
    P = P + np.triu(P, 1).T
    if not accepted:
        if not (np.isnan(x).all() and np.isnan(P).all()):
            raise MessageError("malformed", f"an alignment that is not accepted holds an "
                                            f"estimate, x = {x.tolist()}, P = "
                                            f"{P[_UPPER].tolist()} (upper triangle), not NaN")
        return x, P
    if team:
        if not (np.isfinite(x).all() and np.isfinite(P).all()
                and np.linalg.eigvalsh(P).min() >= -1e-12):
            raise MessageError("malformed", "an accepted team alignment needs a finite x and "
                                            "a positive semi-definite P")
    else:
        check_usable(x, P, "an accepted alignment")
    return x, P


def check_usable(x: np.ndarray, P: np.ndarray, what: str) -> None:
    """Refuse (MessageError "malformed") `what`'s estimate x (3,), P (3, 3) unless
    `TeamConsistency` takes it (`tcaff_gtsam.team.usable_estimates`)."""
    # imported here: it loads numba, whose load a process that only reads messages (`tcaff
    # listen`, the bag tools) then pays at its first accepted alignment, not at its start
    from tcaff_gtsam.team import ESTIMATE_RULE, usable_estimates

    if not usable_estimates(x[None], P[None])[0]:
        raise MessageError("malformed", f"{what} needs {ESTIMATE_RULE}, got x = {x.tolist()}, "
                                        f"P = {P.tolist()}")


def _finished(read: _Reader) -> None:
    if read.at != len(read.payload):
        raise MessageError("malformed", f"{len(read.payload) - read.at} bytes after the end")
