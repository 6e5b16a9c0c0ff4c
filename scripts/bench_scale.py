"""Large maps: one FrameAligner step at 500 to 5000 objects per map, time and peak memory.

Two map generators, every object seen within kappa (the worst case; a robot's recent objects
are usually far fewer):
  sized      the simulator's object size classes with 10 % size noise, 50 % overlap
  identical  the same layout with every object 1 x 1 m, so the size gate passes every pair
Each row runs in a fresh process (after a warm-up step that compiles the kernels) and prints
medians over the seeds:
  pairs      object pairs that pass the size gate
  graph      nodes of the consistency graph (at most `max_associations`)
  step       FrameAligner.measurements, seconds
  peak       peak resident memory during the step above the resident size before it, MB
  error      metres, translation error of the best candidate ('-': no candidate)

Usage: python scripts/bench_scale.py [--sizes 500 1000 2000 5000] [--seeds 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

COLUMNS = ("maps", "n", "pairs", "graph", "step", "peak", "error")


def _status_kb(field: str) -> int:
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith(field + ":"))


def _reset_peak() -> int:
    """Reset the process's peak resident size to its current one (Linux); returns it, kB."""
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")
    return _status_kb("VmRSS")


def one_case(kind: str, n: int, seed: int) -> dict:
    """Runs in the child process: one step on one pair of maps."""
    import numpy as np
    from tcaff_gtsam.eval.sim.maps import overlapping_maps

    from tcaff_gtsam import FrameAligner, ObjectMap
    from tcaff_gtsam import frame_aligner as fa
    from tcaff_gtsam.association import size_compatible
    from tcaff_gtsam.geometry import se2_error

    aligner = FrameAligner()
    warm = overlapping_maps(np.random.default_rng(1), 20, overlap=0.5)
    aligner.measurements(warm.ego, warm.other, warm.now)
    pair = overlapping_maps(np.random.default_rng(seed), n, overlap=0.5, noise=0.1,
                            size_noise=0.1 if kind == "sized" else 0.0)
    ego, other = pair.ego, pair.other
    if kind == "identical":
        ego, other = (ObjectMap(m.centroids, np.ones(len(m)), np.ones(len(m)), m.last_seen)
                      for m in (ego, other))
    nodes = []
    build = fa._graph  # the aligner's unchecked graph builder
    fa._graph = lambda p, q, a, *rest: nodes.append(len(a)) or build(p, q, a, *rest)
    base = _reset_peak()
    start = time.perf_counter()
    found = aligner.measurements(ego, other, pair.now)
    step = time.perf_counter() - start
    peak = (_status_kb("VmHWM") - base) / 1024
    prm = aligner.params
    pairs = int(np.count_nonzero(size_compatible(ego, other, prm.size_ratio, prm.size_abs_diff,
                                                 prm.size_partial)))
    error = se2_error(found[0].T, pair.T_oi_oj)[0] if found else float("nan")
    return {"pairs": pairs, "graph": nodes[0] if nodes else 0, "step": step, "peak": peak,
            "error": error}


def run(kind: str, n: int, seed: int) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", kind, str(n), str(seed)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 1000, 2000, 5000])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, n, seed = args.child
        print(json.dumps(one_case(kind, int(n), int(seed))))
        return
    print(" ".join(f"{c:>10}" for c in COLUMNS))
    for kind in ("sized", "identical"):
        for n in args.sizes:
            rows = [run(kind, n, seed) for seed in range(args.seeds)]
            errors = [r["error"] for r in rows if r["error"] == r["error"]]
            cells = [kind, n, int(statistics.median(r["pairs"] for r in rows)),
                     int(statistics.median(r["graph"] for r in rows)),
                     f"{statistics.median(r['step'] for r in rows):.2f}",
                     f"{statistics.median(r['peak'] for r in rows):.0f}",
                     f"{statistics.median(errors):.2f}" if errors else "-"]
            print(" ".join(f"{c:>10}" for c in cells), flush=True)
    print("target: 5000 objects per map, step < 2 s and < 500 MB")


if __name__ == "__main__":
    main()
