"""RobotNode: one robot of a live team. Its maps go out, its neighbours' maps come in, and one
PairwiseAligner per neighbour turns them into alignments it publishes and hands to a callback."""

from __future__ import annotations

import hashlib
import logging
import math
import os
import queue
import random
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tcaff_gtsam.aligner_params import _kappa
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.inputs import finite_time, shown
from tcaff_gtsam.object_map import ObjectMap, as_object_map
from tcaff_gtsam.pairwise import PairwiseAligner
from tcaff_gtsam.params import (
    FrameAlignerParams,
    TCAFFParams,
    _finite,
    _int_at_least,
    _require,
)
from tcaff_gtsam.tcaff import TCAFF, write_snapshot
from tcaff_gtsam.team import ESTIMATE_RULE, TeamConsistency, TeamParams, usable_estimates

from .link import Link, check_name
from .messages import AlignmentMessage, MapMessage, MessageError, TeamMessage
from .transport import Transport, ZenohTransport

__all__ = ["NodeParams", "RobotNode"]

log = logging.getLogger(__name__)

#: ego maps kept for neighbours' maps of the same exchange arriving late (lockstep)
_EGO_HISTORY = 8
#: s `finish` waits for the worker and the saver at the end of a run that no signal stopped
FINISH_TIMEOUT = 30.0


@dataclass(frozen=True)
class NodeParams:
    """How a node treats its team.

    Attributes:
        kappa: s, only objects seen within kappa are published; at most a year
            (`MAX_SECONDS`), or inf (every object), as `FrameAlignerParams.kappa`.
        silence: s on the ego clock: a neighbour whose latest map is older steps its filter
            without measurements at each ego map, so that its estimate holds and then drops as
            TCAFF drops an unsupported hypothesis.
        lockstep: a neighbour's map of exchange k is aligned with the ego map of exchange k
            (robots replaying one run, whose exchange counters agree); off: with the latest
            ego map, on the ego clock at arrival (robots with their own counters).
        speed: the ego clock's rate against the wall clock (a replay's speed-up; 1 live).
        queue: incoming messages waiting to be aligned; beyond it the newest are dropped.
        drop_share: share of neighbours' maps discarded on arrival, to try a lossy link; whether
            a map is lost depends only on (seed, sender, seq), not on the order maps arrive in,
            so that a lossy replay loses the same maps every run.
        seed: draws of `drop_share`.
        team_consistency: also take the alignments the other robots publish and, after each
            step of a pair, publish the pair's team-consistent alignment
            (`tcaff_gtsam.TeamConsistency`: pair alignments that fail a cycle of three robots
            left out, pairs without one chained through a third robot) on
            `tcaff/<team>/<robot>/team/<neighbour>`. Another robot's alignment counts for
            `silence` s (ego clock) after it arrives.
        ros2: also publish the shared map and every accepted (and team) alignment as ROS 2
            topics with standard messages, as ROS 2's Zenoh middleware would (`node.ros2`);
            robot names must then be ROS 2 name tokens.
        domain_id: the ROS 2 domain (ROS_DOMAIN_ID) of those topics, 0 to 232.
        ros2_objects: with `ros2` (and not `lockstep`), take the robot's map from the ROS 2
            topic /<robot>/tcaff/objects (a MarkerArray as `node.ros2` describes) instead of
            from `publish`: each message newer than the last is published as `publish` would.
    """

    kappa: float = 20.0
    silence: float = 3.0
    lockstep: bool = False
    speed: float = 1.0
    queue: int = 256
    drop_share: float = 0.0
    seed: int = 0
    team_consistency: bool = False
    ros2: bool = False
    domain_id: int = 0
    ros2_objects: bool = False

    def __post_init__(self) -> None:
        o = "NodeParams"
        _kappa(o, "kappa", self.kappa)  # the node's aligner's
        for name in ("silence", "speed"):
            value = getattr(self, name)
            _require(_finite(value) and value > 0, o, name, value, "must be a number > 0")
        _require(_finite(self.drop_share) and 0 <= self.drop_share < 1, o, "drop_share",
                 self.drop_share, "must be a number in [0, 1)")
        _require(_int_at_least(self.queue, 1), o, "queue", self.queue, "must be an int >= 1")
        _require(_int_at_least(self.seed, 0), o, "seed", self.seed, "must be an int >= 0")
        for name in ("lockstep", "team_consistency", "ros2", "ros2_objects"):
            value = getattr(self, name)
            _require(isinstance(value, bool), o, name, value, "must be True or False")
        _require(_int_at_least(self.domain_id, 0) and self.domain_id <= 232, o, "domain_id",
                 self.domain_id, "must be an int in 0..232")
        _require(self.ros2 or not self.ros2_objects, o, "ros2_objects", self.ros2_objects,
                 "needs ros2=True")
        _require(not (self.ros2_objects and self.lockstep), o, "ros2_objects",
                 self.ros2_objects, "takes live maps: needs lockstep=False")


