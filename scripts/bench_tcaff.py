"""Time per TCAFF update on generated measurement streams.

Four regimes per measurement count k:
  exploring  k wrong alignments per step, scattered over +-15 m and all headings: no main tree
             ever forms, so every step extends and prunes the exploring trees only;
  main tree  one correct alignment (slow drift, 0.2 m / 2 deg noise) and k - 1 wrong ones: a main
             tree exists from step W + 1 on; the default preset keeps exploring beside it, the
             reference preset does not;
  in gate    all k measurements near the truth (0.3 m / 3 deg apart), so every one passes
             every gate and the main tree fills up to its leaf limit;
  rivals     the worst case for exploring beside a main tree: k hypotheses 3 m apart, each
             consistent over time (a grid-like world), so k - 1 of them keep seeding full
             exploring trees that are inconsistent with the main one.
Prints median, 95th percentile and maximum milliseconds per update (first 20 steps excluded,
so the compile of the first call does not count).

    python scripts/bench_tcaff.py [--steps 1000] [--counts 0 1 4 10 32] [--profile]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tcaff_gtsam.eval.sim.streams import wrong_alignments

from tcaff_gtsam import TCAFF, FrameAlignerParams, TCAFFParams
from tcaff_gtsam.pairwise import fed_by
from tcaff_gtsam.params import constant_alignment_covariance

R = constant_alignment_covariance()


def make_stream(steps: int, k: int, regime: str, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    x = np.array([3.0, -2.0, 1.0])
    stream = []
    for _ in range(steps):
        x = x + rng.normal(0, [0.005, 0.005, 0.001])
        if regime == "exploring" or k == 0:
            stream.append(wrong_alignments(rng, k))
        elif regime == "main tree":
            true = x + rng.normal(0, [0.2, 0.2, np.radians(2)])
            stream.append(np.vstack([true[None], wrong_alignments(rng, k - 1)]))
        elif regime == "in gate":
            stream.append(x + rng.normal(0, [0.3, 0.3, np.radians(3)], (k, 3)))
        else:
            shifts = np.column_stack([3.0 * np.arange(k), np.zeros(k), np.zeros(k)])
            stream.append(x + shifts + rng.normal(0, [0.2, 0.2, np.radians(2)], (k, 3)))
    return stream


def time_stream(params: TCAFFParams, stream: list[np.ndarray], skip: int = 20):
    filt = TCAFF(params)
    times, n_estimates = [], 0
    for zs in stream:
        Rs = np.broadcast_to(R, (zs.shape[0], 3, 3))
        t0 = time.perf_counter()
        est = filt.update(zs, Rs)
        times.append(time.perf_counter() - t0)
        n_estimates += est is not None
    ms = 1e3 * np.array(times[skip:])
    return np.median(ms), np.percentile(ms, 95), ms.max(), n_estimates / len(stream)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--counts", type=int, nargs="+", default=[0, 1, 4, 10, 32])
    parser.add_argument("--profile", action="store_true",
                        help="profile the default preset at k = 4 with a main tree")
    args = parser.parse_args()
    # "pair": as `PairwiseAligner` runs it, with the aligner's jitter reference
    presets = {"default": TCAFFParams(),
               "pair": fed_by(TCAFFParams(), FrameAlignerParams()),
               "at W": TCAFFParams(sequential=False, recall_for=None),
               "reference": TCAFFParams.reference()}
    time_stream(presets["default"], make_stream(50, 4, "in gate"))  # compile (cached afterwards)
    print(f"{'preset':10} {'regime':10} {'k':>3} {'median ms':>10} {'p95 ms':>8} {'max ms':>8} "
          f"{'estimates':>9}")
    for name, params in presets.items():
        for regime in ("exploring", "main tree", "in gate", "rivals"):
            for k in args.counts:
                if k == 0 and regime != "exploring":
                    continue  # an empty stream is the same in every regime
                stream = make_stream(args.steps, k, regime)
                med, p95, mx, share = time_stream(params, stream)
                print(f"{name:10} {regime:10} {k:3d} {med:10.3f} {p95:8.3f} {mx:8.3f} "
                      f"{share:9.3f}")
    if args.profile:
        from pyinstrument import Profiler

        stream = make_stream(args.steps, 4, "main tree")
        profiler = Profiler(interval=0.0002)
        profiler.start()
        time_stream(presets["default"], stream)
        profiler.stop()
        print(profiler.output_text(unicode=False, color=False, show_all=False))


if __name__ == "__main__":
    main()
