"""Parameter sweeps: a base study run at several parameter points, resumable, with a report.

Every job (one point, one scenario, one seed) is named by a content hash of its resolved
configuration (scenario, method set, seed; a window left to the TCAFF presets written out as
theirs) and written to `<output>/<sweep>/jobs/<hash>/` as soon as it finishes; `job.json`,
written last, marks it done. A rerun of the sweep skips the jobs already done, so a sweep
resumes after Ctrl-C or a crash, and a sweep given more values runs only the new jobs. Points
that resolve to the same configuration share their jobs. A job that raises leaves `failed.json`
(error and traceback) and is tried again by the next run, and so does a done job whose saved
files the report cannot read (edited or damaged since).

The report pools each point's jobs (every scenario, seed and directed pair) into one row per
point: sweep.csv (a row per point and method), sweep.json (also per scenario), and figures:
the trade-off of false accepts against availability with the default marked, and the response
of the metrics to each parameter.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import logging
import traceback
import zipfile
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.inputs import shown, write_whole

from .config import MethodsConfig, ScenarioConfig, StudyConfig, SweepConfig, apply_settings
from .datasets.text_tables import read_json
from .executor import Executor, JobSpec, Progress, job_runner
from .registry import estimate_names
from .results import JobResult, is_file_name, pool, summarize, thresholds_of, write_csv

__all__ = ["SweepOutcome", "SweepPlan", "SweepPoint", "job_hash", "jobs_to_run", "plan_sweep",
           "run_sweep"]

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class SweepPoint:
    """One parameter point.

    Attributes:
        settings: path -> value this point sets (empty for the default point).
        values: path -> the value in effect: the setting, or for the default point the base
            study's (a window left to the TCAFF presets: theirs; "per scenario" where the
            scenarios differ).
        default: the base study unchanged (or a point that resolves to it).
    """

    settings: dict[str, Any]
    values: dict[str, Any]
    default: bool

    @property
    def label(self) -> str:
        return ", ".join(f"{path.rsplit('.', 1)[-1]}={_text(v)}" for path, v in self.values.items())


@dataclass(frozen=True)
class SweepPlan:
    """The points and their jobs, before anything runs.

    Attributes:
        points: the default point first when the grid does not hold it, then the sweep's.
        jobs: content hash -> job, each configuration once.
        point_jobs: per point, the hashes of its jobs (scenarios x seeds).
    """

    points: list[SweepPoint]
    jobs: dict[str, JobSpec]
    point_jobs: list[list[str]]


@dataclass
class SweepOutcome:
    """What a sweep run did and its report.

    Attributes:
        folder: `<output>/<sweep name>/`.
        plan: the points and jobs.
        reused: jobs done by an earlier run and skipped.
        ran: jobs finished by this run.
        failed: jobs that raised in this run, and done jobs whose saved files could not be
            read (each runs again next time): hash, scenario, seed, error, traceback.
        interrupted: Ctrl-C stopped the run (the report covers the jobs done by then).
        rows: the report, one row per point and method (as in sweep.csv).
    """

    folder: Path
    plan: SweepPlan
    reused: int
    ran: int
    failed: list[dict]
    interrupted: bool
    rows: list[dict]


def _text(value: Any) -> str:
    return json.dumps(value) if isinstance(value, (dict, list)) else str(value)


def job_hash(spec: JobSpec) -> str:
    """16 hex digits of the SHA-256 of a job's resolved configuration (scenario, method set,
    seed), the same on every machine and Python run."""
    text = json.dumps({"scenario": spec.scenario.model_dump(mode="json"),
                       "methods": spec.methods.model_dump(mode="json"), "seed": spec.seed},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _base_value(specs: list[JobSpec], path: str) -> Any:
    """The value in effect at a parameter path in the base study's jobs ("per scenario" where
    scenarios differ)."""
    root, *keys = path.split(".")
    configs = [specs[0].methods] if root == "methods" else [spec.scenario for spec in specs]
    values = []
    for config in configs:
        node: Any = config.model_dump(mode="json")
        for key in keys:
            node = node.get(key) if isinstance(node, dict) else None
        values.append(node)
    return values[0] if all(v == values[0] for v in values) else "per scenario"


def _in_effect(scenario: ScenarioConfig, methods: MethodsConfig) -> ScenarioConfig:
    """`scenario` with the window in effect written out where it leaves it to the TCAFF
    presets (and they agree on it), so that a point setting that window is the same job as the
    base study, and the report shows it."""
    windows = {methods.tcaff_params(reference, None).window for reference in (False, True)}
    if scenario.window is not None or len(windows) != 1:
        return scenario
    return scenario.model_copy(update={"window": windows.pop()})


def plan_sweep(sweep: SweepConfig, study: StudyConfig, source: str = "sweep") -> SweepPlan:
    """Every point's configurations and jobs, checked before anything runs.

    Args:
        study: the resolved base study (see `config.load_sweep`).
        source: names the sweep in errors.
    Raises:
        ConfigError: a path the configs do not have or a value they refuse (naming the path
            and the value), or a `method` the method set does not produce.
    """
    methods: MethodsConfig = study.methods  # type: ignore[assignment]
    if sweep.method not in estimate_names(methods):
        raise ConfigError(f"{source}: method {sweep.method!r}: not an estimate of the method "
                          f"set {methods.name} ({', '.join(estimate_names(methods))})")
    parameters = sweep.parameters
    if sweep.grid is not None:
        settings = [dict(zip(parameters, combo, strict=True))
                    for combo in itertools.product(*(sweep.grid[p] for p in parameters))]
        # each value alone first, so that a bad value is named by itself
        for path, values in sweep.grid.items():
            for value in values:
                _resolve_point(study, {path: value}, source)
    else:
        settings = [dict(point) for point in sweep.points or []]
    base_specs = _resolve_point(study, {}, source)
    base = [job_hash(spec) for spec in base_specs]
    points: list[SweepPoint] = []
    point_jobs: list[list[str]] = []
    jobs: dict[str, JobSpec] = {}
    for point in settings:
        specs = _resolve_point(study, point, source)
        hashes = [job_hash(spec) for spec in specs]
        jobs.update(zip(hashes, specs, strict=True))
        points.append(SweepPoint(point, point, hashes == base))
        point_jobs.append(hashes)
    if not any(p.default for p in points):
        jobs = {**dict(zip(base, base_specs, strict=True)), **jobs}
        points.insert(0, SweepPoint({}, {p: _base_value(base_specs, p) for p in parameters},
                                    True))
        point_jobs.insert(0, base)
    return SweepPlan(points, jobs, point_jobs)


def _resolve_point(study: StudyConfig, settings: dict[str, Any], source: str) -> list[JobSpec]:
    """The jobs of one point: every scenario x seed, with the point's settings applied."""
    def part(root: str) -> dict[str, Any]:
        return {p: v for p, v in settings.items() if p.split(".", 1)[0] == root}

    methods, scenarios = study.methods, study.scenarios
    if part("methods"):
        methods = apply_settings(methods, part("methods"), source)  # type: ignore[arg-type]
    if part("scenario"):
        scenarios = [apply_settings(s, part("scenario"), source)  # type: ignore[arg-type]
                     for s in scenarios]
    scenarios = [_in_effect(s, methods) for s in scenarios]  # type: ignore[arg-type]
    return [JobSpec(s, methods, seed) for s in scenarios for seed in study.seeds]  # type: ignore[arg-type]


