"""TCAFF against an early decoy: false accepts, recovery, and recovery after a jump.

A wrong but self-consistent alignment (a look-alike cluster re-matched at every sighting) is
seen alone first; then the truth comes at a higher rate than the decoy, with random outliers;
later the robots part, the truth jumps and the overlap resumes (`eval.sim.streams.
decoy_stream`). For each preset, over the seeds:

- false accepts: share of estimates more than 1 m or 5 deg from the truth;
- recovery: steps from the truth's first measurement to the first correct estimate;
- jump recovery: the same from the first correct measurement after the jump;
- flaps: hypothesis changes after the first correct estimate, not counting the jump's.

    python scripts/bench_decoy.py [--seeds 20] [--window 8]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from tcaff_gtsam.eval.sim.streams import decoy_stream

from tcaff_gtsam.geometry import wrap_angle
from tcaff_gtsam.params import TCAFFParams, constant_alignment_covariance
from tcaff_gtsam.tcaff import TCAFF

PRESETS = {
    "distinct evidence": TCAFFParams(min_distinct=2, switch_stale=True),
    "default (the paper's)": TCAFFParams(),
    "reference": TCAFFParams.reference(),
}


def first_correct(x: np.ndarray, truth: np.ndarray, start: int) -> int | None:
    """Steps from `start` to the first correct estimate at or after it (1 = at `start`)."""
    ok = correct(x, truth)
    hits = np.flatnonzero(ok[start:])
    return None if hits.size == 0 else int(hits[0]) + 1


def correct(x: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return ((np.hypot(*(x[:, :2] - truth[:, :2]).T) <= 1.0)
            & (np.abs(wrap_angle(x[:, 2] - truth[:, 2])) <= np.radians(5.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--window", type=int, default=8, help="W")
    args = parser.parse_args()
    R = constant_alignment_covariance()
    print(f"{'preset':28} {'false acc.':>10} {'recovery':>16} {'jump recovery':>16} "
          f"{'flaps':>6}")
    for name, params in PRESETS.items():
        params = replace(params, window=args.window)
        n_est = n_wrong = flaps = 0
        recovery, jump_recovery = [], []
        for seed in range(args.seeds):
            stream = decoy_stream(np.random.default_rng(seed))
            tcaff = TCAFF(params)
            x = np.full((len(stream), 3), np.nan)
            hyp = np.zeros(len(stream), np.int64)
            for t, (zs, ev) in enumerate(zip(stream.zs, stream.evidence, strict=True)):
                est = tcaff.update(zs, np.broadcast_to(R, (len(zs), 3, 3)), ev)
                if est is not None:
                    x[t], hyp[t] = est.x, est.hypothesis
            has = ~np.isnan(x[:, 0])
            n_est += int(has.sum())
            n_wrong += int((has & ~correct(np.nan_to_num(x), stream.truth)).sum())
            steps = first_correct(np.nan_to_num(x, nan=1e9), stream.truth, stream.truth_from)
            recovery.append(np.inf if steps is None else steps)
            after = first_correct(np.nan_to_num(x, nan=1e9), stream.truth, stream.rejoin)
            jump_recovery.append(np.inf if after is None else after)
            if steps is not None:
                changes = np.flatnonzero(np.diff(hyp[stream.truth_from + steps - 1:]))
                flaps += max(len(changes) - 1, 0)  # the jump needs one switch
        def spread(values: list[float]) -> str:
            v = np.array(values)
            return f"{np.median(v):.1f} ({v.min():.0f}-{v.max():.0f})"
        print(f"{name:28} {100 * n_wrong / max(n_est, 1):>8.1f} % {spread(recovery):>16} "
              f"{spread(jump_recovery):>16} {flaps:>6}")


if __name__ == "__main__":
    main()
