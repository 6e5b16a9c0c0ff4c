"""Time the simulator and every compared method on one scenario.

Simulates the scenario (default: four robots for ten minutes), runs every method over every
directed pair and prints where the time goes, per pair and 1 Hz step.

    python scripts/bench_study.py [--scenario four_robots] [--duration 600] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

from tcaff_gtsam.eval.config import MethodsConfig, load_scenario
from tcaff_gtsam.eval.methods import run_methods
from tcaff_gtsam.eval.sim.simulate import simulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="four_robots")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds simulated")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cfg = load_scenario(args.scenario).model_copy(update={"duration": args.duration})
    warm = cfg.model_copy(update={"duration": 12.0})
    run_methods(simulate(warm, 99), MethodsConfig())  # compile numba kernels outside the timing
    start = time.perf_counter()
    run = simulate(cfg, args.seed)
    simulated = time.perf_counter() - start
    frames = run.n_robots * args.duration * cfg.mapping.frame_rate
    print(f"{args.scenario}: {run.n_robots} robots, {args.duration:.0f} s, "
          f"{len(run.world)} objects")
    print(f"simulation: {simulated:.2f} s ({1e3 * simulated / frames:.3f} ms per robot frame)")
    start = time.perf_counter()
    runs = run_methods(run, MethodsConfig())
    total = time.perf_counter() - start
    pair_steps = len(runs.pairs) * len(run.times)
    print(f"methods: {total:.2f} s for {len(runs.pairs)} directed pairs x {len(run.times)} "
          f"steps\n")
    print(f"{'part':24} {'total s':>8} {'ms per pair-step':>17}")
    for name in ("candidates", "tcaff", "tcaff_reference", "tcaff_isam2_causal",
                 "tcaff_isam2_smoothed", "clipper_k3", "icp"):
        label = "single-shot CLIPPER" if name == "clipper_k3" else name
        seconds = runs.seconds[name]
        print(f"{label:24} {seconds:8.2f} {1e3 * seconds / pair_steps:17.3f}")


if __name__ == "__main__":
    main()