def _stem(folder: Path) -> str:
    """The stem of the job files in `folder`, from its job.json.

    Raises:
        DataError: job.json unreadable, or naming no file of the folder.
    """
    record = read_json(folder / "job.json", "job record")
    stem = record.get("stem") if isinstance(record, dict) else None
    if not (isinstance(stem, str) and is_file_name(stem)):
        raise DataError(f"{folder / 'job.json'}: stem must name the job's files, got "
                        f"{shown(stem)}")
    return stem


def _job_done(folder: Path) -> bool:
    """Whether the job in `folder` is done: its job.json names its files and its arrays
    are a whole archive. One that is not is run again now (its job.json removed)."""
    marker = folder / "job.json"
    if not marker.is_file():
        return False
    try:
        stem = _stem(folder)
        npz = folder / f"{stem}.npz"
        # is_file first: is_zipfile would open a FIFO, and wait for a writer
        if npz.is_file() and zipfile.is_zipfile(npz) and (folder / f"{stem}.json").is_file():
            return True
        reason = "its files are missing or cut short"
    except (DataError, OSError) as exc:
        reason = str(exc)
    log.warning("%s: unreadable (%s), run again", folder, reason)
    marker.unlink(missing_ok=True)
    return False


def jobs_to_run(plan: SweepPlan, folder: Path) -> list[str]:
    """The hashes of the plan's jobs not done yet in the sweep's `folder` (or whose saved
    files are unreadable)."""
    return [h for h in plan.jobs if not _job_done(folder / "jobs" / h)]


