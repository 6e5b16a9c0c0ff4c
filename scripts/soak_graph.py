"""Soak of the inter-robot graph: a team at 1 Hz for hours, memory and step times as it goes.

Every directed pair of `--robots` robots runs a TCAFF filter (default preset) on candidates made
step by step from odometry frames that drift for the whole run (0.2 m / 2 deg noise, 0-4 wrong
candidates, 20 % empty steps), feeds one `InterRobotGraph` (Huber) with what each filter's best
path took, and reads every pair's alignment with its covariance after each update, as a CSLAM
front end would. Every `--every` steps it prints the resident memory, the median, p95, p99 and
maximum of `update` over those steps (wall clock), the median, p99 and maximum of the CPU time
`update` took (what other processes on a shared machine do not inflate), the median time to add the
filters' outputs (`add_tcaff_estimate` for every pair) and to read every pair's alignment; at the
end, the growth of memory per 1000 steps after `--settle` steps.

    python scripts/soak_graph.py [--robots 4] [--steps 20000] [--horizon 300] [--history N]
                                 [--every 500]

`--horizon 0` keeps every step (the unbounded graph); `--history N` keeps the latest N steps
that left the horizon readable and forgets older ones (`GraphParams.history`; all by default).
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np
from tcaff_gtsam.eval.sim.streams import observe_alignments

from tcaff_gtsam import TCAFF, GraphParams, InterRobotGraph
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.params import constant_alignment_covariance

R = constant_alignment_covariance()
DRIFT = (0.004, 0.004, np.radians(0.04))  # per step, as `robot_team_streams`


def rss_mb() -> float:
    """Resident set size now, MB (Linux /proc; the peak where that is missing)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize() / 2**20
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--horizon", type=int, default=300,
                        help="steps the graph keeps; 0 keeps all (default 300)")
    parser.add_argument("--history", type=int, default=None,
                        help="steps that left the horizon kept readable (default: all)")
    parser.add_argument("--every", type=int, default=500, help="steps between reports")
    parser.add_argument("--settle", type=int, default=2000,
                        help="steps before the memory growth is measured")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.history is not None and not args.horizon:
        parser.error("--history needs a horizon (--horizon > 0)")
    rng = np.random.default_rng(args.seed)
    graph = InterRobotGraph(args.robots, GraphParams(horizon=args.horizon or None,
                                                     history=args.history))
    pairs = [(i, j) for i in range(args.robots) for j in range(args.robots) if i != j]
    filters = {pair: TCAFF() for pair in pairs}
    # each odometry frame in robot 0's, drifting as in the simulator's team streams
    x = np.c_[rng.uniform(-20, 20, (args.robots, 2)), rng.uniform(-np.pi, np.pi, args.robots)]
    x[0] = 0.0
    times, cpu, adds, reads, marks = [], [], [], [], []
    print(f"{args.robots} robots, horizon {args.horizon or 'none'}, history "
          f"{'all' if args.history is None else args.history}")
    print(f"{'step':>7} {'RSS MB':>8} {'update ms':>10} {'p95':>8} {'p99':>8} {'max':>8} "
          f"{'cpu med':>8} {'cpu p99':>8} {'cpu max':>8} {'add ms':>8} {'read ms':>8}")
    for k in range(args.steps):
        x[1:] += rng.normal(0.0, DRIFT, (args.robots - 1, 3))
        A = se2_from_params(x)
        t_add = 0.0
        for i, j in pairs:
            truth = se2_to_params(np.linalg.inv(A[i]) @ A[j])
            zs = observe_alignments(rng, truth[None]).zs[0]
            Rs = np.broadcast_to(R, (len(zs), 3, 3))
            estimate = filters[(i, j)].update(zs, Rs)
            t0 = time.perf_counter()
            graph.add_tcaff_estimate(k, i, j, estimate, zs, Rs)
            t_add += time.perf_counter() - t0
        t0, c0 = time.perf_counter(), time.process_time()
        graph.update(k)
        times.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
        adds.append(1e3 * t_add)
        t0 = time.perf_counter()
        for pair in pairs:
            graph.alignment(*pair)
        reads.append(1e3 * (time.perf_counter() - t0))
        if (k + 1) % args.every == 0:
            t, c = np.array(times), np.array(cpu)
            marks.append((k + 1, rss_mb()))
            print(f"{k + 1:>7} {marks[-1][1]:8.1f} {np.median(t):10.3f} "
                  f"{np.percentile(t, 95):8.3f} {np.percentile(t, 99):8.3f} {t.max():8.3f} "
                  f"{np.median(c):8.3f} {np.percentile(c, 99):8.3f} {c.max():8.3f} "
                  f"{np.median(adds):8.3f} {np.median(reads):8.3f}", flush=True)
            times, cpu, adds, reads = [], [], [], []  # so that the soak's own lists stay bounded
    after = [(k, m) for k, m in marks if k >= args.settle]
    if len(after) >= 2:
        (k0, m0), (k1, m1) = after[0], after[-1]
        print(f"RSS growth after step {k0}: {1000 * (m1 - m0) / (k1 - k0):.2f} MB per 1000 steps")


if __name__ == "__main__":
    main()
