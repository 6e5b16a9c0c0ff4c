"""Rerun recordings of runs: the world, the robots' maps, paths, candidates, the accepted
alignment and the truth on one timeline, and every method's errors as time series.

`record` writes jobs (`JobResult`, fresh or loaded from a results folder) to one `.rrd` file for
the Rerun viewer (`rerun FILE.rrd`). Each job has its own root entity, its stem; its timeline
`time` is the job's exchange times (s since a simulated run's start, since a recorded run's
first exchange). Under `<stem>/world/` (metres, the world
frame of the truth; without truth, the reference robot's odometry frame):

    objects, walls                    static: the world's objects (radius half their width)
    robots/<name>/path                static: the robot's true path
    robots/<name>/pose, /map          over time: its true pose; its shared map (the objects
                                      seen within kappa) placed by the truth, sized by width
    aligned/<name>/pose, /map         over time: robot <name>'s pose and map placed in the
                                      reference robot's frame through the accepted alignment
                                      (the method shown), where it has one
    candidates/<name>                 over time: robot <name>'s pose under each candidate
                                      alignment (MNO-CLIPPER) of the pair (reference, <name>)

and under `<stem>/errors/<i>_to_<j>/translation/<method>` and `.../heading/<method>` each
method's error (m, deg) of each directed pair at the steps it has an estimate, and under
`.../nees/<method>` its NEES (`metrics.step_nees`) when the job kept the method's covariances.

rerun-sdk is the optional extra `viz`, pinned to the release these calls are written for.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se2_from_params

from .metrics import step_errors, step_nees
from .results import JobResult
from .trajectories import (
    check_odometry,
    estimate_streams,
    frame_alignment,
    robot_names,
    with_robot,
)

__all__ = ["RERUN_VERSION", "check_rerun", "record"]

RERUN_VERSION = "0.41"  # the release these calls are written for (pyproject's extra viz)
TIMELINE = "time"

_GREY, _TRUTH = (150, 150, 150), (40, 160, 40)
_ROBOT_COLORS = [(214, 39, 40), (31, 119, 180), (255, 127, 14), (148, 103, 189),
                 (140, 86, 75), (227, 119, 194), (23, 190, 207), (188, 189, 34)]


def check_rerun():
    """The rerun module, or a ConfigError saying how to install it."""
    try:
        import rerun
    except ImportError:
        raise ConfigError("Rerun recordings need the optional extra viz: pip install "
                          f"'tcaff-gtsam[viz]' (rerun-sdk {RERUN_VERSION})") from None
    version = getattr(rerun, "__version__", "?")
    if ".".join(version.split(".")[:2]) != RERUN_VERSION:
        raise ConfigError(f"rerun-sdk {version} is installed; the recordings are written for "
                          f"{RERUN_VERSION}: pip install 'tcaff-gtsam[viz]'")
    return rerun


def _place(T: np.ndarray, xy: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Points (N, 2) given per step (counts (S,), summing to N) moved by that step's
    T (S, 3, 3)."""
    T_each = np.repeat(T, counts, axis=0)
    return np.einsum("nij,nj->ni", T_each[:, :2, :2], xy) + T_each[:, :2, 2]


def _shown_method(job: JobResult, method: str | None) -> str:
    streams = estimate_streams(job)
    if method is None:
        return "tcaff" if "tcaff" in streams else streams[0]
    if method not in streams:
        raise ConfigError(f"method {method!r}: not in {job.stem} (has {', '.join(streams)})")
    return method


