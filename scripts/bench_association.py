"""Benchmark of the association core: size gate -> consistency graph -> CLIPPER -> MNO-CLIPPER.

Two map generators, n objects per map, 50 % overlap, 0.1 m centroid noise per axis, every
object seen within the last 15 s:
  sized      objects spread uniformly, the simulator's object size classes with 10 % size
             noise: the size gate passes about 5 % of the pairs
  clustered  objects in tight clusters (8 per cluster on average, 1 m spread), every object
             1 x 1 m: the size gate passes every pair, n^2 of them; beyond the aligner's
             `max_associations` (10 000) each object keeps its `pairs_per_object` (2) pairs
             whose neighbourhoods agree best, as the aligner does. The pair count, not the
             layout, is what costs: 5 % of the pairs at 200 objects is the sized maps' 2000,
             all of them 40 000
The first table sets our graph + MNO time beside the C++ CLIPPER's, which is cited (measured
elsewhere, single thread, on problems of the issue's sizes), not run here. The second gives
medians over the map pairs:
  m          putative associations (nodes of the consistency graph)
  rank       choosing the best pairs per object when the gate passes more than the cap [ms]
             (`association._neighbourhood_pairs`; - where the cap is not reached)
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
             (200 s at kappa = 20 s), the most a step costs [ms]; sized maps up to
             --memory-up-to objects
  precision, recall of the best solution's associations (recall over true pairs among the
             graph's nodes)
  found      the best solution's true associations over all true pairs of the two maps
plus an all-to-all row (every pair of objects associated, no size gate) at n = 50. Each time is
the median of --repeat calls on one map pair (one call when it takes over 50 ms), then the
median over the pairs (--runs for sized maps, --clustered-runs for clustered ones).

The third table weighs the size gates on worlds of objects of assorted sizes in clusters
(`gate_worlds`: clusters over 40 x 40 m, log-normal widths and heights, each map a random 70 %
of the world's objects plus 10 % clutter, 0.1 m centroid noise per axis and 5 % size noise, the
other's frame turned and moved at random; --gate-sizes objects per map, --gate-runs seeded map
pairs each). Settings: "default" (FrameAlignerParams()), "all partial" (every pair the
partial-view rule passes enters the graph: `partial_pairs="all"`) and "paper gate"
(`size_partial=None`). Columns, medians over the map pairs unless said:
  gate       pairs the size gate passes (the partial-view rule's included)
  nodes      putative associations in the consistency graph
  ms, cpu ms FrameAligner().measurements end to end, a fresh aligner per call: per map pair the
             median of --repeat calls (the settings taking turns), wall clock and this
             process's CPU time (the latter steadier on a shared machine)
  cand.      share of the map pairs with a candidate
  correct    share of the map pairs whose first candidate lies within 1 m and 5 deg of the truth

Usage: python scripts/bench_association.py [--runs 15] [--sizes 20 50 100 200 500] [--profile]
       python scripts/bench_association.py --only-gates [--gate-runs 20] [--gate-sizes 50 100]
"""

from __future__ import annotations

import argparse
import logging
import math
import statistics
import time

import numpy as np
from tcaff_gtsam.eval.sim.maps import MapPair, overlapping_maps

import tcaff_gtsam.frame_aligner as frame_aligner
from tcaff_gtsam import (
    ClipperParams,
    FrameAligner,
    FrameAlignerParams,
    ObjectMap,
    clipper_solve,
    consistency_graph,
    mno_clipper,
)
from tcaff_gtsam.association import _neighbourhood_pairs, putative_associations, size_compatible
from tcaff_gtsam.geometry import invert, se2_error, se2_from_params, transform_points
from tcaff_gtsam.pairwise import unchecked

COLUMNS = ("n", "m", "edges", "rank", "graph", "solve", "mno", "graph+mno", "unchecked",
           "aligner", "+memory", "precision", "recall", "found")

#: C++ CLIPPER, one thread, on the same association problems as ours (measured elsewhere, not
#: run here): objects per map -> (associations, graph + 4 solves [ms], as the authors' code
#: calls it [ms])
CPP_CLIPPER = {20: (29, 0.19, 0.42), 50: (149, 2.4, 5.4), 100: (522, 21.5, 59.0),
               200: (2069, 245.0, 858.0)}
#: graph + MNO [ms] the targets allow, per objects per map (both generators)
TARGETS = {20: 0.2, 50: 0.6, 200: 12.0}


