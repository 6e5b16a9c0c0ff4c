"""iSAM2 time per 1 Hz step, and accuracy and NEES of pure TCAFF, the causal and the smoothed graph.

A team of robots whose odometry frames drift (eval.sim.streams.robot_team_streams); every
directed pair runs a TCAFF filter (default preset) on its candidate stream (0.2 m / 2 deg noise,
0-4 wrong candidates, 20 % empty steps) and feeds the graph with the candidate its best path
took. Each candidate's covariance R is the original's constant (0.5 m, 5 deg)^2 (--R constant,
the default: the series of timings in docs/benchmarks.md) or the streams' own noise (--R noise,
the honest one). Errors are over the steps where the pair's filter has an estimate:
  pure TCAFF     the filter's own estimate and P,
  causal graph   T_oi_oj(k) and its covariance read right after update k,
  smoothed graph T_oi_oj(k) and its covariance read after the last step,
with the NEES of each against its covariance (mean, and share under the chi-square 95 % bound
7.815; honest: 3 and 95 %): with the constant R, which overstates the noise 2.5 times, they
are low by design. The streams' candidate errors are independent from pair to pair, unlike
alignments of shared maps, so the graph's `shared_maps` inflation makes it cautious here;
--count-in-full turns it off.

With --horizon H the graph keeps H steps (`GraphParams.horizon`); the smoothed errors then read
each step as it was when it left the graph.

    python scripts/bench_graph.py [--robots 4] [--steps 3600] [--seed 0] [--horizon H]
                                  [--R constant|noise] [--count-in-full]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tcaff_gtsam.eval.metrics import NEES_95, step_nees
from tcaff_gtsam.eval.sim.streams import robot_team_streams

from tcaff_gtsam import TCAFF, GraphParams, InterRobotGraph
from tcaff_gtsam.geometry import se2_error, se2_to_params
from tcaff_gtsam.params import constant_alignment_covariance

#: each candidate's covariance: the original's constant, or the streams' own candidate noise
#: (`observe_alignments`' default)
COVARIANCES = {"constant": constant_alignment_covariance(),
               "noise": np.diag(np.array([0.2, 0.2, np.radians(2.0)]) ** 2)}


def errors(T_true: np.ndarray, T_est: np.ndarray) -> np.ndarray:
    """(n, 2) translation [m] and |heading| [deg] of T_true^-1 T_est, stacks (n, 3, 3)."""
    return se2_error(T_true, T_est) * [1.0, 180.0 / np.pi]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--steps", type=int, default=3600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robust", default="huber", choices=["huber", "cauchy", "none"])
    parser.add_argument("--horizon", type=int, default=None,
                        help="steps the graph keeps (default: all)")
    parser.add_argument("--R", choices=list(COVARIANCES), default="constant",
                        help="each candidate's covariance (default: the original's constant)")
    parser.add_argument("--count-in-full", action="store_true",
                        help="GraphParams(shared_maps=False): every alignment factor in full")
    args = parser.parse_args()
    R = COVARIANCES[args.R]
    streams = robot_team_streams(np.random.default_rng(args.seed), args.robots, args.steps)
    filters = {pair: TCAFF() for pair in streams.pairs}
    graph = InterRobotGraph(args.robots, GraphParams(robust=args.robust, horizon=args.horizon,
                                                     shared_maps=not args.count_in_full))
    t_graph, t_filter = [], []
    kept = {pair: [] for pair in streams.pairs}  # (step, filter T, P, causal T, covariance)
    for k in range(args.steps):
        t0 = time.perf_counter()
        estimates = {}
        for pair, stream in streams.pairs.items():
            zs = stream.zs[k]
            estimates[pair] = (filters[pair].update(zs, np.broadcast_to(R, (len(zs), 3, 3))),
                               zs)
        t1 = time.perf_counter()
        for pair, (est, zs) in estimates.items():
            graph.add_tcaff_estimate(k, *pair, est, zs, np.broadcast_to(R, (len(zs), 3, 3)))
        graph.update(k)
        t2 = time.perf_counter()
        t_filter.append(t1 - t0)
        t_graph.append(t2 - t1)
        for pair, (est, _) in estimates.items():
            # before its first factor (or with its factors held out) the graph has no
            # alignment of the pair: its covariance is infinite
            if est is not None and graph.connected(*pair):
                kept[pair].append((k, est.T, est.P, *graph.alignment(*pair, k)))
        if (k + 1) % 600 == 0:
            print(f"  step {k + 1}/{args.steps}", flush=True)
    ms = 1e3 * np.array(t_graph)
    print(f"\n{args.robots} robots, {len(streams.pairs)} directed pairs, {args.steps} steps, "
          f"horizon {args.horizon or 'none'}, R {args.R}, "
          f"{'every factor in full' if args.count_in_full else 'shared maps'}")
    print(f"{'per step':24} {'median ms':>10} {'p95 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    for name, t in (("iSAM2 graph update", ms), ("TCAFF, all pairs", 1e3 * np.array(t_filter))):
        print(f"{name:24} {np.median(t):10.3f} {np.percentile(t, 95):8.3f} "
              f"{np.percentile(t, 99):8.3f} {t.max():8.3f}")
    rows = {"pure TCAFF": [], "causal graph": [], "smoothed graph": []}
    for pair, entries in kept.items():
        if not entries:
            continue
        steps = np.array([e[0] for e in entries])
        truth = np.linalg.inv(streams.A[pair[0], steps]) @ streams.A[pair[1], steps]
        all_steps, smoothed = graph.alignment_history(*pair)
        smoothed = smoothed[np.searchsorted(all_steps, steps)]
        smoothed_P = np.array([graph.alignment(*pair, int(k))[1] for k in steps])
        for name, T, P in (("pure TCAFF", [e[1] for e in entries], [e[2] for e in entries]),
                           ("causal graph", [e[3] for e in entries], [e[4] for e in entries]),
                           ("smoothed graph", smoothed, smoothed_P)):
            T = np.asarray(T)
            nees = step_nees(truth, se2_to_params(T), np.asarray(P))
            rows[name].append(np.column_stack([errors(truth, T), nees]))
    print(f"\n{'method':16} {'translation m':>14} {'heading deg':>12} {'NEES':>6} "
          f"{'<7.81':>7} {'estimates':>10}")
    for name, parts in rows.items():
        err = np.vstack(parts)
        print(f"{name:16} {err[:, 0].mean():8.3f} +- {err[:, 0].std():.3f} "
              f"{err[:, 1].mean():6.3f} +- {err[:, 1].std():.3f} {err[:, 2].mean():6.2f} "
              f"{100 * np.mean(err[:, 2] < NEES_95):5.0f} % {len(err):10d}")


if __name__ == "__main__":
    main()