def run_sweep(sweep: SweepConfig, study: StudyConfig, executor: Executor | None = None,
              progress: Progress | None = None, figures: bool = True, source: str = "sweep",
              on_job_done: Callable[[JobResult], None] | None = None,
              plan: SweepPlan | None = None) -> SweepOutcome:
    """Run the jobs of a sweep not done yet, then write its report.

    Args:
        study: the resolved base study (see `config.load_sweep`).
        executor: where the jobs run; default `study.workers` local processes.
        progress: told of the jobs to run only (keys index the jobs run by this call).
        figures: draw the PNG figures.
        source: names the sweep in errors.
        on_job_done: called in this process with each finished job, after it is written.
        plan: `plan_sweep(sweep, study, source)` when the caller has made it already.
    Returns:
        The outcome; Ctrl-C stops the jobs, writes the report of what is done and sets
        `interrupted`. With no job left to run, `executor` is not started (no cluster, no
        connection to a scheduler).
    """
    plan = plan or plan_sweep(sweep, study, source)
    progress = progress or Progress()
    executor = executor or Executor(workers=study.workers)
    folder = Path(sweep.output) / sweep.name
    jobs_folder = folder / "jobs"
    todo = jobs_to_run(plan, folder)
    reused = len(plan.jobs) - len(todo)
    specs = [plan.jobs[h] for h in todo]
    failed: list[dict] = []
    ran = 0
    interrupted = False
    with job_runner(executor) if specs else nullcontext() as run:
        try:
            jobs_folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataError(f"output {str(folder)!r}: cannot make the sweep's folder "
                            f"({exc.strerror or exc})") from None
        write_whole(folder / "sweep.yaml", yaml.safe_dump(
            {"sweep": sweep.model_dump(mode="json", exclude={"study"}),
             "study": study.model_dump(mode="json")}, sort_keys=False))

        def done(key: int, job: JobResult) -> None:
            nonlocal ran
            where = jobs_folder / todo[key]
            job.save(where)
            (where / "failed.json").unlink(missing_ok=True)
            write_whole(where / "job.json", json.dumps(_job_record(todo[key], specs[key],
                                                                     job.stem), indent=1))
            ran += 1
            progress.finish(key, True)
            if on_job_done is not None:
                on_job_done(job)

        def fail(key: int, exc: BaseException) -> None:
            spec = specs[key]
            log.error("%s (%s) failed: %s", spec.label, todo[key], exc)
            failed.append(_failure(jobs_folder / todo[key], todo[key], spec, exc))
            progress.finish(key, False)

        point_of = {h: point for point, hashes in reversed(list(zip(
            plan.points, plan.point_jobs, strict=True))) for h in hashes}  # the first point
        for key, (digest, spec) in enumerate(zip(todo, specs, strict=True)):
            progress.start(key, f"{spec.label} ({point_of[digest].label})")
        try:
            if run is not None:
                run(specs, progress, done, fail)
        except KeyboardInterrupt:
            interrupted = True
            log.info("interrupted: reporting the %d finished jobs", reused + ran)
    rows = _report(folder, sweep, study, plan, interrupted, figures, failed)
    return SweepOutcome(folder, plan, reused, ran, failed, interrupted, rows)


def _job_record(digest: str, spec: JobSpec, stem: str) -> dict:
    return {"hash": digest, "stem": stem, "scenario": spec.scenario.name, "seed": spec.seed,
            "config": {"scenario": spec.scenario.model_dump(mode="json"),
                       "methods": spec.methods.model_dump(mode="json")}}