class _Neighbour:
    """What a node keeps of one neighbour."""

    def __init__(self, aligner: PairwiseAligner) -> None:
        self.aligner = aligner
        self.boot: int | None = None
        self.seq = -1          # the latest map taken
        self.stamp = 0.0       # its stamp, neighbour's clock
        # ego-clock time of the latest map aligned (None: none yet, silence counts from the
        # first ego map)
        self.last_seen: float | None = None
        self.pending: dict[int, tuple[MapMessage, float]] = {}  # seq -> (map, arrival)
        self.clock: float | None = None  # ego-clock time of the pair's latest step
        # restored from a saved filter, not yet confirmed by a measurement of the neighbour
        self.unconfirmed = False


class RobotNode:
    """One robot's process in a team: publishes its maps, aligns to every neighbour's.

    `publish(t, object_map)` is the one verb: a mapping pipeline calls it with each new map.
    Neighbours' maps arrive on the transport's threads (Zenoh's or rclpy's) and are aligned on
    the node's own worker thread; each step of a pair's filter is published (over Zenoh on
    `tcaff/<team>/<robot>/alignment/<neighbour>`) and passed to `on_alignment` (called on the
    worker thread; keep it short).

    Bad messages (see `messages.decode`), maps of robots outside `members`, duplicates and
    maps older than the latest taken from that robot are dropped with one log line each and
    counted in `counters`; the node keeps running.

    Attributes:
        counters: Counter of "maps_sent", "maps_received", "aligned", "silent_steps",
            "dropped_<reason>", "lost" (discarded on purpose, `NodeParams.drop_share`),
            "skipped" (live, a neighbour's map with a newer one of it already waiting: a
            node that falls behind aligns the newest maps),
            "early" (a neighbour's map before this robot's first) and "errors" (a step that
            failed, logged with its traceback; the node goes on); with team consistency also
            "alignments_heard" (other robots'), "team_rejected" (steps whose own accepted
            alignment failed the team's cycles), "team_chained" (steps whose team alignment
            is chained through another robot) and "team_unusable" (alignments the team
            consistency cannot take, left out of its steps and logged: another robot's once,
            then forgotten, the node's own at each step); "withheld_restored" (steps of a
            filter restored from `state_dir` whose hypothesis no new map had confirmed yet:
            reported as none);
            with ROS 2, "ros2_sent" (maps and alignments published there) and "ros2_errors"
            (ones that could not be, logged).
        latest: neighbour -> the latest AlignmentMessage of that pair.
        team_latest: with team consistency, neighbour -> the latest TeamMessage of that pair.
        latencies: s from each of the latest 10 000 neighbours' maps arriving to its
            alignment being published (queueing included).
    """

    def __init__(self, robot: str, team: str, members: list[str], link: Link | Transport,
                 params: NodeParams | None = None,
                 aligner_params: FrameAlignerParams | None = None,
                 tcaff_params: TCAFFParams | None = None,
                 on_alignment: Callable[[AlignmentMessage], None] | None = None,
                 state_dir: str | Path | None = None, team_params: TeamParams | None = None,
                 on_team: Callable[[TeamMessage], None] | None = None) -> None:
        """Open the session, restore saved filters, and start listening.

        Args:
            members: every robot of the team (this one included or not); maps of others are
                dropped.
            link: the node's Zenoh endpoints, or a `Transport` (`node.dds.DdsTransport`: the
                team over ROS 2's default middleware).
            state_dir: each pair's filter is saved there after each step (`TCAFF.snapshot`,
                written on a thread of its own; counters "states_saved", "save_errors") and
                restored from there on start; None: nothing saved. A saved filter that
                cannot be read (a corrupt file, one of other parameters' shapes) is logged,
                counted ("restore_errors") and kept beside as "<file>.refused", and its pair
                starts afresh: the robot's node comes up either way.
            team_params, on_team: with `NodeParams.team_consistency`, the settings of the
                team consistency, and a callback given every TeamMessage the node publishes
                (on the worker thread).
        Raises:
            ConfigError: bad names, a team of fewer than two robots, bad parameters, a
                state_dir that is not a folder.
        """
        self.robot = check_name("--robot", robot)
        self.team = check_name("--team", team)
        self.members = frozenset(check_name("--members", m) for m in members) - {robot}
        if not self.members:
            raise ConfigError(f"--members {members!r}: the team needs another robot besides "
                              f"{robot!r}")
        self._transport = ZenohTransport(link) if isinstance(link, Link) else link
        # from here on the transport may hold a started ROS node: nothing is left open by
        # a node that could not start
        try:
            self.params = self._transport.configure(robot, params or NodeParams())
            if self.params.ros2:  # before anything is opened
                from .ros2 import check_ros_name

                for name in (robot, *self.members):
                    check_ros_name("--robot" if name == robot else "--members", name)
            self._aligner_params = aligner_params or FrameAlignerParams(kappa=self.params.kappa)
            self._tcaff_params = tcaff_params
            self._on_alignment = on_alignment
            self._on_team = on_team
            self._state_dir = None if state_dir is None else Path(state_dir)
            self.counters: Counter[str] = Counter()
            self.latest: dict[str, AlignmentMessage] = {}
            self.latencies: deque[float] = deque(maxlen=10_000)
            self.team_latest: dict[str, TeamMessage] = {}
            # robots in index order for TeamConsistency, and the other robots' latest alignments:
            # (robot, neighbour) -> (message, perf_counter time of arrival)
            self._robots = sorted(self.members | {self.robot})
            self._team = (TeamConsistency(len(self._robots), team_params)
                          if self.params.team_consistency else None)
            self._heard: dict[tuple[str, str], tuple[AlignmentMessage, float]] = {}
            self._neighbours: dict[str, _Neighbour] = {}
            self._restore()
            self.boot = random.SystemRandom().randrange(2**32)
            self._seq = 0
            self._publishing = threading.Lock()
            # maps queued per key, to skip all but the newest of a robot when the node is behind
            self._waiting: Counter[str] = Counter()
            self._waiting_lock = threading.Lock()
            self._ros2_last: float | None = None  # the latest ROS 2 map's time
            self._closed = False
            self._finished: bool | None = None  # `finish`'s answer, once called
            self._ego: dict[int, tuple[float, ObjectMap]] = {}
            # seq, stamp, perf_counter() when it was published
            self._ego_latest: tuple[int, float, float] | None = None
            self._inbox: queue.Queue = queue.Queue(self.params.queue)
            self._idle = threading.Event()
            self._transport.open(self)
        except BaseException:
            self._transport.close()
            raise
        self._saver = None if self._state_dir is None else _Saver(self.robot, self.counters)
        self._worker = threading.Thread(target=self._work, name=f"tcaff-node-{robot}",
                                        daemon=True)
        self._worker.start()

    # -- the pipeline's side ------------------------------------------------------------------

    def publish(self, t: float, object_map: ObjectMap, seq: int | None = None,
                cancel: Callable[[], bool] | None = None) -> None:
        """Send the robot's map at time `t` (s, the clock of its `last_seen`) and align the
        neighbours' maps that wait for it.

        Args:
            object_map: the map in the robot's odometry frame; objects seen kappa or more
                seconds before t are left out.
            seq: the exchange counter (a replay's exchange index); None: one more than the last.
            cancel: while the worker's queue is full (a worker stuck or far behind), the map
                waits for a place in it until `cancel()` is true (asked every 0.05 s; None:
                as long as it takes); it is then not aligned (counted "dropped_overflow"),
                though it went out to the team.
        Raises:
            DataError: t not finite, not an ObjectMap, seq not after the previous one.
        """
        self._publish(t, object_map, seq, block=True, cancel=cancel)

    def _publish(self, t: float, object_map: ObjectMap, seq: int | None, block: bool,
                 cancel: Callable[[], bool] | None = None) -> None:
        object_map = as_object_map("RobotNode.publish", "object_map", object_map)
        t = finite_time("RobotNode.publish", "t", t)
        with self._publishing:  # the pipeline's thread, or the transport's with ros2_objects
            seq = self._seq if seq is None else int(seq)
            if seq < self._seq:
                raise DataError(f"RobotNode.publish: seq {seq} is not after the previous "
                                f"{self._seq - 1}")
            recent = object_map.recent(t, self.params.kappa)
            self._transport.put_map(MapMessage.of(self.robot, self.boot, seq, t, recent),
                                    recent)
            self.counters["maps_sent"] += 1
            self._seq = seq + 1
            item = ("ego", seq, t, recent, time.perf_counter())
            if not _until(lambda s: _put(self._inbox, item, s), math.inf if block else 0.0,
                          cancel):  # never block the transport's thread
                self.drop("overflow", "queue full (own map)")

    def present(self, timeout: float = 1.0) -> set[str]:
        """The team members whose nodes are up and linked to this one (Zenoh liveliness, or
        over DDS a publisher of the member's map)."""
        return self._transport.present(timeout) & self.members

    def wait_idle(self, timeout: float = 10.0, cancel: Callable[[], bool] | None = None
                  ) -> bool:
        """Block until every message received so far is handled; False after `timeout` s, or
        once `cancel()` is true (asked every 0.05 s; a node told to stop now)."""
        deadline = time.monotonic() + timeout
        self._idle.clear()
        # a full queue waits for the worker too
        return (_until(lambda s: _put(self._inbox, ("idle",), s), timeout, cancel)
                and _until(self._idle.wait, deadline - time.monotonic(), cancel))

    def finish(self, timeout: float = FINISH_TIMEOUT, cancel: Callable[[], bool] | None = None
               ) -> bool:
        """Let the worker handle what is queued and end, and the saver write the filters
        waiting to be saved: within `timeout` s in all, or until `cancel()` is true (asked
        every 0.05 s). The session stays open (`close` closes it); again: the first answer.

        Returns:
            True when both ended. False: the stop was cut short (a worker stuck in a step,
            a step longer than what was left); the worker and the saver are left to the
            process's exit (daemon threads) with what they hold (`queued`).
        """
        if self._finished is None:
            deadline = time.monotonic() + timeout

            def left() -> float:
                return max(deadline - time.monotonic(), 0.0)

            self._finished = (
                _until(lambda s: _put(self._inbox, None, s), left(), cancel)
                and _until(lambda s: _joined(self._worker, s), left(), cancel))
            if self._saver is not None:  # the filters of steps made are results too: its
                # writes take milliseconds, and it gets a moment even past a stuck worker
                saved = self._saver.close(max(left(), _SAVER_LEAST), cancel)
                self._finished = saved and self._finished
        return self._finished

    def queued(self) -> int:
        """Maps and alignments received (or published) and not yet handled by the worker; the
        one it is handling not counted."""
        waiting = list(self._inbox.queue)  # a copy: the transport's threads add to it
        return sum(item is not None and item[0] != "idle" for item in waiting)

    def close(self) -> None:
        """Stop the worker (after what is queued, `finish`, unless it was called before) and
        close the session; again: nothing."""
        if self._closed:
            return
        self._closed = True
        self.finish()
        self._transport.close()

    def __enter__(self) -> RobotNode:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the team's side ----------------------------------------------------------------------

    def arrived(self, kind: str, source: str, read: Callable[[], MapMessage | AlignmentMessage]
                ) -> None:
        """The transport's callback (on its thread): queue a neighbour's "map" or another
        robot's "alignment" from `source` (one name per sender and kind), to be read with
        `read()` on the worker thread (see `node.transport`); never blocks."""
        if kind == "map":  # counted before the worker can see it
            with self._waiting_lock:
                self._waiting[source] += 1
        try:
            self._inbox.put_nowait((kind, source, read, time.perf_counter()))
        except queue.Full:
            if kind == "map":
                self._unqueue(source)
            self.drop("overflow", "queue full")

    def _unqueue(self, key: str) -> int:
        """One map of `key` less waiting; the number still waiting."""
        with self._waiting_lock:
            self._waiting[key] -= 1
            left = self._waiting[key]
            if not left:
                del self._waiting[key]  # bounded by the keys waiting, not every key seen
        return left

    def ros2_map(self, t: float, object_map: ObjectMap) -> None:
        """A map from the ROS 2 objects topic (on the transport's thread): published as `publish`
        would; one not newer than the last is dropped as stale, one that cannot be published
        as malformed."""
        if self._ros2_last is not None and not t > self._ros2_last:
            self.drop("stale", f"ROS 2 map at {t!r} s, the last at {self._ros2_last!r} s")
            return
        self._ros2_last = t
        try:
            self._publish(t, object_map, None, block=False)
        except DataError as exc:
            self.drop("malformed", f"on the ROS 2 objects topic: {exc}")

    def drop(self, reason: str, detail: str) -> None:
        """Count and log a message the node refuses (`counters["dropped_<reason>"]`)."""
        self.counters[f"dropped_{reason}"] += 1
        log.warning("%s: dropped a message (%s): %s", self.robot, reason, detail)

    def _work(self) -> None:
        while (item := self._inbox.get()) is not None:
            try:
                if item[0] == "ego":
                    self._ego_step(*item[1:])
                elif item[0] == "map":
                    self._take(*item[1:])
                elif item[0] == "alignment":
                    self._hear(*item[1:])
                else:
                    self._idle.set()
            except Exception:  # a failure of one step must not stop the node
                log.exception("%s: failed to handle %s", self.robot, item[0])
                self.counters["errors"] += 1

    def _take(self, source: str, read: Callable[[], MapMessage], arrived: float) -> None:
        """Check a neighbour's map message and align it, now or when its ego map comes; live
        (not lockstep), a map with a newer one of its robot already queued is skipped."""
        if self._unqueue(source) > 0 and not self.params.lockstep:
            self.counters["skipped"] += 1  # behind: the newest map of the robot counts
            return
        try:
            message = read()
            if message.sender not in self.members:
                raise MessageError("outsider", f"robot {message.sender!r} is not in the team")
        except MessageError as exc:
            self.drop(exc.reason, f"on {source}: {exc}")
            return
        self.counters["maps_received"] += 1
        if self.params.drop_share and _draw(self.params.seed, message.sender, message.seq) < \
                self.params.drop_share:
            self.counters["lost"] += 1
            return
        nb = self._neighbour(message.sender)
        if message.boot == nb.boot and message.seq <= nb.seq:
            self.drop("duplicate" if message.seq == nb.seq else "stale",
                       f"{message.sender} seq {message.seq}, latest {nb.seq}")
            return
        if message.boot != nb.boot and nb.boot is not None:
            log.info("%s: %s restarted", self.robot, message.sender)
        nb.boot, nb.seq, nb.stamp = message.boot, message.seq, message.stamp
        if not self.params.lockstep:
            if self._ego_latest is None:
                self.counters["early"] += 1  # nothing of ours to align it with yet
                return
            # the ego clock when the map arrived (not when the worker got to it), never before
            # the pair's last step: a late ego map must not turn the clock back
            seq, stamp, wall = self._ego_latest
            now = max(stamp + self.params.speed * (arrived - wall), _after(nb.clock))
            self._align(message.sender, nb, message, seq, now, self._ego[seq][1], arrived)
        elif message.seq in self._ego:
            stamp, ego_map = self._ego[message.seq]
            self._align(message.sender, nb, message, message.seq, stamp, ego_map, arrived)
        elif self._ego_latest is None or message.seq > self._ego_latest[0]:
            nb.pending[message.seq] = (message, arrived)
            while len(nb.pending) > _EGO_HISTORY:
                nb.pending.pop(min(nb.pending))
        else:
            self.drop("stale", f"{message.sender} seq {message.seq} is older than the ego "
                                f"maps kept")

    def _ego_step(self, seq: int, t: float, ego_map: ObjectMap, wall: float) -> None:
        """A new ego map: align what waited for it, step silent neighbours."""
        self._ego[seq] = (t, ego_map)
        while len(self._ego) > _EGO_HISTORY:
            self._ego.pop(min(self._ego))
        self._ego_latest = (seq, t, wall)
        for name, nb in self._neighbours.items():
            waiting = nb.pending.pop(seq, None)
            for old in [k for k in nb.pending if k < seq]:
                del nb.pending[old]
            if waiting is not None:
                message, arrived = waiting
                self._align(name, nb, message, seq, t, ego_map, arrived)
            elif nb.last_seen is None:
                nb.last_seen = t
            elif t - nb.last_seen > self.params.silence:
                self._align(name, nb, None, seq, max(t, _after(nb.clock)), ego_map)

    def _neighbour(self, name: str) -> _Neighbour:
        if name not in self._neighbours:
            self._neighbours[name] = _Neighbour(PairwiseAligner(self._aligner_params,
                                                                self._tcaff_params))
        return self._neighbours[name]

    def _align(self, name: str, nb: _Neighbour, message: MapMessage | None, seq: int, t: float,
               ego_map: ObjectMap, arrived: float | None = None) -> None:
        """One filter step of pair (robot, name) at ego time t; `message` None: a silent step.
        `arrived`: perf_counter time the neighbour's map arrived."""
        other = ObjectMap.empty() if message is None else message.object_map(t)
        try:
            estimate = nb.aligner.update(t, ego_map, other)
        except DataError as exc:  # t not after the pair's last step: nothing was changed
            self.drop("stale", f"{name}: {exc}")
            return
        nb.clock = t
        if nb.unconfirmed and estimate is not None:
            # a restarted node vouches for a saved hypothesis only once a new map of the
            # neighbour lands on it: until then it reports none
            if message is not None and estimate.measurement >= 0:
                nb.unconfirmed = False
            else:
                self.counters["withheld_restored"] += 1
                estimate = None
        if message is None:
            self.counters["silent_steps"] += 1
        else:
            nb.last_seen = t
            self.counters["aligned"] += 1
        accepted = estimate is not None
        out = AlignmentMessage(
            self.robot, self.boot, seq, t, name, max(nb.seq, 0), nb.stamp,
            nb.aligner.filter.step, estimate.hypothesis if accepted else -1, accepted,
            estimate.x if accepted else np.full(3, np.nan),
            estimate.P if accepted else np.full((3, 3), np.nan))
        self._transport.put_alignment(out)
        if arrived is not None:
            self.latencies.append(time.perf_counter() - arrived)
        self.latest[name] = out
        self._save(name, nb.aligner.filter)
        if self._on_alignment is not None:
            self._on_alignment(out)
        if self._team is not None:
            self._team_step(name, seq, t)

    # -- team consistency ---------------------------------------------------------------------

    def _hear(self, source: str, read: Callable[[], AlignmentMessage], arrived: float) -> None:
        """Keep another robot's alignment for the team consistency."""
        try:
            message = read()
            if not {message.sender, message.neighbour} <= self.members | {self.robot}:
                raise MessageError("outsider", f"pair {message.sender!r}, "
                                               f"{message.neighbour!r} is not of the team")
        except MessageError as exc:
            self.drop(exc.reason, f"on {source}: {exc}")
            return
        self.counters["alignments_heard"] += 1
        pair = (message.sender, message.neighbour)
        if message.accepted and not usable_estimates(message.x[None], message.P[None])[0]:
            # one the transports' decoders let through (they refuse it): it replaces the
            # pair's older alignment, and is forgotten with it
            self._heard.pop(pair, None)
            self._left_out(message)
            return
        self._heard[pair] = (message, arrived)

    def _team_step(self, name: str, seq: int, t: float) -> None:
        """Publish the team-consistent alignment of the pair (robot, name) just stepped, from
        the node's own latest alignments and the other robots' recent ones."""
        index = {r: k for k, r in enumerate(self._robots)}
        horizon = time.perf_counter() - self.params.silence / self.params.speed
        own = {(index[self.robot], index[b]): m for b, m in self.latest.items() if m.accepted}
        self._leave_out_unusable(own)
        estimates = {(index[a], index[b]): m for (a, b), (m, arrived) in self._heard.items()
                     if m.accepted and arrived >= horizon} | own
        i, j = index[self.robot], index[name]
        est = self._team.update(estimates, [(i, j)]).get((i, j))
        if self.latest[name].accepted and (min(i, j), max(i, j)) in self._team.rejected:
            self.counters["team_rejected"] += 1
        if est is None:
            out = TeamMessage(self.robot, self.boot, seq, t, name, (), False,
                              np.full(3, np.nan), np.full((3, 3), np.nan))
        else:
            out = TeamMessage(self.robot, self.boot, seq, t, name,
                              tuple(self._robots[k] for k in est.path[1:-1]), True, est.x, est.P)
            self.counters["team_chained"] += est.chained
        self._transport.put_team(out)
        self.team_latest[name] = out
        if self._on_team is not None:
            self._on_team(out)

    def _leave_out_unusable(self, own: dict[tuple[int, int], AlignmentMessage]) -> None:
        """Take out of the node's `own` accepted alignments what `TeamConsistency.update`
        would refuse, which would make it refuse the whole step (another robot's are checked
        once, as they arrive: `_hear`)."""
        if not own:
            return
        keys = list(own)
        usable = usable_estimates(np.array([own[k].x for k in keys], dtype=float),
                                  np.array([own[k].P for k in keys], dtype=float))
        for key in (k for k, ok in zip(keys, usable.tolist(), strict=True) if not ok):
            self._left_out(own.pop(key))

    def _left_out(self, m: AlignmentMessage) -> None:
        """Count and log an alignment the team consistency cannot take."""
        self.counters["team_unusable"] += 1
        log.warning("%s: left out the alignment of %s to %s from the team consistency: it "
                    "needs %s, got x = %s, P = %s", self.robot, m.sender, m.neighbour,
                    ESTIMATE_RULE, shown(m.x), shown(m.P))

    # -- restarts -----------------------------------------------------------------------------

    def _state_path(self, name: str) -> Path:
        return self._state_dir / f"{self.robot}-{name}.npz"

    def _save(self, name: str, tcaff: TCAFF) -> None:
        if self._saver is not None:
            self._saver.offer(self._state_path(name), tcaff.snapshot())

    def _restore(self) -> None:
        if self._state_dir is None:
            return
        try:
            self._state_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a file where the folder goes, no permission
            raise ConfigError(f"state_dir {str(self._state_dir)!r}: not a folder the node can "
                              f"save to ({exc.strerror or exc})") from None
        for name in sorted(self.members):
            path = self._state_path(name)
            if path.exists():
                try:
                    restored = TCAFF.load(path)
                except DataError as exc:
                    aside = path.with_name(path.name + ".refused")
                    path.replace(aside)
                    self.counters["restore_errors"] += 1
                    log.error("%s: the saved filter of %s was refused (%s); kept as %s, the "
                              "pair starts afresh", self.robot, name, exc, aside)
                    continue
                nb = self._neighbour(name)
                nb.aligner.filter = restored
                nb.unconfirmed = True
                log.info("%s: restored the filter of %s from %s", self.robot, name, path)


