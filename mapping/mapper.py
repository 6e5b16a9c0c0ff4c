"""ObjectMapper: tracks per-frame object observations into a robot's sparse object map.

This is the paper's mapping step: each frame's observations (centroid, width, height in the
robot's odometry frame) are associated to tracks by global nearest neighbour; a track is
confirmed, and appears in the map, after `nu` sightings and is removed after `kappa` seconds
unseen.

When the observations come with their point clouds (the RGB-D front end's), each track keeps
the union of its views (`objects.ObjectCloud`): observations are assigned by how much of their
cloud lies on a track's, tracks merge when their clouds do, and a track's centroid and sizes
are those of its whole cloud, the same object seen from wherever it was seen rather than the
average of partial views. With colour histograms too, the map carries each object's
descriptor (colour and shape) for the aligner to compare.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.inputs import real_array
from tcaff_gtsam.object_map import ObjectMap, object_arrays
from tcaff_gtsam.params import FrameAlignerParams, _int_at_least, _real, _require
from tcaff_gtsam.registration import MAX_COORDINATE

from .objects import ObjectCloud, cloud_extent, shape_features

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
        cloud_voxel: metres; when observations come with their clouds, each track merges
            them into one cloud of this voxel edge (`objects.ObjectCloud`), and its centroid,
            width and height are those of the merged cloud's upright box
            (`objects.cloud_extent`, measured when the map is read) rather than running
            means of single views: the object seen from everywhere it was seen from.
        cloud_points: the most voxels a track's cloud keeps (coarser voxels beyond).
        extent_pad: metres added to a merged cloud's width and height: lifted points are
            the means of the lifter's voxels (`LiftParams.voxel_size`, 1 cm), which pulls
            the outermost inside; the lifter pads a single view's sizes by the same.
        cloud_span: seconds; voxels unseen this long leave the cloud (odometry drifts).
        hue_bins, saturation_bins: the colour histogram of an object (`objects.colour_bins`
            of its pixels; the front end makes them).
        colour_weight: in [0, 1], the colour's share of an object's descriptor, the shape's
            (`objects.shape_features` of its merged cloud) the rest: two descriptors' dot
            product is colour_weight times their colours' Bhattacharyya coefficient plus
            (1 - colour_weight) times their shapes'.
        overlap_cell: metres; with clouds, an observation is assigned to the track on whose
            merged cloud most of its own cloud lies (`objects.ObjectCloud.share_on`: the share
            of its points in cells of this edge that the track's cloud occupies) ...
        min_overlap: ... if at least this share does (in (0, 1]); otherwise it starts a
            track. Centroids and sizes do not decide, so that a view of an object's other
            side joins it and a fragment of a neighbouring cabinet does not.
        merge_overlap: in (0, 1]; with clouds, two tracks merge when this share of either
            cloud lies on the other (two faces first seen apart, then together in one view;
            faces only ever seen apart share no more than their edge and stay two tracks).
            Without clouds, `merge_distance` decides.
    """

    nu: int = 3
    kappa: float = FrameAlignerParams.kappa
    gate: float = 1.0
    size_gate: float = 2.0
    size_weight: float = 0.5
    max_average: int = 10
    merge_distance: float = 0.3
    tentative_timeout: float = 1.0
    cloud_voxel: float = 0.02
    cloud_points: int = 1500
    extent_pad: float = 0.01
    cloud_span: float = 60.0
    hue_bins: int = 12
    saturation_bins: int = 3
    colour_weight: float = 0.7
    overlap_cell: float = 0.05
    min_overlap: float = 0.3
    merge_overlap: float = 0.5

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
        _require(_real(self.cloud_voxel) and math.isfinite(self.cloud_voxel)
                 and self.cloud_voxel > 0, o, "cloud_voxel", self.cloud_voxel,
                 "must be a finite number > 0 metres")
        _require(_int_at_least(self.cloud_points, 16), o, "cloud_points", self.cloud_points,
                 "must be an int >= 16")
        _require(_real(self.extent_pad) and math.isfinite(self.extent_pad)
                 and self.extent_pad >= 0, o, "extent_pad", self.extent_pad,
                 "must be a finite number >= 0 metres")
        _require(_real(self.cloud_span) and self.cloud_span > 0, o, "cloud_span",
                 self.cloud_span, "must be a number > 0 seconds")
        for name in ("hue_bins", "saturation_bins"):
            _require(_int_at_least(getattr(self, name), 1) and getattr(self, name) <= 64, o,
                     name, getattr(self, name), "must be an int in [1, 64]")
        _require(_real(self.colour_weight) and 0 <= self.colour_weight <= 1, o,
                 "colour_weight", self.colour_weight, "must be in [0, 1]")
        _require(_real(self.overlap_cell) and math.isfinite(self.overlap_cell)
                 and self.overlap_cell > 0, o, "overlap_cell", self.overlap_cell,
                 "must be a finite number > 0 metres")
        for name in ("min_overlap", "merge_overlap"):
            _require(_real(getattr(self, name)) and 0 < getattr(self, name) <= 1, o, name,
                     getattr(self, name), "must be in (0, 1]")


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
        self._clouds: list[ObjectCloud | None] = []  # per track, when clouds are given
        self._dirty = np.zeros(0, dtype=bool)  # clouds changed since their box was measured
        # (n, B) colour histograms, NaN rows where none was given
        self._colours = np.zeros((0, params.hue_bins * params.saturation_bins + 1))
        self._next_id = 0
        self._t_last: float | None = None
        self._with_clouds: bool | None = None  # fixed by the first update with observations

    def __len__(self) -> int:
        """Number of live tracks, confirmed or not."""
        return self._ids.shape[0]

    def __repr__(self) -> str:
        return f"ObjectMapper(tracks={len(self)}, confirmed={int(self._confirmed().sum())})"

    # -----------------------------------------------------------------------------------------
    # public API

    def update(self, t: float, centroids, widths, heights, clouds=None, colours=None
               ) -> np.ndarray:
        """Add one frame of observations.

        Args:
            t: seconds, time of the frame; finite and not earlier than the previous update's.
            centroids: (k, 3) metres, observed object centroids in the odometry frame.
            widths: (k,) metres, horizontal extents, >= 0.
            heights: (k,) metres, vertical extents, >= 0.
            clouds: None, or the k observations' point clouds ((n_o, 3) metres each, odometry
                frame, n_o >= 1): each track then merges the clouds of its observations, and
                its centroid and sizes are those of the merged cloud (`cloud_voxel`).
            colours: None, or (k, B) colour histograms (counts of `objects.colour_bins` of
                each object's pixels, B = hue_bins x saturation_bins + 1): each track keeps
                their running mean.

        Returns:
            (k,) int64, the id of the track each observation was assigned to (after merging);
            distinct, since two observations of one frame are never merged.

        Raises:
            DataError: on a bad time stamp or bad observation arrays, or observations with
                clouds after some without or the reverse (nothing is changed).
        """
        t, C, W, H = self._validate(t, centroids, widths, heights)
        clouds = self._valid_clouds(clouds, C.shape[0])
        colours = self._valid_colours(colours, C.shape[0])
        if C.shape[0]:
            self._check_mode(clouds is not None)
        self._t_last = t
        self._forget(t)
        if clouds is None:
            self._refresh()
            rows = self._associate(C, W, H)
        else:
            rows = self._associate_clouds(clouds)

        assigned = rows >= 0
        tr = rows[assigned]
        self._hits[tr] += 1
        weight = 1.0 / np.minimum(self._hits[tr], self.params.max_average)
        if clouds is None:  # with clouds, the merged cloud's box replaces these
            self._centroids[tr] += weight[:, None] * (C[assigned] - self._centroids[tr])
            self._widths[tr] += weight * (W[assigned] - self._widths[tr])
            self._heights[tr] += weight * (H[assigned] - self._heights[tr])
        self._last_seen[tr] = t

        if colours is not None:
            known = ~np.isnan(self._colours[tr, 0])
            self._colours[tr] = np.where(known[:, None], self._colours[tr] + weight[:, None]
                                         * (colours[assigned] - self._colours[tr]),
                                         colours[assigned])

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
            self._clouds.extend([None] * n_new)
            self._dirty = np.concatenate([self._dirty, np.zeros(n_new, dtype=bool)])
            fresh = np.full((n_new, self._colours.shape[1]), np.nan)
            if colours is not None:
                fresh = colours[new]
            self._colours = np.concatenate([self._colours, fresh])
            touched = np.concatenate([touched, np.ones(n_new, dtype=bool)])

        if clouds is not None:
            p = self.params
            for o, r in enumerate(rows):
                if self._clouds[r] is None:
                    self._clouds[r] = ObjectCloud(p.cloud_voxel, p.cloud_points)
                cloud = self._clouds[r]
                cloud.forget(t, p.cloud_span)
                cloud.add(clouds[o], t)
            self._dirty[rows] = True

        out = self._ids[rows]  # int64, and fancy indexing copies
        if clouds is None:
            self._merge(touched, out)
        else:
            self._merge_clouds(touched, out)
        return out

    def object_map(self) -> ObjectMap:
        """The confirmed tracks (hits >= nu) as an `ObjectMap` in the odometry frame, rows in
        increasing track id (the order of `confirmed_ids`). It carries descriptors when every
        confirmed track has a colour histogram and a cloud (`_descriptors`)."""
        self._refresh()
        m = self._confirmed()
        return ObjectMap(self._centroids[m], self._widths[m], self._heights[m],
                         self._last_seen[m], self._descriptors(np.flatnonzero(m)))

    def _descriptors(self, rows: np.ndarray) -> np.ndarray | None:
        """(len(rows), B + 3) unit descriptors of the tracks at `rows`: the square roots of
        colour_weight times the colour histogram and of (1 - colour_weight) times the merged
        cloud's `objects.shape_features`, so that two descriptors' dot product weighs the
        Bhattacharyya coefficients of colour and shape; None for no rows, or unless every
        one of those tracks has both."""
        if (rows.size == 0 or np.isnan(self._colours[rows, 0]).any()
                or any(self._clouds[r] is None or len(self._clouds[r]) == 0 for r in rows)):
            return None
        w = self.params.colour_weight
        shape = np.array([shape_features(self._clouds[r].points) for r in rows]).reshape(-1, 3)
        colour = np.clip(self._colours[rows], 0.0, None)
        colour /= np.maximum(colour.sum(axis=1, keepdims=True), 1e-12)
        return np.sqrt(np.column_stack([w * colour, (1.0 - w) * shape]))

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

    def _check_mode(self, with_clouds: bool) -> None:
        """Observations come with clouds in every update or in none: a track without a cloud
        could never be assigned by overlap, and its object would start a second track."""
        if self._with_clouds is None:
            self._with_clouds = with_clouds
        elif with_clouds != self._with_clouds:
            raise DataError(
                "ObjectMapper.update: clouds = " + ("a list" if with_clouds else "None")
                + ", but this mapper's earlier observations came "
                + ("without" if with_clouds else "with")
                + " clouds; give them in every update or in none")

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
        self._clouds = [c for c, k in zip(self._clouds, keep, strict=True) if k]
        self._colours = self._colours[keep]
        self._dirty = self._dirty[keep]

    def _refresh(self) -> None:
        """Centroid, width and height of every track whose merged cloud changed since they
        were last measured, from the cloud's upright box. Measured when they are read (a map
        once a second), not at every frame."""
        for r in np.flatnonzero(self._dirty):
            extent = cloud_extent(self._clouds[r].points, pad=self.params.extent_pad)
            self._centroids[r] = extent.centre
            self._widths[r] = extent.width
            self._heights[r] = extent.height
        self._dirty[:] = False

    def _valid_clouds(self, clouds, k: int) -> list[np.ndarray] | None:
        o = "ObjectMapper.update"
        if clouds is None:
            return None
        if not isinstance(clouds, (list, tuple)) or len(clouds) != k:
            raise DataError(f"{o}: clouds must be None or a list of {k} (n, 3) arrays, one "
                            f"per observation, got {type(clouds).__name__}"
                            + (f" of {len(clouds)}" if isinstance(clouds, (list, tuple))
                               else ""))
        out = []
        for i, cloud in enumerate(clouds):
            arr = real_array(o, f"clouds[{i}]", cloud)
            if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
                raise DataError(f"{o}: clouds[{i}] must have shape (n, 3) with n >= 1, got "
                                f"{arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise DataError(f"{o}: clouds[{i}] holds non-finite values")
            if np.abs(arr).max() > MAX_COORDINATE:
                raise DataError(f"{o}: clouds[{i}] holds coordinates beyond "
                                f"{MAX_COORDINATE:g} m")
            out.append(arr)
        return out

    def _valid_colours(self, colours, k: int) -> np.ndarray | None:
        o = "ObjectMapper.update"
        if colours is None:
            return None
        arr = real_array(o, "colours", colours)
        bins = self._colours.shape[1]
        if arr.ndim != 2 or arr.shape[0] != k:
            raise DataError(f"{o}: colours must have shape ({k}, B), got {arr.shape}")
        if arr.shape[1] != bins:
            raise DataError(f"{o}: colours has {arr.shape[1]} bins; the histograms of "
                            f"hue_bins = {self.params.hue_bins} x saturation_bins = "
                            f"{self.params.saturation_bins} have {bins} (one for grey)")
        if not np.all(np.isfinite(arr)) or (arr < 0).any():
            raise DataError(f"{o}: colours must be finite numbers >= 0")
        empty = np.flatnonzero(arr.sum(axis=1) <= 0)
        if empty.size:
            raise DataError(f"{o}: colours[{int(empty[0])}] is all zeros; a histogram counts "
                            f"at least one pixel")
        return arr

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

    def _associate_clouds(self, clouds: list[np.ndarray]) -> np.ndarray:
        """(k,) row of the track each observation is assigned to, -1 for none, by how much of
        the observation's cloud lies on the track's merged cloud (in the cells of edge
        `overlap_cell` that the track's cloud occupies):
        at least `min_overlap` of it, the largest share winning (Hungarian). Centroids do not
        decide: a view of an object's other side has its centroid elsewhere, and a fragment
        of a neighbouring cabinet has its centroid close by."""
        p = self.params
        k = len(clouds)
        rows = np.full(k, -1, dtype=np.intp)
        have = [r for r, cloud in enumerate(self._clouds) if cloud is not None and len(cloud)]
        if k == 0 or not have:
            return rows
        reach = p.overlap_cell
        obs_lo = np.array([c.min(axis=0) for c in clouds]) - reach
        obs_hi = np.array([c.max(axis=0) for c in clouds]) + reach
        track_lo = np.array([self._clouds[r].lo for r in have])
        track_hi = np.array([self._clouds[r].hi for r in have])
        # only boxes that touch can share points: (k, tracks)
        touch = np.all((track_hi[None] >= obs_lo[:, None]) & (track_lo[None] <= obs_hi[:, None]),
                       axis=2)
        share = np.zeros((k, len(self)))
        for o, t in zip(*np.nonzero(touch), strict=True):
            share[o, have[t]] = self._clouds[have[t]].share_on(clouds[o], p.overlap_cell)
        feasible = share >= p.min_overlap
        r_idx = np.flatnonzero(feasible.any(axis=1))
        if r_idx.size == 0:
            return rows
        c_idx = np.flatnonzero(feasible.any(axis=0))
        from scipy.optimize import linear_sum_assignment

        sub = np.where(feasible, 1.0 - share, 2.0 * k)[np.ix_(r_idx, c_idx)]
        r, c = linear_sum_assignment(sub)
        ok = feasible[r_idx[r], c_idx[c]]
        rows[r_idx[r[ok]]] = c_idx[c[ok]]
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
            touched = self._combine(int(idx[r]), int(c), touched, out)

    def _merge_clouds(self, touched: np.ndarray, out: np.ndarray) -> None:
        """`_merge` for tracks with clouds: two tracks are one object when at least
        `merge_overlap` of either cloud lies on the other (`ObjectCloud.share_on`), as when
        the two faces of a box, first seen apart, meet in a later view. The same rules as
        `_merge` on which pairs are checked."""
        p = self.params
        reach = p.overlap_cell
        while len(self) >= 2:
            have = np.array([c is not None and len(c) > 0 for c in self._clouds])
            lo = np.array([c.lo if h else np.full(3, np.inf)
                           for c, h in zip(self._clouds, have, strict=True)])
            hi = np.array([c.hi if h else np.full(3, -np.inf)
                           for c, h in zip(self._clouds, have, strict=True)])
            pair = None
            for i in np.flatnonzero(touched & have):
                near = np.flatnonzero(~touched & have & np.all(
                    (hi + reach >= lo[i]) & (lo - reach <= hi[i]), axis=1))
                for j in near:
                    a, b = self._clouds[i], self._clouds[j]
                    # either may be the fragment: a grown cloud has coarser voxels, so fewer
                    # points need not mean a smaller object
                    if max(a.share_of(b, p.overlap_cell),
                           b.share_of(a, p.overlap_cell)) >= p.merge_overlap:
                        pair = (int(i), int(j))
                        break
                if pair is not None:
                    break
            if pair is None:
                return
            touched = self._combine(*pair, touched, out)

    def _combine(self, a: int, b: int, touched: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Merge track rows a and b into the one with the lower id (running means weighted by
        hits, clouds merged, colours averaged); rewrites the other's id in `out`. Returns the
        touched flags of the rows left, the survivor touched."""
        # Rows are sorted by id, so the lower row is the lower id and survives.
        i, j = sorted((a, b))
        hi, hj = self._hits[i], self._hits[j]
        total = hi + hj
        self._centroids[i] = (hi * self._centroids[i] + hj * self._centroids[j]) / total
        self._widths[i] = (hi * self._widths[i] + hj * self._widths[j]) / total
        self._heights[i] = (hi * self._heights[i] + hj * self._heights[j]) / total
        self._hits[i] = total
        self._last_seen[i] = max(self._last_seen[i], self._last_seen[j])
        ci, cj = self._colours[i], self._colours[j]
        if not np.isnan(cj[0]):
            self._colours[i] = cj if np.isnan(ci[0]) else (hi * ci + hj * cj) / total
        if self._clouds[j] is not None:
            if self._clouds[i] is None:
                self._clouds[i] = self._clouds[j]
            else:
                self._clouds[i].absorb(self._clouds[j])
            self._dirty[i] = True
        out[out == self._ids[j]] = self._ids[i]
        keep = np.ones(len(self), dtype=bool)
        keep[j] = False
        self._keep_rows(keep)
        touched[i] = True
        return touched[keep]

