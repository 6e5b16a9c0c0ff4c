"""Benchmark of the association core: size gate -> consistency graph -> CLIPPER -> MNO-CLIPPER.

Map pairs of n objects each (50 % overlap, 0.1 m centroid noise per axis, 10 % size noise, the
simulator's object size classes). Prints medians over the runs:
  m          putative associations after the size gate
  edges      consistent pairs in the graph
  graph      consistency graph construction [ms]
  solve      one CLIPPER solve [ms]
  mno        MNO-CLIPPER with N = 4, on a built graph [ms]
  graph+mno  the two together: the figure the targets refer to [ms]
  unchecked  FrameAligner.measurements end to end (kappa window, gate, graph, MNO, Arun) without
             the checks beyond MNO-CLIPPER (the released code's candidates) [ms]
  aligner    the same with the default checks (objects explained, spread, ambiguity among the
             step's solutions) [ms]
  +memory    the default aligner also searching 10 earlier maps of each robot for look-alikes
             (200 s at kappa = 20 s), the most a step costs [ms]
  precision, recall of the best solution's associations (recall over true pairs that passed
             the size gate)
plus an all-to-all row (every pair of objects associated, no size gate) at n = 50.

Usage: python scripts/bench_association.py [--runs 15] [--sizes 20 50 100 200] [--profile]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import ClipperParams, FrameAligner, clipper_solve, consistency_graph, mno_clipper
from tcaff_gtsam.pairwise import unchecked
from tcaff_gtsam.registration import putative_associations

COLUMNS = ("n", "m", "edges", "graph", "solve", "mno", "graph+mno", "unchecked", "aligner",
           "+memory", "precision", "recall")


def ms(start: float) -> float:
    return 1e3 * (time.perf_counter() - start)


def one_run(n: int, seed: int, all_to_all: bool) -> dict[str, float]:
    pair = overlapping_maps(np.random.default_rng(seed), n, overlap=0.5, noise=0.1,
                            size_noise=0.1)
    params = ClipperParams()
    if all_to_all:
        associations = np.argwhere(np.ones((n, n), bool))
    else:
        associations = putative_associations(pair.ego, pair.other)
    p, q = pair.ego.centroids[:, :2], pair.other.centroids[:, :2]
    start = time.perf_counter()
    graph = consistency_graph(p, q, associations, params.epsilon, params.sigma)
    t_graph = ms(start)
    start = time.perf_counter()
    solution = clipper_solve(graph, params)
    t_solve = ms(start)
    start = time.perf_counter()
    mno_clipper(graph, 4, params)
    t_mno = ms(start)
    aligner = FrameAligner()
    start = time.perf_counter()
    FrameAligner(unchecked(aligner.params)).measurements(pair.ego, pair.other, pair.now)
    t_unchecked = ms(start)
    start = time.perf_counter()
    aligner.measurements(pair.ego, pair.other, pair.now)
    t_aligner = ms(start)
    earlier = [overlapping_maps(np.random.default_rng(1000 * seed + k), n, overlap=0.5,
                                noise=0.1, size_noise=0.1) for k in range(10)]
    start = time.perf_counter()
    aligner.measurements(pair.ego, pair.other, pair.now, [(e.now, e.ego) for e in earlier],
                         [(e.now, e.other) for e in earlier])
    t_memory = ms(start)
    true = set(map(tuple, pair.true_pairs.tolist()))
    gated = true & set(map(tuple, associations.tolist()))
    chosen = set(map(tuple, solution.associations.tolist()))
    return {"n": n, "m": graph.m, "edges": graph.n_edges, "graph": t_graph, "solve": t_solve,
            "mno": t_mno, "graph+mno": t_graph + t_mno, "unchecked": t_unchecked,
            "aligner": t_aligner, "+memory": t_memory,
            "precision": len(chosen & true) / max(len(chosen), 1),
            "recall": len(chosen & gated) / max(len(gated), 1)}


def row(n: int, runs: int, all_to_all: bool = False) -> dict[str, float]:
    results = [one_run(n, seed, all_to_all) for seed in range(runs)]
    return {key: statistics.median(r[key] for r in results) for key in COLUMNS}


def print_table(rows: list[tuple[str, dict[str, float]]]) -> None:
    header = f"{'case':<12}" + "".join(f"{c:>11}" for c in COLUMNS)
    print(header)
    print("-" * len(header))
    for label, values in rows:
        cells = []
        for key in COLUMNS:
            v = values[key]
            if key in ("n", "m", "edges"):
                cells.append(f"{v:>11.0f}")
            elif key in ("precision", "recall"):
                cells.append(f"{v:>11.3f}")
            else:
                cells.append(f"{v:>11.2f}")
        print(f"{label:<12}" + "".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Times in milliseconds; medians over --runs.")
    parser.add_argument("--runs", type=int, default=15, help="map pairs per size (default 15)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 50, 100, 200],
                        help="objects per map")
    parser.add_argument("--profile", action="store_true",
                        help="also profile 20 MNO runs at the largest size with pyinstrument")
    args = parser.parse_args()

    one_run(12, 0, False)  # compile (or load the cached machine code) before timing anything
    rows = [("gated", row(n, args.runs)) for n in args.sizes]
    rows.append(("all-to-all", row(50, args.runs, all_to_all=True)))
    print_table(rows)
    print("targets: graph+mno <= 5 ms at n = 100, <= 15 ms at n = 200")

    if args.profile:
        from pyinstrument import Profiler

        n = max(args.sizes)
        graphs = []
        for seed in range(20):
            pair = overlapping_maps(np.random.default_rng(seed), n, 0.5, 0.1)
            graphs.append((pair, putative_associations(pair.ego, pair.other)))
        profiler = Profiler(interval=0.0002)
        profiler.start()
        for pair, associations in graphs:
            graph = consistency_graph(pair.ego.centroids[:, :2], pair.other.centroids[:, :2],
                                      associations)
            mno_clipper(graph, 4)
        profiler.stop()
        print(profiler.output_text(unicode=False, color=False, show_all=False))


if __name__ == "__main__":
    main()