class _Writer:
    """One job into a recording stream."""

    def __init__(self, rr, stream, job: JobResult, reference: int, method: str) -> None:
        self.rr, self.stream, self.job = rr, stream, job
        self.root = job.stem
        self.names = robot_names(job)
        self.times = np.asarray(job.arrays["times"], dtype=float)
        a = job.arrays
        self.T_o_b = se2_from_params(a["poses_odom"])
        self.has_truth = bool(np.all(np.isfinite(a["poses_true"])))
        self.reference, self.method = reference, method
        S = len(self.times)
        if self.has_truth:
            self.T_w_b = se2_from_params(a["poses_true"])
            self.T_w_o = self.T_w_b @ invert(self.T_o_b)
        else:  # the reference robot's odometry frame stands for the world
            self.T_w_o = np.full((len(self.T_o_b), S, 3, 3), np.nan)
            self.T_w_o[reference] = np.eye(3)

    def send(self, entity: str, steps: np.ndarray, columns) -> None:
        index = self.rr.TimeColumn(TIMELINE, duration=self.times[steps])
        self.stream.send_columns(f"{self.root}/{entity}", indexes=[index], columns=columns)

    def points(self, entity: str, steps: np.ndarray, xy: np.ndarray, counts: np.ndarray,
               radii, color) -> None:
        """Per step a batch of points: counts (len(steps),) of xy (N, 2)."""
        if len(steps) == 0:
            return
        radii = np.broadcast_to(np.asarray(radii, dtype=np.float32), (len(xy),))
        self.send(entity, steps, self.rr.Points2D.columns(
            positions=xy, radii=radii, colors=np.tile(color, (len(xy), 1))).partition(counts))

    def world(self) -> None:
        a, rr = self.job.arrays, self.rr
        if "world_xy" in a and len(a["world_xy"]):
            self.stream.log(f"{self.root}/world/objects", rr.Points2D(
                a["world_xy"], radii=0.5 * a["world_widths"], colors=_GREY), static=True)
        if "walls" in a and len(a["walls"]):
            self.stream.log(f"{self.root}/world/walls",
                            rr.LineStrips2D(a["walls"], colors=_GREY), static=True)

    def robots(self) -> None:
        a, S = self.job.arrays, len(self.times)
        every = np.arange(S)
        for r, name in enumerate(self.names):
            color = _ROBOT_COLORS[r % len(_ROBOT_COLORS)]
            if self.has_truth:
                self.stream.log(f"{self.root}/world/robots/{name}/path", self.rr.LineStrips2D(
                    [self.T_w_b[r, :, :2, 2]], colors=color, radii=0.03), static=True)
                self.points(f"world/robots/{name}/pose", every, self.T_w_b[r, :, :2, 2],
                            np.ones(S, int), 0.25, color)
            if f"map_xy_{r}" in a and np.all(np.isfinite(self.T_w_o[r])):
                counts = a[f"map_counts_{r}"]
                self.points(f"world/robots/{name}/map", every,
                            _place(self.T_w_o[r], a[f"map_xy_{r}"], counts), counts,
                            0.5 * a[f"map_widths_{r}"], color)

    def aligned(self) -> None:
        """The other robots placed through the shown method's alignment, and the candidates."""
        a, ref = self.job.arrays, self.reference
        for j, name in enumerate(self.names):
            if j == ref:
                continue
            color = _ROBOT_COLORS[j % len(_ROBOT_COLORS)]
            # every step is logged, empty where there is nothing: the viewer shows the latest
            # batch at each time, which must not outlive its step
            every = np.arange(len(self.times))
            found = frame_alignment(self.job, f"est_{self.method}", ref, j)
            if found is not None:
                steps, T_oref_oj = found
                T_w_oj = self.T_w_o[ref, steps] @ T_oref_oj
                has = np.isin(every, steps)
                self.points(f"world/aligned/{name}/pose", every,
                            (T_w_oj @ self.T_o_b[j, steps])[:, :2, 2], has.astype(int), 0.25,
                            color)
                if f"map_xy_{j}" in a:
                    counts = a[f"map_counts_{j}"]
                    first = np.r_[0, np.cumsum(counts)]
                    keep = np.concatenate([np.arange(first[s], first[s + 1]) for s in steps]
                                          + [np.zeros(0, int)])
                    self.points(f"world/aligned/{name}/map", every,
                                _place(T_w_oj, a[f"map_xy_{j}"][keep], counts[steps]),
                                np.where(has, counts, 0), 0.5 * a[f"map_widths_{j}"][keep],
                                color)
            if (ref, j) in self.job.pairs and f"cand_z_{self.job.pairs.index((ref, j))}" in a:
                p = self.job.pairs.index((ref, j))
                cand_steps, z = a[f"cand_steps_{p}"].astype(int), a[f"cand_z_{p}"]
                order = np.argsort(cand_steps, kind="stable")
                cand_steps, z = cand_steps[order], z[order]
                T = self.T_w_o[ref, cand_steps] @ se2_from_params(z) @ self.T_o_b[j, cand_steps]
                self.points(f"world/candidates/{name}", every, T[:, :2, 2],
                            np.bincount(cand_steps, minlength=len(every)), 0.15, (230, 200, 0))

    def errors(self) -> None:
        a = self.job.arrays
        if not np.all(np.isfinite(a["truth"])):
            return
        T_true = se2_from_params(a["truth"])
        for stream in estimate_streams(self.job):
            for p, (i, j) in enumerate(self.job.pairs):
                estimate = a[f"est_{stream}"][p]
                steps = np.flatnonzero(np.all(np.isfinite(estimate), axis=1))
                if not len(steps):
                    continue
                err = step_errors(T_true[p], estimate)[steps]
                pair = f"{self.names[i]}_to_{self.names[j]}"
                self.send(f"errors/{pair}/translation/{stream}", steps,
                          self.rr.Scalars.columns(scalars=err[:, 0]))
                self.send(f"errors/{pair}/heading/{stream}", steps,
                          self.rr.Scalars.columns(scalars=np.degrees(err[:, 1])))
                if f"cov_{stream}" in a:
                    nees = step_nees(T_true[p], estimate, a[f"cov_{stream}"][p])[steps]
                    self.send(f"errors/{pair}/nees/{stream}", steps,
                              self.rr.Scalars.columns(scalars=nees))