def clustered_maps(rng: np.random.Generator, n_objects: int, overlap: float = 0.5,
                   noise: float = 0.1, per_cluster: float = 8.0, cluster_spread: float = 1.0,
                   spacing: float = 4.0, now: float = 100.0, max_age: float = 15.0) -> MapPair:
    """Two maps of `n_objects` objects each of one world whose objects stand in clusters (rows of
    cars, groups of chairs): cluster centres uniform in a square of side spacing * sqrt(objects),
    objects normal about a centre with `cluster_spread` metres per axis, all 1 x 1 m. Many object
    pairs then lie at similar distances and the size gate tells no pair apart."""
    T_oi_oj = se2_from_params([*rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)])
    shared = round(overlap * n_objects)
    n_world = 2 * n_objects - shared
    side = spacing * math.sqrt(max(n_world, 1))
    centres = rng.uniform(0.0, side, (max(1, round(n_world / per_cluster)), 2))
    xy = (centres[rng.integers(len(centres), size=n_world)]
          + rng.normal(0.0, cluster_spread, (n_world, 2)))

    def observe(ids: np.ndarray, T_frame_world: np.ndarray) -> tuple[ObjectMap, np.ndarray]:
        k = ids.size
        c = np.column_stack([transform_points(T_frame_world, xy[ids]), np.full(k, 0.5)])
        c += rng.normal(0.0, noise, c.shape)
        order = rng.permutation(k)
        return (ObjectMap(c[order], np.ones(k), np.ones(k), now - rng.uniform(0.0, max_age, k)),
                ids[order])

    ego, ego_ids = observe(np.arange(n_objects), np.eye(3))
    other, other_ids = observe(np.r_[np.arange(shared), np.arange(n_objects, n_world)],
                               invert(T_oi_oj))
    true_pairs = np.argwhere(ego_ids[:, None] == other_ids[None, :]).astype(np.int64)
    return MapPair(ego, other, T_oi_oj, true_pairs, now)


def gate_worlds(rng: np.random.Generator, n_objects: int, side: float = 40.0,
                per_cluster: float = 6.0, cluster_spread: float = 1.5, seen: float = 0.7,
                clutter: float = 0.1, noise: float = 0.1, size_noise: float = 0.05,
                now: float = 100.0, max_age: float = 15.0) -> MapPair:
    """Two maps of `n_objects` objects each (a world of n_objects / (seen + clutter) objects:
    each map a random `seen` share of them plus `clutter` times as many false ones) of one
    world whose objects of assorted sizes stand in clusters: cluster centres uniform in a
    square of `side` metres, objects normal about a centre with `cluster_spread` metres per
    axis, widths and heights log-normal (medians 0.7 and 0.8 m, sigma 0.6 in log), so that the
    paper's size gate passes about a tenth of the pairs and the partial-view rule about twice
    as many again. Every map entry has `noise` metres of centroid noise per axis and
    `size_noise` relative noise on each extent; centroids stand at half the height."""
    n_world = max(1, round(n_objects / (seen + clutter)))
    centres = rng.uniform(0.0, side, (max(1, round(n_world / per_cluster)), 2))
    xy = (centres[rng.integers(len(centres), size=n_world)]
          + rng.normal(0.0, cluster_spread, (n_world, 2)))

    def sizes(k: int) -> tuple[np.ndarray, np.ndarray]:
        return (rng.lognormal(math.log(0.7), 0.6, k), rng.lognormal(math.log(0.8), 0.6, k))

    widths, heights = sizes(n_world)
    T_oi_oj = se2_from_params([*rng.uniform(-20, 20, 2), rng.uniform(-np.pi, np.pi)])

    def observe(T_frame_world: np.ndarray) -> tuple[ObjectMap, np.ndarray]:
        ids = rng.choice(n_world, round(seen * n_world), replace=False)
        k = round(clutter * n_world)
        false_w, false_h = sizes(k)
        w = np.r_[widths[ids], false_w] * (1 + size_noise * rng.standard_normal(ids.size + k))
        h = np.r_[heights[ids], false_h] * (1 + size_noise * rng.standard_normal(ids.size + k))
        w, h = np.abs(w), np.abs(h)
        points = np.r_[xy[ids], rng.uniform(0.0, side, (k, 2))]
        c = np.column_stack([transform_points(T_frame_world, points), h / 2])
        c += rng.normal(0.0, noise, c.shape)
        order = rng.permutation(ids.size + k)
        labels = np.r_[ids, np.full(k, -1)]
        return (ObjectMap(c[order], w[order], h[order],
                          now - rng.uniform(0.0, max_age, ids.size + k)), labels[order])

    ego, ego_ids = observe(np.eye(3))
    other, other_ids = observe(invert(T_oi_oj))
    true_pairs = np.argwhere((ego_ids[:, None] == other_ids[None, :])
                             & (ego_ids[:, None] >= 0)).astype(np.int64)
    return MapPair(ego, other, T_oi_oj, true_pairs, now)