class _Saver:
    """Writes the pairs' filters on its own thread, so that a step pays for a copy of the
    state only: each file written aside and renamed (a node killed mid-write keeps the
    previous state), a pair stepped again before its file was written written once, with the
    newest state."""

    def __init__(self, robot: str, counters: Counter) -> None:
        self._robot, self._counters = robot, counters
        self._pending: dict[Path, dict[str, np.ndarray]] = {}
        self._wake = threading.Condition()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name=f"tcaff-save-{robot}",
                                        daemon=True)
        self._thread.start()

    def offer(self, path: Path, snapshot: dict[str, np.ndarray]) -> None:
        with self._wake:
            self._pending[path] = snapshot
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._pending and not self._stopping:
                    self._wake.wait()
                if not self._pending:
                    return
                batch, self._pending = self._pending, {}
            for path, snapshot in batch.items():
                partial = path.with_suffix(".partial")
                try:
                    write_snapshot(partial, snapshot)
                    os.replace(partial, path)
                    self._counters["states_saved"] += 1
                except (DataError, OSError) as exc:
                    self._counters["save_errors"] += 1
                    log.warning("%s: could not save %s: %s", self._robot, path, exc)

    def close(self, timeout: float, cancel: Callable[[], bool] | None) -> bool:
        """Write what is pending, then stop: within `timeout` s, or until `cancel()` is true
        (asked every 0.05 s). False: not all written then (the thread is left to the
        process's exit; a file it is writing is renamed into place only once whole)."""
        with self._wake:
            self._stopping = True
            self._wake.notify()
        return _until(lambda s: _joined(self._thread, s), timeout, cancel)


