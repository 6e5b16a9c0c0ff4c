"""Every method on a UTIAS MRCLAM data set, raw and VIO-like odometry: accuracy and speed.

Reads the data set once, then for raw odometry and for each seed of the VIO-like odometry
builds the maps (the shipped `mrclam` evaluation's settings), runs every method of the method
set over every directed pair and prints two tables:

- accuracy, pooled over pairs (and over seeds for vio): false accepts (and the confident
  ones, outside their own 99.7 % ellipse), availability (overlap steps with an estimate) and
  correct availability (with a correct one), median translation and mean heading error, the
  NEES of the reported covariances (mean, share under the 95 % bound 7.815; "-" for a method
  that reports none), time to the first correct estimate, ms per pair and step;
- time per pair and step of each stage: reading, maps, MNO-CLIPPER candidates, each method.

    python scripts/bench_mrclam.py --data ../shared/data/mrclam/MRCLAM_Dataset6 [--seeds 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from tcaff_gtsam.eval.config import load_methods, load_mrclam
from tcaff_gtsam.eval.dataset_runs import evaluate_run, load_mrclam_run
from tcaff_gtsam.eval.datasets import mrclam
from tcaff_gtsam.eval.registry import describe, estimate_names, shown_streams
from tcaff_gtsam.eval.results import summarize, thresholds_of


def cell(value, scale: float = 1.0, digits: int = 2) -> str:
    return "-" if value is None else f"{scale * value:.{digits}f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="an MRCLAM data set folder")
    parser.add_argument("--seeds", type=int, default=3, help="seeds of the VIO-like odometry")
    parser.add_argument("--methods", default=None, help="method set (default: the config's)")
    parser.add_argument("--duration", type=float, default=None, help="s of data to use")
    parser.add_argument("--odometry", nargs="+", default=["raw", "vio"], choices=["raw", "vio"])
    args = parser.parse_args()
    config = load_mrclam("default")
    methods = config.methods if args.methods is None else load_methods(args.methods)
    names = estimate_names(methods)
    start = time.perf_counter()
    data = mrclam.read_dataset(args.data)
    read = time.perf_counter() - start
    print(f"{args.data.name}: {len(data.robots)} robots, {len(data.landmarks)} landmarks, "
          f"{data.span[1] - data.span[0]:.0f} s; read in {read:.2f} s; skipped {data.skipped}")
    stage_rows, accuracy = [], {}
    for odometry in args.odometry:
        seeds = range(args.seeds) if odometry == "vio" else [0]
        jobs, build = [], 0.0
        for seed in seeds:
            start = time.perf_counter()
            run = load_mrclam_run(data, config, odometry, seed, args.duration, odometry)
            build += time.perf_counter() - start
            jobs.append(evaluate_run(run, methods)[0])
        pair_steps = sum(len(j.pairs) * j.n_steps for j in jobs)
        seconds = {k: sum(j.seconds.get(k, 0.0) for j in jobs) for k in jobs[0].seconds}
        stage_rows.append((odometry, 1e3 * build / pair_steps, seconds, pair_steps))
        accuracy[odometry] = summarize(jobs, names, thresholds_of(methods))[odometry]
    print("\nAccuracy, pooled over the directed pairs (vio: and seeds)")
    header = (f"{'odometry':9} {'method':22} {'false acc.':>10} {'conf.':>7} {'available':>9} "
              f"{'correct':>7} {'median m':>8} {'mean deg':>8} {'NEES':>9} {'<7.81':>6} "
              f"{'1st ok s':>8} {'ms':>7}")
    print(header)
    for odometry, by_method in accuracy.items():
        for method in names:
            r = by_method[method]
            print(f"{odometry:9} {describe(method).label:22} "
                  f"{cell(r['false_accept'], 100, 1):>8} % "
                  f"{cell(r['confident_false_accept'], 100, 1):>5} % "
                  f"{cell(r['availability'], 1, 3):>9} "
                  f"{cell(r['correct_availability'], 1, 3):>7} "
                  f"{cell(r['translation_error_m_median']):>8} "
                  f"{cell(r['heading_error_deg_mean']):>8} "
                  f"{cell(r['nees_mean']):>9} {cell(r['nees_under_95'], 100, 0):>4} % "
                  f"{cell(r['time_to_first_correct_s'], 1, 0):>8} "
                  f"{r['ms_per_pair_step']:7.3f}")
    print("\nTime per pair and step [ms]")
    # one single-shot CLIPPER solution serves every k: its time is shown once
    parts = ["maps", "candidates", *shown_streams(methods)]
    print(f"{'odometry':9} " + " ".join(f"{p.removeprefix('tcaff_')[:12]:>12}" for p in parts))
    for odometry, maps_ms, seconds, pair_steps in stage_rows:
        values = [maps_ms] + [1e3 * seconds.get(p, 0.0) / pair_steps for p in parts[1:]]
        print(f"{odometry:9} " + " ".join(f"{v:12.3f}" for v in values))


if __name__ == "__main__":
    main()
