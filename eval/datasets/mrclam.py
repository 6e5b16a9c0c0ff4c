"""UTIAS MRCLAM data sets: five robots, fifteen identical landmarks, Vicon truth.

A data set folder holds whitespace-separated text files (`#` comment lines at the top, times in
Unix seconds):

- `Barcodes.dat`: subject, barcode. Subjects 1-5 are the robots, 6-20 the landmarks.
- `Landmark_Groundtruth.dat`: subject, x [m], y [m], x std, y std (world frame).
- `Robot<N>_Odometry.dat`: time, forward velocity [m/s], angular velocity [rad/s] (commanded).
- `Robot<N>_Measurement.dat`: time, barcode, range [m], bearing [rad] (camera sightings).
- `Robot<N>_Groundtruth.dat`: time, x [m], y [m], orientation [rad] (Vicon, world frame).

`read_dataset` reads and checks them; `load_run` turns them into a `RecordedRun` of object maps:

- Odometry: `raw` dead-reckons the commanded velocities; `vio` is the Vicon truth with seeded
  visual-inertial-like drift: the heading takes a random walk (after t minutes its error's std
  is `heading_rw_deg_per_sqrt_min` * sqrt(t) degrees) and every distance driven is scaled by
  (1 + e), e drawn once per robot with std `scale_std` (0.01: 1 % of distance). Each robot's
  odometry frame is its pose when the run starts.
- Maps: a robot's sightings of landmarks are placed in its odometry frame through its odometry
  pose at the sighting. At each 1 Hz exchange its map holds every landmark it sighted at least
  `nu` times in the last `kappa` seconds, at the mean of those sightings, stamped with the last
  one. Sightings are grouped by the barcode the robot's own camera read (its own data
  association, which a robot has); the map it shares carries no identity, so aligners see only
  geometry. The landmarks are identical tubes: every entry has the same width and height.
  Sightings of robots are left out.
- Truth: T_oi_oj from Vicon and the odometry at every exchange; two maps overlap when they hold
  at least `min_shared` of the same landmarks.

Rows the published data sets are known to hold and that cannot be used are skipped and counted
in `MrclamData.skipped` (sightings of a barcode in no table: data set 6 has six). Anything else
wrong (a missing file, a short or non-numeric row, a non-finite value, times that go backwards,
a subject outside 1-20, no usable rows, odometry and truth that share more than `MAX_SPAN`) is
a `DataError` naming the file and line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, se2_to_se3
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.span import interpolate_poses, misplacement, vio_like_odometry

from ..runs import RecordedRun, RunSettings
from .text_tables import read_table

__all__ = ["LANDMARK_SIZE", "MrclamData", "RobotRecord", "load_run", "map_drift", "read_dataset"]

ROBOTS = range(1, 6)        # subjects
LANDMARKS = range(6, 21)    # subjects
SUBJECTS = range(1, 21)
#: s, the longest time the robots' odometry and truth may share. The data sets last minutes
#: (data set 6: 15); a span of more than a day comes from a stray time stamp (a row of another
#: day), and its 1 Hz maps and 10 Hz VIO-like odometry would fill the memory (a span of 1e9 s
#: asks for 7 GiB in one array) long before anything is aligned
MAX_SPAN = 86_400.0
#: width and height [m] given to every landmark of a map (the tubes are identical)
LANDMARK_SIZE = (0.2, 0.5)
_VIO_STEP = 0.1  # s between the truth samples the VIO-like odometry integrates


def _check_times(path: Path, times: np.ndarray, lines: np.ndarray) -> None:
    back = np.flatnonzero(np.diff(times) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise DataError(f"{path}:{lines[k]}: time goes backwards ({times[k]:.3f} s after "
                        f"{times[k - 1]:.3f} s on line {lines[k - 1]})")


@dataclass(frozen=True)
class RobotRecord:
    """One robot's files.

    Attributes:
        odometry: (k, 3) time [s], forward velocity [m/s], angular velocity [rad/s].
        sightings: (m, 4) time [s], subject, range [m], bearing [rad]; landmarks only.
        truth: (g, 4) time [s], x [m], y [m], heading [rad] in the world frame.
    """

    odometry: np.ndarray
    sightings: np.ndarray
    truth: np.ndarray


@dataclass(frozen=True)
class MrclamData:
    """A whole data set as read from its folder.

    Attributes:
        folder: where it was read from.
        landmarks: subject -> (x, y) [m] in the world frame.
        robots: robot subject (1-5) -> its record, for the robots with files.
        skipped: what was left out, and how often: {"sightings of unknown barcodes": 6}.
    """

    folder: Path
    landmarks: dict[int, np.ndarray]
    robots: dict[int, RobotRecord]
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def span(self) -> tuple[float, float]:
        """(start, end) s: the time every robot has odometry and truth."""
        start = max(max(r.odometry[0, 0], r.truth[0, 0]) for r in self.robots.values())
        end = min(min(r.odometry[-1, 0], r.truth[-1, 0]) for r in self.robots.values())
        return start, end


def _timed(path: Path, columns: int, bounds: list[tuple]) -> np.ndarray:
    """The rows of a file of times, with its first and last time (and their lines) appended
    to `bounds`."""
    rows, lines, _ = read_table(path, columns)
    _check_times(path, rows[:, 0], lines)
    bounds.append((path.name, lines[0], rows[0, 0], lines[-1], rows[-1, 0]))
    return rows


def read_dataset(folder: Path, robots: list[int] | None = None) -> MrclamData:
    """Read an MRCLAM data set folder.

    Args:
        robots: robot subjects to read (default: 1-5).
    Raises:
        DataError: see the module's notes.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"--data {folder}: not a folder")
    robots = list(ROBOTS) if robots is None else robots
    if not robots or any(r not in ROBOTS for r in robots):
        raise DataError(f"robots: need some of the robot subjects 1-5, got {robots}")
    path = folder / "Barcodes.dat"
    codes, lines, _ = read_table(path, 2)
    subject_of = {}
    for (subject, barcode), line in zip(codes, lines, strict=True):
        if (subject not in SUBJECTS or barcode != int(barcode)
                or int(barcode) in subject_of):
            raise DataError(f"{path}:{line}: expected a subject and a new barcode, got "
                            f"{subject:g} {barcode:g} (subjects are {SUBJECTS.start}-"
                            f"{SUBJECTS.stop - 1})")
        subject_of[int(barcode)] = int(subject)
    path = folder / "Landmark_Groundtruth.dat"
    table = read_table(path, 5, empty_ok=True).rows
    landmarks = {int(row[0]): row[1:3].copy() for row in table if int(row[0]) in LANDMARKS}
    if not landmarks:
        raise DataError(f"{path}: no landmark (subjects {LANDMARKS.start}-{LANDMARKS.stop - 1})")
    unknown = 0
    records = {}
    bounds = []  # (file name, first line, first time, last line, last time)
    for robot in robots:
        odometry, truth = (_timed(folder / f"Robot{robot}_{kind}.dat", columns, bounds)
                           for kind, columns in (("Odometry", 3), ("Groundtruth", 4)))
        path = folder / f"Robot{robot}_Measurement.dat"
        seen, lines, _ = read_table(path, 4, empty_ok=True)
        _check_times(path, seen[:, 0], lines)
        fractional = np.flatnonzero(seen[:, 1] != np.round(seen[:, 1]))
        if fractional.size:
            k = int(fractional[0])
            raise DataError(f"{path}:{lines[k]}: a barcode is a whole number, got "
                            f"{seen[k, 1]:g}")
        subjects = np.array([subject_of.get(int(b), -1) for b in seen[:, 1]], dtype=np.int64)
        unknown += int(np.sum(subjects < 0))
        keep = np.isin(subjects, list(landmarks))
        sightings = np.column_stack([seen[keep, 0], subjects[keep], seen[keep, 2:4]])
        records[robot] = RobotRecord(odometry, sightings.reshape(-1, 4), truth)
    skipped = {"sightings of unknown barcodes": unknown} if unknown else {}
    data = MrclamData(folder, landmarks, records, skipped)
    start, end = data.span
    if end - start > MAX_SPAN:
        first = max(bounds, key=lambda b: b[2])  # the latest start, and the earliest end
        last = min(bounds, key=lambda b: b[4])
        raise DataError(f"{folder}: the robots' odometry and truth share {end - start:.4g} s, "
                        f"more than a day ({MAX_SPAN:g} s), from {first[0]}:{first[1]} "
                        f"({start:.13g} s) to {last[0]}:{last[3]} ({end:.13g} s): a time stamp "
                        "is wrong")
    if end - start < 1.0:
        raise DataError(f"{folder}: the robots' odometry and truth share less than a second "
                        f"({start:.3f} to {end:.3f} s)")
    return data


