"""TCAFF against an early decoy: false accepts, recovery, and recovery after a jump.

A wrong but self-consistent alignment (a look-alike cluster re-matched at every sighting) is
seen alone first; then the truth comes at a higher rate than the decoy, with random outliers;
later the robots part, the truth jumps and the overlap resumes (`eval.sim.streams.
decoy_stream`). For each preset, over the seeds:

- false accepts: share of estimates more than 1 m or 5 deg from the truth;
- recovery: steps from the truth's first measurement to the first correct estimate;
- jump recovery: the same from the first correct measurement after the jump;
- available: share of the steps from the truth's first measurement with a correct estimate;
- flaps: hypothesis changes after the first correct estimate, not counting the jump's (steps
  without an estimate are skipped).

    python scripts/bench_decoy.py [--seeds 20] [--window 8]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from tcaff_gtsam.eval.metrics import Thresholds, step_errors
from tcaff_gtsam.eval.sim.streams import decoy_stream

from tcaff_gtsam.geometry import se2_from_params
from tcaff_gtsam.params import TCAFFParams, constant_alignment_covariance
from tcaff_gtsam.tcaff import TCAFF

PRESETS = {
    "distinct evidence, withheld": TCAFFParams(min_distinct=2, switch_stale=True,
                                               withhold_contested=True),
    "distinct evidence": TCAFFParams(min_distinct=2, switch_stale=True),
    "default (the paper's)": TCAFFParams(),
    "reference": TCAFFParams.reference(),
}


def steps_to_correct(correct: np.ndarray, start: int) -> float:
    """Steps from `start` to the first correct estimate at or after it (1 = at `start`); inf
    when there is none."""
    hits = np.flatnonzero(correct[start:])
    return float(hits[0] + 1) if hits.size else np.inf


def median_range(values: list[float]) -> str:
    v = np.array(values)
    return f"{np.median(v):.1f} ({v.min():.0f}-{v.max():.0f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--window", type=int, default=8, help="W")
    args = parser.parse_args()
    R = constant_alignment_covariance()
    limits = Thresholds()
    print(f"{'preset':28} {'false acc.':>10} {'available':>10} {'recovery':>16} "
          f"{'jump recovery':>16} {'flaps':>6}")
    for name, params in PRESETS.items():
        params = replace(params, window=args.window)
        n_est = n_wrong = flaps = 0
        recovery, jump_recovery, available = [], [], []
        for seed in range(args.seeds):
            stream = decoy_stream(np.random.default_rng(seed))
            tcaff = TCAFF(params)
            x = np.full((len(stream), 3), np.nan)
            hyp = np.zeros(len(stream), np.int64)
            for t, (zs, ev) in enumerate(zip(stream.zs, stream.evidence, strict=True)):
                est = tcaff.update(zs, np.broadcast_to(R, (len(zs), 3, 3)), ev)
                if est is not None:
                    x[t], hyp[t] = est.x, est.hypothesis
            err = step_errors(se2_from_params(stream.truth), x)  # NaN rows: no estimate
            has = ~np.isnan(err[:, 0])
            correct = has & (err[:, 0] <= limits.translation) & (err[:, 1] <= limits.heading)
            n_est += int(has.sum())
            n_wrong += int((has & ~correct).sum())
            steps = steps_to_correct(correct, stream.truth_from)
            recovery.append(steps)
            jump_recovery.append(steps_to_correct(correct, stream.rejoin))
            available.append(correct[stream.truth_from:].mean())
            if np.isfinite(steps):
                later = np.arange(len(stream)) >= stream.truth_from + int(steps) - 1
                changes = np.flatnonzero(np.diff(hyp[later & has]))
                flaps += max(len(changes) - 1, 0)  # the jump needs one switch
        print(f"{name:28} {100 * n_wrong / max(n_est, 1):>8.1f} % {np.mean(available):>10.3f} "
              f"{median_range(recovery):>16} "
              f"{median_range(jump_recovery):>16} {flaps:>6}")


if __name__ == "__main__":
    main()