def gate_settings() -> dict[str, FrameAlignerParams]:
    """The settings of the gate table (without "all partial" where the installed library has
    no `partial_pairs`, whose default then is every partial pair)."""
    settings = {"default": FrameAlignerParams()}
    if "partial_pairs" in FrameAlignerParams.__dataclass_fields__:
        settings["all partial"] = FrameAlignerParams(partial_pairs="all")
    settings["paper gate"] = FrameAlignerParams(size_partial=None)
    return settings


def graph_nodes(params: FrameAlignerParams, pair: MapPair) -> int:
    """The nodes of the first consistency graph the aligner builds for the pair (0: none)."""
    seen: list[int] = []
    real = frame_aligner._graph

    def spy(p, q, associations, *args):
        seen.append(len(associations))
        return real(p, q, associations, *args)

    frame_aligner._graph = spy
    try:
        FrameAligner(params).measurements(pair.ego, pair.other, pair.now)
    finally:
        frame_aligner._graph = real
    return seen[0] if seen else 0


def gate_rows(n: int, runs: int, repeat: int) -> list[tuple[str, dict[str, float]]]:
    """The gate table's rows for maps of n objects: per setting, medians over `runs` pairs."""
    settings = gate_settings()
    found: dict[str, dict[str, list[float]]] = {name: {"gate": [], "nodes": [], "ms": [],
                                                      "cpu": [], "cand": [], "correct": []}
                                               for name in settings}
    for seed in range(runs):
        pair = gate_worlds(np.random.default_rng(seed), n)
        wall: dict[str, list[float]] = {name: [] for name in settings}
        cpu: dict[str, list[float]] = {name: [] for name in settings}
        first = {}
        for _ in range(repeat):
            for name, params in settings.items():  # in turns: the same load for each
                start, start_cpu = time.perf_counter(), time.process_time()
                out = FrameAligner(params).measurements(pair.ego, pair.other, pair.now)
                wall[name].append(1e3 * (time.perf_counter() - start))
                cpu[name].append(1e3 * (time.process_time() - start_cpu))
                first[name] = out[0] if out else None
        for name, params in settings.items():
            r = found[name]
            r["gate"].append(int(size_compatible(pair.ego, pair.other, params.size_ratio,
                                                 params.size_abs_diff,
                                                 params.size_partial).sum()))
            r["nodes"].append(graph_nodes(params, pair))
            r["ms"].append(statistics.median(wall[name]))
            r["cpu"].append(statistics.median(cpu[name]))
            candidate = first[name]
            r["cand"].append(candidate is not None)
            ok = False
            if candidate is not None:
                dt, dtheta = se2_error(pair.T_oi_oj, candidate.T)
                ok = bool(dt <= 1.0 and dtheta <= math.radians(5.0))
            r["correct"].append(ok)
    return [(name, {"n": n, "gate": statistics.median(r["gate"]),
                    "nodes": statistics.median(r["nodes"]), "ms": statistics.median(r["ms"]),
                    "cpu": statistics.median(r["cpu"]), "cand": float(np.mean(r["cand"])),
                    "correct": float(np.mean(r["correct"]))})
            for name, r in found.items()]


def print_gate_table(rows: list[tuple[str, dict[str, float]]], runs: int) -> None:
    print(f"size gates on clustered worlds of assorted sizes, medians over {runs} map pairs "
          "(ms: FrameAligner().measurements, a fresh aligner per call)")
    header = (f"{'objects':>8}  {'setting':<12}{'gate':>8}{'nodes':>8}{'ms':>9}{'cpu ms':>9}"
              f"{'cand.':>8}{'correct':>9}")
    print(header)
    print("-" * len(header))
    for name, v in rows:
        print(f"{v['n']:>8.0f}  {name:<12}{v['gate']:>8.0f}{v['nodes']:>8.0f}{v['ms']:>9.2f}"
              f"{v['cpu']:>9.2f}{v['cand']:>8.2f}{v['correct']:>9.2f}")


def make_pair(kind: str, n: int, seed: int) -> MapPair:
    rng = np.random.default_rng(seed)
    if kind == "sized":
        return overlapping_maps(rng, n, overlap=0.5, noise=0.1, size_noise=0.1)
    return clustered_maps(rng, n)


