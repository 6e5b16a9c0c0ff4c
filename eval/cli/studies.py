"""The `tcaff` commands that run studies of simulated scenarios: study, demo and sweep, with
their progress bars, where their jobs run (local processes or Dask), Ctrl-C handling and the
tracking (MOT) and sweep tables they print.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from .common import (
    _RERUN_HELP,
    _add_columns,
    _bars,
    _cell,
    _check_duration,
    _check_recording,
    _console,
    _keep_numbers_whole,
    _record,
    _refuse,
    _shipped,
    _since_start,
    _summary_table,
    _table,
    _writable_folder,
    app,
)

if TYPE_CHECKING:
    from rich.progress import Progress as RichProgress
    from rich.table import Table

    from ..config import ScenarioConfig, StudyConfig, SweepConfig
    from ..executor import Executor


def _study_bars(bars: RichProgress, n_jobs: int, title: str = "study"):
    """The progress of jobs as rich bars: one for them all, one per running job."""
    from rich.markup import escape

    from ..study import Progress

    # Defined here: the base class lives in the study module, which loads the whole stack.
    class _Bars(Progress):
        def __init__(self) -> None:
            self.total = bars.add_task(title, total=n_jobs)
            self.tasks: dict[int, int] = {}
            self.labels: dict[int, str] = {}
            self.shares: dict[int, float] = {}
            self.lost_workers: list[str] = []
            self.run_again: set[int] = set()

        def start(self, key: int, label: str) -> None:
            self.labels[key] = label

        def advance(self, key: int, share: float) -> None:
            if key not in self.tasks:
                self.tasks[key] = bars.add_task(self.labels[key], total=1.0)
            bars.update(self.tasks[key], completed=share)
            self.shares[key] = share
            bars.update(self.total, completed=sum(self.shares.values()))

        def finish(self, key: int, ok: bool) -> None:
            self.shares[key] = 1.0
            bars.update(self.total, completed=sum(self.shares.values()))
            if key in self.tasks:
                bars.remove_task(self.tasks[key])
            _console().print(f"{'done' if ok else '[red]failed[/]'}: "
                             f"{escape(self.labels[key])}")

        def lost(self, worker: str, keys: list[int]) -> None:
            self.lost_workers.append(worker)
            self.run_again.update(keys)
            held = ", ".join(escape(self.labels.get(k, f"job {k}")) for k in keys) or "no job"
            _console().print(f"[yellow]worker lost[/]: {escape(worker)} (held {held}); the "
                             f"cluster runs its jobs again", soft_wrap=True)

        def summary(self) -> str | None:
            """What the cluster lost, for the end of the output; None when nothing."""
            if not self.lost_workers:
                return None
            return (f"{len(self.lost_workers)} Dask worker(s) lost during the run; "
                    f"{len(self.run_again)} job(s) run again on other workers")

    return _Bars()


def _mot_table(mot_summary: dict) -> Table:
    from rich.markup import escape

    from .. import plots

    table = _table("Tracking people together: MOTA averaged over the robots, mean ± std over "
                   "seeds; errors as shares of the people to track, pooled over robots and "
                   "seeds")
    _add_columns(table, ("method", "MOTA", "false pos.", "misses", "switches"))

    def share(report: dict, key: str) -> str:
        value = _cell(report, f"{key}_share", 100, 1)
        return value if value == "-" else value + " %"

    for scenario, by_method in mot_summary.items():
        table.add_row(f"[bold]{escape(scenario)}[/]")
        for row, (method, r) in enumerate(by_method.items()):
            table.add_row("  " + escape(plots.label(method)),
                          f"{_cell(r, 'mota', digits=3)} ± {_cell(r, 'mota_std', digits=3)}",
                          share(r, "false_positives"), share(r, "misses"),
                          share(r, "switches"), end_section=row == len(by_method) - 1)
    return _keep_numbers_whole(table)


def _by_interrupt(exc: BaseException) -> bool:
    """Whether `exc` is a Ctrl-C, or was raised while handling one (an import cut short by
    Ctrl-C may end in an ImportError, as Open3D's does)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _run(study_config: StudyConfig, figures: bool, rerun: Path | None = None,
         executor: Executor | None = None) -> None:
    """Run a study and print its tables; Ctrl-C ends it with one line and exit status 130,
    the runs already finished written (see `run_study`)."""
    try:
        _run_study(study_config, figures, rerun, executor)
    except BaseException as exc:
        if not _by_interrupt(exc):
            raise
        _console(stderr=True).print("interrupted", soft_wrap=True)
        raise SystemExit(130) from None


