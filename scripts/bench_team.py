"""The whole team's work per second of data: every directed pair, team consistency, the graph.

A team of N robots shares one room of the `four_robots` scenario (its objects, sensor, mapping
and drift; N robots instead of four, looping, sweeping and touring as the scenario's robots do).
After a warm-up of `--warm-up` seconds (the maps fill to their kappa window, the filters
settle), each of the next `--seconds` 1 Hz exchanges runs what a team's alignment does:
  pairs   every directed pair's `PairwiseAligner.update` (candidates from MNO-CLIPPER, their
          checks, the TCAFF filter), N (N - 1) of them;
  team    `TeamConsistency.update` over the pairs' estimates;
  graph   `InterRobotGraph.add_tcaff_estimate` for one direction of each robot pair and
          `InterRobotGraph.update`.
Prints, per team size, milliseconds per second of data (the mean over the measured seconds, and
the median and maximum of single seconds) and each stage's share, on one thread (numba, BLAS
and OpenMP are limited to one thread before they load); and what the pairs found: the share
holding an estimate, its median translation error and the NEES of its covariance (mean, and
share under the chi-square 95 % bound 7.815).

    python scripts/bench_team.py [--robots 2 4 8 16] [--seconds 20] [--warm-up 30] [--seed 0]
                                 [--guide-radius METRES|none]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from tcaff_gtsam.eval.config import load_scenario  # noqa: E402
from tcaff_gtsam.eval.methods.stages import warm_up  # noqa: E402
from tcaff_gtsam.eval.metrics import NEES_95, step_nees  # noqa: E402
from tcaff_gtsam.eval.sim.simulate import simulate  # noqa: E402

from tcaff_gtsam import (  # noqa: E402
    FrameAlignerParams,
    InterRobotGraph,
    PairwiseAligner,
    TeamConsistency,
)
from tcaff_gtsam.geometry import se2_error  # noqa: E402

STAGES = ("pairs", "team", "graph")


def cell(value: float, width: int, digits: int = 2) -> str:
    """value in a column of `width`, "-" when there is none (NaN: no estimate)."""
    return f"{'-' if value != value else f'{value:.{digits}f}':>{width}}"


def team_run(n_robots: int, seconds: float, seed: int):
    """The `four_robots` room driven by n_robots robots for `seconds` seconds. The scenario
    file allows at most 8 robots per room; the layout itself has no such bound, so the copy is
    made without the file's validation."""
    config = load_scenario("four_robots")
    layout = config.layout.model_copy(update={"robots": n_robots})
    return simulate(config.model_copy(update={"layout": layout, "duration": seconds}), seed)


def run_team(run, warm: int, guide_radius: float | None = None
             ) -> tuple[dict[str, list[float]], dict[str, float]]:
    """Seconds of each stage per measured exchange (those from `warm` on), and what the team
    found over them: pairs with an estimate, median translation error [m] of those and the
    NEES of their covariances (mean, share under NEES_95)."""
    n = run.n_robots
    pairs = [(i, j) for i in range(n) for j in range(n) if i != j]
    aligners = {pair: PairwiseAligner(FrameAlignerParams(guide_radius=guide_radius))
                for pair in pairs}
    team = TeamConsistency(n)
    graph = InterRobotGraph(n)
    seconds = {stage: [] for stage in STAGES}
    held, errors, nees = [], [], []
    for s, t in enumerate(run.times):
        t0 = time.process_time()
        estimates = {(i, j): aligners[(i, j)].update(t, run.maps[i][s], run.maps[j][s])
                     for i, j in pairs}
        t1 = time.process_time()
        team.update(estimates)
        t2 = time.process_time()
        for (i, j) in pairs:
            if i < j:
                taken = aligners[(i, j)].taken
                zs = np.array([m.z for m in taken]).reshape(-1, 3)
                Rs = np.array([m.R for m in taken]).reshape(-1, 3, 3)
                # the filter's own estimate: the graph weighs the candidate it takes
                graph.add_tcaff_estimate(s, i, j, aligners[(i, j)].filter.estimate, zs, Rs)
        graph.update(s)
        t3 = time.process_time()
        if s < warm:
            continue
        for stage, dt in zip(STAGES, (t1 - t0, t2 - t1, t3 - t2), strict=True):
            seconds[stage].append(dt)
        found = [(pair, est) for pair, est in estimates.items() if est is not None]
        held.append(len(found))
        if found:
            T_true = np.array([run.T_true(*pair)[s] for pair, _ in found])
            errors.extend(se2_error(T_true, np.array([est.T for _, est in found]))[:, 0])
            nees.extend(step_nees(T_true, np.array([est.x for _, est in found]),
                                  np.array([est.P for _, est in found])))
    return seconds, {"held": statistics.mean(held) / len(pairs),
                     "error": float(np.median(errors)) if errors else float("nan"),
                     "nees": float(np.mean(nees)) if nees else float("nan"),
                     "under": 100 * float(np.mean(np.array(nees) < NEES_95)) if nees
                     else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[2, 4, 8, 16])
    parser.add_argument("--seconds", type=int, default=20, help="measured 1 Hz exchanges")
    parser.add_argument("--warm-up", type=int, default=30, help="exchanges before them")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--guide-radius", type=lambda text: None if text.lower() == "none"
                        else float(text), default=FrameAlignerParams().guide_radius,
                        help="FrameAlignerParams.guide_radius of the pairs' aligners, metres "
                             "or 'none' (every search full); default: the library's")
    args = parser.parse_args()
    if min(args.robots) < 2 or args.seconds < 1 or args.warm_up < 0:
        parser.error("a team has at least 2 robots; --seconds >= 1, --warm-up >= 0")
    warm_up()
    header = (f"{'robots':>6} {'pairs':>5} {'ms/s mean':>9} {'median':>7} {'max':>7} "
              f"{'pairs %':>7} {'team %':>6} {'graph %':>7} {'ms/pair':>7} {'held':>5} "
              f"{'err m':>6} {'NEES':>6} {'<7.81':>6}")
    print(header)
    for n in args.robots:
        run = team_run(n, args.warm_up + args.seconds, args.seed)
        seconds, found = run_team(run, args.warm_up, args.guide_radius)
        total = np.sum([seconds[stage] for stage in STAGES], axis=0)
        share = {stage: 100 * sum(seconds[stage]) / total.sum() for stage in STAGES}
        n_pairs = n * (n - 1)
        print(f"{n:>6} {n_pairs:>5} {1e3 * total.mean():>9.1f} {1e3 * np.median(total):>7.1f} "
              f"{1e3 * total.max():>7.1f} {share['pairs']:>7.1f} {share['team']:>6.1f} "
              f"{share['graph']:>7.1f} {1e3 * np.mean(seconds['pairs']) / n_pairs:>7.3f} "
              f"{found['held']:>5.2f} {cell(found['error'], 6)} {cell(found['nees'], 6)} "
              f"{cell(found['under'], 4, 0)} %", flush=True)
    print("ms/s: milliseconds of one thread per second of data; held: share of directed pairs "
          "with an estimate; err m: median translation error of those estimates; NEES: of "
          "their covariances (honest: 3, 95 % under 7.81)")
    print("target: 16 robots (240 directed pairs) <= 250 ms per second of data")


if __name__ == "__main__":
    main()
