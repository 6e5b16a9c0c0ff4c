"""Results: one job's estimates and scores, summaries over jobs, and the files they are written to.

A job is one run (a simulated scenario and seed, or a recorded data set) with every method's
estimate of every directed pair at every exchange. `JobResult.save` writes it as
`<stem>.npz` (the arrays) and `<stem>.json` (the scores); the stem is `<scenario>-seed<seed>` for
a simulated run and the data set's name for a recorded one.
"""

from __future__ import annotations

import csv
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params

from .config import MethodsConfig
from .metrics import PairTrace, Thresholds, pair_metrics, pooled_metrics
from .mot import COUNTS
from .registry import describe

__all__ = [
    "JobResult",
    "load_saved",
    "pool",
    "score",
    "summarize",
    "summarize_mot",
    "thresholds_of",
    "write_csv",
    "write_tables",
]

@dataclass
class JobResult:
    """One run, every method's estimates and (once scored) their metrics.

    Attributes:
        name: the scenario or recorded data set.
        seed: the simulator's seed; None for a recorded run.
        pairs: directed pairs (i, j), i the ego robot.
        arrays: as saved in `<stem>.npz`: times (S,) s; poses_true and poses_odom (n, S, 3)
            (x, y, theta of each body in the world and in its odometry frame; NaN rows where
            there is no truth); truth (P, S, 3) the true T_oi_oj; est_<method> (P, S, 3), NaN
            rows where the method had no estimate; cov_<method> (P, S, 3, 3) the covariance
            of (x, y, theta) it reported with each estimate, NaN where it had none (only for
            the methods that report one; jobs saved before covariances were kept have none);
            cand_steps_<p> (M,) and cand_z_<p> (M, 3) the candidates the TCAFF filter saw;
            overlap (P, S) bool when the run knows it;
            map_xy_<r>, map_widths_<r> and map_counts_<r>: what robot r shared at each
            exchange (see `jobs.shared_maps`).
            A simulated run adds world_xy (m, 2), world_widths (m,) and walls (w, 2, 2); with
            people to track, mot_times (F,), mot_window (s) and mot_counts_<method> (n, F, 4):
            per robot and frame the `mot.COUNTS`.
        metrics: method -> {"all": report pooled over the pairs, "i->j": one pair's report}.
        seconds: method (and shared stage: "candidates") -> compute time over the run, numba
            compilation excluded.
        mot: method -> {"mota": averaged over the robots, "robots": [per robot summary]};
            empty without people.
        info: what the source wants kept with the job (JSON-ready), e.g. the fingerprint of
            the settings and files a recorded job came from.
    """

    name: str
    seed: int | None
    pairs: list[tuple[int, int]]
    arrays: dict[str, np.ndarray]
    metrics: dict[str, dict[str, dict]] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    mot: dict[str, dict] = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    @property
    def stem(self) -> str:
        return self.name if self.seed is None else f"{self.name}-seed{self.seed}"

    @property
    def n_steps(self) -> int:
        return len(self.arrays["times"])

    def overlap(self) -> np.ndarray:
        """(P, S) bool: where the maps shared enough objects (every step when unknown)."""
        if "overlap" in self.arrays:
            return self.arrays["overlap"]
        return np.ones((len(self.pairs), self.n_steps), dtype=bool)

    def traces(self, method: str) -> list[PairTrace]:
        """The method's PairTrace of every pair, with its covariances when the job kept them
        and, for a stream built from the default TCAFF's candidates (`Estimate.judged`), those
        candidates."""
        a = self.arrays
        T_odom = se2_from_params(a["poses_odom"])
        overlap = self.overlap()
        covariance = a.get(f"cov_{method}")
        judged = _judged(method)
        return [PairTrace(a["times"], se2_from_params(a["truth"][p]), a[f"est_{method}"][p],
                          overlap[p], T_odom[i], T_odom[j],
                          None if covariance is None else covariance[p],
                          (a[f"cand_steps_{p}"], a[f"cand_z_{p}"])
                          if judged and f"cand_z_{p}" in a else None)
                for p, (i, j) in enumerate(self.pairs)]

    def save(self, folder: Path) -> None:
        """Write `<stem>.npz` and `<stem>.json` into `folder` (made when missing)."""
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / f"{self.stem}.npz", "wb") as file:
            np.savez_compressed(file, **self.arrays)
        (folder / f"{self.stem}.json").write_text(json.dumps(
            {"name": self.name, "seed": self.seed, "pairs": self.pairs,
             "seconds": self.seconds, "metrics": self.metrics, "mot": self.mot,
             "info": self.info}, indent=1))

    @classmethod
    def load(cls, folder: Path, stem: str) -> JobResult:
        """A job written by `save`.

        Raises:
            DataError: the files are missing, truncated or not a saved job.
        """
        try:
            meta = json.loads((folder / f"{stem}.json").read_text())
            with np.load(folder / f"{stem}.npz") as data:
                arrays = {k: data[k] for k in data.files}
            return cls(meta["name"], meta["seed"], [tuple(p) for p in meta["pairs"]], arrays,
                       meta["metrics"], meta["seconds"], meta["mot"], meta.get("info", {}))
        except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
            raise DataError(f"{folder / stem}.*: not a saved job ({type(exc).__name__}: "
                            f"{exc})") from exc


def _judged(stream: str) -> bool:
    """Whether a stream is built from the default TCAFF's candidates (`Estimate.judged`);
    False for a stream no registered method produces (one a tool or test made)."""
    try:
        return describe(stream).judged
    except ConfigError:
        return False