def _run_study(study_config: StudyConfig, figures: bool, rerun: Path | None,
               executor: Executor | None) -> None:
    import time

    from rich.markup import escape

    from ..executor import Executor
    from ..study import run_study

    console, err_console = _console(), _console(stderr=True)
    executor = executor or Executor(workers=study_config.workers)
    n_jobs = len(study_config.scenarios) * len(study_config.seeds)
    console.print(f"study [bold]{study_config.name}[/]: {len(study_config.scenarios)} "
                  f"scenarios x {len(study_config.seeds)} seeds on {executor.describe()}")
    start = time.perf_counter()
    with _bars() as bars:
        progress = _study_bars(bars, n_jobs)
        outcome = run_study(study_config, progress, figures=figures, executor=executor)
    if outcome.summary:
        console.print(_summary_table(outcome.summary, study_config.methods))
        console.print("CLIPPER's whole sweep, every pair and seed: metrics.csv and "
                      "figures/clipper_sweep.png. APE and RPE (as evo computes them; RMSE, m) "
                      "of the other robot's path in the ego's frame; available: the overlap steps "
                      "with an estimate (with a correct one); the paths are in "
                      "trajectories/. ms is each method's own time per pair and step; the TCAFF "
                      "methods share the MNO-CLIPPER candidates on top.")
    if outcome.mot_summary:
        console.print(_mot_table(outcome.mot_summary))
        console.print("Per robot and seed: mot.csv; over time: figures/mot_<scenario>.png; "
                      "against CLIPPER's k: figures/mot_sweep.png.")
    if lost := progress.summary():
        console.print(lost)
    console.print(f"results: {outcome.folder} ({_since_start(start):.0f} s)")
    _record(rerun, outcome.jobs)
    if outcome.interrupted:
        err_console.print(f"interrupted: {len(outcome.jobs)} of {n_jobs} runs finished, kept "
                          f"in {escape(str(outcome.folder))}", soft_wrap=True)
        raise SystemExit(130)
    if outcome.failed:
        for fail in outcome.failed:
            err_console.print(f"[red]failed:[/] {fail['scenario']} seed {fail['seed']}: "
                              f"{escape(fail['error'])}", soft_wrap=True)
        raise SystemExit(1)


_STUDY_HELP = f"""\
Compare the methods over scenarios x seeds; write metrics.json, metrics.csv, figures.

Scenarios: {_shipped("scenarios")} (eval/configs/scenarios/). Methods: TCAFF, its reference
preset, TCAFF + iSAM2 (causal and smoothed), single-shot CLIPPER for each threshold k, ICP
from the true initial alignment, ground truth. In scenarios with people (mot) every robot
also tracks them with its own and its neighbours' detections, shared through each method's
alignment, and the tracking is scored with MOTA. Ctrl-C keeps the runs already finished.
"""


_SchedulerOption = Annotated[str | None, typer.Option(
    help="Run the jobs on the Dask cluster of this scheduler (tcp://host:8786); its workers "
         "need tcaff-gtsam installed (docs/sweeps.md#running-on-a-real-cluster).",
    rich_help_panel="Where jobs run")]
_LocalClusterOption = Annotated[int | None, typer.Option(
    help="Start a Dask cluster of N worker processes on this machine for the jobs.", min=1,
    rich_help_panel="Where jobs run")]


def _picked_scenarios(values: list[str] | None, near: Path | None = None
                      ) -> list[ScenarioConfig] | None:
    """The scenarios -s/--scenario picked (None: none given), loaded here so that a scenario
    given twice, by one name or by another that loads it again, is refused naming the option
    (the study's own check would blame its YAML file). A relative YAML path is taken from the
    folder `near` (the study file's) when the file is there, else from the current folder."""
    if not values:
        return None
    from ..config import _near, load_scenario

    first: dict[str, str] = {}  # scenario name -> the value that picked it
    scenarios = []
    for value in values:
        scenario = load_scenario(_near(value, near))
        if scenario.name in first:
            again = "" if first[scenario.name] == value else f" (first as {first[scenario.name]!r})"
            _refuse("-s/--scenario", value, f"picks scenario {scenario.name} a second time"
                    f"{again}; each scenario runs once")
        first[scenario.name] = value
        scenarios.append(scenario)
    return scenarios


def _executor(workers: int, scheduler: str | None, local_cluster: int | None):
    """Where the jobs run: local processes, or Dask by --scheduler or --local-cluster."""
    from tcaff_gtsam.errors import ConfigError

    from ..executor import Executor

    if scheduler is not None and local_cluster is not None:
        raise ConfigError(f"--scheduler {scheduler!r} and --local-cluster {local_cluster}: "
                          f"give one or the other")
    executor = Executor(workers=workers, scheduler=scheduler, local_cluster=local_cluster)
    if executor.on_dask:
        import logging

        try:
            import distributed  # noqa: F401  (its import sets its loggers' levels: first)
        except ImportError:
            pass  # the executor says how to install it
        # the scheduler's and nanny's INFO lines would bury the progress bars
        logging.getLogger("distributed").setLevel(logging.WARNING)
    return executor


