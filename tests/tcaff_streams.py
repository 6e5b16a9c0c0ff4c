"""Shared by the TCAFF tests: feeding a filter a generated stream and scoring its estimates."""

from __future__ import annotations

import numpy as np

from tcaff_gtsam import TCAFF
from tcaff_gtsam.geometry import wrap_angle
from tcaff_gtsam.params import constant_alignment_covariance

R_CONSTANT = constant_alignment_covariance()  # what the frame aligner gives by default
R_HONEST = np.diag([0.2**2, 0.2**2, np.radians(2.0) ** 2])  # the streams' actual noise
SLOW_DRIFT = np.diag([0.005**2, 0.005**2, np.radians(0.05) ** 2])


def run(filt: TCAFF, zs_per_step, R=R_CONSTANT):
    """Estimates per step (None where there is none)."""
    return [filt.update(zs, np.broadcast_to(R, (len(zs), 3, 3))) for zs in zs_per_step]


def errors(estimates, truth):
    """(m, 2) translation [m] and absolute heading [deg] errors of the steps with an estimate."""
    rows = []
    for est, x in zip(estimates, truth, strict=True):
        if est is not None:
            e = est.x - x
            rows.append((np.hypot(e[0], e[1]), abs(np.degrees(wrap_angle(e[2])))))
    return np.array(rows).reshape(-1, 2)


def first_estimate(estimates) -> int | None:
    """1-based update number of the first estimate."""
    return next((i + 1 for i, est in enumerate(estimates) if est is not None), None)


def last_estimate(estimates) -> int:
    """1-based update number of the last estimate (there must be one)."""
    return max(i + 1 for i, est in enumerate(estimates) if est is not None)
