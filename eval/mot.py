"""Collaborative multi-object tracking of people, and its MOTA, for every alignment method.

Every robot tracks people with a `MultiObjectTracker` on its own detections and on its
neighbours' detections moved into its odometry frame through a method's current alignment
T_oi_oj: the estimate of the latest 1 Hz exchange at or before the frame. A neighbour whose
alignment the method does not know yet is not used. `no_sharing` is the robot alone.

Each robot's tracks are scored against the truth in its own odometry frame (where it would
place the people if it saw them without error) with `motmetrics` (CLEAR MOT). The people to
track in a frame are those in some robot's field of view; a track on a person nobody sees
right now (a track coasting after the person walked out of view) is neither a hit nor a false
positive: it is left out before scoring.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, transform_points_batch

from .config import PedestriansConfig
from .registry import describe
from .sim.people import PeopleRun
from .tracker import MultiObjectTracker

if TYPE_CHECKING:
    import motmetrics as mm

__all__ = ["COUNTS", "NO_SHARING", "MotScore", "Tracks", "collaborative_mot", "held_alignment",
           "mot_methods", "robot_alignments", "rolling_mota", "score_tracks", "track_robot"]

NO_SHARING = "no_sharing"
#: the per-frame counts kept for each robot, in this order
COUNTS = ("objects", "false_positives", "misses", "switches")
_METRICS = ["mota", "motp", "idf1", "num_objects", "num_false_positives", "num_misses",
            "num_switches"]


@dataclass
class MotScore:
    """One method's tracking over a run.

    Attributes:
        counts: (n_robots, F, 4) int, per robot and frame: people to track, false positives,
            misses and identity switches (`COUNTS`).
        robots: per robot, motmetrics' summary: mota, motp (m, mean distance of matched
            tracks), idf1, objects, false_positives, misses, switches.
    """

    counts: np.ndarray
    robots: list[dict]

    @property
    def mota(self) -> float | None:
        """MOTA averaged over the robots that had people to track."""
        values = [r["mota"] for r in self.robots if r["mota"] is not None]
        return float(np.mean(values)) if values else None


def mot_methods(names: list[str]) -> list[str]:
    """The methods whose alignments can drive online tracking, after `no_sharing`."""
    return [NO_SHARING, *(n for n in names if describe(n).causal)]


def held_alignment(times: np.ndarray, exchange_times: np.ndarray, estimate: np.ndarray
                   ) -> np.ndarray:
    """(F, 3, 3) the alignment of the latest exchange at or before each frame; NaN before the
    first exchange and where the method had no estimate.

    Args:
        times: (F,) seconds of the frames. exchange_times: (S,) seconds of the exchanges.
        estimate: (S, 3) (x, y, theta) of T_oi_oj at each exchange, NaN rows where none.
    """
    estimate = np.asarray(estimate, dtype=float)
    if estimate.shape != (len(exchange_times), 3):
        raise DataError(f"held_alignment: estimate must be ({len(exchange_times)}, 3), one row "
                        f"per exchange, got {estimate.shape}")
    step = np.searchsorted(exchange_times, times + 1e-9, side="right") - 1
    params = np.full((len(times), 3), np.nan)
    params[step >= 0] = estimate[step[step >= 0]]
    return se2_from_params(params)


def robot_alignments(people: PeopleRun, exchange_times: np.ndarray,
                     pairs: list[tuple[int, int]], estimates: np.ndarray, robot: int
                     ) -> dict[int, np.ndarray]:
    """Neighbour j -> (F, 3, 3) the T_oi_oj robot i = `robot` uses at each frame (NaN: none).

    Args:
        estimates: (n_pairs, S, 3) one method's estimates of the directed `pairs`.
    """
    return {j: held_alignment(people.times, exchange_times, estimates[p])
            for p, (i, j) in enumerate(pairs) if i == robot}


@dataclass(frozen=True, eq=False)
class Tracks:
    """One robot's confirmed tracks at every frame, frame after frame in flat arrays; also a
    sequence of F frames, each (ids (m,), xy (m, 2)).

    Attributes:
        ids: (T,) int64 track ids.
        xy: (T, 2) metres, the tracks' positions in the robot's odometry frame.
        starts: (F + 1,) int64; frame f's tracks are rows starts[f]:starts[f + 1].
    """

    ids: np.ndarray
    xy: np.ndarray
    starts: np.ndarray

    @classmethod
    def of(cls, frames: Sequence[tuple[np.ndarray, np.ndarray]]) -> Tracks:
        """Tracks from a sequence of frames, each (ids (m,), xy (m, 2))."""
        if isinstance(frames, Tracks):
            return frames
        ids = [np.asarray(i, dtype=np.int64).reshape(-1) for i, _ in frames]
        xy = [np.asarray(p, dtype=float).reshape(-1, 2) for _, p in frames]
        starts = np.zeros(len(ids) + 1, dtype=np.int64)
        starts[1:] = np.cumsum([len(i) for i in ids])
        if any(len(i) != len(p) for i, p in zip(ids, xy, strict=True)):
            raise DataError("Tracks: each frame needs as many positions (m, 2) as ids (m,)")
        return cls(np.concatenate([np.zeros(0, dtype=np.int64), *ids]),
                   np.concatenate([np.zeros((0, 2)), *xy]), starts)

    def __len__(self) -> int:
        return len(self.starts) - 1

    def __getitem__(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        rows = slice(self.starts[f], self.starts[f + 1])
        return self.ids[rows], self.xy[rows]

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        return (self[f] for f in range(len(self)))

    def key(self) -> bytes:
        """The tracks as bytes: equal for equal tracks at every frame."""
        return self.ids.tobytes() + self.xy.tobytes() + self.starts.tobytes()


def robot_detections(people: PeopleRun, robot: int, T_i: dict[int, np.ndarray]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """What the robot's tracker takes at each frame: its own detection set, then each
    neighbour's (ascending) moved into its frame, a neighbour's only at the frames whose
    alignment it has (a set whose first point is not finite is left out).

    Args:
        T_i: neighbour j -> (F, 3, 3) T_oi_oj used at each frame (NaN: not shared then).
    Returns:
        detections (D, 2) metres in the robot's odometry frame, frame after frame and set
        after set, and bounds (F, S + 1): set s of frame f is rows bounds[f, s]:bounds[f, s + 1]
        (`MultiObjectTracker.run`).
    """
    n_frames = len(people.times)
    sources = [robot, *sorted(T_i)]
    keys, points = [], []
    for rank, j in enumerate(sources):
        frame, xy, _ = people.detections[j]
        if j != robot:
            xy = transform_points_batch(T_i[j][frame], xy)
        starts = np.searchsorted(frame, np.arange(n_frames + 1))
        seen = starts[1:] > starts[:-1]
        used = np.zeros(n_frames, dtype=bool)
        used[seen] = np.isfinite(xy[starts[:-1][seen], 0])
        kept = used[frame]
        keys.append(frame[kept] * len(sources) + rank)
        points.append(xy[kept])
    keys, points = np.concatenate(keys), np.concatenate(points).reshape(-1, 2)
    order = np.argsort(keys, kind="stable")
    edges = np.searchsorted(keys[order], np.arange(n_frames * len(sources) + 1))
    bounds = edges[np.arange(n_frames)[:, None] * len(sources) + np.arange(len(sources) + 1)]
    return points[order], bounds


def track_robot(people: PeopleRun, robot: int, T_i: dict[int, np.ndarray],
                tracker: MultiObjectTracker) -> Tracks:
    """One robot's confirmed tracks at every frame, the tracker run on `robot_detections`.

    Args:
        T_i: neighbour j -> (F, 3, 3) T_oi_oj used at each frame (NaN: not shared then).
    Returns:
        per frame, (ids (m,), xy (m, 2) in the robot's odometry frame), as `Tracks`.
    """
    detections, bounds = robot_detections(people, robot, T_i)
    return Tracks(*tracker.run(people.times, detections, bounds))


def score_tracks(truth: np.ndarray, in_view: np.ndarray,
                 tracks: Tracks | Sequence[tuple[np.ndarray, np.ndarray]],
                 match_distance: float) -> tuple[np.ndarray, dict]:
    """CLEAR MOT of one robot's tracks.

    The distances of every track to every person are computed at once for the whole run;
    motmetrics' accumulator takes each frame's.

    Args:
        truth: (F, n, 2) the people's true positions in the robot's frame.
        in_view: (F, n) bool, the people to track in each frame.
        tracks: per frame, (ids (m,), xy (m, 2)) (`Tracks` or a sequence of frames).
        match_distance: metres; a track further from a person does not track them.
    Returns:
        counts (F, 4) (`COUNTS`) and the summary (mota and motp None without people to track).
    """
    tracks = Tracks.of(tracks)
    n_frames = len(tracks)
    # (T, n) squared distances of each track to every person of its frame, as motmetrics'
    # norm2squared_matrix computes them, and the distances
    frame_of = np.repeat(np.arange(n_frames), np.diff(tracks.starts))
    d2 = np.sum((truth[frame_of] - tracks.xy[:, None]) ** 2, axis=-1)
    distance = np.sqrt(d2)
    # beyond the match distance a person and a track cannot be paired (NaN for motmetrics)
    pairable = np.where(d2 > match_distance**2, np.nan, distance)
    near = distance <= match_distance
    import motmetrics as mm  # with pandas, 0.3 s of every worker's start that scores no people

    acc = mm.MOTAccumulator(auto_id=False)
    person_ids = np.arange(truth.shape[1])
    for f in range(n_frames):
        rows = slice(tracks.starts[f], tracks.starts[f + 1])
        ids, seen = tracks.ids[rows], in_view[f]
        kept = slice(None)
        if not seen.all() and near[rows][:, ~seen].any():
            # A track on a person out of everyone's view is neither right nor wrong. Everyone
            # is assigned at once, so a hidden person never takes a visible one's track.
            d = distance[rows].T
            persons, cols = linear_sum_assignment(np.where(d <= match_distance, d, 1e12))
            on_hidden = (d[persons, cols] <= match_distance) & ~seen[persons]
            kept = np.ones(len(ids), dtype=bool)
            kept[cols[on_hidden]] = False
            ids = ids[kept]
        acc.update(person_ids[seen], ids, pairable[rows][kept][:, seen].T, frameid=f)
    summary = _metrics_host().compute(acc, metrics=_METRICS, return_dataframe=False)
    has_people = summary["num_objects"] > 0
    report = {
        "mota": float(summary["mota"]) if has_people else None,
        "motp": float(summary["motp"]) if has_people and np.isfinite(summary["motp"]) else None,
        "idf1": float(summary["idf1"]) if np.isfinite(summary["idf1"]) else None,
        "objects": int(summary["num_objects"]),
        "false_positives": int(summary["num_false_positives"]),
        "misses": int(summary["num_misses"]),
        "switches": int(summary["num_switches"]),
    }
    return _frame_counts(acc.events, n_frames), report


def _frame_counts(events, n_frames: int) -> np.ndarray:
    """(F, 4) int64 `COUNTS` per frame from motmetrics' events (a frame's people to track are
    its matches, switches and misses)."""
    types = events["Type"].cat
    per_type = np.bincount(
        events.index.get_level_values("FrameId").to_numpy(np.int64) * len(types.categories)
        + types.codes.to_numpy(np.int64),
        minlength=n_frames * len(types.categories)).reshape(n_frames, -1)

    def column(name: str) -> np.ndarray:
        return per_type[:, types.categories.get_loc(name)]

    return np.column_stack([column("MATCH") + column("SWITCH") + column("MISS"),
                            column("FP"), column("MISS"), column("SWITCH")]).astype(np.int64)


@cache
def _metrics_host() -> mm.metrics.MetricsHost:
    """motmetrics' metrics, registered once per process (5 ms a time, twice per robot and
    method otherwise)."""
    import motmetrics as mm

    return mm.metrics.create()


def collaborative_mot(people: PeopleRun, exchange_times: np.ndarray,
                      pairs: list[tuple[int, int]], estimates: dict[str, np.ndarray],
                      config: PedestriansConfig,
                      progress: Callable[[float], None] | None = None) -> dict[str, MotScore]:
    """Every robot tracks the people with each method's alignments; each is scored.

    Args:
        exchange_times: (S,) seconds of the 1 Hz exchanges the estimates belong to.
        pairs: the directed pairs (i, j) of the estimates' first axis.
        estimates: method -> (n_pairs, S, 3) (x, y, theta) of T_oi_oj, NaN where none; only
            the names of `mot_methods` are tracked (`no_sharing` needs no estimate).
        progress: called after each method with the share of methods done.
    """
    out = {}
    names = mot_methods(list(estimates))
    truths = [people.truth_in_odom(i) for i in range(people.n_robots)]
    # a robot that takes the same detections under two methods (neither shared anything with
    # it, or both the same) is tracked once, and tracks the same at every frame scored once:
    # (robot, detections or tracks as bytes) -> tracks or (counts, report)
    tracked: dict[tuple[int, bytes], Tracks] = {}
    scored: dict[tuple[int, bytes], tuple[np.ndarray, dict]] = {}
    for done, method in enumerate(names, start=1):
        counts, robots = [], []
        for i, truth in enumerate(truths):
            T_i = ({} if method == NO_SHARING else
                   robot_alignments(people, exchange_times, pairs, estimates[method], i))
            detections, bounds = robot_detections(people, i, T_i)
            inputs = (i, detections.tobytes() + bounds.tobytes())
            if inputs not in tracked:
                tracker = MultiObjectTracker(config.tracker)
                tracked[inputs] = Tracks(*tracker.run(people.times, detections, bounds))
            tracks = tracked[inputs]
            key = (i, tracks.key())
            if key not in scored:
                scored[key] = score_tracks(truth, people.in_view, tracks,
                                           config.match_distance)
            c, report = scored[key]
            counts.append(c)
            robots.append(dict(report))
        out[method] = MotScore(np.array(counts), robots)
        if progress is not None:
            progress(done / len(names))
    return out


def rolling_mota(times: np.ndarray, counts: np.ndarray, window: float) -> np.ndarray:
    """(..., F) MOTA over the frames in (t - window, t] at each frame t; NaN where no person
    was to be tracked in the window.

    Args:
        times: (F,) seconds. counts: (..., F, 4) per-frame counts (`COUNTS`).
    """
    total = np.concatenate([np.zeros((*counts.shape[:-2], 1, 4)), np.cumsum(counts, axis=-2)],
                           axis=-2)
    start = np.searchsorted(times, times - window + 1e-9, side="right")  # robust to rounding
    summed = total[..., 1:, :] - total[..., start, :]
    objects = summed[..., 0]
    errors = summed[..., 1:].sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(objects > 0, 1.0 - errors / objects, np.nan)