@app.command(help=_STUDY_HELP)
def study(
    config: Annotated[str, typer.Argument(
        help=f"A study YAML file, or the name of a shipped one ({_shipped('studies')}).")
    ] = "paper",
    scenario: Annotated[list[str] | None, typer.Option(
        "--scenario", "-s", help="Run only this scenario (name or YAML path); repeatable.")
    ] = None,
    methods: Annotated[str | None, typer.Option(
        help=f"Method set: a YAML path or a shipped name ({_shipped('methods')}).")] = None,
    seeds: Annotated[int | None, typer.Option(
        help="Run seeds 0 .. N-1 instead of the config's.", min=1)] = None,
    workers: Annotated[int | None, typer.Option(
        help="Parallel processes, 1 to 64.", min=1, max=64)] = None,
    output: Annotated[Path | None, typer.Option(
        help="Folder for results/<timestamp>/ and the results/latest link.")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look.")] = None,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    rerun: Annotated[Path | None, typer.Option(help=_RERUN_HELP)] = None,
    scheduler: _SchedulerOption = None,
    local_cluster: _LocalClusterOption = None,
) -> None:
    _check_duration(duration)
    _check_recording(rerun)
    if output is not None:  # checked before the configs' imports: a mistake is told at once
        _writable_folder(output, "--output")
    from ..config import _resolve, load_study

    overrides = {"scenarios": _picked_scenarios(scenario, _resolve(config, "studies").parent),
                 "methods": methods,
                 "seeds": None if seeds is None else list(range(seeds)), "workers": workers,
                 "output": None if output is None else str(output)}
    study_config = load_study(config, {k: v for k, v in overrides.items() if v is not None})
    executor = _executor(study_config.workers, scheduler, local_cluster)
    _writable_folder(Path(study_config.output),
                     "--output" if output is not None else f"{config}: output")
    _run(_capped(study_config, duration), figures, rerun, executor)


def _capped(study_config: StudyConfig, duration: float | None) -> StudyConfig:
    """The study with every scenario's duration capped at `duration` seconds (None: as is)."""
    if duration is None:
        return study_config
    return study_config.model_copy(update={"scenarios": [
        s.model_copy(update={"duration": min(s.duration, duration)})
        for s in study_config.scenarios]})


@app.command()
def demo(
    output: Annotated[Path, typer.Option(help="Folder for the results.")] = Path("results"),
    workers: Annotated[int, typer.Option(help="Parallel processes, 1 to 64.", min=1, max=64)] = 2,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look.")] = None,
) -> None:
    """Every scenario with one seed, the costliest cut short (about a minute on 2 cores)."""
    _check_duration(duration)
    _writable_folder(output, "--output")
    from ..config import load_study

    study_config = load_study("demo", {"output": str(output), "workers": workers})
    _run(_capped(study_config, duration), True)


_SWEEP_HELP = f"""\
Run a base study at several parameter points and report the trade-off.

SWEEP.yaml names a base study (name, path or inline) and a grid of values by dotted path into
the method set (methods.tcaff.tau) or every scenario (scenario.window), every combination run
x scenarios x seeds; or a list of points. Shipped sweeps: {_shipped("sweeps")}.

Each job is saved under OUTPUT/<sweep>/jobs/<hash of its configuration>/ as it finishes; a
rerun skips the jobs already done (resume after Ctrl-C or a crash, or after adding values) and
retries the failed ones. Writes sweep.csv (a row per point and method, pooled over scenarios,
seeds and pairs), sweep.json (also per scenario, and every failure with its traceback) and
figures/tradeoff.png (false accepts against availability, the default marked) and
figures/response_<parameter>.png.
"""


@app.command(help=_SWEEP_HELP)
def sweep(
    config: Annotated[str, typer.Argument(
        metavar="SWEEP.yaml", help="A sweep YAML file, or the name of a shipped one.")],
    scenario: Annotated[list[str] | None, typer.Option(
        "--scenario", "-s", help="Run only this scenario (name or YAML path); repeatable.")
    ] = None,
    seeds: Annotated[int | None, typer.Option(
        help="Run seeds 0 .. N-1 instead of the sweep's (or its study's).", min=1)] = None,
    workers: Annotated[int | None, typer.Option(
        help="Local parallel processes, 1 to 64 (default: the study's).", min=1, max=64)
    ] = None,
    output: Annotated[Path | None, typer.Option(
        help="Folder for <sweep name>/ (default: the sweep's output).")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look; the jobs are other "
             "jobs than the full-length ones.")] = None,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    scheduler: _SchedulerOption = None,
    local_cluster: _LocalClusterOption = None,
) -> None:
    _check_duration(duration)
    if output is not None:
        _writable_folder(output, "--output")
    from ..config import _resolve, load_sweep, resolve_study

    sweep_config, study_config = load_sweep(config)
    if scenario:  # a relative YAML path beside the sweep file, as `study` takes it beside its own
        picked = _picked_scenarios(scenario, _resolve(config, "sweeps").parent)
        study_config = resolve_study(study_config.model_copy(update={"scenarios": picked}),
                                     strict=False)
    updates = {"seeds": None if seeds is None else list(range(seeds)), "workers": workers}
    study_config = _capped(study_config.model_copy(
        update={k: v for k, v in updates.items() if v is not None}), duration)
    if output is not None:
        sweep_config = sweep_config.model_copy(update={"output": str(output)})
    executor = _executor(study_config.workers, scheduler, local_cluster)
    _writable_folder(Path(sweep_config.output),
                     "--output" if output is not None else f"{config}: output")
    try:
        _run_sweep(sweep_config, study_config, executor, figures, Path(config).name)
    except BaseException as exc:
        if not _by_interrupt(exc):
            raise
        _console(stderr=True).print("interrupted", soft_wrap=True)
        raise SystemExit(130) from None


