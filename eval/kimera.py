"""Offline Kimera-Multi evaluation: every robot's bags are mapped with the RGB-D front end, the
maps are exchanged at 1 Hz, every directed pair is aligned by the compared methods, and the
alignments are scored against the ground-truth CSVs.

Results go to `<output>/<test name>/`:
- `maps/<robot>.npz` and `.json`: a robot's map at each exchange, its odometry and true poses
  and its mapping throughput. Written as soon as the robot is mapped and reused by a later run
  with the same settings and bags (`resume`), so a failure in one robot's bags never loses the
  robots already mapped.
- `<test>-seed0.npz` / `.json`: every method's estimate of every pair at every exchange.
- `metrics.json`, `metrics.csv`, `table.md`: the paper's table (mean +- std translation and
  heading error), when there is ground truth; `figures/errors_<i>_<j>.png`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tcaff_gtsam.mapping.camera import R_BODY_OPTICAL, rigid_transform
from tcaff_gtsam.mapping.frontend import DepthRegistration, RgbdFrontEnd
from tcaff_gtsam.mapping.mapper import MapperParams

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se3_from_rt, se3_to_se2
from tcaff_gtsam.object_map import ObjectMap

from . import plots
from .config import ExtrinsicsConfig, KimeraMultiConfig, MethodsConfig
from .datasets.kimera_multi import (
    PoseTrack,
    RobotBags,
    read_ground_truth,
)
from .methods import RunSettings, method_names, run_methods
from .study import JobResult, job_from_runs, score, summarize, write_csv

__all__ = ["KimeraOutcome", "RobotMapping", "align_robots", "map_robot", "run_kimera_multi"]

log = logging.getLogger(__name__)

MAPS_VERSION = 1  # bump when the saved maps' meaning changes


def extrinsic(config: ExtrinsicsConfig, optical: bool) -> np.ndarray:
    """(4, 4) the configured frame in its parent. With `optical`, xyz/rpy place a camera link
    (x forward) and the optical frame (x right, y down, z forward) is turned from it."""
    if config.matrix is not None:
        return rigid_transform("extrinsics matrix", np.reshape(config.matrix, (4, 4)),
                               ConfigError)
    R = Rotation.from_euler("xyz", config.rpy_deg, degrees=True).as_matrix()
    return se3_from_rt(R @ R_BODY_OPTICAL if optical else R, config.xyz)


def _planar(T: np.ndarray) -> np.ndarray:
    """(..., 3) x, y, yaw of (..., 4, 4) poses; NaN poses (no ground truth) give NaN rows,
    where `se3_to_se2` would refuse them."""
    yaw = np.arctan2(T[..., 1, 0], T[..., 0, 0])
    return np.stack([T[..., 0, 3], T[..., 1, 3], yaw], axis=-1)


@dataclass
class RobotMapping:
    """One robot's maps at the 1 Hz exchanges.

    Attributes:
        robot: its name.
        times: (S,) s, whole seconds of ROS time at which maps are exchanged.
        frame_times: (S,) s, the last mapped frame at or before each exchange.
        T_odom_body: (S, 4, 4) the body pose in the odometry frame at those frames.
        T_map_body: (S, 4, 4) the true body pose in the shared map frame (NaN: no ground truth).
        maps: the map at each exchange, in the odometry frame.
        frames: frames mapped; seconds: wall time of reading and mapping them.
        fingerprint: of the settings and files the maps came from (see `_fingerprint`).
        stage_seconds: the front end's time per stage, summed over the frames.
    """

    robot: str
    times: np.ndarray
    frame_times: np.ndarray
    T_odom_body: np.ndarray
    T_map_body: np.ndarray
    maps: list[ObjectMap]
    frames: int
    seconds: float
    fingerprint: str = ""
    stage_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def frames_per_second(self) -> float | None:
        return self.frames / self.seconds if self.seconds > 0 else None

    @property
    def has_truth(self) -> bool:
        return bool(np.all(np.isfinite(self.T_map_body)))

    def save(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        sizes = np.array([len(m) for m in self.maps], dtype=np.int64)
        entries = {key: np.concatenate([getattr(m, key) for m in self.maps])
                   for key in ("centroids", "widths", "heights", "last_seen")}
        with open(folder / f"{self.robot}.npz", "wb") as file:
            np.savez_compressed(
                file, times=self.times, frame_times=self.frame_times,
                T_odom_body=self.T_odom_body, T_map_body=self.T_map_body, map_sizes=sizes,
                **entries)
        (folder / f"{self.robot}.json").write_text(json.dumps({
            "robot": self.robot, "version": MAPS_VERSION, "fingerprint": self.fingerprint,
            "frames": self.frames, "seconds": self.seconds,
            "frames_per_second": self.frames_per_second,
            "stage_seconds": self.stage_seconds, "exchanges": len(self.times)}, indent=1))

    @classmethod
    def load(cls, folder: Path, robot: str) -> RobotMapping | None:
        """The saved mapping of `robot`, or None when there is none or it cannot be read."""
        try:
            meta = json.loads((folder / f"{robot}.json").read_text())
            with np.load(folder / f"{robot}.npz") as a:
                arrays = {k: a[k] for k in a.files}
        except (OSError, ValueError, KeyError) as err:
            if (folder / f"{robot}.json").exists():
                log.warning("ignoring the saved maps of %s: %s", robot, err)
            return None
        if meta.get("version") != MAPS_VERSION:
            return None
        ends = np.cumsum(arrays["map_sizes"])
        maps = [ObjectMap(arrays["centroids"][e - n:e], arrays["widths"][e - n:e],
                          arrays["heights"][e - n:e], arrays["last_seen"][e - n:e])
                for n, e in zip(arrays["map_sizes"], ends, strict=True)]
        return cls(robot, arrays["times"], arrays["frame_times"], arrays["T_odom_body"],
                   arrays["T_map_body"], maps, int(meta["frames"]), float(meta["seconds"]),
                   meta["fingerprint"], meta.get("stage_seconds", {}))


def _bag_paths(config: KimeraMultiConfig, robot: str, data: Path) -> list[Path]:
    pattern = config.bags.replace("{robot}", robot)
    paths = sorted(data.glob(pattern))
    if not paths:
        present = sorted(p.name for p in data.glob("*.bag"))
        raise DataError(f"robot {robot}: no bag matches {pattern!r} in {data}; bags there: "
                        f"{present}")
    return paths


def _fingerprint(config: KimeraMultiConfig, robot: str, paths: list[Path], gt: Path) -> str:
    """Changes when anything that shapes the robot's maps changes."""
    files = [(p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in paths]
    if gt.is_file():
        files.append((gt.name, gt.stat().st_size, gt.stat().st_mtime_ns))
    keys = ("topics", "rig", "stride", "sync_tolerance", "start", "duration", "mapping")
    settings = config.model_dump(mode="json", include=set(keys))
    blob = json.dumps({"robot": robot, "files": files, "settings": settings}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def map_robot(config: KimeraMultiConfig, robot: str, data: Path,
              progress: Callable[[float], None] | None = None) -> RobotMapping:
    """Map one robot's bags and record its map at every whole second of ROS time.

    Raises:
        DataError: missing or damaged bags, missing topics, bad messages.
    """
    paths = _bag_paths(config, robot, data)
    gt_path = data / config.ground_truth.replace("{robot}", robot)
    truth = read_ground_truth(gt_path) if gt_path.is_file() else None
    if truth is None:
        log.warning("robot %s: no ground truth at %s; its alignments are not scored", robot,
                    gt_path)
    with RobotBags(paths, robot, config.topics) as bags:
        calibration = bags.calibration()
        T_color_depth = extrinsic(config.rig.color_depth, optical=False)
        registration = DepthRegistration(calibration.depth, T_color_depth)
        front_end = RgbdFrontEnd(
            calibration.color, extrinsic(config.rig.body_color, optical=True),
            config.rig.depth_scale, registration=registration,
            mapper_params=MapperParams(nu=config.mapping.nu, kappa=config.mapping.kappa))
        first, last = bags.time_span()
        begin = first + (config.start or 0.0)
        end = last if config.duration is None else min(last, begin + config.duration)
        times, frame_times, poses, maps = [], [], [], []
        stage_seconds: dict[str, float] = {}
        frames, clock = 0, time.perf_counter()
        exchange, previous = None, None
        for frame in bags.frames(config.mapping.frame_rate, config.stride,
                                 config.sync_tolerance, begin, end + 1e-9):
            if exchange is None:
                exchange = math.ceil(frame.t)
            while frame.t > exchange and previous is not None:
                times.append(exchange)
                frame_times.append(previous.t)
                poses.append(previous.T_odom_body)
                maps.append(front_end.object_map())
                exchange += 1
            result = front_end.process(frame.t, frame.rgb, frame.depth, frame.T_odom_body)
            for stage, s in result.seconds.items():
                stage_seconds[stage] = stage_seconds.get(stage, 0.0) + s
            previous, frames = frame, frames + 1
            if progress is not None and end > begin:
                progress(min(1.0, (frame.t - begin) / (end - begin)))
        seconds = time.perf_counter() - clock
    if not times:
        raise DataError(f"robot {robot}: {frames} frames mapped, not enough for one 1 Hz map "
                        f"exchange (check the topics' stamps and sync_tolerance)")
    frame_times = np.array(frame_times)
    T_map_body = np.full((len(times), 4, 4), np.nan)
    if truth is not None:
        T, inside = PoseTrack(*truth)(frame_times)
        T_map_body[inside] = T[inside]
        if not inside.all():
            log.warning("robot %s: ground truth covers %d of %d exchanges", robot,
                        inside.sum(), inside.size)
    return RobotMapping(robot, np.array(times, dtype=float), frame_times, np.array(poses),
                        T_map_body, maps, frames, seconds,
                        _fingerprint(config, robot, paths, gt_path), stage_seconds)


@dataclass(frozen=True, eq=False)
class RecordedRun:
    """The robots' maps at their common exchanges (an `AlignmentRun`)."""

    settings: RunSettings
    times: np.ndarray
    maps: list[list[ObjectMap]]
    T_map_odom: np.ndarray  # (n, S, 4, 4), NaN where there is no ground truth

    @property
    def n_robots(self) -> int:
        return len(self.maps)

    def T_true(self, i: int, j: int) -> np.ndarray:
        """(S, 3, 3) the true planar T_oi_oj (NaN without ground truth)."""
        if not np.all(np.isfinite(self.T_map_odom[[i, j]])):
            return np.full((len(self.times), 3, 3), np.nan)
        return se3_to_se2(invert(self.T_map_odom[i]) @ self.T_map_odom[j])


def align_robots(config: KimeraMultiConfig, mappings: list[RobotMapping],
                 progress: Callable[[float], None] | None = None
                 ) -> tuple[JobResult, MethodsConfig]:
    """Every method over every directed pair, at the exchanges all robots share, and the
    method set that ran.

    Without ground truth for every robot, ICP and the ground-truth method are left out and
    the result has no metrics; the estimates are still there.
    """
    common = mappings[0].times
    for m in mappings[1:]:
        common = np.intersect1d(common, m.times)
    if common.size == 0:
        spans = {m.robot: (m.times[0], m.times[-1]) for m in mappings}
        raise DataError(f"the robots' recordings share no whole second of ROS time: {spans}")
    index = [np.searchsorted(m.times, common) for m in mappings]
    maps = [[m.maps[k] for k in idx] for m, idx in zip(mappings, index, strict=True)]
    T_odom_body = np.array([m.T_odom_body[idx] for m, idx in zip(mappings, index, strict=True)])
    T_map_body = np.array([m.T_map_body[idx] for m, idx in zip(mappings, index, strict=True)])
    T_map_odom = T_map_body @ invert(T_odom_body)
    methods = config.methods
    assert isinstance(methods, MethodsConfig)
    truth = all(m.has_truth for m in mappings)
    if not truth:
        kept = [m for m in methods.methods if m not in ("icp", "ground_truth")]
        methods = methods.model_copy(update={"methods": kept})
    settings = RunSettings(config.mapping.kappa, config.window, config.graph_drift)
    run = RecordedRun(settings, common, maps, T_map_odom)
    runs = run_methods(run, methods, progress)
    job = job_from_runs(config.name, 0, runs, {
        "times": common - common[0], "t0": np.array(common[0]),
        "poses_true": _planar(T_map_body), "poses_odom": _planar(T_odom_body),
        "overlap": np.ones((len(runs.pairs), common.size), dtype=bool),
        "world_xy": np.zeros((0, 2)), "world_widths": np.zeros(0),
        "walls": np.zeros((0, 2, 2)),
    })
    if truth:
        score(job, methods)
    return job, methods


@dataclass
class KimeraOutcome:
    """What a run produced.

    Attributes:
        folder: where the results are.
        mappings: the robots mapped (also those of an earlier run that were reused).
        reused: robots whose saved maps were reused.
        job: the alignment (None when mapping failed).
        summary: method -> pooled report ({} without ground truth).
        methods: the method set that ran.
    """

    folder: Path
    mappings: list[RobotMapping]
    reused: list[str]
    job: JobResult | None = None
    summary: dict[str, dict] = field(default_factory=dict)
    methods: MethodsConfig | None = None


class KimeraProgress:
    """Hooks for progress reports; the default reports nothing."""

    def robot(self, robot: str, reused: bool) -> None: ...
    def mapping(self, robot: str, share: float) -> None: ...
    def aligning(self, share: float) -> None: ...


def run_kimera_multi(config: KimeraMultiConfig, data: Path, output: Path,
                     resume: bool = True, figures: bool = True,
                     progress: KimeraProgress | None = None) -> KimeraOutcome:
    """Map every robot (reusing saved maps when `resume`), align, score, write the results.

    Raises:
        DataError: a robot's data cannot be read. The robots mapped before it are saved.
    """
    progress = progress or KimeraProgress()
    data, folder = Path(data), Path(output) / config.name
    if not data.is_dir():
        raise DataError(f"--data {data}: not a folder")
    maps_folder = folder / "maps"
    outcome = KimeraOutcome(folder, [], [])
    for robot in config.robots:
        saved = RobotMapping.load(maps_folder, robot) if resume else None
        if saved is not None:
            paths = _bag_paths(config, robot, data)
            gt = data / config.ground_truth.replace("{robot}", robot)
            if saved.fingerprint == _fingerprint(config, robot, paths, gt):
                progress.robot(robot, True)
                outcome.mappings.append(saved)
                outcome.reused.append(robot)
                continue
        progress.robot(robot, False)
        mapping = map_robot(config, robot, data, lambda s, r=robot: progress.mapping(r, s))
        mapping.save(maps_folder)
        outcome.mappings.append(mapping)
    job, outcome.methods = align_robots(config, outcome.mappings, progress.aligning)
    outcome.job = job
    job.save(folder)
    if job.metrics:
        outcome.summary = summarize([job], outcome.methods)[config.name]
        _write_tables(folder, config, outcome)
    if figures:
        (folder / "figures").mkdir(exist_ok=True)
        shown = [m for m in method_names(outcome.methods) if m in (
            "tcaff", "tcaff_isam2_smoothed", f"clipper_k{outcome.methods.clipper_k_shown}")]
        if job.metrics:
            for p, (i, j) in enumerate(job.pairs):
                plots.errors_over_time(folder / "figures" / f"errors_{i}_{j}.png", job, shown, p)
    return outcome



def _write_tables(folder: Path, config: KimeraMultiConfig, outcome: KimeraOutcome) -> None:
    """metrics.json, metrics.csv (every method and pair) and table.md (the paper's table)."""
    job = outcome.job
    (folder / "metrics.json").write_text(json.dumps(
        {"test": config.name, "robots": config.robots, "summary": outcome.summary,
         "pairs": job.metrics,
         "frames_per_second": {m.robot: m.frames_per_second for m in outcome.mappings}},
        indent=1))
    write_csv(folder / "metrics.csv", [{"method": method, "pair": pair, **report}
                                       for method, by_pair in job.metrics.items()
                                       for pair, report in by_pair.items()])
    lines = [f"| {config.name} | translation error [m] | heading error [deg] | available |",
             "|---|---|---|---|"]
    for method, r in outcome.summary.items():
        if r["translation_error_m_mean"] is None:
            cells = ["-", "-"]
        else:
            cells = [f"{r['translation_error_m_mean']:.2f} +- {r['translation_error_m_std']:.2f}",
                     f"{r['heading_error_deg_mean']:.2f} +- {r['heading_error_deg_std']:.2f}"]
        available = "-" if r["availability"] is None else f"{100 * r['availability']:.0f} %"
        lines.append(f"| {plots.label(method)} | {cells[0]} | {cells[1]} | {available} |")
    (folder / "table.md").write_text("\n".join(lines) + "\n")
