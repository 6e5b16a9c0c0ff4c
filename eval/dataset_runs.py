"""Recorded data sets: a run from a loader in `datasets/`, every method over every directed pair,
scored where the data set has the truth, written to one folder.

Results of a data set `name` go to `<output>/<name>/`:
- `<name>.npz` / `.json`: every method's estimate of every pair at every exchange (`JobResult`);
- `metrics.json`, `metrics.csv`, `table.md` (the paper's table: mean +- std translation and
  heading error, availability), when there is truth;
- `trajectories/`: every robot's path in the first robot's frame, through the estimates of
  the table's methods and the truth, as TUM files (see `trajectories`);
- `figures/`, when there is truth and figures are asked for: `errors_<i>_<j>.png` (error over
  time), `candidates_<i>_<j>.png` (MNO-CLIPPER candidates, the truth and TCAFF) of every pair,
  and `arena.png` (the landmarks and every robot's path) when the data set knows the landmarks.
A loader may keep its own files there too (Kimera-Multi: `maps/`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params

from .config import KimeraMultiConfig, MethodsConfig, MrclamConfig, RgbdConfig
from .datasets import kimera_multi, mrclam, rgbd_robots
from .datasets.text_tables import read_json
from .jobs import evaluate
from .metrics import NEES_95, NEES_997, Thresholds, step_errors, step_nees
from .registry import METHODS, describe, estimate_names, shown_streams
from .results import JobResult, summarize, thresholds_of, write_tables
from .runs import RecordedRun, planar_poses
from .trajectories import write_tum

__all__ = ["KimeraOutcome", "MrclamOutcome", "RecordedOutcome", "RgbdOutcome",
           "evaluate_recorded", "evaluate_run", "mrclam_name", "rgbd_name", "run_kimera_multi",
           "run_mrclam", "run_rgbd", "walk_report"]

log = logging.getLogger(__name__)


@dataclass
class RecordedOutcome:
    """What the evaluation of a recorded run produced.

    Attributes:
        folder: where the results are.
        job: every method's estimates (and metrics, with truth).
        summary: estimate stream -> pooled report ({} without truth).
        methods: the method set that ran (without the methods that need the truth, when the
            run has none).
    """

    folder: Path
    job: JobResult
    summary: dict[str, dict]
    methods: MethodsConfig


def evaluate_run(run: RecordedRun, methods: MethodsConfig,
                 progress: Callable[[float], None] | None = None,
                 arrays: dict[str, np.ndarray] | None = None
                 ) -> tuple[JobResult, MethodsConfig]:
    """`jobs.evaluate` of a recorded run, writing nothing: the job and the method set that ran
    (without the methods that need the truth, when the run has none). Times in the job are
    seconds since the first exchange; `t0` is that exchange's time on the run's clock."""
    if not run.has_truth:
        kept = [m for m in methods.methods if not METHODS[m].needs_truth]
        methods = methods.model_copy(update={"methods": kept})
    T_world_body = run.T_world_odom @ run.T_odom_body
    job = evaluate(run, methods, run.name, None, {
        "times": run.times - run.times[0], "t0": np.array(run.times[0]),
        "poses_true": planar_poses(T_world_body), "poses_odom": planar_poses(run.T_odom_body),
        **(arrays or {}),
    }, progress)
    return job, methods


def evaluate_recorded(run: RecordedRun, methods: MethodsConfig, folder: Path,
                      figures: bool = True, header: dict | None = None,
                      progress: Callable[[float], None] | None = None,
                      arrays: dict[str, np.ndarray] | None = None,
                      info: dict | None = None) -> RecordedOutcome:
    """Every method over every directed pair of a recorded run; results into `folder`.

    Without truth for every robot, the methods that need it are left out and nothing is scored;
    the estimates are still written. What an earlier run left in `folder` is set aside first
    (`_set_aside`).

    Args:
        header: extra entries of metrics.json (the data set's own facts).
        arrays: extra arrays of the job (world_xy (m, 2), world_widths (m,) and walls
            (w, 2, 2) draw the arena).
        info: kept in the job's JSON (`JobResult.info`).
    """
    _set_aside(folder, run.name)
    job, methods = evaluate_run(run, methods, progress, arrays)
    job.info = {"robots": list(run.robot_names), **(info or {})}
    folder.mkdir(parents=True, exist_ok=True)
    summary: dict[str, dict] = {}
    if job.metrics:
        summary = summarize([job], estimate_names(methods), thresholds_of(methods))[run.name]
        write_tables(folder, {"name": run.name, "robots": list(run.robot_names),
                              **(header or {})}, [job], {run.name: summary})
        _write_markdown(folder / "table.md", run.name, summary)
        if figures:
            _draw(folder, job, methods)
    write_tum(folder, job, streams=shown_streams(methods))  # `tcaff export` writes them all
    job.save(folder)  # last: a saved job means the tables and figures were written
    return RecordedOutcome(folder, job, summary, methods)


#: what an evaluation writes into its folder beside its job (`evaluate_recorded`, `run_rgbd`),
#: and the recording `tcaff view` makes of it
_RESULTS = ("metrics.json", "metrics.csv", "table.md", "walk_report.json", "figures",
            "trajectories", "recording.rrd")


def _set_aside(folder: Path, name: str) -> None:
    """Clear `folder` for a new evaluation of the run `name` (one that is not reused: other
    settings, or told not to resume), keeping a finished one: when the folder holds a job
    (`<name>.json`, written last), its results (the job, tables, figures, trajectories, a
    recording; not a Kimera run's maps, which a run of the same settings reuses) move to
    `<folder's parent>/previous/<folder's name>/`, replacing what an earlier one left there;
    without one, what an interrupted run left is removed, and `previous` is left as it is. A
    new run then neither writes its tables beside another's figures nor loses a finished run.

    Raises:
        DataError: `previous` is there but is no folder (a file, a link), or a move failed
            (naming both folders); what moved stays moved.
    """
    found = [folder / item for item in (f"{name}.json", f"{name}.npz", *_RESULTS)
             if (folder / item).exists() or (folder / item).is_symlink()]
    if not found:
        return
    previous = folder.parent / "previous"
    aside = previous / folder.name
    finished = (folder / f"{name}.json").exists()
    try:
        if not finished:  # no job: an interrupted run's partial results
            for path in found:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
            log.warning("%s: an interrupted run's partial results removed from %s", name,
                        folder)
            return
        if previous.is_symlink() or (previous.exists() and not previous.is_dir()):
            raise DataError(f"{folder}: {previous} is no folder; an earlier run's results are "
                            f"moved there")
        if aside.is_symlink() or aside.is_file():
            aside.unlink()
        elif aside.exists():
            shutil.rmtree(aside)
        aside.mkdir(parents=True)
        for path in found:
            shutil.move(path, aside / path.name)
    except OSError as exc:
        raise DataError(f"{folder}: an earlier run's results could not be set aside "
                        f"({'moved to ' + str(aside) if finished else 'removed'}: {exc})"
                        ) from None
    log.warning("%s: an earlier run's results, not reused, moved to %s", name, aside)


def _draw(folder: Path, job: JobResult, methods: MethodsConfig) -> None:
    from . import plots

    shown = [m for m in shown_streams(methods) if m != "ground_truth"]
    plots.draw_recorded(folder / "figures", job, shown)


def _write_markdown(path: Path, name: str, summary: dict[str, dict]) -> None:
    """The paper's table: mean +- std translation and heading error, and availability."""
    lines = [f"| {name} | translation error [m] | heading error [deg] | available |",
             "|---|---|---|---|"]
    for method, r in summary.items():
        if r["translation_error_m_mean"] is None:
            cells = ["-", "-"]
        else:
            cells = [f"{r['translation_error_m_mean']:.2f} +- {r['translation_error_m_std']:.2f}",
                     f"{r['heading_error_deg_mean']:.2f} +- {r['heading_error_deg_std']:.2f}"]
        available = "-" if r["availability"] is None else f"{100 * r['availability']:.0f} %"
        lines.append(f"| {describe(method).label} | {cells[0]} | {cells[1]} | {available} |")
    path.write_text("\n".join(lines) + "\n")


# -- Kimera-Multi ------------------------------------------------------------------------------


class KimeraProgress(kimera_multi.KimeraProgress):
    """The loader's hooks, and the alignment's."""

    def aligning(self, share: float) -> None: ...


@dataclass
class KimeraOutcome:
    """What a Kimera-Multi run produced.

    Attributes:
        folder: where the results are.
        mappings: the robots mapped (also those of an earlier run that were reused).
        reused: robots whose saved maps were reused.
        recorded: the evaluation (None when mapping failed).
    """

    folder: Path
    mappings: list[kimera_multi.RobotMapping] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    recorded: RecordedOutcome | None = None


def run_kimera_multi(config: KimeraMultiConfig, data: Path, output: Path,
                     resume: bool = True, figures: bool = True,
                     progress: KimeraProgress | None = None) -> KimeraOutcome:
    """Map every robot (reusing saved maps when `resume`), align, score, write the results to
    `<output>/<test name>/`.

    Raises:
        DataError: a robot's data cannot be read. The robots mapped before it are saved.
    """
    progress = progress or KimeraProgress()
    folder = Path(output) / config.name
    run, mappings, reused = kimera_multi.load_run(config, data, folder / "maps", resume,
                                                  progress)
    methods = config.methods
    assert isinstance(methods, MethodsConfig)
    header = {"frames_per_second": {m.robot: m.frames_per_second for m in mappings}}
    recorded = evaluate_recorded(run, methods, folder, figures, header, progress.aligning)
    return KimeraOutcome(folder, mappings, reused, recorded)


# -- UTIAS MRCLAM ------------------------------------------------------------------------------


def mrclam_name(data: Path, odometry: str, seed: int | None) -> str:
    """The results' name of one data set, odometry and seed (raw odometry has none)."""
    return f"{Path(data).name}-{odometry}" + ("" if seed is None else f"-seed{seed}")


def _fingerprint(config: MrclamConfig, data: Path, odometry: str, seed: int | None,
                 pairs: list[tuple[int, int]] | None) -> str:
    """Changes when anything that shapes the results changes: settings and the files."""
    files = sorted((f.name, f.stat().st_size, f.stat().st_mtime_ns)
                   for f in Path(data).glob("*.dat"))
    blob = json.dumps({"config": config.model_dump(mode="json"), "files": files,
                       "odometry": odometry, "seed": seed, "pairs": pairs}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass
class MrclamOutcome:
    """One data set, odometry and seed (None for raw odometry): the evaluation, or the one saved
    by an earlier run with the same settings and files (`reused`)."""

    odometry: str
    seed: int | None
    recorded: RecordedOutcome
    reused: bool
    skipped: dict[str, int]


def _odometry_runs(odometries, seeds) -> list[tuple[str, int | None]]:
    """(odometry, seed) of every run to make, repeats dropped, in the order given: each seed
    for "vio" (seeded drift), one run without a seed for every other odometry."""
    return [(o, s) for o in dict.fromkeys(odometries)
            for s in (dict.fromkeys(seeds) if o == "vio" else [None])]


def _saved(folder: Path, name: str, fingerprint: str, methods: MethodsConfig,
           figures: bool) -> RecordedOutcome | None:
    """The results an earlier run with the same fingerprint left in `folder`, or None. The
    job is written last, so its presence means the tables were written too; figures missing
    from a run without them are drawn."""
    if not (folder / f"{name}.json").is_file():
        return None
    try:
        job = JobResult.load(folder, name)
    except DataError as exc:
        log.warning("%s: results not reusable (%s); running again", name, exc)
        return None
    if job.info.get("fingerprint") != fingerprint:
        return None
    if job.metrics:  # the tables written before the job: one of them spoilt since, run again
        try:
            read_json(folder / "metrics.json", "metrics table")
        except DataError as exc:
            log.warning("%s: results not reusable (metrics.json: %s); running again", name, exc)
            return None
    summary = (summarize([job], estimate_names(methods), thresholds_of(methods))[name]
               if job.metrics else {})
    if figures and job.metrics and not (folder / "figures").is_dir():
        _draw(folder, job, methods)
    return RecordedOutcome(folder, job, summary, methods)


def load_mrclam_run(dataset: mrclam.MrclamData, config: MrclamConfig, odometry: str,
                    seed: int | None, duration: float | None = None, name: str | None = None,
                    pairs: list[tuple[int, int]] | None = None) -> RecordedRun:
    """`mrclam.load_run` with an evaluation config's settings (`duration`: None takes the
    config's)."""
    run, _ = mrclam.load_run(
        dataset, odometry, seed, config.kappa_of(odometry), config.nu, config.min_shared,
        config.vio.heading_rw_deg_per_sqrt_min, config.vio.scale_std, config.window,
        config.graph_drift, config.duration if duration is None else duration, name, pairs)
    return run


def run_mrclam(config: MrclamConfig, data: Path, output: Path, odometries: list[str],
               seeds: list[int], pairs: list[tuple[int, int]] | None = None,
               resume: bool = True, figures: bool = True,
               progress: Callable[[str, float], None] | None = None) -> list[MrclamOutcome]:
    """Every method over every directed pair of an MRCLAM data set, for each odometry and seed
    (raw odometry once: it has no seed), each into `<output>/<set>-<odometry>[-seed<s>]/`.

    A run whose results are already there, from the same settings and files, is reused when
    `resume`; a run that fails leaves the finished ones in place.

    Args:
        pairs: directed pairs of robot subjects (1-5) to align (None: all 20).
        progress: called with the run's name and the share done.
    Raises:
        DataError: the data set cannot be read (see `datasets.mrclam`).
    """
    methods = config.methods
    assert isinstance(methods, MethodsConfig)
    dataset = mrclam.read_dataset(data)
    todo = _odometry_runs(odometries, seeds)
    outcomes = []
    for odometry, seed in todo:
        name = mrclam_name(data, odometry, seed)
        folder = Path(output) / name
        fingerprint = _fingerprint(config, data, odometry, seed, pairs)
        saved = _saved(folder, name, fingerprint, methods, figures) if resume else None
        if saved is not None:
            outcomes.append(MrclamOutcome(odometry, seed, saved, True, dataset.skipped))
            continue
        run = load_mrclam_run(dataset, config, odometry, seed, name=name, pairs=pairs)
        landmarks = np.array(list(dataset.landmarks.values()))
        arrays = {"world_xy": landmarks,
                  "world_widths": np.full(len(landmarks), mrclam.LANDMARK_SIZE[0]),
                  "walls": np.zeros((0, 2, 2))}
        header = {"data": str(data), "odometry": odometry, "seed": seed,
                  "skipped": dataset.skipped}
        recorded = evaluate_recorded(
            run, methods, folder, figures, header,
            None if progress is None else (lambda share, n=name: progress(n, share)),
            arrays, {"fingerprint": fingerprint, "odometry": odometry, "seed": seed})
        outcomes.append(MrclamOutcome(odometry, seed, recorded, False, dataset.skipped))
    return outcomes


# -- recorded RGB-D sequences ------------------------------------------------------------------


@dataclass
class RgbdOutcome:
    """One odometry and seed (None for exact odometry) of an RGB-D evaluation.

    Attributes:
        recorded: the evaluation (or the one an earlier run saved, `reused`).
        frame_seconds: per robot, (k, 5) seconds of the front end's stages per frame
            (register, segment, filter, lift, track); None when the maps were reused.
        report: estimate stream -> `walk_report` of it.
    """

    odometry: str
    seed: int | None
    recorded: RecordedOutcome
    reused: bool
    frame_seconds: list[np.ndarray] | None
    report: dict[str, dict]


def rgbd_name(walks: list[rgbd_robots.Walk], odometry: str, seed: int | None) -> str:
    """The results' name of one set of walks, odometry and seed (exact odometry has none):
    `<sequences>[-<ranges>][-<rate>hz][-back]-<odometry>[-seed<s>]`.

    The ranges are left out when they are the default: the two halves of one sequence
    (`rgbd_robots.halves`), or each of several sequences whole. Else each robot's range
    [start, stop) is `<start>to<stop>` (an open end left empty, `all` for a whole sequence),
    joined by `+`. The rate is left out when every frame is walked (one per robot when they
    differ, `all` for every frame). `-back`: the robots walk there and back (`-back<r>+<r>`,
    robot indices, when only some do). E.g. `redkitchen-back-exact`,
    `redkitchen-0to500+400to900-5hz-vio-seed0`.
    """
    names = "+".join(dict.fromkeys(w.sequence.name for w in walks))
    ranges = [(w.start, w.stop) for w in walks]
    folders = [w.sequence.folder for w in walks]
    if len(set(folders)) == 1 and len(walks) == 2:
        default = ranges == rgbd_robots.halves(walks[0].sequence.frame_ids)
    else:
        default = len(set(folders)) == len(walks) and all(r == (None, None) for r in ranges)
    span = "" if default else "-" + "+".join(
        "all" if (a, b) == (None, None) else f"{_bound(a)}to{_bound(b)}" for a, b in ranges)
    rates = [w.rate for w in walks]
    if len(set(rates)) == 1:
        rates = rates[:1]
    rate = "" if rates == [None] else "-" + "+".join(
        "all" if r is None else f"{r:g}hz" for r in rates)
    walked_back = [r for r, w in enumerate(walks) if w.there_and_back]
    back = ("" if not walked_back else "-back" if len(walked_back) == len(walks)
            else "-back" + "+".join(map(str, walked_back)))
    return f"{names}{span}{rate}{back}-{odometry}" + ("" if seed is None else f"-seed{seed}")


def _bound(frame_id: int | None) -> str:
    return "" if frame_id is None else str(frame_id)


def walk_report(job: JobResult, streams: list[str], thresholds: Thresholds, tight: Thresholds,
                first: int) -> dict[str, dict]:
    """Per estimate stream, pooled over the job's pairs: false accepts at `thresholds` and at
    `tight` (shares of the estimates), availability from exchange `first` + 1 on (the share of
    those exchanges with an estimate: the first TCAFF can answer at is W + 1), the median
    translation [m] and heading [deg] errors, and the NEES figures of `metrics.Metrics` at
    `thresholds` (None for a stream without covariances or estimates)."""
    report = {}
    T_true = [se2_from_params(job.arrays["truth"][p]) for p in range(len(job.pairs))]
    for stream in streams:
        errors = np.concatenate([step_errors(T, job.arrays[f"est_{stream}"][p])
                                 for p, T in enumerate(T_true)])
        late = np.concatenate([~np.isnan(job.arrays[f"est_{stream}"][p][first:, 0])
                               for p in range(len(job.pairs))])
        got = errors[~np.isnan(errors[:, 0])]
        n = got.shape[0]

        def wrong(limit: Thresholds, got=got, n=n) -> float | None:
            return None if n == 0 else float(np.mean(~limit.correct(got)))

        covariance = job.arrays.get(f"cov_{stream}")
        nees = None
        if covariance is not None and n:
            nees = np.concatenate([step_nees(T, job.arrays[f"est_{stream}"][p], covariance[p])
                                   for p, T in enumerate(T_true)])
            nees = nees[~np.isnan(nees)]  # the estimate steps, in the order of `got`

        report[stream] = {
            "estimates": n, "false_accept": wrong(thresholds), "false_accept_tight": wrong(tight),
            "availability_from_first": float(late.mean()) if late.size else None,
            "first_exchange": first + 1,
            "median_translation_m": float(np.median(got[:, 0])) if n else None,
            "median_heading_deg": float(np.degrees(np.median(got[:, 1]))) if n else None,
            "nees_mean": None if nees is None else float(nees.mean()),
            "nees_under_95": None if nees is None else float(np.mean(nees < NEES_95)),
            "confident_false_accept": (None if nees is None
                                       else float(np.mean(~thresholds.correct(got)
                                                          & (nees > NEES_997))))}
    return report


#: bump when what a saved RGB-D run holds changes (2: paths of level bodies in a level world;
#: 3: each estimate's covariance)
RGBD_RESULTS_VERSION = 3


def _walk_fingerprint(config: RgbdConfig, walks: list[rgbd_robots.Walk], odometry: str,
                      seed: int | None) -> str:
    """Changes when anything that shapes the results changes: settings, frames, files and the
    front end's settings."""
    from tcaff_gtsam.mapping.lift import LiftParams
    from tcaff_gtsam.mapping.segment import DepthSegmenterParams, MaskFilter

    files = sorted({(str(w.sequence.folder), f.name, f.stat().st_size, f.stat().st_mtime_ns)
                    for w in walks for f in w.sequence.folder.glob("*.txt")})
    blob = json.dumps({
        "version": RGBD_RESULTS_VERSION,
        "config": config.model_dump(mode="json"), "odometry": odometry, "seed": seed,
        "walks": [[str(w.sequence.folder), w.sequence.frame_ids[w.positions].tolist(),
                   w.times.tolist()] for w in walks],
        "files": files, "front_end": repr((DepthSegmenterParams(), MaskFilter(), LiftParams(),
                                           _mapper_params(config)))}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _mapper_params(config: RgbdConfig):
    from tcaff_gtsam.mapping.mapper import MapperParams

    return MapperParams(nu=config.nu, kappa=config.kappa)


def run_rgbd(config: RgbdConfig, walks: list[rgbd_robots.Walk], output: Path,
             odometries: list[str], seeds: list[int], resume: bool = True,
             figures: bool = True, progress: Callable[[str, str, float], None] | None = None
             ) -> list[RgbdOutcome]:
    """Every method over every directed pair of robots walking RGB-D sequences, for each
    odometry and seed (exact odometry once), each into `<output>/<name>/` (`rgbd_name`).

    A run whose results are already there, from the same settings, frames and files, is
    reused when `resume`; a run that fails leaves the finished ones in place.

    Args:
        walks: one per robot (`rgbd_robots.walk`).
        progress: called with the run's name, the stage ("mapping <robot>" or "aligning")
            and the share done.
    Raises:
        DataError: a frame cannot be read (see `datasets.rgbd_sequence`).
    """
    methods = config.methods
    assert isinstance(methods, MethodsConfig)
    thresholds = thresholds_of(methods)
    tight = Thresholds(config.tight.translation, np.radians(config.tight.heading_deg))
    first = methods.tcaff_params(False, config.window).window
    todo = _odometry_runs(odometries, seeds)
    outcomes = []
    for odometry, seed in todo:
        name = rgbd_name(walks, odometry, seed)
        folder = Path(output) / name
        fingerprint = _walk_fingerprint(config, walks, odometry, seed)
        saved = _saved(folder, name, fingerprint, methods, figures) if resume else None
        if saved is not None:
            if figures:
                _draw_top_views(folder, saved.job)
            report = walk_report(saved.job, _scored(saved.methods), thresholds, tight, first)
            outcomes.append(RgbdOutcome(odometry, seed, saved, True, None, report))
            continue

        def mapping(robot: int, share: float, name=name) -> None:
            if progress is not None:
                progress(name, f"mapping {walks[robot].label}", share)

        run, seconds = rgbd_robots.load_run(
            walks, odometry, seed, config.kappa, _mapper_params(config), config.min_shared,
            config.match_radius, config.vio.heading_rw_deg_per_sqrt_min, config.vio.scale_std,
            config.window, config.graph_drift, name, mapping)
        header = {"data": sorted({str(w.sequence.folder) for w in walks}),
                  "robots": [w.label for w in walks], "odometry": odometry, "seed": seed,
                  "ms_per_frame": {w.label: 1e3 * float(np.median(s.sum(axis=1)))
                                   for w, s in zip(walks, seconds, strict=True)}}
        recorded = evaluate_recorded(
            run, methods, folder, figures, header,
            None if progress is None else (lambda share, n=name: progress(n, "aligning", share)),
            None, {"fingerprint": fingerprint, "odometry": odometry, "seed": seed})
        report = walk_report(recorded.job, _scored(recorded.methods), thresholds, tight, first)
        (folder / "walk_report.json").write_text(json.dumps(report, indent=2) + "\n")
        if figures:
            _draw_top_views(folder, recorded.job)
        outcomes.append(RgbdOutcome(odometry, seed, recorded, False, seconds, report))
    return outcomes


def _scored(methods: MethodsConfig) -> list[str]:
    """The causal estimate streams of a method set, without the truth itself."""
    return [m for m in estimate_names(methods)
            if describe(m).causal and m != "ground_truth"]


def _draw_top_views(folder: Path, job: JobResult) -> None:
    """Each pair's top view (`plots.top_view`) into folder/figures, unless it is there."""
    from . import plots

    for p, (i, j) in enumerate(job.pairs):
        path = folder / "figures" / f"top_view_{i}_{j}.png"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            plots.top_view(path, job, p)
