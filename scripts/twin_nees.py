"""The NEES of estimates whose covariance covers their map's twins, and of other rules for it.

A map of few objects can fit itself: moved by a rigid motion S, the objects a candidate
registers land on other objects of the same map (MRCLAM's landmarks stand in twos and threes;
on data set 6's 150 s maps robots 0 and 4 hold a turn of 112-116 deg for 85-140 steps). Then
S o x (S a motion of the ego's map) or x o S^-1 (of the other's) explains those objects as
x does: a twin of alignment x. `PairwiseAligner` reports a covariance that covers the twins
whose maps have fitted themselves over the window (`twins.Twins`):

    P' = P + sum_k (R + d_k d_k') / (m + 1),  d_k = twin_k - x (theta wrapped),

m the twins, R the covariance of the measurement they were found on (`twins.covering`). This
runs `PairwiseAligner` (the library's defaults, the runs of `bench_nees.py`) and prints, per
data set, the NEES of every estimate against the filter's own P (before the twins), against
the P reported (as built), and against P widened under other rules for which twins count,
all found with `twins.map_motions` on the measurement linked to the estimate:

  L=n       (--persist, one column per value) the candidate track within
            `confirm_translation` and `confirm_heading` of the estimate that is longest
            (candidates linked from step to step within the same gate, kept W steps or while
            the estimate is near), its motions found at each of the last min(n, k) steps of
            the track (k its length). 1 counts every motion of the step.
  earlier   those of L=1 whose twins explain the two maps of W steps ago (mutual nearest
            neighbours within `inlier_radius` through the size gate) as well as the estimate.
  explains  those of L=1 whose twins explain the current maps as well as the estimate (the
            aligner's own test of a rival).
  path      the motions that every measurement on the main tree's best path in the window
            has (the filter's own association), of the latest of them.

Estimates, their errors and their correctness are the same in every column.

    python scripts/twin_nees.py [--data mrclam sim kitchen] [--seeds 3] [--sim-seeds 2]
                                [--persist 1 8] [--cache results/bench_nees] [--workers 2]

Columns per rule: twinned (share of the estimates with a twin counted), NEES mean, share
under 7.815 and confident false accepts (off by more than 1 m / 5 deg and outside the
99.7 % ellipse).
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from bench_nees import SCENARIOS, library_params, load, run_arguments, sources
from tcaff_gtsam.eval.metrics import NEES_95, NEES_997, Thresholds, step_errors, step_nees
from tcaff_gtsam.eval.runs import directed_pairs

from tcaff_gtsam.association import size_gates
from tcaff_gtsam.frame_aligner import _confirms
from tcaff_gtsam.geometry import se2_from_params, se2_to_params
from tcaff_gtsam.pairwise import PairwiseAligner
from tcaff_gtsam.registration import mutual_inliers
from tcaff_gtsam.twins import _twin, covering, map_motions


def explained(z: np.ndarray, ego, other, now: float, params) -> int:
    """How many recent objects alignment z explains: pairs (one object of each map) that are
    mutual nearest neighbours within `inlier_radius` once the other map is moved by z, and
    pass the size gate."""
    ego = ego.subset(ego.recent_indices(now, params.kappa))
    other = other.subset(other.recent_indices(now, params.kappa))
    if len(ego) == 0 or len(other) == 0:
        return 0
    gate = size_gates(ego, other, params.size_ratio, params.size_abs_diff)[0]
    return len(mutual_inliers(se2_from_params(z), ego.centroids[:, :2], other.centroids[:, :2],
                              gate, params.inlier_radius))


class _Steps:
    """The candidates the filter was given over the last W + 2 steps, with their maps, and
    the self-motions of those asked for (computed once)."""

    def __init__(self, window: int, params) -> None:
        self.window, self.params = window, params
        self.given: dict[int, tuple] = {}  # step -> (taken, ego map, other map, t)
        self.found: dict[tuple[int, int], list] = {}  # (step, index) -> [(side, S)]

    def add(self, step: int, taken: list, ego, other, now: float) -> None:
        self.given[step] = (taken, ego, other, now)
        oldest = step - self.window - 1
        self.given = {k: v for k, v in self.given.items() if k >= oldest}
        self.found = {k: v for k, v in self.found.items() if k[0] >= oldest}

    def motions(self, step: int, index: int) -> list[tuple[int, np.ndarray]]:
        if (step, index) not in self.found:
            taken, ego, other, now = self.given[step]
            self.found[(step, index)] = map_motions(taken[index], ego, other, now, self.params)
        return self.found[(step, index)]


def on_path(pair, steps: _Steps, s: int) -> tuple | None:
    """The self-motions (side, S) of the latest measurement on the main tree's best path in
    the window that every other measurement of the window on that path also has (within
    `confirm_translation` and `confirm_heading`), and that measurement's R; None without a
    measurement in the window."""
    f, W = pair.filter, steps.window
    path = f._main.choice[int(np.argmin(f._main.cost))]
    cols = [c for c in range(2, W + 2) if path[c] >= 0]
    if not cols:
        return None
    at = [(s - W - 1 + c, int(path[c])) for c in cols]
    keep = [(side, S) for side, S in steps.motions(*at[-1])
            if all(any(other_side == side and _confirms(S, S2, steps.params)
                       for other_side, S2 in steps.motions(*key)) for key in at[:-1])]
    return keep, steps.given[at[-1][0]][0][at[-1][1]].R


def run_source(source, cache: Path, persist: list[int]) -> dict:
    """Per estimate: correct, its NEES against the filter's own P, against the P reported
    ("built") and against the filter's P widened under each rule (each L of `persist`,
    "earlier", "explains" and "path"), and how many twins each counted."""
    from tcaff_gtsam.precompile import compile_kernels

    compile_kernels()
    run = load(source, cache)
    aligner, tcaff = library_params(run)
    limits = Thresholds()
    rows = []
    for i, j in directed_pairs(run):
        pair = PairwiseAligner(aligner, tcaff)
        prm = pair.aligner.params
        window = pair.filter.params.window
        truth = se2_to_params(run.T_true(i, j))
        tracks: list[dict] = []  # z, R, length, last step, motions [(side, S, length)]
        carried: dict | None = None
        steps = _Steps(window, prm)
        path_motions: tuple | None = None
        for s, t in enumerate(run.times):
            ego, other = run.maps[i][s], run.maps[j][s]
            est = pair.update(float(t), ego, other)
            steps.add(s, pair.taken, ego, other, float(t))
            if pair.measurements:
                fresh = []
                for m in pair.measurements:
                    before = max((tr for tr in tracks if _confirms(m.z, tr["z"], prm)),
                                 key=lambda tr: tr["length"], default=None)
                    found = []
                    for side, S in map_motions(m, ego, other, float(t), prm):
                        lengths = [n + 1 for side0, S0, n in (before or {"motions": []})["motions"]
                                   if side0 == side and _confirms(S, S0, prm)]
                        found.append((side, S, max(lengths, default=1)))
                    fresh.append({"z": m.z, "R": m.R, "motions": found, "last": s,
                                  "length": 1 + (before["length"] if before else 0)})
                # a track not continued is kept W steps, or while it is the held estimate's
                tracks = fresh + [tr for tr in tracks
                                  if not any(_confirms(tr["z"], f["z"], prm) for f in fresh)
                                  and (s - tr["last"] <= window
                                       or (est is not None and _confirms(est.x, tr["z"], prm)))]
            if est is None:
                path_motions = None
            elif pair.filter._main is not None and est.hypothesis == pair.filter.hypothesis:
                path_motions = on_path(pair, steps, s) or path_motions
            if est is None or not np.all(np.isfinite(truth[s])):
                continue
            carried = max((tr for tr in tracks if _confirms(est.x, tr["z"], prm)),
                          key=lambda tr: tr["length"], default=carried)
            T_true = run.T_true(i, j)[s][None]
            own = pair.filter.estimate.P
            row = {"ok": bool(limits.correct(step_errors(T_true, est.x[None]))[0]),
                   "nees": float(step_nees(T_true, est.x[None], own[None])[0]),
                   "nees built": float(step_nees(T_true, est.x[None], est.P[None])[0]),
                   "twins built": int(not np.array_equal(est.P, own))}
            rules: dict[str, tuple[list, np.ndarray]] = {}
            for L in persist:
                rules[f"{L}"] = ([] if carried is None else
                                 [_twin(S, side, est.x) for side, S, n in carried["motions"]
                                  if n >= min(L, carried["length"])],
                                 None if carried is None else carried["R"])
            # twins that explain the maps of W steps ago as well as the estimate does
            rules["earlier"] = ([], None)
            if carried is not None and s >= window:
                then = float(run.times[s - window])
                ego_then, other_then = run.maps[i][s - window], run.maps[j][s - window]
                base = explained(est.x, ego_then, other_then, then, prm)
                rules["earlier"] = ([z for z in (_twin(S, side, est.x)
                                                 for side, S, _ in carried["motions"])
                                     if explained(z, ego_then, other_then, then, prm) >= base],
                                    carried["R"])
            # twins that explain as many recent objects of the two maps as the estimate does
            rules["explains"] = ([], None)
            if carried is not None:
                base = explained(est.x, ego, other, float(t), prm)
                rules["explains"] = ([z for z in (_twin(S, side, est.x)
                                                  for side, S, _ in carried["motions"])
                                      if explained(z, ego, other, float(t), prm) >= base],
                                     carried["R"])
            rules["path"] = (([], None) if path_motions is None else
                             ([_twin(S, side, est.x) for side, S in path_motions[0]],
                              path_motions[1]))
            for name, (twins, R) in rules.items():
                P = own if not twins else covering(own, est.x, np.array(twins), R)
                row[f"nees {name}"] = float(step_nees(T_true, est.x[None], P[None])[0])
                row[f"twins {name}"] = len(twins)
            rows.append(row)
    return {"group": source.group, "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    run_arguments(parser, ["mrclam", "sim", "kitchen"])
    parser.add_argument("--persist", type=int, nargs="+", default=[1, 8],
                        help="steps a twin must persist along its candidate's track (L)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    if any(L < 1 for L in args.persist):
        parser.error(f"--persist must be at least 1, got {args.persist}")
    todo = [s for s in sources(args.data, args.seeds, args.sim_seeds, list(SCENARIOS),
                               [20.0, 150.0]) if s.odometry != "raw"]
    groups: dict[str, list] = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for done in pool.map(run_source, todo, [args.cache] * len(todo),
                             [args.persist] * len(todo)):
            groups.setdefault(done["group"], []).extend(done["rows"])
            print(f"  {done['group']}: {len(done['rows'])} estimates", flush=True)
    head = f"{'data set':26} {'est':>6} {'P: NEES':>8} {'<7.81':>6} {'conf':>6}"
    for L in ["as built", *(f"L={L}" for L in args.persist), "earlier", "explains", "path"]:
        head += f" | {L}: {'twinned':>7} {'NEES':>6} {'<7.81':>6} {'conf':>6}"
    print(head)
    for group, rows in groups.items():
        line = f"{group:26} {len(rows):>6}   {_cells(rows, 'nees')}"
        for L in ["built", *map(str, args.persist), "earlier", "explains", "path"]:
            twinned = np.mean([r[f"twins {L}"] > 0 for r in rows])
            line += f" |      {twinned:>7.3f} {_cells(rows, f'nees {L}')}"
        print(line, flush=True)


def _cells(rows: list[dict], key: str) -> str:
    """NEES mean, share under 7.815 and confident false accepts of `key` over `rows`."""
    ok = np.array([r["ok"] for r in rows])
    nees = np.array([r[key] for r in rows])
    return (f"{nees.mean():>6.2f} {np.mean(nees < NEES_95):>6.3f} "
            f"{np.mean(~ok & (nees > NEES_997)):>6.3f}")


if __name__ == "__main__":
    main()
