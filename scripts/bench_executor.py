"""Time the Dask executor: scheduling overhead per job, and the speed-up of a second worker.

Overhead: the same short jobs run in this process and on a local Dask cluster of one worker
(both warmed up first: numba compiled, stack imported); the overhead per job is the difference
of the wall times divided by the jobs. Speed-up: a sweep-sized batch of jobs (scenarios x
seeds, `--duration` s each) on a local cluster of 1 and of 2 workers; the cluster's start is
timed apart. Medians over `--repeat` runs.

    python scripts/bench_executor.py [--jobs 20] [--batch 40] [--duration 60] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from tcaff_gtsam.eval.config import MethodsConfig, load_methods, load_scenario
from tcaff_gtsam.eval.executor import Executor, JobSpec, Progress, job_runner

SCENARIOS = ("indoor_return", "same_direction", "opposite_directions", "four_robots",
             "ambiguous_grid")


def specs_of(n: int, duration: float, methods: MethodsConfig) -> list[JobSpec]:
    """n jobs: the scenarios in turn, seeds counting up."""
    scenarios = [load_scenario(s).model_copy(update={"duration": duration}) for s in SCENARIOS]
    return [JobSpec(scenarios[k % len(scenarios)], methods, k // len(scenarios))
            for k in range(n)]


def timed(run, specs: list[JobSpec]) -> float:
    failed: dict = {}
    start = time.perf_counter()
    run(specs, Progress(), lambda key, job: None, failed.__setitem__)
    seconds = time.perf_counter() - start
    if failed:
        raise RuntimeError(f"jobs failed: {failed}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=20, help="short jobs for the overhead")
    parser.add_argument("--short", type=float, default=3.0, help="s of each short job")
    parser.add_argument("--batch", type=int, default=40, help="jobs for the speed-up")
    parser.add_argument("--duration", type=float, default=60.0, help="s of each batch job")
    parser.add_argument("--methods", default="tcaff_only")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    methods = load_methods(args.methods)
    short = specs_of(args.jobs, args.short, methods)
    batch = specs_of(args.batch, args.duration, methods)

    with job_runner(Executor(workers=1)) as local:
        timed(local, short[:2])  # warm-up: numba, imports
        here = [timed(local, short) for _ in range(args.repeat)]
        one_here = [timed(local, batch) for _ in range(1)]
    rows = []
    for workers in (1, 2):
        start = time.perf_counter()
        with job_runner(Executor(local_cluster=workers)) as run:
            started = time.perf_counter() - start
            timed(run, short[:2 * workers])  # warm-up of every worker
            dask_short = [timed(run, short) for _ in range(args.repeat)] if workers == 1 else []
            dask_batch = [timed(run, batch) for _ in range(args.repeat)]
        rows.append((workers, started, dask_short, dask_batch))

    print(f"{args.jobs} short jobs ({args.short:g} s scenarios, {args.methods}), medians of "
          f"{args.repeat}:")
    overhead = (statistics.median(rows[0][2]) - statistics.median(here)) / args.jobs
    print(f"  in this process       {statistics.median(here):8.2f} s")
    print(f"  Dask, 1 worker        {statistics.median(rows[0][2]):8.2f} s")
    print(f"  overhead per job      {overhead:8.3f} s")
    print(f"\n{args.batch} jobs of {args.duration:g} s scenarios ({args.methods}):")
    print(f"  {'executor':22} {'start [s]':>10} {'wall [s] (median)':>18} {'runs':>24}")
    print(f"  {'this process':22} {'-':>10} {one_here[0]:18.1f}")
    for workers, started, _, walls in rows:
        runs = " ".join(f"{w:.1f}" for w in walls)
        print(f"  {f'Dask, {workers} worker(s)':22} {started:10.1f} "
              f"{statistics.median(walls):18.1f} {runs:>24}")
    ratio = statistics.median(rows[1][3]) / statistics.median(rows[0][3])
    print(f"  2 workers / 1 worker: {ratio:.2f}")


if __name__ == "__main__":
    main()