# -- odometry ----------------------------------------------------------------------------------


def dead_reckoning(odometry: np.ndarray, start: float) -> tuple[np.ndarray, np.ndarray]:
    """Poses integrated from commanded velocities, the odometry frame at the pose at `start`.

    Each (v, w) holds until the next record (exact arcs of a unicycle).
    Returns: times (k,) s and poses (k, 3) (x, y, theta) in the odometry frame.
    """
    t, v, w = odometry[:, 0], odometry[:, 1], odometry[:, 2]
    dt = np.diff(t)
    dtheta = w[:-1] * dt
    theta = np.r_[0.0, np.cumsum(dtheta)]
    # chord of the arc: length v dt sinc(dtheta / 2), at the mid heading
    chord = v[:-1] * dt * np.sinc(dtheta / (2 * np.pi))
    mid = theta[:-1] + dtheta / 2
    xy = np.vstack([np.zeros(2), np.cumsum(np.column_stack([chord * np.cos(mid),
                                                            chord * np.sin(mid)]), axis=0)])
    poses = np.column_stack([xy, theta])
    origin = se2_from_params(interpolate_poses(t, poses, np.array([start]))[0])
    local = np.linalg.solve(origin, se2_from_params(poses))
    return t, np.column_stack([local[:, 0, 2], local[:, 1, 2],
                               np.arctan2(local[:, 1, 0], local[:, 0, 0])])


