"""Trajectories for the field's tools: every robot's path in one robot's frame, as TUM or g2o.

A method's estimate of T_oi_oj places robot j's odometry path in robot i's odometry frame:
T_oi_bj(s) = T_oi_oj(s) T_oj_bj(s), at the steps the method has an estimate. With the true
T_oi_oj the same product is the ground truth; robot i's own path in its frame is its odometry.
`write_tum` writes, for one reference robot,

    trajectories/<job stem>/frame_<reference>/truth/<robot>.tum      every robot, all steps
    trajectories/<job stem>/frame_<reference>/<method>/<robot>.tum   every other robot

as `t x y z qx qy qz qw` (evo's TUM writer; planar poses at z = 0, times on the run's clock), so
`evo_ape tum truth/<robot>.tum <method>/<robot>.tum` gives the `ape_m` of the pair
(reference -> robot) in metrics.csv. `write_g2o` writes each method's paths as one pose graph.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import invert, se2_from_params, se2_to_params, se2_to_se3

from .results import JobResult, load_saved

__all__ = ["FORMATS", "TRUTH", "export", "frame_alignment", "robot_names", "robot_paths",
           "with_robot", "write_g2o", "write_rosbag2", "write_tum"]

log = logging.getLogger(__name__)
FORMATS = ("tum", "g2o", "rosbag2")
TRUTH = "truth"  # the folder of the ground truth, beside the methods'


def robot_names(job: JobResult) -> list[str]:
    """The job's robot names (indices when it has none), safe as file and entity names."""
    n = job.arrays["poses_odom"].shape[0]
    names = job.info.get("robots") or [str(r) for r in range(n)]
    return [re.sub(r"[^\w.-]", "_", str(name)) for name in names]


def check_reference(job: JobResult, reference: int) -> None:
    """ConfigError unless `reference` is a robot index of the job."""
    n = job.arrays["poses_odom"].shape[0]
    if isinstance(reference, bool) or not isinstance(reference, (int, np.integer)) or not (
            0 <= reference < n):
        raise ConfigError(f"reference {reference!r}: expected a robot index in 0..{n - 1} "
                          f"({job.stem} has {n} robots)")


def with_robot(jobs: list[JobResult], reference: int, skipping: bool = True
               ) -> list[JobResult]:
    """The jobs that have robot `reference` (a study's runs may have two robots or four),
    with a warning naming each of the others when the caller is `skipping` them.

    Raises:
        ConfigError: no job has it (`check_reference` of the job of the most robots).
    """
    def has(job: JobResult) -> bool:
        try:
            check_reference(job, reference)
        except ConfigError:
            return False
        return True

    having = [has(job) for job in jobs]
    if not any(having):
        check_reference(max(jobs, key=lambda job: job.arrays["poses_odom"].shape[0]),
                        reference)
    for job, held in zip(jobs, having, strict=True):
        if skipping and not held:
            log.warning("%s: no robot %s, whose frame the paths are put in: skipped",
                        job.stem, reference)
    return [job for job, held in zip(jobs, having, strict=True) if held]


def check_odometry(job: JobResult) -> None:
    """DataError unless every robot's odometry (poses_odom) is finite at every step: each
    robot's path is placed in another's frame through it."""
    finite = np.isfinite(job.arrays["poses_odom"]).all(axis=2)
    if not finite.all():
        r, s = (int(k) for k in np.argwhere(~finite)[0])
        raise DataError(f"{job.stem}: poses_odom, the robots' odometry, is not finite for robot "
                        f"{robot_names(job)[r]} at step {s} "
                        f"({job.arrays['poses_odom'][r, s].tolist()}; {(~finite).sum()} of "
                        f"{finite.size} poses): the paths cannot be placed through it")


