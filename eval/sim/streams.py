"""Synthetic streams of frame-alignment measurements with a known truth, for TCAFF.

Each step holds at most one correct measurement (the truth plus noise) among wrong alignments
scattered over the plane, which is what MNO-CLIPPER hands the filter when maps overlap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, wrap_angle

__all__ = [
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
    """(k, 3) alignments uniform over +-spread metres and all headings."""
    return np.column_stack([rng.uniform(-spread, spread, (k, 2)), rng.uniform(-np.pi, np.pi, k)])


def alignment_stream(rng: np.random.Generator, steps: int, x0=(3.0, -2.0, 1.0),
                     drift=(0.005, 0.005, 0.05 * DEG), noise=(0.2, 0.2, 2.0 * DEG),
                     p_empty: float = 0.2, outliers: tuple[int, int] = (0, 4),
                     spread: float = 15.0,
                     jumps: dict[int, tuple[float, float, float]] | None = None
                     ) -> AlignmentStream:
    """A drifting true alignment observed with noise among outliers.

    Args:
        steps: length of the stream.
        x0: the true (x, y, theta) at the first step.
        drift: per-step std of the random walk of the truth (x, y, theta).
        noise, p_empty, outliers, spread: see `observe_alignments`.
        jumps: {step: (dx, dy, dtheta)} added to the truth at that step (a re-initialised
            odometry frame).
    """
    if steps < 0:
        raise DataError(f"alignment_stream: steps = {steps} must be >= 0")
    return observe_alignments(rng, drifting_truth(rng, steps, x0, drift, jumps), noise,
                              p_empty, outliers, spread)


def drifting_truth(rng: np.random.Generator, steps: int, x0, drift,
                   jumps: dict[int, tuple[float, float, float]] | None = None) -> np.ndarray:
    """(steps, 3) alignments (x, y, theta) that start at x0 and random-walk with per-step std
    `drift`, plus `jumps` {step: (dx, dy, dtheta)} added at their steps; theta wrapped."""
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
        outliers: inclusive range of the number of wrong alignments per step.
        spread: metres, half-width of the square the wrong alignments fall in.
    """
    if not 0 <= p_empty <= 1 or not 0 <= outliers[0] <= outliers[1]:
        raise DataError(f"observe_alignments: need p_empty in [0, 1] and 0 <= outliers[0] <= "
                        f"outliers[1], got {p_empty}, {outliers}")
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
    """
    for name, value in (("lead", lead), ("lead_gap", lead_gap)):
        if not (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
            raise DataError(f"decoy_stream: {name} = {value!r}: must be an int >= 0")
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
    """
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
