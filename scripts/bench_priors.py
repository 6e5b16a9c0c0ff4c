"""What the association priors do: precision of the putative associations and of the first
candidate, with the paper's size gate and with this project's additions, on three kinds of maps.

For every map pair (every directed pair of robots at every exchange from the 9th, the first
TCAFF can answer at) and every setting of the aligner, prints, pooled:

- putative associations: how many per exchange, their precision (the share that pair the
  same object) and recall (the share of the truly shared objects that pass the gate);
- the first candidate (the best-scoring MNO-CLIPPER candidate the aligner returns): on how
  many exchanges there is one, and the share of those within 1 m and 5 deg of the truth.

Settings: `paper gate` (both width and height within 1.35, no descriptors: the released code's
gate), `partial gate` (the default: one extent may differ by 2x), `+ descriptors` (gate at a
similarity of 0.5 and CLIPPER's prior), `+ gravity` (the height test) and `camera` (both, with
residual covariances: `FrameAlignerParams.camera()`).

Maps and truth:
- the 7-Scenes kitchen (`--sequence`): its two halves walked there and back by the front end,
  exact poses; an object pair is true when they are mutual nearest neighbours within 0.3 m
  under the true alignment (the objects carry no identity);
- the simulator's `indoor_rgbd` (rendered RGB-D through the front end; `--sim-seeds`): true
  pairs from the world objects the map entries were built from;
- MRCLAM (`--mrclam`, VIO-like odometry, seed 0): true pairs from the landmark identities;
  every landmark looks alike and the maps carry no descriptors, so the descriptors can change
  nothing there, which the table shows.

    python scripts/bench_priors.py [--sequence ../shared/data/rgbd/7scenes_redkitchen]
        [--mrclam ../shared/data/mrclam/MRCLAM_Dataset6] [--sim-seeds 2]
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from tcaff_gtsam.eval.config import load_mrclam, load_scenario
from tcaff_gtsam.eval.datasets import mrclam, rgbd_robots
from tcaff_gtsam.eval.datasets.rgbd_sequence import read_sequence
from tcaff_gtsam.eval.sim.simulate import simulate

from tcaff_gtsam import FrameAligner, FrameAlignerParams
from tcaff_gtsam.association import _descriptor_gate, size_compatible
from tcaff_gtsam.geometry import invert, se2_error, se3_to_se2
from tcaff_gtsam.registration import mutual_inliers

SETTINGS = {
    "paper gate": FrameAlignerParams(size_partial=None),
    "partial gate": FrameAlignerParams(),
    "+ descriptors": FrameAlignerParams(descriptor_min=0.5, descriptor_prior=True),
    "+ gravity": FrameAlignerParams(height_epsilon=0.25),
    "camera": FrameAlignerParams.camera(),
}
FIRST = 8  # exchanges before the first TCAFF can answer at (W = 8)


def gate(prm: FrameAlignerParams, ego, other) -> np.ndarray:
    """(n, m) bool: the aligner's putative associations (its size and descriptor gates)."""
    compatible = size_compatible(ego, other, prm.size_ratio, prm.size_abs_diff, prm.size_partial)
    return _descriptor_gate(ego, other, compatible, prm.descriptor_min)


def score(pairs, settings) -> dict[str, dict[str, float]]:
    """Pooled numbers of each setting over (ego, other, now, T_true (3, 3), true (n, m) bool)."""
    out = {}
    for name, prm in settings.items():
        prm = replace(prm, kappa=math.inf)  # the maps hold what they hold
        aligner = FrameAligner(prm)
        kept = hits = true = steps = with_candidate = correct = 0
        for ego, other, now, T_true, truth in pairs:
            putative = gate(prm, ego, other)
            kept += int(putative.sum())
            hits += int((putative & truth).sum())
            true += int(truth.sum())
            steps += 1
            found = aligner.measurements(ego, other, now)
            if found:
                with_candidate += 1
                err = se2_error(T_true[None], found[0].T[None])[0]
                correct += bool(err[0] <= 1.0 and err[1] <= math.radians(5.0))
        out[name] = {"putative": kept / max(steps, 1), "precision": hits / max(kept, 1),
                     "recall": hits / max(true, 1), "steps": steps,
                     "with_candidate": with_candidate,
                     "first_correct": correct / max(with_candidate, 1)}
    return out


