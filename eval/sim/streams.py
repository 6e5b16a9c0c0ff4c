"""Synthetic streams of frame-alignment measurements with a known truth, for TCAFF.

Each step holds at most one correct measurement (the truth plus noise) among wrong alignments
scattered over the plane, which is what MNO-CLIPPER hands the filter when maps overlap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, wrap_angle
from tcaff_gtsam.params import MAX_SOLUTIONS

from .sizes import count

__all__ = [
    "MAX_PAIRS",
    "MAX_PER_STEP",
    "MAX_STEPS",
    "AlignmentStream",
    "DecoyStream",
    "RobotTeamStreams",
    "alignment_stream",
    "decoy_stream",
    "drifting_truth",
    "observe_alignments",
    "robot_team_streams",
    "wrong_alignments",
]

DEG = np.pi / 180.0

#: the longest stream, steps (of every directed pair together in `robot_team_streams`): 28
#: hours of exchanges at 1 Hz, 2.4 GB with MAX_PER_STEP measurements at every step
MAX_STEPS = 100_000

#: the most wrong alignments a step holds (`wrong_alignments`' k, `outliers`' high end): as
#: many as MNO-CLIPPER hands the filter at most (`params.MAX_SOLUTIONS`)
MAX_PER_STEP = MAX_SOLUTIONS

#: the most object pairs a `decoy_stream`'s evidence holds, steps x (outliers[1] + 2) x
#: objects_per_match at the most: 160 MB
MAX_PAIRS = 10_000_000


def _outliers(owner: str, outliers) -> tuple[int, int]:
    """The inclusive range (low, high) of the wrong alignments per step: ints, 0 <= low <=
    high <= MAX_PER_STEP; DataError naming `owner` otherwise."""
    if not (isinstance(outliers, (tuple, list)) and len(outliers) == 2):
        raise DataError(f"{owner}: outliers = {outliers!r:.60}: must be a (low, high) pair of "
                        f"ints")
    low = count(owner, "outliers[0]", outliers[0], MAX_PER_STEP, "MAX_PER_STEP")
    return low, count(owner, "outliers[1]", outliers[1], MAX_PER_STEP, "MAX_PER_STEP", low)


@dataclass(frozen=True)
class AlignmentStream:
    """Attributes:
        truth: (n, 3) true (x [m], y [m], theta [rad]) of T_oi_oj per step.
        zs: n arrays (k_t, 3) of measurements, in random order.
        correct: (n,) index of the correct measurement in zs[t], -1 if the step has none.
    """

    truth: np.ndarray
    zs: list[np.ndarray]
    correct: np.ndarray

    def __len__(self) -> int:
        return len(self.zs)


def wrong_alignments(rng: np.random.Generator, k: int, spread: float = 15.0) -> np.ndarray:
    """(k, 3) alignments uniform over +-spread metres and all headings; k an int in
    [0, MAX_PER_STEP] (DataError otherwise)."""
    k = count("wrong_alignments", "k", k, MAX_PER_STEP, "MAX_PER_STEP")
    return np.column_stack([rng.uniform(-spread, spread, (k, 2)), rng.uniform(-np.pi, np.pi, k)])


def alignment_stream(rng: np.random.Generator, steps: int, x0=(3.0, -2.0, 1.0),
                     drift=(0.005, 0.005, 0.05 * DEG), noise=(0.2, 0.2, 2.0 * DEG),
                     p_empty: float = 0.2, outliers: tuple[int, int] = (0, 4),
                     spread: float = 15.0,
                     jumps: dict[int, tuple[float, float, float]] | None = None
                     ) -> AlignmentStream:
    """A drifting true alignment observed with noise among outliers.

    Args:
        steps: length of the stream, an int in [0, MAX_STEPS].
        x0: the true (x, y, theta) at the first step.
        drift: per-step std of the random walk of the truth (x, y, theta).
        noise, p_empty, outliers, spread: see `observe_alignments`.
        jumps: {step: (dx, dy, dtheta)} added to the truth at that step (a re-initialised
            odometry frame).
    """
    steps = count("alignment_stream", "steps", steps, MAX_STEPS, "MAX_STEPS")
    return observe_alignments(rng, drifting_truth(rng, steps, x0, drift, jumps), noise,
                              p_empty, outliers, spread)


def drifting_truth(rng: np.random.Generator, steps: int, x0, drift,
                   jumps: dict[int, tuple[float, float, float]] | None = None) -> np.ndarray:
    """(steps, 3) alignments (x, y, theta) that start at x0 and random-walk with per-step std
    `drift`, plus `jumps` {step: (dx, dy, dtheta)} added at their steps; theta wrapped.
    steps: an int in [0, MAX_STEPS] (DataError otherwise)."""
    steps = count("drifting_truth", "steps", steps, MAX_STEPS, "MAX_STEPS")
    jumps = jumps or {}
    x = np.array(x0, dtype=float)
    truth = np.empty((steps, 3))
    for t in range(steps):
        if t:
            x = x + rng.normal(0.0, drift)
        x = x + np.asarray(jumps.get(t, (0.0, 0.0, 0.0)))
        x[2] = wrap_angle(x[2])
        truth[t] = x
    return truth


def observe_alignments(rng: np.random.Generator, truth: np.ndarray,
                       noise=(0.2, 0.2, 2.0 * DEG), p_empty: float = 0.2,
                       outliers: tuple[int, int] = (0, 4), spread: float = 15.0
                       ) -> AlignmentStream:
    """Candidate measurements of a given true alignment sequence truth (n, 3).

    Args:
        noise: std of the correct measurement per component.
        p_empty: probability that a step has no correct measurement.
        outliers: inclusive range of the number of wrong alignments per step, ints in
            [0, MAX_PER_STEP].
        spread: metres, half-width of the square the wrong alignments fall in.
    """
    outliers = _outliers("observe_alignments", outliers)
    if not 0 <= p_empty <= 1:
        raise DataError(f"observe_alignments: p_empty = {p_empty!r}: must be in [0, 1]")
    zs, correct = [], []
    for x in truth:
        meas = wrong_alignments(rng, int(rng.integers(outliers[0], outliers[1] + 1)), spread)
        index = -1
        if rng.random() >= p_empty:
            z = x + rng.normal(0.0, noise)
            z[2] = wrap_angle(z[2])
            index = int(rng.integers(meas.shape[0] + 1))
            meas = np.insert(meas, index, z, axis=0)
        zs.append(meas)
        correct.append(index)
    return AlignmentStream(np.asarray(truth, float).reshape(-1, 3), zs,
                           np.array(correct, np.int64))


@dataclass(frozen=True)
class DecoyStream:
    """A stream in which a wrong but self-consistent alignment comes first.

    Attributes:
        truth: (n, 3) true (x [m], y [m], theta [rad]) of T_oi_oj per step.
        zs: n arrays (k_t, 3) of measurements.
        evidence: n lists of k_t arrays (m, 2) of the (ego id, other id) object pairs each
            measurement associates (`TCAFF.update`'s evidence).
        correct: (n,) index of the correct measurement in zs[t], -1 if none.
        truth_from: first step at which the truth may be seen after the decoy came (a
            correct measurement then comes at rate p_truth).
        rejoin: first step with a correct measurement after the jump (-1 for none).
    """

    truth: np.ndarray
    zs: list[np.ndarray]
    evidence: list[list[np.ndarray]]
    correct: np.ndarray
    truth_from: int
    rejoin: int

    def __len__(self) -> int:
        return len(self.zs)


def decoy_stream(rng: np.random.Generator, steps: int = 120, decoy_alone: int = 30,
                 p_truth: float = 0.9, p_decoy: float = 0.45, outliers: tuple[int, int] = (0, 2),
                 jump_at: int | None = 80, gap: int = 10,
                 jump=(3.0, -2.0, 40.0 * DEG), x0=(3.0, -2.0, 1.0),
                 decoy_offset=(4.0, 3.0, 120.0 * DEG), noise=(0.2, 0.2, 2.0 * DEG),
                 objects_per_match: int = 6, new_object_every: int = 2,
                 decoy_moves: bool = False, lead: int = 0, lead_gap: int = 0) -> DecoyStream:
    """The decoy of a repetitive world: a look-alike cluster that matches a wrong alignment
    (the truth composed with `decoy_offset`, so it drifts with the truth and is consistent
    over time) and re-matches the same objects at every sighting, while the true match moves
    through new objects as the robots move.

    The decoy alone is seen at every step for `decoy_alone` steps; then the truth at rate
    `p_truth` and the decoy at `p_decoy`. With `jump_at`, the robots part for `gap` steps (no
    correct measurement), the truth jumps by `jump` (a re-initialised odometry frame), and the
    overlap resumes. Outliers have random object ids. With `decoy_moves`, the decoy's
    sightings move through new objects as the truth's do (a shift of a repetitive world onto
    itself, which pairs other objects as the robots move): distinct evidence cannot tell
    them apart, only how often each is seen. With `lead` and `lead_gap`, the truth comes
    first (at rate `p_truth`) for `lead` steps, then nothing but outliers for `lead_gap`
    steps, then the decoy alone: a decoy met after the robots parted, while the filter holds
    the truth.

    Steps, lead, lead_gap, decoy_alone, gap and jump_at are ints in [0, MAX_STEPS] (decoy_alone
    and new_object_every >= 1), outliers a range of ints in [0, MAX_PER_STEP], and
    objects_per_match an int >= 0 with steps x (outliers[1] + 2) x objects_per_match at most
    MAX_PAIRS; DataError otherwise.
    """
    o = "decoy_stream"
    steps = count(o, "steps", steps, MAX_STEPS, "MAX_STEPS")
    lead, lead_gap, gap = (count(o, name, value, MAX_STEPS, "MAX_STEPS") for name, value in
                           (("lead", lead), ("lead_gap", lead_gap), ("gap", gap)))
    decoy_alone = count(o, "decoy_alone", decoy_alone, MAX_STEPS, "MAX_STEPS", low=1)
    new_object_every = count(o, "new_object_every", new_object_every, MAX_STEPS, "MAX_STEPS",
                             low=1)
    if jump_at is not None:
        jump_at = count(o, "jump_at", jump_at, MAX_STEPS, "MAX_STEPS")
    outliers = _outliers(o, outliers)
    objects_per_match = count(o, "objects_per_match", objects_per_match,
                              MAX_PAIRS // (max(steps, 1) * (outliers[1] + 2)),
                              "MAX_PAIRS // (steps (outliers[1] + 2))")
    start = lead + lead_gap  # the decoy's first step
    if not (0 < decoy_alone < steps - start and 0 <= p_truth <= 1 and 0 <= p_decoy <= 1):
        raise DataError(f"decoy_stream: need 0 < decoy_alone < steps - lead - lead_gap, rates "
                        f"in [0, 1], got {decoy_alone}, {steps}, {lead}, {lead_gap}, "
                        f"{p_truth}, {p_decoy}")
    truth = drifting_truth(rng, steps, x0, (0.005, 0.005, 0.05 * DEG),
                           None if jump_at is None else {jump_at: jump})
    decoy_T = se2_from_params(np.asarray(decoy_offset, float))
    decoy_pairs = np.column_stack([np.arange(objects_per_match),
                                   10_000 + np.arange(objects_per_match)])
    gap_steps = range(jump_at - gap, jump_at) if jump_at is not None else range(0)
    zs, evidence, correct = [], [], []
    rejoin = -1
    for t in range(steps):
        meas, pairs = [], []
        decoy_seen = start <= t and (t < start + decoy_alone or rng.random() < p_decoy)
        if decoy_seen:
            z = se2_to_params(se2_from_params(truth[t]) @ decoy_T) + rng.normal(0.0, noise)
            meas.append(z)
            moved = 30_000 + t // new_object_every + np.arange(objects_per_match)
            pairs.append(np.column_stack([moved, moved + 100_000]) if decoy_moves
                         else decoy_pairs)
        index = -1
        if ((t < lead or t >= start + decoy_alone) and t not in gap_steps
                and rng.random() < p_truth):
            index = len(meas)
            meas.append(truth[t] + rng.normal(0.0, noise))
            first = t // new_object_every  # objects enter and leave the overlap as robots move
            ids = 20_000 + first + np.arange(objects_per_match)
            pairs.append(np.column_stack([ids, ids + 100_000]))
            if jump_at is not None and t >= jump_at and rejoin < 0:
                rejoin = t
        for z in wrong_alignments(rng, int(rng.integers(outliers[0], outliers[1] + 1))):
            meas.append(z)
            pairs.append(rng.integers(0, 1_000_000, (objects_per_match, 2)))
        arr = np.array(meas).reshape(-1, 3)
        arr[:, 2] = wrap_angle(arr[:, 2])
        zs.append(arr)
        evidence.append(pairs)
        correct.append(index)
    return DecoyStream(truth, zs, evidence, np.array(correct, np.int64), start + decoy_alone,
                       rejoin)


@dataclass(frozen=True)
class RobotTeamStreams:
    """Attributes:
        A: (n_robots, steps, 3, 3) true pose of each robot's odometry frame in a common frame
            (robot 0's, which does not drift) per step.
        pairs: {(i, j): AlignmentStream of T_oi_oj} for every directed pair i != j.
    """

    A: np.ndarray
    pairs: dict[tuple[int, int], AlignmentStream]


def robot_team_streams(rng: np.random.Generator, n_robots: int, steps: int,
                       drift=(0.004, 0.004, 0.04 * DEG), **observe) -> RobotTeamStreams:
    """Every directed pair's candidate stream for a team whose odometry frames drift.

    Robot r != 0 starts at a random alignment (|t| up to 20 m, any heading) and random-walks
    with per-step std `drift`; `observe` goes to `observe_alignments` for each pair.

    Raises:
        DataError: steps not an int in [0, MAX_STEPS], n_robots not an int >= 1 or with more
            steps of all directed pairs, n_robots (n_robots - 1) max(steps, 1), than MAX_STEPS.
    """
    o = "robot_team_streams"
    steps = count(o, "steps", steps, MAX_STEPS, "MAX_STEPS")
    # the largest n with n (n - 1) <= MAX_STEPS // max(steps, 1)
    most = (1 + math.isqrt(1 + 4 * (MAX_STEPS // max(steps, 1)))) // 2
    n_robots = count(o, "n_robots", n_robots, most, "n (n - 1) max(steps, 1) <= MAX_STEPS",
                     low=1)
    A = np.zeros((n_robots, steps, 3, 3))
    for r in range(n_robots):
        x = np.zeros(3) if r == 0 else np.r_[rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)]
        for t in range(steps):
            if t and r:
                x = x + rng.normal(0.0, drift)
            A[r, t] = se2_from_params(x)
    pairs = {}
    for i in range(n_robots):
        for j in range(n_robots):
            if i != j:
                truth = se2_to_params(np.linalg.inv(A[i]) @ A[j])
                pairs[(i, j)] = observe_alignments(rng, truth, **observe)
    return RobotTeamStreams(A, pairs)
