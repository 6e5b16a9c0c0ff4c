"""The comparison study: schedules scenarios x seeds as jobs, on an `executor.Executor` (local
processes by default, or a Dask cluster).

Each job (`jobs.simulated_job`: one scenario, one seed) simulates the run, runs every
method over every directed pair and scores them. A finished job is written to
`<output>/<timestamp>/runs/` at once, with the trajectories of the table's methods in TUM files
under `trajectories/` (see `trajectories`), so an interrupted or partly failed study keeps
everything it finished. At the end the study writes
metrics.json, metrics.csv and the figures, and points `<output>/latest` at the folder.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from tcaff_gtsam.errors import DataError

from .config import MethodsConfig, StudyConfig, dump_study
from .executor import Executor, JobSpec, Progress, job_runner
from .registry import estimate_names, shown_streams
from .results import JobResult, summarize, summarize_mot, thresholds_of, write_tables
from .trajectories import write_tum

__all__ = ["Progress", "StudyOutcome", "run_study"]

log = logging.getLogger(__name__)


@dataclass
class StudyOutcome:
    """What a study produced, including when it stopped early."""

    folder: Path
    jobs: list[JobResult]
    failed: list[dict]
    interrupted: bool
    summary: dict[str, dict[str, dict]]
    mot_summary: dict[str, dict[str, dict]] = field(default_factory=dict)


def _new_folder(root: Path) -> Path:
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    root.mkdir(parents=True, exist_ok=True)
    for n in range(1, 1000):
        folder = root / (stamp if n == 1 else f"{stamp}-{n}")
        try:
            folder.mkdir()  # atomic: two studies started in the same second get two folders
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"{root}: no free results folder for {stamp}")


def _link_latest(root: Path, folder: Path) -> None:
    latest = root / "latest"
    try:
        if latest.is_symlink() or latest.exists():
            latest.unlink()
        latest.symlink_to(folder.name, target_is_directory=True)
    except OSError as exc:  # some file systems have no symbolic links; results are still there
        log.warning("could not link %s: %s", latest, exc)


def run_study(study: StudyConfig, progress: Progress | None = None,
              on_job_done: Callable[[JobResult], None] | None = None,
              figures: bool = True, executor: Executor | None = None) -> StudyOutcome:
    """Run a resolved study (see `config.resolve_study`) and write its results.

    Jobs run on `executor`, by default in `study.workers` local processes (in this process
    when 1). Ctrl-C stops the study: the jobs already finished are summarised and written, and
    `interrupted` is set.

    Args:
        executor: where the jobs run (see `executor.Executor`); the results are the same.
        on_job_done: called in this process with each finished job, after it is saved.
        figures: draw the PNG figures.
    """
    from . import plots

    progress = progress or Progress()
    executor = executor or Executor(workers=study.workers)
    methods: MethodsConfig = study.methods  # type: ignore[assignment]
    specs = [JobSpec(s, methods, seed) for s in study.scenarios for seed in study.seeds]
    jobs: list[JobResult] = []
    failed: list[dict] = []
    shown = shown_streams(methods)  # the table's; `tcaff export` writes the whole sweep
    interrupted = False
    root = Path(study.output)
    with job_runner(executor) as run:
        try:
            folder = _new_folder(root)
        except OSError as exc:
            raise DataError(f"output {str(root)!r}: cannot make a results folder in it "
                            f"({exc.strerror or exc})") from None
        (folder / "config.yaml").write_text(dump_study(study))

        def done(key: int, job: JobResult) -> None:
            job.save(folder / "runs")
            write_tum(folder, job, streams=shown)
            jobs.append(job)
            progress.finish(key, True)
            if on_job_done is not None:
                on_job_done(job)

        def fail(key: int, exc: BaseException) -> None:
            spec = specs[key]
            log.error("%s failed: %s", spec.label, exc)
            failed.append({"scenario": spec.scenario.name, "seed": spec.seed, "error": str(exc),
                           "traceback": "".join(traceback.format_exception(exc))})
            progress.finish(key, False)

        for key, spec in enumerate(specs):
            progress.start(key, spec.label)
        try:
            run(specs, progress, done, fail)
        except KeyboardInterrupt:
            interrupted = True  # the caller reports it; the finished jobs are written below
            log.info("interrupted: writing the %d finished jobs", len(jobs))
    order = {(spec.scenario.name, spec.seed): k for k, spec in enumerate(specs)}
    jobs.sort(key=lambda j: order[(j.name, j.seed)])
    names = estimate_names(methods)
    outcome = StudyOutcome(folder, jobs, failed, interrupted,
                           summarize(jobs, names, thresholds_of(methods)), summarize_mot(jobs))
    write_tables(folder, {"study": study.name, "interrupted": interrupted, "failed": failed},
                 jobs, outcome.summary, outcome.mot_summary)
    if figures and jobs:
        plots.draw_all(folder / "figures", jobs, outcome.summary, methods, outcome.mot_summary)
    if jobs:
        _link_latest(root, folder)
    return outcome