def robot_paths(job: JobResult, stream: str, reference: int = 0
                ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every robot's path in the reference robot's odometry frame, through a method's estimates
    (or the truth: `stream` = TRUTH).

    A robot j is placed through the estimate of the pair (reference, j), or the inverse of the
    estimate of (j, reference) when only that pair was aligned; robots in neither are left out.
    The reference robot's own path (its odometry) is given for the truth only.

    Returns:
        robot -> (steps (k,), T_oref_b (k, 3, 3)): the k steps with an estimate (truth: with a
        known truth) and the poses there; robots with no such step are left out.
    Raises:
        ConfigError: `reference` is no robot of the job, or `stream` no estimate of it.
    """
    check_reference(job, reference)
    a = job.arrays
    key = "truth" if stream == TRUTH else f"est_{stream}"
    if key not in a:
        raise ConfigError(f"method {stream!r}: not in {job.stem} (has "
                          f"{', '.join(_streams(job))})")
    T_o_b = se2_from_params(a["poses_odom"])
    paths = {}
    if stream == TRUTH:
        paths[reference] = (np.arange(T_o_b.shape[1]), T_o_b[reference])
    for j in range(len(T_o_b)):
        found = frame_alignment(job, key, reference, j)
        if found is not None and found[0].size:
            steps, T_oref_oj = found
            paths[j] = (steps, T_oref_oj @ T_o_b[j][steps])
    return paths


def frame_alignment(job: JobResult, key: str, reference: int, j: int
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """Robot j's odometry frame in the reference robot's, T_oref_oj, from the job's (P, S, 3)
    array `key` (an estimate or the truth): the pair (reference, j), or the inverse of
    (j, reference) when only that pair was aligned.

    Returns:
        (steps (k,), T_oref_oj (k, 3, 3)) at the k steps the array has a value; None when
        neither pair was aligned.
    """
    if (reference, j) in job.pairs:
        values, inverse = job.arrays[key][job.pairs.index((reference, j))], False
    elif (j, reference) in job.pairs:
        values, inverse = job.arrays[key][job.pairs.index((j, reference))], True
    else:
        return None
    steps = np.flatnonzero(np.all(np.isfinite(values), axis=1))
    T_oref_oj = se2_from_params(values[steps])
    return steps, invert(T_oref_oj) if inverse else T_oref_oj


def _times(job: JobResult) -> np.ndarray:
    """(S,) s, the job's exchanges on the run's clock (a recorded job keeps its start, t0)."""
    return job.arrays["times"] + float(job.arrays.get("t0", 0.0))


def estimate_streams(job: JobResult) -> list[str]:
    """The names of the job's estimate streams, one per method (`est_<name>` arrays)."""
    return [k.removeprefix("est_") for k in job.arrays if k.startswith("est_")]


def _streams(job: JobResult) -> list[str]:
    """The truth (where the job knows it) and every method's estimate stream."""
    truth = [TRUTH] if np.isfinite(job.arrays["truth"]).any() else []
    return truth + estimate_streams(job)


def _folder(root: Path, job: JobResult, reference: int) -> Path:
    return root / "trajectories" / job.stem / f"frame_{robot_names(job)[reference]}"


def planar_trajectory(times, T):
    """An evo trajectory (`PoseTrajectory3D`) of planar poses: times (k,) s, T (k, 3, 3) SE(2),
    placed at z = 0."""
    from evo.core.trajectory import PoseTrajectory3D

    T = np.asarray(T, dtype=float)
    half_yaw = 0.5 * np.arctan2(T[:, 1, 0], T[:, 0, 0])
    xyz = np.column_stack([T[:, 0, 2], T[:, 1, 2], np.zeros(len(T))])
    quat_wxyz = np.column_stack([np.cos(half_yaw), np.zeros((len(T), 2)), np.sin(half_yaw)])
    # every representation given: evo would otherwise build them pose by pose
    return PoseTrajectory3D(xyz, quat_wxyz, np.asarray(times, dtype=float),
                            poses_se3=list(se2_to_se3(T)))


def write_tum(root: Path, job: JobResult, reference: int = 0,
              streams: list[str] | None = None) -> Path:
    """The truth's and the methods' paths of a job as TUM files under `root` (see the module);
    returns the folder of the reference robot's frame.

    Args:
        streams: the estimate streams to write (None: every one the job has).
    """
    from evo.tools.file_interface import write_tum_trajectory_file

    folder = _folder(root, job, reference)
    names, times = robot_names(job), _times(job)
    for stream in _streams(job):
        if streams is not None and stream != TRUTH and stream not in streams:
            continue
        (folder / stream).mkdir(parents=True, exist_ok=True)
        for robot, (steps, T) in robot_paths(job, stream, reference).items():
            write_tum_trajectory_file(str(folder / stream / f"{names[robot]}.tum"),
                                      planar_trajectory(times[steps], T))
    return folder


def write_g2o(root: Path, job: JobResult, reference: int = 0) -> Path:
    """The truth's and every method's paths of a job as g2o pose graphs under `root`, one file
    per stream (`<stream>.g2o`); returns their folder.

    Vertices (VERTEX_SE2) are every robot's poses in the reference robot's frame; edges
    (EDGE_SE2) join each robot's consecutive poses (its odometry between them) and, at each step
    with an estimate, the reference robot's pose to the other robot's (the alignment). Every edge
    carries the identity information matrix: odometry has no covariance in a saved run, and a
    method's alignment covariance is over T_oi_oj's parameters, not over this body-to-body
    edge. Robot r's pose at step s is vertex r * S + s (S steps).
    """
    import gtsam

    folder = _folder(root, job, reference)
    folder.mkdir(parents=True, exist_ok=True)
    S = job.n_steps
    unit = gtsam.noiseModel.Unit.Create(3)
    odometry = job.arrays["poses_odom"][reference]  # (S, 3) x, y, theta
    for stream in _streams(job):
        paths = robot_paths(job, stream, reference)
        paths[reference] = (np.arange(len(odometry)), se2_from_params(odometry))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for robot, (steps, T) in paths.items():
            keys = [robot * S + int(s) for s in steps]
            poses = [gtsam.Pose2(*xyt) for xyt in se2_to_params(T)]
            for key, pose in zip(keys, poses, strict=True):
                values.insert(key, pose)
            for k in range(len(keys) - 1):
                graph.add(gtsam.BetweenFactorPose2(keys[k], keys[k + 1],
                                                   poses[k].between(poses[k + 1]), unit))
            if robot != reference:
                for key, pose, s in zip(keys, poses, steps, strict=True):
                    ref_key = reference * S + int(s)
                    T_bref_b = gtsam.Pose2(*odometry[s]).between(pose)
                    graph.add(gtsam.BetweenFactorPose2(ref_key, key, T_bref_b, unit))
        path = folder / f"{stream}.g2o"
        path.unlink(missing_ok=True)
        gtsam.writeG2o(graph, values, str(path))
        if not path.is_file():
            raise DataError(f"{path}: could not be written")
    return folder


def _ros_token(name: str, prefix: str) -> str:
    """`name` as a ROS 2 name token: other characters (ASCII letters, digits and `_` only)
    as `_`, `prefix` before a leading non-letter, doubled `_` single."""
    token = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", name))
    return token if token[:1].isalpha() and token[:1].isascii() else prefix + token.lstrip("_")


def write_rosbag2(root: Path, job: JobResult, reference: int = 0) -> Path:
    """Every pair's alignments of a job, each method's and the truth, as a ROS 2 bag (rosbag2,
    MCAP storage) in `trajectories/<job stem>/rosbag2/` (replaced if there); returns it.

    Topics (see `tcaff_gtsam.node.ros2`; robots named as ROS 2 name tokens, `r<k>` for a
    number): `/<robot_i>/tcaff/<method>/alignment/<robot_j>` at the steps the method has an
    estimate and `/<robot_i>/tcaff/truth/<robot_j>` where the truth is known, each a
    geometry_msgs/msg/PoseWithCovarianceStamped in `<robot_i>/odom` stamped and logged at its
    exchange's time, with the covariance of (x, y, yaw) the method reported (`cov_<method>`;
    zero for the truth, for a method that reports none and in jobs saved before covariances
    were kept). `reference` is unused: every pair is written.

    Raises:
        DataError: robot or method names that become the same topic name, or times a ROS 2
            stamp cannot hold (before 0 s, from 2**31 s on), naming the job.
    """
    import shutil

    from tcaff_gtsam.node.bag import ns, write_bag
    from tcaff_gtsam.node.ros2 import ALIGNMENT_TYPE, pose_message

    names = [_ros_token(name, "r") for name in robot_names(job)]
    streams = [("truth", "truth")] + [(s, f"est_{s}") for s in estimate_streams(job)]
    labels = ["truth"] + [f"{_ros_token(s, 'm')}/alignment" for s, _ in streams[1:]]
    if len(set(names)) < len(names) or len(set(labels)) < len(labels):
        raise DataError(f"{job.stem}: robots {robot_names(job)} or methods "
                        f"{[s for s, _ in streams]} share a ROS 2 name")
    times = _times(job)
    messages = []
    for (stream, key), label in zip(streams, labels, strict=True):
        covariances = job.arrays.get(f"cov_{stream}")
        for p, (i, j) in enumerate(job.pairs):
            topic = f"/{names[i]}/tcaff/{label}/{names[j]}"
            values = job.arrays[key][p]
            for s in np.flatnonzero(np.all(np.isfinite(values), axis=1)):
                t = float(times[s])
                P = np.zeros((3, 3)) if covariances is None else covariances[p, s]
                try:
                    messages.append((ns(t), topic, ALIGNMENT_TYPE, pose_message(
                        t, f"{names[i]}/odom", values[s], P)))
                except DataError as exc:  # a time ROS 2 cannot stamp
                    raise DataError(f"{job.stem}: {exc}") from None
    folder = root / "trajectories" / job.stem / "rosbag2"
    if folder.exists():
        shutil.rmtree(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    write_bag(folder, messages)
    return folder


def export(results: Path, fmt: str = "tum", reference: int = 0) -> list[Path]:
    """Write the trajectories of every job saved in a results folder (see
    `results.load_saved`) as TUM or g2o files, or its alignments as a ROS 2 bag, under
    `results/trajectories/`; returns the folders written.

    A job without the reference robot (a study's run of fewer robots) is skipped, with a
    warning, in TUM and g2o.

    Raises:
        ConfigError: an unknown format or a reference robot no job has (the ROS 2 bag holds
            every pair and needs none, but such an index is refused there too).
        DataError: the folder holds no saved job, a job's files are unreadable, its
            odometry is not finite (tum, g2o: its paths are placed through it), or the files
            cannot be written (a file where a folder goes, a full disk).
    """
    if fmt not in FORMATS:
        raise ConfigError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
    write = {"tum": write_tum, "g2o": write_g2o, "rosbag2": write_rosbag2}[fmt]
    jobs = load_saved(results)
    # the bag holds every pair's alignments, the reference's or not
    placed = with_robot(jobs, reference, skipping=fmt != "rosbag2")
    if fmt != "rosbag2":  # the paths are placed through the odometry
        jobs = placed
        for job in jobs:  # before anything is written
            check_odometry(job)
    written = []
    for job in jobs:
        try:
            written.append(write(Path(results), job, reference))
        except OSError as exc:  # the folders of the jobs written before stay
            raise DataError(f"{job.stem}: its {fmt} files could not be written under "
                            f"{Path(results) / 'trajectories'} ({exc})") from None
    return written
