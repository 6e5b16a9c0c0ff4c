"""Results: one job's estimates and scores, summaries over jobs, and the files they are written to.

A job is one run (a simulated scenario and seed, or a recorded data set) with every method's
estimate of every directed pair at every exchange. `JobResult.save` writes it as
`<stem>.npz` (the arrays) and `<stem>.json` (the scores); the stem is `<scenario>-seed<seed>` for
a simulated run and the data set's name for a recorded one. `JobResult.load` checks both files
(`check_saved`) before anything reads them.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_from_params
from tcaff_gtsam.inputs import check_within, index_pairs, read_npz, real_array, shown
from tcaff_gtsam.param_checks import MAX_COORDINATE, MAX_VARIANCE, _real

from .config import MethodsConfig
from .datasets.text_tables import read_json
from .metrics import PairTrace, Thresholds, pair_metrics, pooled_metrics
from .mot import COUNTS
from .registry import describe

__all__ = [
    "MAX_CLOCK",
    "JobResult",
    "check_saved",
    "is_file_name",
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
        """A job written by `save`, checked (see `check_saved`).

        Raises:
            DataError: the files are missing, not regular files, truncated or not a saved
                job, naming the file and the key or array that is wrong.
        """
        json_path, npz_path = Path(folder) / f"{stem}.json", Path(folder) / f"{stem}.npz"
        meta = read_json(json_path, "saved job")
        arrays = read_npz(npz_path, "job", bools=True)
        return check_saved(str(json_path), str(npz_path), meta, arrays)


#: s, the largest magnitude of a saved job's clock (its times + t0): ROS 2 bags stamp messages
#: in int64 nanoseconds, which end at 9.2e9 s (the year 2262)
MAX_CLOCK = 9e9
#: the JSON entries of a saved job and the type each holds (`info` may be left out)
_META = {"name": str, "seed": (int, type(None)), "pairs": list, "metrics": dict,
         "seconds": dict, "mot": dict, "info": dict}


def check_saved(json_name: str, npz_name: str, meta, arrays: dict[str, np.ndarray]
                ) -> JobResult:
    """The job whose `<stem>.json` holds `meta` and whose `<stem>.npz` holds `arrays`, checked
    as far as the reports, exports and figures read it: every entry of the JSON of its type
    (name a file name, seed an int >= 0 or null, pairs [i, j] of distinct robots, each once),
    every array real numbers (overlap bool) of the shape `JobResult.arrays` gives with n robots
    (poses_odom), S steps (times) and P pairs, no infinity (NaN marks a missing value; the
    odometry is left to the exports to name), times finite, increasing and within `MAX_CLOCK` s.

    Raises:
        DataError: naming the file (`json_name`, `npz_name`) and the key or array.
    """
    if not isinstance(meta, dict):
        raise DataError(f"{json_name}: not a saved job (a JSON object), got {shown(meta)}")
    for key, kind in _META.items():
        if key not in meta and key != "info":
            raise DataError(f"{json_name}: no {key!r}, not a saved job")
        value = meta.get(key, {})
        if not isinstance(value, kind) or isinstance(value, bool):
            raise DataError(f"{json_name}: {key} must be a JSON "
                            f"{'int >= 0 or null' if key == 'seed' else kind.__name__}, got "
                            f"{shown(value)}")
    name, seed = meta["name"], meta["seed"]
    if not is_file_name(name):
        raise DataError(f"{json_name}: name must be a file name, got {shown(name)}")
    if seed is not None and seed < 0:
        raise DataError(f"{json_name}: seed must be an int >= 0 or null, got {seed}")
    for key, value in meta["seconds"].items():
        if not (_real(value) and 0 <= value <= MAX_CLOCK):
            raise DataError(f"{json_name}: seconds.{key} must be seconds >= 0, got "
                            f"{shown(value)}")
    for key, by_pair in meta["metrics"].items():
        if not (isinstance(by_pair, dict) and all(isinstance(r, dict) for r in by_pair.values())):
            raise DataError(f"{json_name}: metrics.{key} must map pairs to reports, got "
                            f"{shown(by_pair)}")
    for key, summary in meta["mot"].items():
        if not (isinstance(summary, dict) and isinstance(summary.get("robots"), list)
                and (summary.get("mota") is None or _real(summary["mota"]))):
            raise DataError(f"{json_name}: mot.{key} must hold a mota (a number or null) and "
                            f"robots (a list), got {shown(summary)}")

    def array(key: str, dims: str, shape: tuple[int | None, ...], bound: float,
              missing=np.isnan) -> np.ndarray:
        """arrays[key], real numbers of `shape` (None: any length) named `dims`, each
        `missing` or within `bound`."""
        if key not in arrays:
            raise DataError(f"{npz_name}: no array {key!r}, not a saved job")
        value = real_array(npz_name, f"array {key!r}", arrays[key])
        if value.ndim != len(shape) or any(want is not None and got != want
                                           for got, want in zip(value.shape, shape, strict=True)):
            sizes = ", ".join("*" if n is None else str(n) for n in shape)
            raise DataError(f"{npz_name}: array {key!r} has shape {value.shape}, expected "
                            f"{dims} = ({sizes}{',' if len(shape) == 1 else ''})")
        check_within(npz_name, key, np.where(missing(value), 0.0, value), bound)
        return value

    def counts(key: str, dims: str, shape: tuple[int | None, ...]) -> np.ndarray:
        """arrays[key], integers >= 0 of `shape`."""
        value = array(key, dims, shape, np.inf)
        if arrays[key].dtype.kind not in "iu" or (value < 0).any():
            raise DataError(f"{npz_name}: array {key!r} must hold integers >= 0, got "
                            f"{shown(arrays[key])}")
        return arrays[key]

    for key, value in arrays.items():
        if value.dtype.kind == "b" and key != "overlap":
            raise DataError(f"{npz_name}: array {key!r} must hold numbers, got bool")
    S = len(array("times", "(S,)", (None,), MAX_CLOCK))
    times = arrays["times"]
    if S == 0 or np.isnan(times).any() or (np.diff(times) <= 0).any():
        raise DataError(f"{npz_name}: array 'times' must be finite seconds that increase, got "
                        f"{shown(times)}")
    if "t0" in arrays:
        t0 = array("t0", "()", (), MAX_CLOCK)
        if np.isnan(t0) or not np.all(np.abs(times + t0) <= MAX_CLOCK):
            raise DataError(f"{npz_name}: array 't0' = {t0} puts the times beyond "
                            f"{MAX_CLOCK:g} s or is not finite")
    # odometry that is not finite is named by the exports that place paths through it
    # (`trajectories.check_odometry`), and left to them
    n = len(array("poses_odom", "(n, S, 3)", (None, S, 3), MAX_COORDINATE,
                  lambda v: ~np.isfinite(v)))
    array("poses_true", "(n, S, 3)", (n, S, 3), MAX_COORDINATE)
    pairs = index_pairs(json_name, "pairs", meta["pairs"])
    repeated = len({tuple(p) for p in pairs.tolist()}) < len(pairs)
    if not len(pairs) or repeated or (pairs >= n).any() or (pairs[:, 0] == pairs[:, 1]).any():
        raise DataError(f"{json_name}: pairs must be [i, j] of two of the {n} robots of "
                        f"{npz_name} (0..{n - 1}), each pair once, got {shown(meta['pairs'])}")
    P = len(pairs)
    array("truth", "(P, S, 3)", (P, S, 3), MAX_COORDINATE)
    for key in arrays:
        if key.startswith("est_"):
            array(key, "(P, S, 3)", (P, S, 3), MAX_COORDINATE)
        elif key.startswith("cov_"):
            if f"est_{key.removeprefix('cov_')}" not in arrays:
                raise DataError(f"{npz_name}: array {key!r} without "
                                f"'est_{key.removeprefix('cov_')}'")
            array(key, "(P, S, 3, 3)", (P, S, 3, 3), MAX_VARIANCE)
        elif key == "overlap":
            if arrays[key].dtype.kind != "b" or arrays[key].shape != (P, S):
                raise DataError(f"{npz_name}: array 'overlap' must be (P, S) = ({P}, {S}) "
                                f"bool, got {shown(arrays[key])}")
        elif key.startswith("cand_steps_") or key.startswith("cand_z_"):
            p = key.rsplit("_", 1)[1]
            if p not in {str(k) for k in range(P)} or not {f"cand_steps_{p}",
                                                           f"cand_z_{p}"} <= arrays.keys():
                raise DataError(f"{npz_name}: array {key!r}: the candidates of a pair 0..{P - 1}"
                                f" are cand_steps_<pair> and cand_z_<pair> together")
            if key.startswith("cand_steps_"):
                steps = counts(key, "(M,)", (None,))
                if (steps >= S).any():
                    raise DataError(f"{npz_name}: array {key!r} holds a step beyond the "
                                    f"{S} steps")
                array(f"cand_z_{p}", "(M, 3)", (len(steps), 3), MAX_COORDINATE)
        elif key.startswith("map_"):
            r = key.rsplit("_", 1)[1]
            if r not in {str(k) for k in range(n)} or not {
                    f"map_xy_{r}", f"map_widths_{r}", f"map_counts_{r}"} <= arrays.keys():
                raise DataError(f"{npz_name}: array {key!r}: the map of a robot 0..{n - 1} is "
                                f"map_xy_<r>, map_widths_<r> and map_counts_<r> together")
            if key.startswith("map_counts_"):
                N = int(counts(key, "(S,)", (S,)).sum())
                array(f"map_xy_{r}", "(N, 2)", (N, 2), MAX_COORDINATE)
                array(f"map_widths_{r}", "(N,)", (N,), MAX_COORDINATE)
    if "world_xy" in arrays or "world_widths" in arrays:
        m = len(array("world_xy", "(m, 2)", (None, 2), MAX_COORDINATE))
        array("world_widths", "(m,)", (m,), MAX_COORDINATE)
    if "walls" in arrays:
        array("walls", "(w, 2, 2)", (None, 2, 2), MAX_COORDINATE)
    mot = meta["mot"]
    if mot or any(key.startswith("mot_") for key in arrays):
        F = len(array("mot_times", "(F,)", (None,), MAX_CLOCK))
        array("mot_window", "()", (), MAX_CLOCK)
        for method in mot:
            if f"mot_counts_{method}" not in arrays:
                raise DataError(f"{npz_name}: no array 'mot_counts_{method}' for the "
                                f"tracking results of {method} in {json_name}")
        for key in arrays:
            if key.startswith("mot_counts_"):
                counts(key, "(n, F, 4)", (n, F, len(COUNTS)))
    info = meta.get("info", {})
    robots = info.get("robots")
    if robots is not None and not (isinstance(robots, list) and len(robots) == n
                                   and all(isinstance(r, str) for r in robots)):
        raise DataError(f"{json_name}: info.robots must name the {n} robots, got "
                        f"{shown(robots)}")
    return JobResult(name, seed, [(int(i), int(j)) for i, j in pairs], arrays, meta["metrics"],
                     meta["seconds"], mot, info)


def is_file_name(text: str) -> bool:
    """Whether `text` names a file in a folder: no path, not "." or "..", no NUL."""
    return text not in ("", ".", "..") and Path(text).name == text and "\0" not in text


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