def timed(call, repeat: int) -> float:
    """Median milliseconds of `repeat` calls, or of one when it takes over 50 ms."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        times.append(1e3 * (time.perf_counter() - start))
        if times[0] > 50.0:
            break
    return statistics.median(times)


def one_run(kind: str, n: int, seed: int, cap: int | None, all_to_all: bool, repeat: int,
            memory: bool) -> dict[str, float]:
    """One map pair: beyond `cap` associations each object keeps its best pairs, as the aligner
    does (None: all the size gate passes)."""
    pair = make_pair(kind, n, seed)
    params = ClipperParams()
    aligner_params = FrameAlignerParams()
    p, q = pair.ego.centroids[:, :2], pair.other.centroids[:, :2]
    t_rank = math.nan
    if all_to_all:
        associations = np.argwhere(np.ones((n, n), bool))
    elif cap is None:
        associations = putative_associations(pair.ego, pair.other,
                                             partial_ratio=aligner_params.size_partial)
    else:
        compatible = size_compatible(pair.ego, pair.other, aligner_params.size_ratio,
                                     aligner_params.size_abs_diff, aligner_params.size_partial)
        associations = np.argwhere(compatible)
        if associations.shape[0] > cap:
            def rank() -> np.ndarray:
                return _neighbourhood_pairs(compatible, p, q, pair.ego.ages(pair.now),
                                           pair.other.ages(pair.now), params.epsilon,
                                           aligner_params.pairs_per_object, cap)

            associations = rank()
            t_rank = timed(rank, repeat)
    graph = consistency_graph(p, q, associations, params.epsilon, params.sigma)
    t_graph = timed(lambda: consistency_graph(p, q, associations, params.epsilon,
                                              params.sigma), repeat)
    solution = clipper_solve(graph, params)
    t_solve = timed(lambda: clipper_solve(graph, params), repeat)
    t_mno = timed(lambda: mno_clipper(graph, 4, params), repeat)
    aligner = FrameAligner(aligner_params)
    fast = FrameAligner(unchecked(aligner_params))
    t_unchecked = timed(lambda: fast.measurements(pair.ego, pair.other, pair.now), repeat)
    t_aligner = timed(lambda: aligner.measurements(pair.ego, pair.other, pair.now), repeat)
    t_memory = math.nan
    if memory:
        earlier = [make_pair(kind, n, 1000 * seed + k) for k in range(10)]
        start = time.perf_counter()
        aligner.measurements(pair.ego, pair.other, pair.now,
                             [(e.now, e.ego) for e in earlier],
                             [(e.now, e.other) for e in earlier])
        t_memory = 1e3 * (time.perf_counter() - start)
    true = set(map(tuple, pair.true_pairs.tolist()))
    gated = true & set(map(tuple, associations.tolist()))
    chosen = set(map(tuple, solution.associations.tolist()))
    return {"n": n, "m": graph.m, "edges": graph.n_edges, "rank": t_rank, "graph": t_graph,
            "solve": t_solve,
            "mno": t_mno, "graph+mno": t_graph + t_mno, "unchecked": t_unchecked,
            "aligner": t_aligner, "+memory": t_memory,
            "precision": len(chosen & true) / max(len(chosen), 1),
            "recall": len(chosen & gated) / max(len(gated), 1),
            "found": len(chosen & true) / max(len(true), 1)}


def row(kind: str, n: int, runs: int, repeat: int, memory: bool, cap: int | None = None,
        all_to_all: bool = False) -> dict[str, float]:
    results = [one_run(kind, n, seed, cap, all_to_all, repeat, memory) for seed in range(runs)]
    return {key: statistics.median(r[key] for r in results) for key in COLUMNS}


def print_side_by_side(sized: dict[int, dict], clustered: dict[int, dict]) -> None:
    print("graph + MNO-CLIPPER (4 solutions), medians [ms]; objects per map (associations)")
    columns = (("objects (assoc.)", 18), ("ours: sized", 12), ("target", 8),
               ("clustered (assoc.)", 21), ("ours", 9), ("C++ (assoc.)", 14),
               ("C++ graph+4 solves*", 21), ("C++ authors' call*", 20))
    header = "".join(f"{name:<{width}}" if k == 0 else f"{name:>{width}}"
                     for k, (name, width) in enumerate(columns))
    print(header)
    print("-" * len(header))
    for n, values in sized.items():
        other = clustered[n]
        cpp = CPP_CLIPPER.get(n)
        cells = (f"{n} ({values['m']:.0f})", f"{values['graph+mno']:.2f}",
                 f"{TARGETS[n]:.1f}" if n in TARGETS else "-",
                 f"{n} ({other['m']:.0f})", f"{other['graph+mno']:.2f}",
                 f"({cpp[0]})" if cpp else "-", f"{cpp[1]:.2f}" if cpp else "-",
                 f"{cpp[2]:.2f}" if cpp else "-")
        print("".join(f"{cell:<{width}}" if k == 0 else f"{cell:>{width}}"
                      for k, (cell, (_, width)) in enumerate(zip(cells, columns, strict=True))))
    print("* C++ CLIPPER (one thread) measured elsewhere on problems of the sizes in brackets, "
          "not run here")


def print_table(rows: list[tuple[str, dict[str, float]]]) -> None:
    header = f"{'case':<12}" + "".join(f"{c:>11}" for c in COLUMNS)
    print(header)
    print("-" * len(header))
    for label, values in rows:
        cells = []
        for key in COLUMNS:
            v = values[key]
            if math.isnan(v):
                cells.append(f"{'-':>11}")
            elif key in ("n", "m", "edges"):
                cells.append(f"{v:>11.0f}")
            elif key in ("precision", "recall", "found"):
                cells.append(f"{v:>11.3f}")
            else:
                cells.append(f"{v:>11.2f}")
        print(f"{label:<12}" + "".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="Times in milliseconds; medians over --runs.")
    parser.add_argument("--runs", type=int, default=15, help="map pairs per size (default 15)")
    parser.add_argument("--clustered-runs", type=int, default=5,
                        help="clustered map pairs per size (default 5)")
    parser.add_argument("--repeat", type=int, default=5,
                        help="calls timed per map pair, their median kept (default 5)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[20, 50, 100, 200, 500],
                        help="objects per map (default 20 50 100 200 500)")
    parser.add_argument("--memory-up-to", type=int, default=200, metavar="N",
                        help="time the +memory column up to N objects per map (default 200)")
    parser.add_argument("--profile", action="store_true",
                        help="also profile 20 MNO runs at the largest size with pyinstrument")
    parser.add_argument("--gate-runs", type=int, default=20,
                        help="map pairs per size in the size gates' table (default 20)")
    parser.add_argument("--gate-sizes", type=int, nargs="+", default=[50, 100],
                        help="objects per map in the size gates' table (default 50 100)")
    parser.add_argument("--only-gates", action="store_true",
                        help="print only the size gates' table")
    args = parser.parse_args()
    # the clustered maps are thinned to max_associations on purpose: no warning per step
    logging.getLogger("tcaff_gtsam.frame_aligner").setLevel(logging.ERROR)
    for name in ("runs", "clustered_runs", "repeat", "gate_runs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got "
                         f"{getattr(args, name)}")
    for name in ("sizes", "gate_sizes"):
        if min(getattr(args, name)) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got "
                         f"{min(getattr(args, name))}")

    # compile (or load the cached machine code) before timing anything
    one_run("sized", 12, 0, None, False, 1, False)
    gate_rows(min(args.gate_sizes), 1, 1)
    if args.only_gates:
        print_gate_table([r for n in args.gate_sizes
                          for r in gate_rows(n, args.gate_runs, args.repeat)], args.gate_runs)
        return
    sized = {n: row("sized", n, args.runs, args.repeat, n <= args.memory_up_to)
             for n in args.sizes}
    cap = FrameAlignerParams().max_associations
    clustered = {n: row("clustered", n, args.clustered_runs, args.repeat, False, cap=cap)
                 for n in args.sizes}
    print_side_by_side(sized, clustered)
    print()
    rows = [("sized", values) for values in sized.values()]
    rows += [("clustered", values) for values in clustered.values()]
    rows.append(("all-to-all", row("sized", 50, args.runs, args.repeat, True,
                                   all_to_all=True)))
    print_table(rows)
    print()
    print_gate_table([r for n in args.gate_sizes
                      for r in gate_rows(n, args.gate_runs, args.repeat)], args.gate_runs)

    if args.profile:
        from pyinstrument import Profiler

        n = max(args.sizes)
        graphs = []
        for seed in range(20):
            pair = overlapping_maps(np.random.default_rng(seed), n, 0.5, 0.1)
            graphs.append((pair, putative_associations(
                pair.ego, pair.other, partial_ratio=FrameAlignerParams().size_partial)))
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
