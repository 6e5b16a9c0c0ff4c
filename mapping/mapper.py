"""ObjectMapper: tracks per-frame object observations into a robot's sparse object map.

This is the paper's mapping step: each frame's observations (centroid, width, height in the
robot's odometry frame) are associated to tracks by global nearest neighbour; a track is
confirmed, and appears in the map, after `nu` sightings and is removed after `kappa` seconds
unseen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.object_map import ObjectMap, object_arrays
from tcaff_gtsam.params import FrameAlignerParams, _int_at_least, _real, _require

__all__ = ["MapperParams", "ObjectMapper"]

# Sizes are compared by log ratio; a zero width or height (a flat or degenerate segment) would
# give an infinite ratio, so sizes are floored at 1 mm for comparison only.
_SIZE_FLOOR = 1e-3
# Slack on the size gate so that a ratio of exactly `size_gate` passes despite rounding in log.
_LOG_TOL = 1e-12


@dataclass(frozen=True)
class MapperParams:
    """Settings of `ObjectMapper`.

    Attributes:
        nu: sightings (hits) before a track is confirmed and appears in the map.
        kappa: seconds; a track unseen for longer than kappa (t - last_seen > kappa) is
            removed. math.inf keeps tracks forever. The default is the frame aligner's
            (`FrameAlignerParams.kappa`, the paper's 20 s): the map holds what it aligns.
        gate: metres; largest 3D centroid distance between an observation and a track it may
            be associated with.
        size_gate: largest ratio larger / smaller of width, and of height, for an association
            or a merge (>= 1).
        size_weight: metres of association cost per unit of |log(size ratio)|, summed over
            width and height.
        max_average: centroid and sizes are running means over at most this many hits (update
            weight 1 / min(hits, max_average)), so a track follows odometry drift.
        merge_distance: metres; after each update, tracks (confirmed or not) closer than this
            with sizes within `size_gate` are merged into the one with the lower id. 0 disables
            merging.
        tentative_timeout: seconds; a track not yet confirmed that is unseen for longer than
            this is removed, so scattered false segments do not pile up hits over kappa
            seconds. math.inf keeps tentative tracks as long as confirmed ones.
    """

    nu: int = 3
    kappa: float = FrameAlignerParams.kappa
    gate: float = 1.0
    size_gate: float = 2.0
    size_weight: float = 0.5
    max_average: int = 10
    merge_distance: float = 0.3
    tentative_timeout: float = 1.0

    def __post_init__(self) -> None:
        o = "MapperParams"
        _require(_int_at_least(self.nu, 1), o, "nu", self.nu, "must be an int >= 1")
        _require(_real(self.kappa) and self.kappa > 0, o, "kappa", self.kappa,
                 "must be a number > 0 seconds")
        _require(_real(self.gate) and math.isfinite(self.gate) and self.gate > 0, o, "gate",
                 self.gate, "must be a finite number > 0 metres")
        _require(_real(self.size_gate) and math.isfinite(self.size_gate) and self.size_gate >= 1,
                 o, "size_gate", self.size_gate, "must be a finite number >= 1")
        _require(_real(self.size_weight) and math.isfinite(self.size_weight)
                 and self.size_weight >= 0, o, "size_weight", self.size_weight,
                 "must be a finite number >= 0")
        _require(_int_at_least(self.max_average, 1), o, "max_average", self.max_average,
                 "must be an int >= 1")
        _require(_real(self.merge_distance) and math.isfinite(self.merge_distance)
                 and self.merge_distance >= 0, o, "merge_distance", self.merge_distance,
                 "must be a finite number >= 0 metres")
        _require(_real(self.tentative_timeout) and self.tentative_timeout > 0, o,
                 "tentative_timeout", self.tentative_timeout, "must be a number > 0 seconds")


def _log_size(sizes: np.ndarray) -> np.ndarray:
    return np.log(np.maximum(sizes, _SIZE_FLOOR))


class ObjectMapper:
    """Tracks object observations over frames into one robot's object map.

    All positions are in the robot's odometry frame (metres, z up); times are seconds on the
    robot's clock. Tracks are kept as parallel arrays sorted by track id; ids come from a
    counter and are never reused.
    """

    def __init__(self, params: MapperParams | None = None) -> None:
        if params is None:
            params = MapperParams()
        if not isinstance(params, MapperParams):
            raise ConfigError(f"ObjectMapper.params = {params!r}: must be a MapperParams")
        self.params = params
        self._log_size_gate = math.log(params.size_gate) + _LOG_TOL
        self._ids = np.zeros(0, dtype=np.int64)
        self._centroids = np.zeros((0, 3))
        self._widths = np.zeros(0)
        self._heights = np.zeros(0)
        self._hits = np.zeros(0, dtype=np.int64)
        self._last_seen = np.zeros(0)
        self._next_id = 0
        self._t_last: float | None = None

    def __len__(self) -> int:
        """Number of live tracks, confirmed or not."""
        return self._ids.shape[0]

    def __repr__(self) -> str:
        return f"ObjectMapper(tracks={len(self)}, confirmed={int(self._confirmed().sum())})"

    # -----------------------------------------------------------------------------------------
    # public API

    def update(self, t: float, centroids, widths, heights) -> np.ndarray:
        """Add one frame of observations.

        Args:
            t: seconds, time of the frame; finite and not earlier than the previous update's.
            centroids: (k, 3) metres, observed object centroids in the odometry frame.
            widths: (k,) metres, horizontal extents, >= 0.
            heights: (k,) metres, vertical extents, >= 0.

        Returns:
            (k,) int64, the id of the track each observation was assigned to (after merging);
            distinct, since two observations of one frame are never merged.

        Raises:
            DataError: on a bad time stamp or bad observation arrays (nothing is changed).
        """
        t, C, W, H = self._validate(t, centroids, widths, heights)
        self._t_last = t
        self._forget(t)
        rows = self._associate(C, W, H)

        assigned = rows >= 0
        tr = rows[assigned]
        self._hits[tr] += 1
        weight = 1.0 / np.minimum(self._hits[tr], self.params.max_average)
        self._centroids[tr] += weight[:, None] * (C[assigned] - self._centroids[tr])
        self._widths[tr] += weight * (W[assigned] - self._widths[tr])
        self._heights[tr] += weight * (H[assigned] - self._heights[tr])
        self._last_seen[tr] = t

        touched = np.zeros(len(self), dtype=bool)
        touched[tr] = True
        new = ~assigned
        n_new = int(new.sum())
        if n_new:
            n_old = len(self)
            rows[new] = np.arange(n_old, n_old + n_new)
            new_ids = np.arange(self._next_id, self._next_id + n_new, dtype=np.int64)
            self._next_id += n_new
            self._ids = np.concatenate([self._ids, new_ids])
            self._centroids = np.concatenate([self._centroids, C[new]])
            self._widths = np.concatenate([self._widths, W[new]])
            self._heights = np.concatenate([self._heights, H[new]])
            self._hits = np.concatenate([self._hits, np.ones(n_new, dtype=np.int64)])
            self._last_seen = np.concatenate([self._last_seen, np.full(n_new, t)])
            touched = np.concatenate([touched, np.ones(n_new, dtype=bool)])

        out = self._ids[rows]  # int64, and fancy indexing copies
        self._merge(touched, out)
        return out

    def object_map(self) -> ObjectMap:
        """The confirmed tracks (hits >= nu) as an `ObjectMap` in the odometry frame, rows in
        increasing track id (the order of `confirmed_ids`)."""
        m = self._confirmed()
        return ObjectMap(self._centroids[m], self._widths[m], self._heights[m],
                         self._last_seen[m])

    def confirmed_ids(self) -> np.ndarray:
        """(n,) int64 track ids of the rows of `object_map()`, increasing."""
        return self._ids[self._confirmed()].copy()

    # -----------------------------------------------------------------------------------------
    # steps of update

    def _confirmed(self) -> np.ndarray:
        return self._hits >= self.params.nu

    def _validate(self, t, centroids, widths, heights):
        o = "ObjectMapper.update"
        if not _real(t):
            raise DataError(f"{o}: t must be a number, got {t!r}")
        t = float(t)
        if not math.isfinite(t):
            raise DataError(f"{o}: t must be finite, got {t}")
        if self._t_last is not None and t < self._t_last:
            raise DataError(f"{o}: t = {t} is earlier than the previous update's "
                            f"t = {self._t_last}")
        arrays = object_arrays(f"{o}: ", centroids, widths, heights)
        C = arrays["centroids"]
        return t, C, arrays["widths"], arrays["heights"]

    def _forget(self, t: float) -> None:
        unseen = t - self._last_seen
        keep = (unseen <= self.params.kappa) & (
            self._confirmed() | (unseen <= self.params.tentative_timeout))
        if not keep.all():
            self._keep_rows(keep)

    def _keep_rows(self, keep) -> None:
        self._ids = self._ids[keep]
        self._centroids = self._centroids[keep]
        self._widths = self._widths[keep]
        self._heights = self._heights[keep]
        self._hits = self._hits[keep]
        self._last_seen = self._last_seen[keep]

    def _associate(self, C: np.ndarray, W: np.ndarray, H: np.ndarray) -> np.ndarray:
        """(k,) row of the track each observation is assigned to, -1 for none."""
        p = self.params
        k = C.shape[0]
        rows = np.full(k, -1, dtype=np.intp)
        if k == 0 or len(self) == 0:
            return rows
        # Only tracks inside the observations' bounding box grown by the gate can be within
        # the gate of any observation; this O(n) test keeps the cost matrix small.
        lo = C.min(axis=0) - p.gate
        hi = C.max(axis=0) + p.gate
        cand = np.flatnonzero(np.all((self._centroids >= lo) & (self._centroids <= hi), axis=1))
        if cand.size == 0:
            return rows
        dist = np.linalg.norm(C[:, None, :] - self._centroids[cand][None, :, :], axis=2)
        dlw = np.abs(_log_size(W)[:, None] - _log_size(self._widths[cand])[None, :])
        dlh = np.abs(_log_size(H)[:, None] - _log_size(self._heights[cand])[None, :])
        feasible = ((dist <= p.gate) & (dlw <= self._log_size_gate)
                    & (dlh <= self._log_size_gate))
        r_idx = np.flatnonzero(feasible.any(axis=1))
        if r_idx.size == 0:
            return rows
        c_idx = np.flatnonzero(feasible.any(axis=0))
        cost = dist + p.size_weight * (dlw + dlh)
        # An infeasible entry costs more than any set of feasible ones, so the solver first
        # maximises the number of gated associations and then minimises their total cost.
        max_feasible = p.gate + 2.0 * p.size_weight * self._log_size_gate
        big = max_feasible * min(r_idx.size, c_idx.size) + 1.0
        sub = np.where(feasible, cost, big)[np.ix_(r_idx, c_idx)]
        # imported here: scipy.optimize takes half a second to load, and loading a YAML
        # configuration imports MapperParams for its defaults
        from scipy.optimize import linear_sum_assignment

        r, c = linear_sum_assignment(sub)
        ok = feasible[r_idx[r], c_idx[c]]
        rows[r_idx[r[ok]]] = cand[c_idx[c[ok]]]
        return rows

    def _merge(self, touched: np.ndarray, out: np.ndarray) -> None:
        """Merge near-duplicate tracks in place; rewrites merged-away ids in `out` (k,).

        After every update no two tracks qualify for merging, and tracks this update did not
        touch have not moved, so only pairs involving a touched track (or a merge survivor)
        need checking. The touched tracks are those holding an observation of this frame (a
        merge survivor holds its pair's), and two of them are never merged: one frame's
        segments are distinct objects, so the ids in `out` stay unique. A touched track
        merges only with an untouched one.
        """
        p = self.params
        if p.merge_distance <= 0:
            return
        while len(self) >= 2:
            idx = np.flatnonzero(touched)
            if idx.size == 0:
                return
            dist = np.linalg.norm(self._centroids[idx][:, None, :] - self._centroids[None],
                                  axis=2)
            dist[np.arange(idx.size), idx] = np.inf
            lw, lh = _log_size(self._widths), _log_size(self._heights)
            ok = ((dist < p.merge_distance)
                  & (np.abs(lw[idx][:, None] - lw[None]) <= self._log_size_gate)
                  & (np.abs(lh[idx][:, None] - lh[None]) <= self._log_size_gate)
                  & ~touched[None])
            if not ok.any():
                return
            r, c = np.unravel_index(np.argmin(np.where(ok, dist, np.inf)), dist.shape)
            # Rows are sorted by id, so the lower row is the lower id and survives.
            i, j = sorted((int(idx[r]), int(c)))
            hi, hj = self._hits[i], self._hits[j]
            total = hi + hj
            self._centroids[i] = (hi * self._centroids[i] + hj * self._centroids[j]) / total
            self._widths[i] = (hi * self._widths[i] + hj * self._widths[j]) / total
            self._heights[i] = (hi * self._heights[i] + hj * self._heights[j]) / total
            self._hits[i] = total
            self._last_seen[i] = max(self._last_seen[i], self._last_seen[j])
            out[out == self._ids[j]] = self._ids[i]
            keep = np.ones(len(self), dtype=bool)
            keep[j] = False
            self._keep_rows(keep)
            touched[i] = True
            touched = touched[keep]
