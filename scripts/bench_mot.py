"""Time collaborative people tracking and its MOTA scoring on the MOT scenario.

Simulates the scenario, runs every alignment method, then for every tracked method and robot
times the tracker (own and neighbours' detections) and the CLEAR MOT scoring separately, and
prints the time per robot frame and per job.

    python scripts/bench_mot.py [--scenario mot] [--duration 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from tcaff_gtsam.eval.config import MethodsConfig, load_scenario
from tcaff_gtsam.eval.methods import run_methods
from tcaff_gtsam.eval.mot import (
    NO_SHARING,
    mot_methods,
    robot_alignments,
    score_tracks,
    track_robot,
)
from tcaff_gtsam.eval.sim.simulate import simulate
from tcaff_gtsam.eval.tracker import MultiObjectTracker


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="mot")
    parser.add_argument("--duration", type=float, default=300.0, help="seconds simulated")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cfg = load_scenario(args.scenario).model_copy(update={"duration": args.duration})
    if cfg.pedestrians is None:
        parser.error(f"scenario {args.scenario} has no pedestrians")
    run = simulate(cfg, args.seed)
    runs = run_methods(run, MethodsConfig())
    people = run.people
    n_frames = len(people.times)
    names = mot_methods(list(runs.estimates))
    track_ms, score_ms, tracks_per_frame = [], [], []
    for method in names:
        for i in range(run.n_robots):
            T_i = ({} if method == NO_SHARING else
                   robot_alignments(people, run.times, runs.pairs, runs.estimates[method], i))
            start = time.perf_counter()
            tracks = track_robot(people, i, T_i, MultiObjectTracker(cfg.pedestrians.tracker))
            middle = time.perf_counter()
            score_tracks(people.truth_in_odom(i), people.in_view, tracks,
                         cfg.pedestrians.match_distance)
            end = time.perf_counter()
            track_ms.append(1e3 * (middle - start) / n_frames)
            score_ms.append(1e3 * (end - middle) / n_frames)
            tracks_per_frame.append(np.mean([len(ids) for ids, _ in tracks]))
    detections = sum(len(d[0]) for d in people.detections) / (run.n_robots * n_frames)
    print(f"{args.scenario}: {run.n_robots} robots, {len(names)} tracked methods, "
          f"{n_frames} frames at {cfg.pedestrians.rate:g} Hz, {detections:.1f} detections per "
          f"robot frame, {np.mean(tracks_per_frame):.1f} confirmed tracks per frame\n")
    print(f"{'part':22} {'ms per robot frame':>19} {'p90':>7} {'s per job':>10}")
    for label, ms in (("tracker", track_ms), ("MOTA (motmetrics)", score_ms)):
        print(f"{label:22} {np.median(ms):19.3f} {np.percentile(ms, 90):7.3f} "
              f"{np.sum(ms) * n_frames / 1e3:10.2f}")


if __name__ == "__main__":
    main()