def _failure(where: Path, digest: str, spec: JobSpec, exc: BaseException) -> dict:
    """The record of a job that failed, also written to `where`/failed.json."""
    record = {"hash": digest, "scenario": spec.scenario.name, "seed": spec.seed,
              "error": f"{type(exc).__name__}: {exc}",
              "traceback": "".join(traceback.format_exception(exc))}
    where.mkdir(exist_ok=True)
    write_whole(where / "failed.json", json.dumps(record, indent=1))
    return record


def _load_job(folder: Path) -> JobResult | None:
    """A finished job of the sweep, or None when it is not done.

    Raises:
        DataError: its files are unreadable; its job.json is removed, so that it runs again
            next time.
    """
    if not (folder / "job.json").is_file():
        return None
    try:
        return JobResult.load(folder, _stem(folder))
    except DataError:
        (folder / "job.json").unlink(missing_ok=True)
        raise


def _failed_before(folder: Path, digest: str, spec: JobSpec) -> dict | None:
    """The failed.json of a job not done, or None when it has none; one that cannot be read
    (cut short by hand, say) still names the job."""
    path = folder / "failed.json"
    if not path.exists():
        return None
    try:
        record = read_json(path, "job failure record")
        if isinstance(record, dict):
            return record
        raise DataError(f"{path}: not a job failure record (a JSON object), got "
                        f"{shown(record)}")
    except DataError as exc:
        return {"hash": digest, "scenario": spec.scenario.name, "seed": spec.seed,
                "error": f"its failure record is unreadable: {exc}"}


def _report(folder: Path, sweep: SweepConfig, study: StudyConfig, plan: SweepPlan,
            interrupted: bool, figures: bool, failed: list[dict]) -> list[dict]:
    """Pool each point's finished jobs; write sweep.csv, sweep.json (with every job that
    failed and is not done since) and the figures. A finished job whose files cannot be read
    is reported as failed (added to `failed`) and runs again next time."""
    methods: MethodsConfig = study.methods  # type: ignore[assignment]
    names = estimate_names(methods)
    thresholds = thresholds_of(methods)
    # by hash, the jobs not done or whose files cannot be read: every planned job is some
    # point's, so this is every such job once the points are pooled. The jobs themselves are
    # not kept: a point's are let go once it is pooled
    missing: set[str] = set()

    def load(digest: str) -> JobResult | None:
        """The job when it is done and its files read, else None (an unreadable job logged
        and reported failed once, however many points share it)."""
        if digest in missing:
            return None
        where = folder / "jobs" / digest
        try:
            job = _load_job(where)
        except DataError as exc:
            log.error("%s: its saved files are unreadable, left out and run again next "
                      "time (%s)", where, exc)
            failed.append(_failure(where, digest, plan.jobs[digest], exc))
            job = None
        if job is None:
            missing.add(digest)
        return job

    rows: list[dict] = []
    points_json = []
    for index, (point, hashes) in enumerate(zip(plan.points, plan.point_jobs, strict=True)):
        jobs = [job for h in hashes if (job := load(h)) is not None]
        head = {"point": index, **{p: _text(v) for p, v in point.values.items()},
                "default": point.default, "jobs": len(hashes), "jobs_done": len(jobs)}
        pooled = pool(jobs, names, thresholds) if jobs else {m: {} for m in names}
        rows += [{**head, "method": method, **report} for method, report in pooled.items()]
        points_json.append({"point": index, "settings": point.settings, "values": point.values,
                            "default": point.default, "jobs": hashes,
                            "jobs_done": len(jobs), "pooled": pooled,
                            "by_scenario": summarize(jobs, names, thresholds) if jobs else {}})
    failures = [_failed_before(folder / "jobs" / h, h, spec) for h, spec in plan.jobs.items()
                if h in missing]
    failed_json = [record for record in failures if record is not None]
    (folder / "sweep.json").write_text(json.dumps({
        "sweep": sweep.name, "parameters": sweep.parameters, "method": sweep.method,
        "interrupted": interrupted, "failed": failed_json, "points": points_json}, indent=1))
    write_csv(folder / "sweep.csv", rows)
    if figures:
        from . import plots

        plots.draw_sweep(folder / "figures", plan.points,
                         [p["pooled"][sweep.method] for p in points_json], sweep.parameters,
                         plots.label(sweep.method))
    return rows
