"""What MRCLAM's short maps share: landmark pairs that agree under the true alignment.

For every directed robot pair of UTIAS MRCLAM data set 6 (`mrclam.load_run` with the shipped
evaluation's settings, VIO-like odometry) and every overlap step (the maps share enough
landmarks, `AlignmentRun.overlap`), counts the pairs of recent landmarks, one from each map,
that are mutual nearest neighbours within --radius metres once the other map is moved by the
true T_oi_oj: the associations an aligner could find consistent. Prints, per count, the share
of the overlap steps and how often the truth (within 1 m / 5 deg, scored as the evaluation
scores) is among the candidates of `PairwiseAligner` with the library's defaults, and without
the aligner's checks (`pairwise.unchecked`).

    python scripts/mrclam_overlap.py [--seeds 3] [--kappa 20] [--radius 0.25]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from tcaff_gtsam.eval.config import load_mrclam
from tcaff_gtsam.eval.datasets import mrclam
from tcaff_gtsam.eval.metrics import Thresholds, step_errors
from tcaff_gtsam.eval.runs import directed_pairs

from tcaff_gtsam import FrameAlignerParams, PairwiseAligner
from tcaff_gtsam.pairwise import unchecked
from tcaff_gtsam.registration import mutual_inliers

MRCLAM = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / \
    "MRCLAM_Dataset6"
#: counts from this one up are pooled in the table's last row
MOST = 7


def agreeing(p: np.ndarray, q: np.ndarray, T: np.ndarray, radius: float) -> int:
    """How many of ego points p (n, 2) and other points q (m, 2) are mutual nearest neighbours
    within `radius` metres once q is moved by T (3, 3)."""
    return len(mutual_inliers(T, p, q, np.ones((len(p), len(q)), bool), radius))


def holds_truth(candidates, T_true: np.ndarray) -> bool:
    """Whether one of the candidates is correct against T_true (3, 3), as the evaluation
    scores an estimate (`metrics.step_errors` within the false-accept thresholds)."""
    if not candidates:
        return False
    err = step_errors(np.broadcast_to(T_true, (len(candidates), 3, 3)),
                      np.array([m.z for m in candidates]))
    return bool(np.any(Thresholds().correct(err)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3, help="VIO-like odometry seeds 0 .. N-1")
    parser.add_argument("--kappa", type=float, default=20.0, help="map span, s")
    parser.add_argument("--radius", type=float, default=0.25,
                        help="metres; the default is CLIPPER's epsilon as given (the aligner "
                        "widens it to 0.27 m for 20 s maps, FrameAlignerParams.span_epsilon)")
    args = parser.parse_args()
    config = load_mrclam("default")
    data = mrclam.read_dataset(MRCLAM)
    # per count of agreeing pairs: overlap steps, with the truth among the default's
    # candidates, among the unchecked ones
    table = np.zeros((MOST + 1, 3), dtype=int)
    for seed in range(args.seeds):
        run, _ = mrclam.load_run(data, "vio", seed, args.kappa, config.nu, config.min_shared,
                                 config.vio.heading_rw_deg_per_sqrt_min, config.vio.scale_std)
        for i, j in directed_pairs(run):
            aligners = [PairwiseAligner(FrameAlignerParams(kappa=args.kappa)),
                        PairwiseAligner(unchecked(FrameAlignerParams(kappa=args.kappa)))]
            T_true = run.T_true(i, j)
            shared = run.overlap(i, j)
            for s, t in enumerate(run.times):
                ego, other = run.maps[i][s], run.maps[j][s]
                for aligner in aligners:
                    aligner.update(float(t), ego, other)
                if not (shared is None or shared[s]) or not np.all(np.isfinite(T_true[s])):
                    continue
                recent_ego = ego.centroids[ego.last_seen >= t - args.kappa, :2]
                recent_other = other.centroids[other.last_seen >= t - args.kappa, :2]
                row = min(agreeing(recent_ego, recent_other, T_true[s], args.radius), MOST)
                table[row] += [1, holds_truth(aligners[0].measurements, T_true[s]),
                               holds_truth(aligners[1].measurements, T_true[s])]
        print(f"seed {seed} done", flush=True)
    total = table[:, 0].sum()
    print(f"\nMRCLAM 6, VIO-like seeds 0-{args.seeds - 1}, {args.kappa:g} s maps: {total} overlap "
          f"steps")
    print(f"{'agreeing pairs':>14} {'steps':>7} {'share':>6} {'truth found':>12} "
          f"{'unchecked':>10}")
    for count, (steps, found, found_unchecked) in enumerate(table):
        label = f">= {count}" if count == MOST else str(count)
        rates = (f"{found / steps:12.2f} {found_unchecked / steps:10.2f}" if steps
                 else f"{'-':>12} {'-':>10}")
        print(f"{label:>14} {steps:7d} {steps / max(total, 1):6.3f} {rates}")
    print(f"{'all':>14} {total:7d} {1:6.3f} {table[:, 1].sum() / max(total, 1):12.3f} "
          f"{table[:, 2].sum() / max(total, 1):10.3f}")


if __name__ == "__main__":
    main()