def vio_like(rng: np.random.Generator, truth: np.ndarray, start: float, end: float,
             heading_rw_deg_per_sqrt_min: float, scale_std: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """The Vicon truth with VIO-like drift, sampled every 0.1 s from `start` to past `end`.

    Args:
        truth: (g, 4) time, x, y, heading in the world frame.
        heading_rw_deg_per_sqrt_min: heading random walk: after t minutes the heading error's
            std is this * sqrt(t) degrees.
        scale_std: std of the robot's distance scale error (0.01: 1 % of distance).
    Returns: times (k,) s and poses (k, 3) in the odometry frame (its pose at `start`).
    """
    # one sample past the end, so that a pose at `end` is interpolated, never clamped
    times = start + _VIO_STEP * np.arange(math.ceil((end - start) / _VIO_STEP) + 2)
    T = se2_from_params(interpolate_poses(truth[:, 0], truth[:, 1:4], times))
    return times, se2_to_params(vio_like_odometry(rng, times, T, heading_rw_deg_per_sqrt_min,
                                                  scale_std))


def odometry_of(data: MrclamData, robot: int, odometry: str, seed: int | None,
                heading_rw_deg_per_sqrt_min: float, scale_std: float, end: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """A robot's odometry from the start of the data set to `end` (None: its end): times
    (k,) s on the data set's clock and poses (k, 3) in its odometry frame; raw (dead
    reckoning, no seed) or vio (VIO-like drift drawn from `seed`)."""
    if odometry not in ("raw", "vio"):
        raise DataError(f"odometry: expected 'raw' or 'vio', got {odometry!r}")
    if odometry == "vio" and seed is None:
        raise DataError("seed: VIO-like odometry needs a seed")
    record, (start, last) = data.robots[robot], data.span
    if odometry == "raw":
        return dead_reckoning(record.odometry, start)
    # a generator per robot: its drift does not depend on the other robots or duration
    return vio_like(np.random.default_rng([seed, robot]), record.truth, start,
                    last if end is None else end, heading_rw_deg_per_sqrt_min, scale_std)


def map_drift(data: MrclamData, odometry: str, seed: int | None, kappas: np.ndarray,
              heading_rw_deg_per_sqrt_min: float, scale_std: float, every: float = 5.0
              ) -> np.ndarray:
    """How far the odometry misplaces, in the robot's current frame, a landmark it sighted
    kappa seconds earlier: what bounds the span of sightings a map can hold before its
    objects disagree (the paper sets kappa by how fast drift accumulates).

    The landmark is taken straight ahead at the median sighting range of the data set. For
    each kappa, every robot and every `every` s from kappa after the start: the position of
    that landmark, placed with the odometry at t - kappa and seen from the odometry at t,
    against the same with the truth.

    Returns: (len(kappas),) root mean square of that error over robots and times [m] (NaN
    where the data set is shorter than kappa).
    """
    if not (isinstance(every, (int, float)) and math.isfinite(every) and every > 0):
        raise DataError(f"every: expected seconds > 0, got {every!r}")
    kappas = np.asarray(kappas, dtype=float)
    if kappas.ndim != 1 or not np.all(np.isfinite(kappas) & (kappas > 0)):
        raise DataError(f"kappas: expected a 1-D array of seconds > 0, got {kappas!r}")
    start, end = data.span
    sightings = np.concatenate([r.sightings for r in data.robots.values()])
    landmark_range = float(np.median(sightings[:, 2])) if len(sightings) else 0.0
    times, truths, odometries = [], [], []
    for robot, record in data.robots.items():
        odom_t, odom = odometry_of(data, robot, odometry, seed, heading_rw_deg_per_sqrt_min,
                                   scale_std)
        # both on the odometry's times within the data set's span
        t = np.unique(odom_t[(odom_t >= start) & (odom_t <= end)])
        times.append(t)
        truths.append(se2_from_params(interpolate_poses(record.truth[:, 0],
                                                        record.truth[:, 1:4], t)))
        odometries.append(se2_from_params(interpolate_poses(odom_t, odom, t)))
    if kappas.size == 0:
        return np.zeros(0)
    spans, back = np.unique(kappas, return_inverse=True)  # increasing, as misplacement wants
    return misplacement(times, truths, odometries, spans, landmark_range, every)[back]


# -- maps --------------------------------------------------------------------------------------


def _maps(sightings: np.ndarray, odom_times: np.ndarray, odom_poses: np.ndarray,
          exchanges: np.ndarray, kappa: float, nu: int) -> tuple[list[ObjectMap], list[np.ndarray]]:
    """The robot's map at each exchange, and the landmark subject of each entry."""
    t = sightings[:, 0]
    pose = interpolate_poses(odom_times, odom_poses, t)
    r, b = sightings[:, 2], sightings[:, 3]
    x = pose[:, 0] + r * np.cos(pose[:, 2] + b)
    y = pose[:, 1] + r * np.sin(pose[:, 2] + b)
    subject = sightings[:, 1].astype(np.int64)
    maps, labels = [], []
    width, height = LANDMARK_SIZE
    for now in exchanges:
        window = (t <= now) & (now - t < kappa)
        ids, inverse, counts = np.unique(subject[window], return_inverse=True, return_counts=True)
        keep = counts >= nu
        n = len(ids)
        cx = np.bincount(inverse, x[window], n) / np.maximum(counts, 1)
        cy = np.bincount(inverse, y[window], n) / np.maximum(counts, 1)
        last = np.full(n, -np.inf)
        np.maximum.at(last, inverse, t[window])
        # entries in order of position, not of identity: the order must not tell them apart
        order = np.flatnonzero(keep)[np.lexsort((cy[keep], cx[keep]))]
        k = order.size
        maps.append(ObjectMap(np.column_stack([cx[order], cy[order], np.zeros(k)]),
                              np.full(k, width), np.full(k, height), last[order]))
        labels.append(ids[order])
    return maps, labels


def load_run(data: MrclamData, odometry: str, seed: int | None, kappa: float, nu: int,
             min_shared: int, heading_rw_deg_per_sqrt_min: float, scale_std: float,
             window: int | None = None, graph_drift: tuple[float, float] | None = None,
             duration: float | None = None, name: str | None = None,
             pairs: list[tuple[int, int]] | None = None
             ) -> tuple[RecordedRun, list[list[np.ndarray]]]:
    """The data set as a recorded run of object maps at 1 Hz exchanges.

    Args:
        odometry: "raw" or "vio" (see the module's notes); `seed` draws the VIO-like drift
            (raw odometry has no randomness: None).
        kappa, nu: a map holds the landmarks sighted at least nu times in the last kappa s.
        min_shared: landmarks two maps must share to count as overlapping.
        window, graph_drift: the run's TCAFF window and iSAM2 drift (None: the defaults).
        duration: s of data to use from the start (None: all).
        pairs: directed pairs of robot subjects (i, j) to align (None: all of them).
    Returns:
        The run (times: s since the start), and labels[r][s]: the landmark subject of each
        entry of robot r's map at exchange s (for scoring; never handed to an aligner).
    """
    start, end = data.span
    if duration is not None:
        end = min(end, start + duration)
    exchanges = start + np.arange(1.0, math.floor(end - start) + 1.0)
    if exchanges.size == 0:
        raise DataError(f"{data.folder}: less than one second of data to align")
    maps, labels, T_world_odom, T_odom_body = [], [], [], []
    for robot, record in data.robots.items():
        odom_t, odom = odometry_of(data, robot, odometry, seed, heading_rw_deg_per_sqrt_min,
                                   scale_std, end)
        # maps are stamped on the run's clock: seconds since the start; sightings from before
        # it have no odometry pose
        sightings = record.sightings[record.sightings[:, 0] >= start].copy()
        sightings[:, 0] -= start
        robot_maps, robot_labels = _maps(sightings, odom_t - start, odom, exchanges - start,
                                         kappa, nu)
        maps.append(robot_maps)
        labels.append(robot_labels)
        T_ob = se2_from_params(interpolate_poses(odom_t, odom, exchanges))
        T_wb = se2_from_params(interpolate_poses(record.truth[:, 0], record.truth[:, 1:4],
                                            exchanges))
        T_world_odom.append(se2_to_se3(T_wb @ np.linalg.inv(T_ob)))
        T_odom_body.append(se2_to_se3(T_ob))
    n = len(maps)
    shared = np.zeros((n, n, exchanges.size), dtype=bool)
    for i in range(n):
        for j in range(n):
            if i != j:
                shared[i, j] = [np.intersect1d(a, b).size >= min_shared
                                for a, b in zip(labels[i], labels[j], strict=True)]
    settings = RunSettings(kappa, window, graph_drift)
    index = {robot: k for k, robot in enumerate(data.robots)}
    if pairs is not None:
        unknown = sorted({r for pair in pairs for r in pair} - set(index))
        if unknown or any(i == j for i, j in pairs):
            raise DataError(f"pairs: robots {sorted(index)} of the data set, two different ones "
                            f"per pair; got {pairs}")
        pairs = [(index[i], index[j]) for i, j in pairs]
    run = RecordedRun(name or data.folder.name, settings, exchanges - start, maps,
                      np.array(T_world_odom), np.array(T_odom_body), shared,
                      tuple(f"robot{r}" for r in data.robots), pairs)
    return run, labels