def record(path: Path, jobs: Iterable[JobResult], reference: int = 0,
           method: str | None = None) -> Path:
    """Write the jobs into one Rerun recording at `path` (see the module); returns it.

    Args:
        reference: the robot (index) the aligned maps and candidates are placed around.
        method: the estimate stream shown as the accepted alignment (default: tcaff, when the
            jobs have it, else their first).
    Raises:
        ConfigError: rerun-sdk missing or of another release, a reference robot no job has
            (the jobs without it are left out, with a warning) or a method the jobs do not
            have.
        DataError: the file cannot be written; a job whose odometry is not finite (as
            `trajectories.export` refuses it) or whose saved arrays disagree.
    """
    rr = check_rerun()
    path = Path(path)
    jobs = list(jobs)
    if not jobs:
        raise DataError(f"{path}: no runs to record")
    jobs = with_robot(jobs, reference)
    for job in jobs:
        check_odometry(job)
    shown = [_shown_method(job, method) for job in jobs]
    if path.is_dir() or not path.parent.is_dir():
        raise DataError(f"{path}: not a file in an existing folder")
    stream = rr.RecordingStream("tcaff", recording_id=path.stem)
    try:
        stream.save(path)
    except Exception as exc:  # rerun raises its own errors for unwritable paths
        raise DataError(f"{path}: cannot write a recording ({exc})") from None
    try:
        for job, job_method in zip(jobs, shown, strict=True):
            writer = _Writer(rr, stream, job, reference, job_method)
            try:
                writer.world()
                writer.robots()
                writer.aligned()
                writer.errors()
            except (IndexError, ValueError, KeyError) as exc:
                raise DataError(f"{job.stem}: its saved arrays disagree with each other "
                                f"({type(exc).__name__}: {exc}); not a run as saved") from None
    finally:  # what was recorded before stays readable
        stream.flush()
        stream.disconnect()
    if not path.is_file():
        raise DataError(f"{path}: the recording could not be written")
    return path

