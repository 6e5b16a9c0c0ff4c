"""Time what a finished job costs after its methods ran: scoring (and the APE and RPE share of
it), the TUM and g2o trajectories and the Rerun recording.

Simulates the scenario once (default: four robots for ten minutes), runs every method, then
times each step `--repeat` times and prints the medians.

    python scripts/bench_results_io.py [--scenario four_robots] [--duration 600] [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from tcaff_gtsam.eval.config import MethodsConfig, load_scenario
from tcaff_gtsam.eval.jobs import simulated_job
from tcaff_gtsam.eval.metrics import PairTrace
from tcaff_gtsam.eval.registry import estimate_names
from tcaff_gtsam.eval.rerun_recording import record
from tcaff_gtsam.eval.results import score, thresholds_of
from tcaff_gtsam.eval.trajectories import write_g2o, write_tum


def median_seconds(work, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def fresh(traces: list[PairTrace]) -> list[PairTrace]:
    """Copies without the cached path errors."""
    return [PairTrace(t.times, t.T_true, t.estimate, t.overlap, t.T_oi_bi, t.T_oj_bj)
            for t in traces]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="four_robots")
    parser.add_argument("--duration", type=float, default=600.0, help="seconds simulated")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    methods = MethodsConfig()
    scenario = load_scenario(args.scenario).model_copy(update={"duration": args.duration})
    job = simulated_job(scenario, methods, args.seed)
    names = estimate_names(methods)
    traces = [t for name in names for t in job.traces(name)]
    print(f"{args.scenario}: {len(job.pairs)} directed pairs x {job.n_steps} steps, "
          f"{len(names)} estimate streams; medians of {args.repeat}\n")
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        rows = [
            ("score (every metric)", lambda: score(job, names, thresholds_of(methods))),
            ("  APE + RPE alone", lambda: [t.path_errors for t in fresh(traces)]),
            ("TUM trajectories", lambda: write_tum(root, job)),
            ("g2o pose graphs", lambda: write_g2o(root, job)),
            ("Rerun recording", lambda: record(root / "run.rrd", [job])),
        ]
        print(f"{'step':24} {'median s':>9}")
        for label, work in rows:
            print(f"{label:24} {median_seconds(work, args.repeat):9.3f}")
        size = (root / "run.rrd").stat().st_size / 1e6
        tum = sum(p.stat().st_size for p in (root / "trajectories").rglob("*.tum")) / 1e6
    print(f"\nrecording {size:.1f} MB, TUM files {tum:.1f} MB")


if __name__ == "__main__":
    main()
