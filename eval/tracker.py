"""A multi-object tracker of points on the floor plane, for people seen by several robots.

Each track is a constant-velocity Kalman filter with state (x, y, vx, vy) in the tracking
robot's odometry frame. A frame brings one set of detections per source (the robot's own, then
each neighbour's, already moved into this frame); each set is associated with the tracks by
global nearest neighbour (an optimal assignment on the negative log-likelihood d^2 + ln|S|,
gated on the squared Mahalanobis distance d^2) and applied in turn, so one person seen by
three robots updates one track three times. Unassigned detections start tentative tracks. A
track is reported once it has had a detection in `confirm_hits` frames; a tentative track dies
after `tentative_misses` frames in a row without one, a confirmed track after `max_coast`
seconds without one.

All tracks live in arrays (state (n, 4), covariance (n, 4, 4), counters (n,)), and a frame is
one compiled pass over them: the tracker runs once per frame, robot and method in a study,
where numpy's per-call overhead on a handful of tracks was most of its time. `run` steps
through a whole run's frames in one compiled call (the same tracks as a `step` per frame).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.params import _int_at_least, _real, _require

__all__ = ["MultiObjectTracker", "TrackerParams"]

@dataclass(frozen=True)
class TrackerParams:
    """Settings of `tracker.MultiObjectTracker`, the tracker each robot runs on its own and its
    neighbours' detections.

    Attributes:
        accel_noise: m/s^2, std of the white acceleration that drives the constant-velocity
            model.
        detection_noise: metres, the detection std per axis the filter assumes (own and
            neighbours' detections alike).
        initial_speed: m/s, velocity std of a new track.
        gate: squared Mahalanobis distance beyond which a detection cannot update a track
            (9.21: 99 % for 2 degrees of freedom).
        confirm_hits: frames with a detection before a track is reported.
        tentative_misses: frames in a row without a detection that delete an unconfirmed track.
        max_coast: seconds; a confirmed track without a detection for longer is deleted
            (math.inf keeps it).
    """

    accel_noise: float = 1.5
    detection_noise: float = 0.3
    initial_speed: float = 1.5
    gate: float = 9.21
    confirm_hits: int = 3
    tentative_misses: int = 1
    max_coast: float = 1.0

    def __post_init__(self) -> None:
        o = "TrackerParams"
        for name, unit in (("accel_noise", "m/s^2"), ("detection_noise", "metres"),
                           ("initial_speed", "m/s")):
            value = getattr(self, name)
            _require(_real(value) and 0 < value < math.inf, o, name, value,
                     f"must be a finite number > 0 {unit}")
        _require(_real(self.gate) and 0 < self.gate < math.inf, o, "gate", self.gate,
                 "must be a finite number > 0")
        for name in ("confirm_hits", "tentative_misses"):
            value = getattr(self, name)
            _require(_int_at_least(value, 1), o, name, value, "must be an int >= 1")
        _require(_real(self.max_coast) and self.max_coast >= 0, o, "max_coast", self.max_coast,
                 "must be a number >= 0 seconds")


class MultiObjectTracker:
    """Constant-velocity Kalman tracks, global nearest neighbour association, confirmation and
    deletion.

    Call `step` once per frame with the frame's time and detection sets; it returns the
    confirmed tracks. A frame is one compiled pass (`_advance`) over the tracks in arrays.

    Args:
        params: `TrackerParams` (None: the defaults).
    """

    def __init__(self, params: TrackerParams | None = None) -> None:
        self.params = TrackerParams() if params is None else params
        _require(isinstance(self.params, TrackerParams), "MultiObjectTracker", "params", params,
                 "must be a TrackerParams")
        self.x = np.zeros((0, 4))        # (n, 4) x, y [m], vx, vy [m/s]
        self.P = np.zeros((0, 4, 4))
        self.ids = np.zeros(0, dtype=np.int64)
        self.hits = np.zeros(0, dtype=np.int64)       # frames with a detection
        self.misses = np.zeros(0, dtype=np.int64)     # frames in a row without one
        self.last_hit = np.zeros(0)                    # s
        self.confirmed = np.zeros(0, dtype=bool)
        self.time: float | None = None
        self._next_id = 0

    def __len__(self) -> int:
        return len(self.ids)

    def step(self, t: float, detections: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Advance to time `t` and apply each detection set in order.

        Args:
            t: seconds, not before the previous step's.
            detections: per source, (k, 2) metres in the tracking frame (k may be 0).
        Returns:
            ids (m,) and positions (m, 2) of the confirmed tracks after this frame.
        Raises:
            DataError: time going backwards, or a detection set of the wrong shape or with
                non-finite values.
        """
        sets = [_checked(z, k) for k, z in enumerate(detections)]
        if not np.isfinite(t) or (self.time is not None and t < self.time):
            raise DataError(f"tracker step: time must be finite and not before {self.time} s, "
                            f"got {t}")
        z = np.concatenate(sets) if sets else np.zeros((0, 2))
        bounds = np.zeros(len(sets) + 1, dtype=np.int64)
        bounds[1:] = np.cumsum([len(s) for s in sets])
        prm = self.params
        t = float(t)
        (self.x, self.P, self.ids, self.hits, self.misses, self.last_hit, self.confirmed,
         self._next_id) = _advance(
            self.x, self.P, self.ids, self.hits, self.misses, self.last_hit, self.confirmed,
            self._next_id, 0.0 if self.time is None else t - self.time, t, z, bounds,
            float(prm.accel_noise) ** 2, float(prm.detection_noise) ** 2,
            float(prm.initial_speed) ** 2, float(prm.gate), int(prm.confirm_hits),
            int(prm.tentative_misses), float(prm.max_coast))
        self.time = t
        return self.ids[self.confirmed], self.x[self.confirmed, :2]

    def run(self, times: np.ndarray, detections: np.ndarray, bounds: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`step` at each of F frames, in one compiled call: the same tracks, ids and states as
        F calls of `step` with the same sets.

        Args:
            times: (F,) seconds, non-decreasing and not before the previous step's.
            detections: (D, 2) metres in the tracking frame, every frame's sets one after
                another, frame after frame.
            bounds: (F, S + 1) int; set s of frame f is detections[bounds[f, s]:bounds[f, s + 1]]
                (empty sets allowed), and frame f + 1 starts where frame f ends.
        Returns:
            ids (T,) and positions (T, 2) of the confirmed tracks after each frame, frame after
            frame, and starts (F + 1,): frame f's are rows starts[f]:starts[f + 1].
        Raises:
            DataError: times not finite or going backwards, detections not (D, 2) finite, or
                bounds not (F, S + 1) consecutive ranges covering the D detections.
        """
        times = np.ascontiguousarray(times, dtype=float)
        z = np.ascontiguousarray(detections, dtype=float)
        bounds = np.ascontiguousarray(bounds, dtype=np.int64)
        n_frames = times.shape[0]
        if times.ndim != 1 or not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0) or (
                n_frames and self.time is not None and times[0] < self.time):
            raise DataError(f"tracker run: times must be (F,) finite, non-decreasing and not "
                            f"before {self.time} s")
        if z.ndim != 2 or z.shape[1] != 2 or not np.all(np.isfinite(z)):
            raise DataError(f"tracker run: detections must be (D, 2) finite, got {z.shape}")
        if (bounds.ndim != 2 or bounds.shape[0] != n_frames or bounds.shape[1] < 1
                or np.any(np.diff(bounds, axis=1) < 0)
                or not np.array_equal(bounds[1:, 0], bounds[:-1, -1])
                or (n_frames and (bounds[0, 0] != 0 or bounds[-1, -1] != z.shape[0]))):
            raise DataError(f"tracker run: bounds must be ({n_frames}, S + 1) consecutive "
                            f"ranges over the {z.shape[0]} detections, got {bounds.shape}")
        if n_frames == 0:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros(1, dtype=np.int64)
        prm = self.params
        (self.x, self.P, self.ids, self.hits, self.misses, self.last_hit, self.confirmed,
         self._next_id, ids, xy, starts) = _run(
            self.x, self.P, self.ids, self.hits, self.misses, self.last_hit, self.confirmed,
            self._next_id, np.nan if self.time is None else self.time, times, z, bounds,
            float(prm.accel_noise) ** 2, float(prm.detection_noise) ** 2,
            float(prm.initial_speed) ** 2, float(prm.gate), int(prm.confirm_hits),
            int(prm.tentative_misses), float(prm.max_coast))
        self.time = float(times[-1])
        return ids, xy, starts


@numba.njit(cache=True)
def _run(x, P, ids, hits, misses, last_hit, confirmed, next_id, previous, times, z, bounds,
         q, r, v0, gate, confirm_hits, tentative_misses, max_coast):  # pragma: no cover
    """`MultiObjectTracker.run`: `_advance` at each frame f of times (F,) with the sets
    z[bounds[f, s]:bounds[f, s + 1]], from the tracks given (the previous step at `previous`
    seconds, NaN for none).

    Returns:
        the track arrays and next_id after the last frame (as `_advance`), then the ids (T,)
        and xy (T, 2) metres of the confirmed tracks after each frame and starts (F + 1,).
    """
    n_frames = times.shape[0]
    capacity = 16 * n_frames + 16
    out_ids = np.empty(capacity, np.int64)
    out_xy = np.empty((capacity, 2))
    starts = np.zeros(n_frames + 1, np.int64)
    count = 0
    for f in range(n_frames):
        t = times[f]
        dt = 0.0 if np.isnan(previous) else t - previous
        first, last = bounds[f, 0], bounds[f, bounds.shape[1] - 1]
        (x, P, ids, hits, misses, last_hit, confirmed, next_id) = _advance(
            x, P, ids, hits, misses, last_hit, confirmed, next_id, dt, t, z[first:last],
            bounds[f] - first, q, r, v0, gate, confirm_hits, tentative_misses, max_coast)
        previous = t
        if count + ids.shape[0] > capacity:
            capacity = 2 * (count + ids.shape[0])
            grown_ids = np.empty(capacity, np.int64)
            grown_xy = np.empty((capacity, 2))
            for k in range(count):
                grown_ids[k] = out_ids[k]
                grown_xy[k, 0], grown_xy[k, 1] = out_xy[k, 0], out_xy[k, 1]
            out_ids, out_xy = grown_ids, grown_xy
        for i in range(ids.shape[0]):
            if confirmed[i]:
                out_ids[count] = ids[i]
                out_xy[count, 0], out_xy[count, 1] = x[i, 0], x[i, 1]
                count += 1
        starts[f + 1] = count
    return (x, P, ids, hits, misses, last_hit, confirmed, next_id, out_ids[:count],
            out_xy[:count], starts)


@numba.njit(cache=True)
def _advance(x, P, ids, hits, misses, last_hit, confirmed, next_id, dt, t, z, bounds,
             q, r, v0, gate, confirm_hits, tentative_misses, max_coast):  # pragma: no cover
    """One frame of `MultiObjectTracker.step` on its arrays: predict by dt seconds, associate
    and apply each detection set z[bounds[s]:bounds[s + 1]] in turn, spawn tracks from the
    unassigned detections, then confirm and delete.

    Args:
        x (n, 4), P (n, 4, 4), ids, hits, misses (n,) int64, last_hit (n,) s, confirmed (n,)
            bool: the tracks; next_id: the id of the next new track.
        z: (D, 2) metres, every set's detections one set after another; bounds (S + 1,).
        q: (m/s^2)^2 acceleration variance; r: m^2 detection variance per axis; v0: (m/s)^2
            velocity variance of a new track.
    Returns:
        the new track arrays (as the arguments, fresh) and next_id.
    """
    n = x.shape[0]
    cap = n + z.shape[0]
    X = np.empty((cap, 4))
    C = np.empty((cap, 4, 4))
    out_ids = np.empty(cap, np.int64)
    out_hits = np.empty(cap, np.int64)
    out_misses = np.empty(cap, np.int64)
    out_last = np.empty(cap)
    out_conf = np.empty(cap, np.bool_)
    for i in range(n):
        out_ids[i], out_hits[i], out_misses[i] = ids[i], hits[i], misses[i]
        out_last[i], out_conf[i] = last_hit[i], confirmed[i]
        _predict(x[i], P[i], dt, q, X[i], C[i])
    hit = np.zeros(cap, np.bool_)
    for s in range(bounds.size - 1):
        k = bounds[s + 1] - bounds[s]
        if k == 0:
            continue
        zs = z[bounds[s]:bounds[s + 1]]
        taken = np.zeros(k, np.bool_)
        if n > 0:
            det_of_track = _associate(X[:n], C[:n], zs, r, gate)
            for i in range(n):
                j = det_of_track[i]
                if j >= 0:
                    _kalman_update(X[i], C[i], zs[j], r)
                    hit[i] = True
                    taken[j] = True
        for j in range(k):
            if taken[j]:
                continue
            X[n, 0], X[n, 1], X[n, 2], X[n, 3] = zs[j, 0], zs[j, 1], 0.0, 0.0
            for a in range(4):
                for b in range(4):
                    C[n, a, b] = 0.0 if a != b else (r if a < 2 else v0)
            out_ids[n] = next_id
            next_id += 1
            out_hits[n] = out_misses[n] = 0
            out_last[n] = t
            out_conf[n] = False
            hit[n] = True
            n += 1
    kept = 0
    for i in range(n):
        if hit[i]:
            out_hits[i] += 1
            out_misses[i] = 0
            out_last[i] = t
        else:
            out_misses[i] += 1
        out_conf[i] = out_conf[i] or out_hits[i] >= confirm_hits
        # the tolerance keeps a gap of exactly max_coast on a clock like 0.2 k from being
        # deleted or kept by rounding
        if out_conf[i]:
            dead = t - out_last[i] > max_coast + 1e-9
        else:
            dead = out_misses[i] >= tentative_misses
        if dead:
            continue
        if kept < i:
            for a in range(4):
                X[kept, a] = X[i, a]
                for b in range(4):
                    C[kept, a, b] = C[i, a, b]
            out_ids[kept], out_hits[kept], out_misses[kept] = out_ids[i], out_hits[i], out_misses[i]
            out_last[kept], out_conf[kept] = out_last[i], out_conf[i]
        kept += 1
    return (X[:kept], C[:kept], out_ids[:kept], out_hits[:kept], out_misses[:kept],
            out_last[:kept], out_conf[:kept], next_id)


@numba.njit(cache=True)
def _predict(x, P, dt, q, x_out, P_out):  # pragma: no cover
    """The constant-velocity prediction of one track (4,), (4, 4) by dt seconds into x_out,
    P_out: F = [[I, dt I], [0, I]], Q of white acceleration of variance q. Plain loops: array
    expressions cost seconds of compilation."""
    FP = np.empty((4, 4))
    for a in range(4):
        x_out[a] = x[a] + dt * x[a + 2] if a < 2 else x[a]
        for b in range(4):
            FP[a, b] = P[a, b] + dt * P[a + 2, b] if a < 2 else P[a, b]
    for a in range(4):
        for b in range(4):
            P_out[a, b] = FP[a, b] + dt * FP[a, b + 2] if b < 2 else FP[a, b]
    dt2 = dt * dt
    for a in range(2):
        P_out[a, a] += q * dt2 * dt2 / 4.0
        P_out[a, a + 2] += q * dt2 * dt / 2.0
        P_out[a + 2, a] += q * dt2 * dt / 2.0
        P_out[a + 2, a + 2] += q * dt2


@numba.njit(cache=True)
def _associate(x, P, z, r, gate):  # pragma: no cover
    """(n,) the detection of z (k, 2) each track of x (n, 4), P (n, 4, 4) takes, -1 for none.

    Global nearest neighbour: the assignment of least total negative log-likelihood
    d^2 + ln|S| (S = P_xy + r I) among those with the most pairs inside the gate d^2 <= gate;
    pairs outside it are never returned. The log-likelihood, not d^2 alone: otherwise a new,
    uncertain track wins a detection from the settled track of the same person and the person
    gets two tracks."""
    n, k = x.shape[0], z.shape[0]
    cost = np.empty((n, k))
    inside = np.zeros((n, k), np.bool_)
    lo, hi = np.inf, -np.inf
    for i in range(n):
        s00, s01, s11, det = _innovation_inverse(P[i], r)
        log_det = np.log(det)
        for j in range(k):
            ex, ey = z[j, 0] - x[i, 0], z[j, 1] - x[i, 1]
            d2 = s00 * ex * ex + 2.0 * s01 * ex * ey + s11 * ey * ey
            # a track or detection so far out that its numbers overflow is outside the gate
            if d2 <= gate and np.isfinite(d2 + log_det):
                inside[i, j] = True
                cost[i, j] = d2 + log_det
                lo, hi = min(lo, cost[i, j]), max(hi, cost[i, j])
    det_of_track = -np.ones(n, np.int64)
    if hi < lo:  # nothing inside the gate
        return det_of_track
    # outside the gate costs more than any number of inside pairs can make up: among the
    # assignments with the most pairs inside, the cheapest
    far = hi + min(n, k) * (hi - lo) + 1.0
    for i in range(n):
        for j in range(k):
            if not inside[i, j]:
                cost[i, j] = far
    if n <= k:
        col = _min_cost_assignment(cost)
        for i in range(n):
            if inside[i, col[i]]:
                det_of_track[i] = col[i]
    else:
        row = _min_cost_assignment(np.ascontiguousarray(cost.T))
        for j in range(k):
            if inside[row[j], j]:
                det_of_track[row[j]] = j
    return det_of_track


@numba.njit(cache=True)
def _min_cost_assignment(cost):  # pragma: no cover
    """(r,) the column of each row in an assignment of least total cost of a finite (r, c)
    matrix with r <= c: shortest augmenting paths with dual potentials (Jonker and
    Volgenant), one row at a time."""
    nr, nc = cost.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    col_of_row = -np.ones(nr, np.int64)
    row_of_col = -np.ones(nc, np.int64)
    shortest = np.empty(nc)
    path = np.empty(nc, np.int64)
    remaining = np.empty(nc, np.int64)
    row_seen = np.empty(nr, np.bool_)
    col_seen = np.empty(nc, np.bool_)
    for start in range(nr):
        for i in range(nr):
            row_seen[i] = False
        for j in range(nc):
            shortest[j] = np.inf
            col_seen[j] = False
            remaining[j] = nc - 1 - j  # the order scipy scans in: equal costs are split alike
        n_left = nc
        i, sink, reach = start, -1, 0.0
        while sink < 0:
            row_seen[i] = True
            best, best_at = np.inf, -1
            for m in range(n_left):
                j = remaining[m]
                through = reach + cost[i, j] - u[i] - v[j]
                if through < shortest[j]:
                    path[j] = i
                    shortest[j] = through
                # ties go to a free column: the path ends sooner
                if shortest[j] < best or (shortest[j] == best and row_of_col[j] < 0):
                    best, best_at = shortest[j], m
            reach = best
            j = remaining[best_at]
            col_seen[j] = True
            n_left -= 1
            remaining[best_at] = remaining[n_left]
            if row_of_col[j] < 0:
                sink = j
            else:
                i = row_of_col[j]
        u[start] += reach
        for i in range(nr):
            if row_seen[i] and i != start:
                u[i] += reach - shortest[col_of_row[i]]
        for j in range(nc):
            if col_seen[j]:
                v[j] -= reach - shortest[j]
        j = sink
        while True:  # augment along the path back to the start row
            i = path[j]
            row_of_col[j] = i
            col_of_row[i], j = j, col_of_row[i]
            if i == start:
                break
    return col_of_row


@numba.njit(cache=True)
def _innovation_inverse(P, r):  # pragma: no cover
    """(S^-1 00, 01, 11, |S|) of a track's innovation covariance S = P[:2, :2] + r I."""
    a, b, d = P[0, 0] + r, P[0, 1], P[1, 1] + r
    det = a * d - b * b
    return d / det, -b / det, a / det, det


@numba.njit(cache=True)
def _kalman_update(x, P, z, r):  # pragma: no cover
    """The Kalman update of one track (4,), (4, 4) in place with a position z (2,) of
    variance r per axis."""
    s00, s01, s11, _ = _innovation_inverse(P, r)
    K = np.empty((4, 2))
    for row in range(4):
        K[row, 0] = P[row, 0] * s00 + P[row, 1] * s01
        K[row, 1] = P[row, 0] * s01 + P[row, 1] * s11
    ex, ey = z[0] - x[0], z[1] - x[1]
    for row in range(4):
        x[row] += K[row, 0] * ex + K[row, 1] * ey
    top = np.empty((2, 4))
    for row in range(2):
        for col in range(4):
            top[row, col] = P[row, col]
    for row in range(4):
        for col in range(4):
            P[row, col] -= K[row, 0] * top[0, col] + K[row, 1] * top[1, col]


def _checked(z, source: int) -> np.ndarray:
    z = np.asarray(z, dtype=float)
    if z.shape == (0,):
        return np.zeros((0, 2))
    if z.ndim != 2 or z.shape[1] != 2:
        raise DataError(f"tracker step: detections[{source}] must be (k, 2), got {z.shape}")
    if not np.all(np.isfinite(z)):
        raise DataError(f"tracker step: detections[{source}] holds non-finite values")
    return z
