"""How many seconds of sightings a map may hold: kappa from how fast the odometry drifts.

A map holds the objects seen in the last kappa seconds, each placed with the odometry of the
moment it was seen. Over that span the odometry drifts: an object seen kappa seconds ago sits
where the drifted odometry put it, not where it is in the robot's current frame. The consistency
graph compares distances between two objects of one map with those of the other within CLIPPER's
epsilon, so a map is consistent while each object is misplaced by at most epsilon / 2. The rule
(the paper sets kappa "by how fast drift accumulates"): kappa is the longest span, on a grid,
whose root-mean-square misplacement stays within epsilon / 2 (`advise_kappa`).

`misplacement` measures it on any pair of trajectories (the truth and the odometry of the same
robot, SE(2) poses of the body in a world and in the odometry frame); `vio_like_odometry` draws
the VIO-like drift of the MRCLAM loader (heading random walk, distance scale error) and
`random_drive` a path to draw it on, for a user who knows their odometry's drift
rates but has no recording at hand.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import DataError
from .geometry import _se2_from_params, _se2_to_params, wrap_angle
from .inputs import real_array
from .params import ClipperParams, _finite

__all__ = ["MAX_SAMPLES", "SPANS", "KappaAdvice", "advise_kappa", "interpolate_poses",
           "misplacement", "random_drive", "vio_like_odometry"]

#: the spans tried by default, s: 30 s steps from 30 s, as the MRCLAM config's rule, with 5,
#: 10 and 20 s (the paper's outdoor and indoor choices) before them
SPANS = np.array([5.0, 10.0, 20.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0, 240.0, 300.0])

#: the most samples a call draws (`random_drive`) or evaluates per span (`misplacement`): a
#: day's drive at 0.1 s steps is 864 000, and a million poses (3, 3) are 72 MB, each
#: temporary of the same size again
MAX_SAMPLES = 1_000_000


@dataclass(frozen=True)
class KappaAdvice:
    """The advised span and what it rests on.

    Attributes:
        kappa: s, the longest span whose misplacement (and every shorter one's) stays within
            `bound`; None when even the shortest does not (the odometry drifts too fast for
            any map of these spans to stay consistent). A span without samples (NaN, longer
            than the trajectory) ends the run: the advice is then at most the longest span
            measured.
        spans: (s,) the spans tried, s, increasing.
        rms: (s,) the root-mean-square misplacement at each span, m (NaN: no sample).
        bound: epsilon / 2, m.
    """

    kappa: float | None
    spans: np.ndarray
    rms: np.ndarray
    bound: float


def _poses(owner: str, name: str, value, k: int | None = None) -> np.ndarray:
    arr = real_array(owner, name, value)
    if arr.ndim != 3 or arr.shape[1:] != (3, 3) or (k is not None and arr.shape[0] != k):
        want = "(k, 3, 3)" if k is None else f"({k}, 3, 3)"
        raise DataError(f"{owner}: {name} must be {want} SE(2) poses, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise DataError(f"{owner}: {name} holds non-finite values")
    return arr


def _spans(owner: str, spans) -> np.ndarray:
    arr = real_array(owner, "spans", spans)
    if (arr.ndim != 1 or arr.size == 0 or not np.isfinite(arr).all() or (arr <= 0).any()
            or (np.diff(arr) <= 0).any()):
        raise DataError(f"{owner}: spans must be increasing seconds > 0, got {arr!r}")
    return arr


def _times(owner: str, times) -> np.ndarray:
    arr = real_array(owner, "times", times)
    if arr.ndim != 1 or arr.size < 2 or not np.isfinite(arr).all() or (np.diff(arr) <= 0).any():
        raise DataError(f"{owner}: times must be 2 or more increasing finite seconds, got "
                        f"shape {arr.shape}")
    return arr


def _check_rng(owner: str, rng) -> None:
    if not isinstance(rng, np.random.Generator):
        raise DataError(f"{owner}: rng must be a numpy Generator (np.random.default_rng(seed)), "
                        f"got {type(rng).__name__}")


def interpolate_poses(times: np.ndarray, poses: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(q, 3) poses (x, y, theta) at the times `at` (q,) s, linear between the samples
    `poses` (k, 3) at `times` (k,) s, increasing (headings unwrapped, so a turn through
    +-pi is interpolated the short way); held at the ends."""
    heading = np.unwrap(poses[:, 2])
    return np.column_stack([np.interp(at, times, poses[:, 0]),
                            np.interp(at, times, poses[:, 1]),
                            wrap_angle(np.interp(at, times, heading))])


def _at(times: np.ndarray, params: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(q, 3, 3) SE(2) poses at `at` (`interpolate_poses`)."""
    return _se2_from_params(interpolate_poses(times, params, at))


def misplacement(times, T_world_body, T_odom_body, spans=SPANS, landmark_range: float = 2.0,
                 every: float = 5.0) -> np.ndarray:
    """How far the odometry misplaces, in the robot's current frame, an object it saw `span`
    seconds earlier, for each span.

    The object is `landmark_range` metres straight ahead of the body when seen. For each
    span, every `every` s from `span` after the first time: where the object seen at t - span
    lies in the body frame at t, placed by the odometry, against the same by the truth.

    Args:
        times: (k,) s, increasing; or a list of such, one per robot (the errors of all are
            pooled), with lists of poses to match.
        T_world_body: (k, 3, 3) the true SE(2) poses of the body.
        T_odom_body: (k, 3, 3) the odometry's poses of the body (any odometry frame).
        spans: (s,) s > 0, increasing.
        landmark_range: m >= 0.
        every: s > 0.
    Returns:
        (s,) the root mean square of that error over the times (and robots), m; NaN for a
        span longer than every trajectory.
    Raises:
        DataError: any argument of the wrong shape or out of range; `every` so short that a
            span of a trajectory would be evaluated at more than `MAX_SAMPLES` times.
    """
    o = "misplacement"
    # several robots: sequences of arrays (a single robot's times may be a list of numbers)
    several = isinstance(times, (list, tuple)) and len(times) > 0 and np.ndim(times[0]) == 1
    if several:
        if not all(isinstance(v, (list, tuple)) and len(v) == len(times)
                   for v in (T_world_body, T_odom_body)):
            raise DataError(f"{o}: with {len(times)} robots' times, T_world_body and "
                            f"T_odom_body must be lists of {len(times)} pose arrays")
        runs = list(zip(times, T_world_body, T_odom_body, strict=True))
    else:
        runs = [(times, T_world_body, T_odom_body)]
    spans = _spans(o, spans)
    if not (_finite(landmark_range) and landmark_range >= 0):
        raise DataError(f"{o}: landmark_range must be a finite number >= 0 metres, got "
                        f"{landmark_range!r}")
    if not (_finite(every) and every > 0):
        raise DataError(f"{o}: every must be a finite number > 0 seconds, got {every!r}")
    landmark = np.array([float(landmark_range), 0.0, 1.0])
    # per span: the sum of the squared errors and their number, over the times and robots
    squares, counts = np.zeros(spans.size), np.zeros(spans.size, np.int64)
    for t, T_true, T_odom in runs:
        t = _times(o, t)
        true_params = _se2_to_params(_poses(o, "T_world_body", T_true, t.size))
        odom_params = _se2_to_params(_poses(o, "T_odom_body", T_odom, t.size))
        # the shortest span is evaluated at the most times
        most = (t[-1] + 1e-9 - t[0] - spans[0]) / every
        if most > MAX_SAMPLES:
            raise DataError(f"{o}: every = {every!r} s evaluates the {t[-1] - t[0]:g} s "
                            f"trajectory at {most:.3g} times per span, more than "
                            f"MAX_SAMPLES = {MAX_SAMPLES}: every must be at least "
                            f"{(t[-1] - t[0]) / MAX_SAMPLES:.3g} s for it")
        for i, span in enumerate(spans):
            at = np.arange(t[0] + span, t[-1] + 1e-9, every)
            if at.size == 0:
                continue
            seen = []
            for params in (odom_params, true_params):
                now, then = _at(t, params, at), _at(t, params, at - span)
                seen.append(np.linalg.solve(now, then) @ landmark)
            squares[i] += np.sum(np.square(seen[0] - seen[1])[:, :2])
            counts[i] += at.size
    with np.errstate(invalid="ignore"):  # 0 / 0: a span longer than every trajectory
        return np.sqrt(squares / counts)


def advise_kappa(rms, spans=SPANS, epsilon: float = ClipperParams().epsilon) -> KappaAdvice:
    """The longest span whose misplacement, and every shorter span's, is within epsilon / 2.

    Args:
        rms: (s,) m, `misplacement` at `spans` (several runs: take their maximum first).
        spans: (s,) s > 0, increasing.
        epsilon: m > 0, CLIPPER's (`ClipperParams.epsilon`).
    Raises:
        DataError: rms or spans of the wrong shape, epsilon not a finite number > 0.
    """
    o = "advise_kappa"
    spans = _spans(o, spans)
    rms = real_array(o, "rms", rms)
    if rms.shape != spans.shape or (rms < 0).any():
        raise DataError(f"{o}: rms must be {spans.shape} metres >= 0 (NaN: no sample), got "
                        f"shape {rms.shape}")
    if not (_finite(epsilon) and epsilon > 0):
        raise DataError(f"{o}: epsilon must be a finite number > 0 metres, got {epsilon!r}")
    bound = 0.5 * float(epsilon)
    within = np.isfinite(rms) & (rms <= bound)
    # the first span that is not within ends the run: a longer span is no better
    run = int(np.argmin(within)) if not within.all() else within.size
    return KappaAdvice(float(spans[run - 1]) if run else None, spans, rms, bound)


def random_drive(rng: np.random.Generator, duration: float, speed: float,
                 turn_std_deg_per_sqrt_s: float = 20.0, step: float = 0.1
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A path to draw odometry drift on: a body driving at `speed` m/s whose heading takes a
    random walk (std `turn_std_deg_per_sqrt_s` after one second), from the origin.

    Returns:
        times (k,) s from 0 to `duration`, every `step` s, and T_world_body (k, 3, 3).
    Raises:
        DataError: a duration, speed, turn or step that is not a finite number > 0 (>= 0 for
            speed and turn); a duration of more than `MAX_SAMPLES` steps.
    """
    o = "random_drive"
    _check_rng(o, rng)
    for name, value, low in (("duration", duration, 0.0), ("step", step, 0.0)):
        if not (_finite(value) and value > low):
            raise DataError(f"{o}: {name} must be a finite number > 0, got {value!r}")
    for name, value in (("speed", speed), ("turn_std_deg_per_sqrt_s", turn_std_deg_per_sqrt_s)):
        if not (_finite(value) and value >= 0):
            raise DataError(f"{o}: {name} must be a finite number >= 0, got {value!r}")
    steps = duration / step
    if not steps <= MAX_SAMPLES - 1:  # also inf, when step is tiny against duration
        raise DataError(f"{o}: duration = {duration!r} s with step = {step!r} s is {steps:.3g} "
                        f"steps, more than MAX_SAMPLES - 1 = {MAX_SAMPLES - 1}: a shorter "
                        f"duration or a longer step")
    n = math.ceil(steps) + 1
    times = step * np.arange(n)
    turns = math.radians(turn_std_deg_per_sqrt_s) * math.sqrt(step) * rng.standard_normal(n - 1)
    heading = np.r_[0.0, np.cumsum(turns)]
    xy = np.vstack([np.zeros(2), np.cumsum(speed * step * np.column_stack(
        [np.cos(heading[:-1]), np.sin(heading[:-1])]), axis=0)])
    return times, _se2_from_params(np.column_stack([xy, wrap_angle(heading)]))


def vio_like_odometry(rng: np.random.Generator, times, T_world_body,
                      heading_rw_deg_per_sqrt_min: float, scale_std: float) -> np.ndarray:
    """The truth with VIO-like drift: the heading takes a random walk (after t minutes its
    error's std is `heading_rw_deg_per_sqrt_min` * sqrt(t) degrees) and every distance moved
    is scaled by 1 + e, e ~ N(0, scale_std^2) drawn once.

    Args:
        times: (k,) s, increasing (the finer, the closer to a continuous random walk).
        T_world_body: (k, 3, 3) the true poses.
    Returns:
        (k, 3, 3) the odometry's poses, the odometry frame at the first pose.
    Raises:
        DataError: arrays of the wrong shape, drift rates that are not finite numbers >= 0.
    """
    o = "vio_like_odometry"
    _check_rng(o, rng)
    times = _times(o, times)
    T = _poses(o, "T_world_body", T_world_body, times.size)
    for name, value in (("heading_rw_deg_per_sqrt_min", heading_rw_deg_per_sqrt_min),
                        ("scale_std", scale_std)):
        if not (_finite(value) and value >= 0):
            raise DataError(f"{o}: {name} must be a finite number >= 0, got {value!r}")
    step = np.linalg.solve(T[:-1], T[1:])  # body-frame increments
    scale = 1.0 + scale_std * rng.standard_normal()
    sigma = math.radians(heading_rw_deg_per_sqrt_min) / math.sqrt(60.0) * np.sqrt(np.diff(times))
    drift = np.cumsum(sigma * rng.standard_normal(step.shape[0]))
    heading = (np.r_[0.0, np.cumsum(np.arctan2(step[:, 1, 0], step[:, 0, 0]))]
               + np.r_[0.0, drift])
    moved = scale * step[:, :2, 2]
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    xy = np.vstack([np.zeros(2), np.cumsum(np.column_stack([c * moved[:, 0] - s * moved[:, 1],
                                                            s * moved[:, 0] + c * moved[:, 1]]),
                                           axis=0)])
    return _se2_from_params(np.column_stack([xy, wrap_angle(heading)]))