def _run_sweep(sweep_config: SweepConfig, study_config: StudyConfig, executor: Executor,
               figures: bool, source: str) -> None:
    import time

    from rich.markup import escape

    from ..sweep import jobs_to_run, plan_sweep, run_sweep

    console, err_console = _console(), _console(stderr=True)
    plan = plan_sweep(sweep_config, study_config, source)
    folder = Path(sweep_config.output) / sweep_config.name
    console.print(f"sweep [bold]{escape(sweep_config.name)}[/]: {len(plan.points)} points "
                  f"({', '.join(sweep_config.parameters)}) x {len(study_config.scenarios)} "
                  f"scenarios x {len(study_config.seeds)} seeds = {len(plan.jobs)} jobs on "
                  f"{executor.describe()}; results in {escape(str(folder))}", soft_wrap=True)
    start = time.perf_counter()
    with _bars() as bars:
        progress = _study_bars(bars, len(jobs_to_run(plan, folder)), "sweep")
        outcome = run_sweep(sweep_config, study_config, executor, progress, figures, source,
                            plan=plan)
    if outcome.reused:
        console.print(f"{outcome.reused} of {len(plan.jobs)} jobs done by an earlier run: "
                      f"reused")
    if lost := progress.summary():
        console.print(lost)
    console.print(_sweep_table(outcome.rows, sweep_config))
    console.print(f"results: {outcome.folder} ({_since_start(start):.0f} s); "
                  f"sweep.csv has every method, figures/ the trade-off and responses")
    if outcome.interrupted:
        done = outcome.reused + outcome.ran
        err_console.print(f"interrupted: {done} of {len(plan.jobs)} jobs done, kept in "
                          f"{escape(str(outcome.folder))}; run the sweep again to finish it",
                          soft_wrap=True)
        raise SystemExit(130)
    if outcome.failed:
        for fail in outcome.failed:
            err_console.print(f"[red]failed:[/] {fail['scenario']} seed {fail['seed']} "
                              f"(job {fail['hash']}): {escape(fail['error'])}", soft_wrap=True)
        err_console.print("tracebacks: sweep.json and jobs/<job>/failed.json; a rerun tries "
                          "the failed jobs again", soft_wrap=True)
        raise SystemExit(1)


def _sweep_table(rows: list[dict], sweep_config: SweepConfig) -> Table:
    """One row per point: the shown method's metrics pooled over scenarios, seeds, pairs."""
    from rich.markup import escape

    from .. import plots

    table = _table(f"{plots.label(sweep_config.method)} at each point, pooled over scenarios, "
                   f"seeds and directed pairs (* the default)")
    names = [p.rsplit(".", 1)[-1] for p in sweep_config.parameters]
    _add_columns(table, ("#", *names, "jobs", "false acc.", "available", "translation [m]",
                         "heading [deg]", "1st correct [s]"), labelled=False)
    for r in rows:
        if r["method"] != sweep_config.method:
            continue
        table.add_row(f"{r['point']}{'*' if r['default'] else ''}",
                      *(escape(str(r[p])) for p in sweep_config.parameters),
                      f"{r['jobs_done']}/{r['jobs']}", _cell(r, "false_accept", 100, 1) + " %",
                      _cell(r, "availability", 100, 0) + " %",
                      _cell(r, "translation_error_m_mean"), _cell(r, "heading_error_deg_mean"),
                      _cell(r, "time_to_first_correct_s", digits=0))
    return _keep_numbers_whole(table, labelled=False)
