"""A multi-object tracker of points on the floor plane, for people seen by several robots.

Each track is a constant-velocity Kalman filter with state (x, y, vx, vy) in the tracking
robot's odometry frame. A frame brings one set of detections per source (the robot's own, then
each neighbour's, already moved into this frame); each set is associated with the tracks by
global nearest neighbour (the Hungarian method on the negative log-likelihood d^2 + ln|S|,
gated on the squared Mahalanobis distance d^2) and applied in turn, so one person seen by
three robots updates one track three times. Unassigned detections start tentative tracks. A
track is reported once it has had a detection in `confirm_hits` frames; a tentative track dies
after `tentative_misses` frames in a row without one, a confirmed track after `max_coast`
seconds without one.

All tracks live in arrays (state (n, 4), covariance (n, 4, 4), counters (n,)), so prediction,
gating and updates are vectorised over tracks and detections.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

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
        _require(_real(self.gate) and self.gate > 0, o, "gate", self.gate, "must be a number > 0")
        for name in ("confirm_hits", "tentative_misses"):
            value = getattr(self, name)
            _require(_int_at_least(value, 1), o, name, value, "must be an int >= 1")
        _require(_real(self.max_coast) and self.max_coast >= 0, o, "max_coast", self.max_coast,
                 "must be a number >= 0 seconds")


_H = np.eye(2, 4)
_FAR = 1e12  # the cost of a pair outside the gate; linear_sum_assignment needs finite costs


class MultiObjectTracker:
    """Constant-velocity Kalman tracks, Hungarian GNN association, confirmation and deletion.

    Call `step` once per frame with the frame's time and detection sets; it returns the
    confirmed tracks.

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
        # imported here, not with the module: configs import this module for TrackerParams
        from scipy.optimize import linear_sum_assignment

        self._assign = linear_sum_assignment
        r = self.params.detection_noise ** 2
        self._R = r * np.eye(2)
        v = self.params.initial_speed ** 2
        self._P0 = np.diag([r, r, v, v])

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
        self._predict(0.0 if self.time is None else t - self.time)
        self.time = t
        hit = np.zeros(len(self), dtype=bool)
        for z in sets:
            if len(z) == 0:
                continue
            tracks, dets = self._associate(z)
            self._update(tracks, z[dets])
            hit[tracks] = True
            new = np.ones(len(z), dtype=bool)
            new[dets] = False
            self._spawn(z[new], t)
            hit = np.concatenate([hit, np.ones(int(new.sum()), dtype=bool)])
        if len(self):
            self._bookkeep(hit, t)
        return self.ids[self.confirmed], self.x[self.confirmed, :2].copy()

    def _predict(self, dt: float) -> None:
        if dt == 0.0 or len(self) == 0:
            return
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.params.accel_noise ** 2
        Q = np.zeros((4, 4))
        Q[[0, 1], [0, 1]] = q * dt**4 / 4
        Q[[0, 1, 2, 3], [2, 3, 0, 1]] = q * dt**3 / 2
        Q[[2, 3], [2, 3]] = q * dt**2
        self.x = self.x @ F.T
        self.P = F @ self.P @ F.T + Q

    def _associate(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(tracks (a,), detections (a,)) assigned pairs within the gate."""
        if len(self) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        S_inv, det = _inverse_2x2(self.P[:, :2, :2] + self._R)
        diff = z[None, :, :] - self.x[:, None, :2]                  # (n, k, 2)
        d2 = np.einsum("nki,nij,nkj->nk", diff, S_inv, diff)
        inside = d2 <= self.params.gate
        # The negative log-likelihood, not d2 alone: otherwise a new, uncertain track wins a
        # detection from the settled track of the same person and the person gets two tracks.
        cost = d2 + np.log(det)[:, None]
        rows, cols = self._assign(np.where(inside, cost, _FAR))
        keep = inside[rows, cols]
        return rows[keep], cols[keep]

    def _update(self, tracks: np.ndarray, z: np.ndarray) -> None:
        if len(tracks) == 0:
            return
        P = self.P[tracks]
        K = P[:, :, :2] @ _inverse_2x2(P[:, :2, :2] + self._R)[0]  # (a, 4, 2)
        innovation = z - self.x[tracks, :2]
        self.x[tracks] += np.einsum("aij,aj->ai", K, innovation)
        self.P[tracks] = P - K @ P[:, :2, :]

    def _spawn(self, z: np.ndarray, t: float) -> None:
        k = len(z)
        if k == 0:
            return
        self.x = np.vstack([self.x, np.column_stack([z, np.zeros((k, 2))])])
        self.P = np.concatenate([self.P, np.broadcast_to(self._P0, (k, 4, 4))])
        self.ids = np.concatenate([self.ids, self._next_id + np.arange(k)])
        self._next_id += k
        zeros = np.zeros(k, dtype=np.int64)
        self.hits = np.concatenate([self.hits, zeros])
        self.misses = np.concatenate([self.misses, zeros])
        self.last_hit = np.concatenate([self.last_hit, np.full(k, t)])
        self.confirmed = np.concatenate([self.confirmed, zeros.astype(bool)])

    def _bookkeep(self, hit: np.ndarray, t: float) -> None:
        prm = self.params
        self.hits += hit
        self.misses = np.where(hit, 0, self.misses + 1)
        self.last_hit = np.where(hit, t, self.last_hit)
        self.confirmed |= self.hits >= prm.confirm_hits
        # the tolerance keeps a gap of exactly max_coast on a clock like 0.2 k from being
        # deleted or kept by rounding
        dead = np.where(self.confirmed, t - self.last_hit > prm.max_coast + 1e-9,
                        self.misses >= prm.tentative_misses)
        if dead.any():
            keep = ~dead
            self.x, self.P, self.ids = self.x[keep], self.P[keep], self.ids[keep]
            self.hits, self.misses = self.hits[keep], self.misses[keep]
            self.last_hit, self.confirmed = self.last_hit[keep], self.confirmed[keep]


def _inverse_2x2(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses (n, 2, 2) and determinants (n,) of symmetric positive definite (n, 2, 2)
    matrices, in closed form (numpy's batched inverse costs more for 2 x 2)."""
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    inv = np.empty_like(S)
    inv[:, 0, 0], inv[:, 1, 1] = d / det, a / det
    inv[:, 0, 1] = inv[:, 1, 0] = -b / det
    return inv, det


def _checked(z, source: int) -> np.ndarray:
    z = np.asarray(z, dtype=float)
    if z.shape == (0,):
        return np.zeros((0, 2))
    if z.ndim != 2 or z.shape[1] != 2:
        raise DataError(f"tracker step: detections[{source}] must be (k, 2), got {z.shape}")
    if not np.all(np.isfinite(z)):
        raise DataError(f"tracker step: detections[{source}] holds non-finite values")
    return z