def kitchen_pairs(folder: Path):
    seq = read_sequence(folder)
    middle = int(seq.frame_ids[len(seq) // 2])
    walks = [rgbd_robots.walk(seq, None, middle, None, True),
             rgbd_robots.walk(seq, middle, None, None, True)]
    run, _ = rgbd_robots.load_run(walks, "exact", None, 20.0)
    for i, j in ((0, 1), (1, 0)):
        T = se3_to_se2(invert(run.T_world_odom[i]) @ run.T_world_odom[j])
        for s in range(FIRST, len(run.times)):
            a, b = run.maps[i][s], run.maps[j][s]
            truth = np.zeros((len(a), len(b)), dtype=bool)
            matched = mutual_inliers(T[s], a.centroids[:, :2], b.centroids[:, :2],
                                     np.ones(truth.shape, dtype=bool), 0.3)
            truth[matched[:, 0], matched[:, 1]] = True
            yield a, b, float(run.times[s]), T[s], truth


def labelled_pairs(maps, labels, times, T_true):
    """Map pairs whose entries carry the world object (or landmark) each was made from."""
    for i, j in ((0, 1), (1, 0)):
        T = T_true(i, j)
        for s in range(FIRST, len(times)):
            a, b = maps[i][s], maps[j][s]
            la, lb = np.asarray(labels[i][s]), np.asarray(labels[j][s])
            truth = (la[:, None] == lb[None, :]) & (la[:, None] >= 0)
            yield a, b, float(times[s]), T[s], truth


def table(title: str, results: dict[str, dict[str, float]]) -> Table:
    t = Table(title=title)
    for column in ("setting", "putative / exchange", "precision", "recall",
                   "exchanges with a candidate", "first candidate correct"):
        t.add_column(column, justify="right")
    for name, r in results.items():
        t.add_row(name, f"{r['putative']:.1f}", f"{100 * r['precision']:.1f} %",
                  f"{100 * r['recall']:.1f} %", f"{r['with_candidate']} of {r['steps']}",
                  f"{100 * r['first_correct']:.1f} %")
    return t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path,
                        default=Path("../shared/data/rgbd/7scenes_redkitchen"),
                        help="a 7-Scenes or TUM RGB-D folder (skipped when absent)")
    parser.add_argument("--mrclam", type=Path,
                        default=Path("../shared/data/mrclam/MRCLAM_Dataset6"),
                        help="an MRCLAM data set folder (skipped when absent)")
    parser.add_argument("--sim-seeds", type=int, default=2, help="seeds of indoor_rgbd")
    args = parser.parse_args()
    console = Console()
    if args.sequence.is_dir():
        console.print(table(f"{args.sequence.name}: two halves there and back, exact poses",
                            score(list(kitchen_pairs(args.sequence)), SETTINGS)))
    pairs = []
    for seed in range(args.sim_seeds):
        run = simulate(load_scenario("indoor_rgbd"), seed)
        pairs += list(labelled_pairs(run.maps, run.labels, run.times, run.T_true))
    if pairs:
        console.print(table(f"simulator indoor_rgbd, seeds 0-{args.sim_seeds - 1}",
                            score(pairs, SETTINGS)))
    if args.mrclam.is_dir():
        data = mrclam.read_dataset(args.mrclam)
        config = load_mrclam("default")
        run, labels = mrclam.load_run(
            data, "vio", 0, config.kappa_of("vio"), config.nu, config.min_shared,
            config.vio.heading_rw_deg_per_sqrt_min, config.vio.scale_std)
        pairs = []
        for i in range(run.n_robots):
            for j in range(run.n_robots):
                if i != j:
                    T = run.T_true(i, j)
                    for s in range(FIRST, len(run.times), 10):  # every 10th: 20 pairs
                        a, b = run.maps[i][s], run.maps[j][s]
                        la, lb = np.asarray(labels[i][s]), np.asarray(labels[j][s])
                        pairs.append((a, b, float(run.times[s]), T[s],
                                      la[:, None] == lb[None, :]))
        console.print(table(f"{args.mrclam.name}, VIO-like odometry, seed 0 (every 10th "
                            f"exchange of every pair)", score(pairs, SETTINGS)))


if __name__ == "__main__":
    main()