#: s the saver gets to end in `RobotNode.finish` whatever is left of its timeout
_SAVER_LEAST = 0.1
#: s between two questions to a wait's `cancel`
_CANCEL_POLL = 0.05


def _until(done: Callable[[float | None], bool], timeout: float,
           cancel: Callable[[], bool] | None = None) -> bool:
    """Call `done(s)`, a wait of at most s seconds (None: no limit, as the waits of `queue`
    and `threading` take it) that returns whether its thing happened, until it does (True),
    `timeout` s have passed or `cancel()` is true (False). With `cancel` the waits are at
    most `_CANCEL_POLL` s each: a signal handler cannot end a wait, it can only make `cancel`
    true."""
    deadline = time.monotonic() + max(timeout, 0.0)
    while True:
        left = max(deadline - time.monotonic(), 0.0)
        wait = left if cancel is None else min(left, _CANCEL_POLL)
        if done(None if wait == math.inf else wait):
            return True
        if left <= 0.0 or (cancel is not None and cancel()):
            return False


def _put(inbox: queue.Queue, item, timeout: float | None) -> bool:
    """Put `item` in `inbox` if a place frees within `timeout` s (0: only if one is free;
    None: whenever one does)."""
    try:
        inbox.put(item, timeout=timeout)
        return True
    except queue.Full:
        return False


def _joined(thread: threading.Thread, timeout: float | None) -> bool:
    """Whether `thread` ended within `timeout` s (None: it is waited for)."""
    thread.join(timeout)
    return not thread.is_alive()


def _after(t: float | None) -> float:
    """The first time after `t` (-inf for None)."""
    return -np.inf if t is None else float(np.nextafter(t, np.inf))


def _draw(seed: int, sender: str, seq: int) -> float:
    """A number in [0, 1) fixed by (seed, sender, seq): the same in every process and run."""
    digest = hashlib.blake2b(f"{seed}/{sender}/{seq}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") / 2.0**64