def load_saved(results: Path) -> list[JobResult]:
    """Every job saved in a results folder: a study's (`runs/<stem>.npz`) or a recorded data
    set's (`<stem>.npz`), each beside its `<stem>.json`.

    Raises:
        DataError: not a folder, no saved job in it, or a job's files are unreadable.
    """
    results = Path(results)
    if not results.is_dir():
        raise DataError(f"{results}: not a results folder")
    jobs = [JobResult.load(folder, npz.stem) for folder in (results, results / "runs")
            for npz in sorted(folder.glob("*.npz")) if npz.with_suffix(".json").is_file()]
    if not jobs:
        raise DataError(f"{results}: no saved runs (<name>.npz and .json, or runs/ of a study)")
    return jobs


def thresholds_of(methods: MethodsConfig) -> Thresholds:
    """The false-accept thresholds of a method set, with its overlap gap and judge's hold."""
    t = methods.thresholds
    return Thresholds(t.translation, float(np.radians(t.heading_deg)), t.overlap_gap_steps,
                      t.judge_hold)


def score(job: JobResult, names: list[str], thresholds: Thresholds) -> None:
    """Fill `job.metrics` for the estimates `names`: pooled over the pairs and per pair."""
    job.metrics = {}
    for method in names:
        traces = job.traces(method)
        job.metrics[method] = {"all": pooled_metrics(traces, thresholds).as_report()}
        for (i, j), trace in zip(job.pairs, traces, strict=True):
            job.metrics[method][f"{i}->{j}"] = pair_metrics(trace, thresholds).as_report()


def pool(jobs: list[JobResult], names: list[str], thresholds: Thresholds) -> dict[str, dict]:
    """method -> report pooled over every pair of `jobs` (at least one), with
    ms_per_pair_step."""
    reports = {m: pooled_metrics([t for j in jobs for t in j.traces(m)], thresholds).as_report()
               for m in names}
    pair_steps = sum(len(j.pairs) * j.n_steps for j in jobs)
    for m, report in reports.items():
        report["ms_per_pair_step"] = 1e3 * sum(j.seconds.get(m, 0.0) for j in jobs) / pair_steps
    return reports


def summarize(jobs: list[JobResult], names: list[str], thresholds: Thresholds
              ) -> dict[str, dict[str, dict]]:
    """run name -> method -> report pooled over every pair and seed, with ms_per_pair_step."""
    return {name: pool([j for j in jobs if j.name == name], names, thresholds)
            for name in dict.fromkeys(j.name for j in jobs)}


def summarize_mot(jobs: list[JobResult]) -> dict[str, dict[str, dict]]:
    """run name -> method -> tracking summary over its seeds: mota (mean of each seed's
    robot-averaged MOTA) and mota_std, and false_positives_share, misses_share and
    switches_share: shares of the people to track, pooled over robots and seeds. Runs without
    people are left out.
    """
    summary: dict[str, dict[str, dict]] = {}
    for name in dict.fromkeys(j.name for j in jobs if j.mot):
        mine = [j for j in jobs if j.name == name and j.mot]
        summary[name] = {}
        for method in mine[0].mot:
            motas = [j.mot[method]["mota"] for j in mine if j.mot[method]["mota"] is not None]
            totals = sum(j.arrays[f"mot_counts_{method}"].sum(axis=(0, 1)) for j in mine)
            objects = int(totals[0])
            shares = {f"{key}_share": float(total / objects) if objects else None
                      for key, total in zip(COUNTS[1:], totals[1:], strict=True)}
            summary[name][method] = {
                "mota": float(np.mean(motas)) if motas else None,
                "mota_std": float(np.std(motas)) if motas else None,
                "seeds": len(motas), "objects": objects, **shares}
    return summary


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows of dictionaries as CSV, the columns in order of first appearance."""
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)


def write_tables(folder: Path, header: dict, jobs: list[JobResult],
                 summary: dict[str, dict[str, dict]],
                 mot_summary: dict[str, dict[str, dict]] | None = None) -> None:
    """metrics.json (header, summaries and every job's scores), metrics.csv (every method and
    pair of every job, then the summary rows) and, with people, mot.csv."""
    mot_summary = mot_summary or {}
    (folder / "metrics.json").write_text(json.dumps({
        **header, "summary": summary, "mot_summary": mot_summary,
        "runs": [{"name": j.name, "seed": j.seed, "metrics": j.metrics, "mot": j.mot}
                 for j in jobs]}, indent=1))

    def seed(job: JobResult) -> int | str:
        return "-" if job.seed is None else job.seed

    rows = [{"scenario": j.name, "seed": seed(j), "method": method, "pair": pair, **report}
            for j in jobs for method, by_pair in j.metrics.items()
            for pair, report in by_pair.items()]
    rows += [{"scenario": name, "seed": "all", "method": method, "pair": "all", **report}
             for name, by_method in summary.items() for method, report in by_method.items()]
    if rows:
        write_csv(folder / "metrics.csv", rows)
    mot_rows = []
    for j in jobs:
        for method, mot in j.mot.items():
            mot_rows.append({"scenario": j.name, "seed": seed(j), "method": method,
                             "robot": "mean", "mota": mot["mota"]})
            mot_rows += [{"scenario": j.name, "seed": seed(j), "method": method,
                          "robot": r, **report} for r, report in enumerate(mot["robots"])]
    mot_rows += [{"scenario": name, "seed": "all", "method": method, "robot": "all", **report}
                 for name, by_method in mot_summary.items()
                 for method, report in by_method.items()]
    if mot_rows:
        write_csv(folder / "mot.csv", mot_rows)
