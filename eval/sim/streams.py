"""Synthetic streams of frame-alignment measurements with a known truth, for TCAFF.

Each step holds at most one correct measurement (the truth plus noise) among wrong alignments
scattered over the plane, which is what MNO-CLIPPER hands the filter when maps overlap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import wrap_angle

__all__ = ["AlignmentStream", "alignment_stream", "wrong_alignments"]

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
                     p_empty: float = 0.2,
                     outliers: tuple[int, int] = (0, 4), spread: float = 15.0,
                     jumps: dict[int, tuple[float, float, float]] | None = None
                     ) -> AlignmentStream:
    """A drifting true alignment observed with noise among outliers.

    Args:
        steps: length of the stream.
        x0: the true (x, y, theta) at the first step.
        drift: per-step std of the random walk of the truth (x, y, theta).
        noise: std of the correct measurement per component.
        p_empty: probability that a step has no correct measurement.
        outliers: inclusive range of the number of wrong alignments per step.
        spread: metres, half-width of the square the wrong alignments fall in.
        jumps: {step: (dx, dy, dtheta)} added to the truth at that step (a re-initialised
            odometry frame).
    """
    if steps < 0 or not 0 <= p_empty <= 1 or not 0 <= outliers[0] <= outliers[1]:
        raise DataError(f"alignment_stream: need steps >= 0, p_empty in [0, 1] and "
                        f"0 <= outliers[0] <= outliers[1], got {steps}, {p_empty}, {outliers}")
    jumps = jumps or {}
    x = np.array(x0, dtype=float)
    truth, zs, correct = [], [], []
    for t in range(steps):
        if t:
            x = x + rng.normal(0.0, drift)
        x = x + np.asarray(jumps.get(t, (0.0, 0.0, 0.0)))
        x[2] = wrap_angle(x[2])
        truth.append(x.copy())
        meas = wrong_alignments(rng, int(rng.integers(outliers[0], outliers[1] + 1)), spread)
        index = -1
        if rng.random() >= p_empty:
            z = x + rng.normal(0.0, noise)
            z[2] = wrap_angle(z[2])
            index = int(rng.integers(meas.shape[0] + 1))
            meas = np.insert(meas, index, z, axis=0)
        zs.append(meas)
        correct.append(index)
    return AlignmentStream(np.array(truth).reshape(-1, 3), zs, np.array(correct, np.int64))
