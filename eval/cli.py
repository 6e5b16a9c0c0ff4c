"""The `tcaff` command line.

Building the app loads typer and the aligner's parameter defaults (numpy) only; every command
imports what it uses (gtsam, Open3D, numba, matplotlib, the study), so `tcaff --help` is instant.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

# The align-maps defaults are the library's own; params needs numpy only.
from tcaff_gtsam.params import FrameAlignerParams

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress as RichProgress
    from rich.table import Table

    from tcaff_gtsam.frame_aligner import AlignmentMeasurement

    from .config import MethodsConfig, StudyConfig, SweepConfig
    from .executor import Executor

_ALIGNER = FrameAlignerParams()
# The same folder as config.CONFIG_DIR, found without importing config (pydantic).
_CONFIG_DIR = Path(__file__).parent / "configs"


def _shipped(kind: str) -> str:
    """The shipped configs of one kind (a folder of `configs/`), as a comma-separated list."""
    names = sorted(path.stem for path in (_CONFIG_DIR / kind).glob("*.yaml"))
    return ", ".join(names) if names else "none shipped"


app = typer.Typer(
    help="Align the coordinate frames of robots from their object maps (TCAFF).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

_consoles: dict[bool, Console] = {}


def _console(stderr: bool = False) -> Console:
    """The rich console of stdout (or stderr), made on first use."""
    if stderr not in _consoles:
        from rich.console import Console

        console = Console(stderr=stderr)
        if not stderr and not console.is_terminal:
            # piped output and CI logs: room for the widest table (the study's, 118 columns)
            # with a few more digits in its timings on a busy machine, labels unwrapped
            console.width = 140
        _consoles[stderr] = console
    return _consoles[stderr]


def _table(title: str) -> Table:
    """A table of numbers: first column labels, the others values, see `_keep_numbers_whole`."""
    from rich import box
    from rich.table import Table

    # Compact padding: the study table then fits 120 columns without wrapping a label.
    return Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, collapse_padding=True,
                 pad_edge=False)


def _add_columns(table: Table, names: tuple[str, ...], labelled: bool = True) -> None:
    """Columns named `names`; with `labelled` the first holds labels (left-aligned)."""
    from rich.markup import escape

    for index, name in enumerate(names):
        table.add_column(escape(name), justify="left" if labelled and index == 0 else "right",
                         overflow="fold")


def _keep_numbers_whole(table: Table, labelled: bool = True) -> Table:
    """Give every value column (all but the first when `labelled`) the width of its longest word.

    On a narrow terminal rich squeezes columns and folds or cuts what no longer fits; with these
    minimum widths it can still wrap a cell at a space ("0.12 ±" over "0.03") and fold headers
    and labels, but never breaks a number. Call once all rows are added.
    """
    from rich.cells import cell_len
    from rich.text import Text

    for column in table.columns[1 if labelled else 0:]:
        words = [word for cell in column.cells if isinstance(cell, str)
                 for word in Text.from_markup(cell).plain.split()]
        column.min_width = max(map(cell_len, words), default=None)
    return table


def _candidates_table(title: str, candidates: list[AlignmentMeasurement]) -> Table:
    import math

    import numpy as np

    table = _table(title)
    _add_columns(table, ("#", "x [m]", "y [m]", "theta [deg]", "assoc", "score", "rmse [m]",
                         "sd [m, deg]"), labelled=False)
    for rank, meas in enumerate(candidates, start=1):
        x, y, theta = meas.z
        sd = np.sqrt(np.diag(meas.R))
        table.add_row(str(rank), f"{x:.2f}", f"{y:.2f}", f"{math.degrees(theta):.1f}",
                      str(len(meas.associations)), f"{meas.score:.2f}", f"{meas.rmse:.3f}",
                      f"{max(sd[0], sd[1]):.2f}, {math.degrees(sd[2]):.1f}")
    return _keep_numbers_whole(table, labelled=False)


def _refuse(option: str, value: object, rule: str, error: type | None = None) -> None:
    """Raise a one-line `ConfigError` (or `error`) naming a command-line option and its value."""
    from tcaff_gtsam.errors import ConfigError

    raise (error or ConfigError)(f"{option} {value!r}: {rule}")


def _check_seeds(seeds: list[int] | None) -> list[int]:
    """The --seed values given (default [0]); refused unless each is an int >= 0."""
    for seed in seeds or []:
        if seed < 0:
            _refuse("--seed", seed, "must be an int >= 0")
    return list(seeds or [0])


def _check_duration(duration: float | None) -> None:
    """`--duration`: None, or a finite number of seconds >= 1 (inf, NaN and <= 0 refused)."""
    if duration is not None and not (math.isfinite(duration) and duration >= 1):
        _refuse("--duration", duration, "must be a finite number of seconds >= 1")


def _writable_folder(path: Path, option: str) -> None:
    """Check, before any work starts, that `path` is a folder results can be written to,
    making it when missing; a `DataError` naming `option` otherwise."""
    import tempfile

    from tcaff_gtsam.errors import DataError

    if path.exists() and not path.is_dir():
        _refuse(option, str(path), "exists and is not a folder", DataError)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        _refuse(option, str(path), f"not a writable folder ({exc.strerror or exc})", DataError)


_RERUN_HELP = ("Also write a Rerun recording of the runs to this .rrd file (needs the extra viz); "
               "open it with `rerun FILE.rrd`.")


def _check_recording(path: Path | None) -> None:
    """Before any work: rerun-sdk is there and `path` can become a recording file."""
    if path is None:
        return
    from .recording import check_rerun

    check_rerun()
    if path.is_dir():
        _refuse("--rerun", str(path), "is a folder, not a file")
    _writable_folder(path.parent, "--rerun")


def _record(path: Path | None, jobs: list) -> None:
    """The runs into a Rerun recording, when asked for and there are runs."""
    if path is None or not jobs:
        return
    from .recording import record

    record(path, jobs)
    _console().print(f"recording: {path} (open it with: rerun {path})", soft_wrap=True)


#: FrameAlignerParams fields (ClipperParams' seed) -> the align-maps option that sets them
_ALIGNER_OPTIONS = {"kappa": "--kappa", "dim": "--dim", "n_solutions": "--solutions",
                    "min_associations": "--min-associations", "covariance": "--covariance",
                    "seed": "--seed"}


def _aligner_params(kappa: float, dim: int, solutions: int, min_associations: int,
                    covariance: str, seed: int) -> FrameAlignerParams:
    from dataclasses import replace

    from tcaff_gtsam.params import ParameterError

    try:
        return replace(_ALIGNER, kappa=kappa, dim=dim, n_solutions=solutions,
                       min_associations=min_associations, covariance=covariance,
                       clipper=replace(_ALIGNER.clipper, seed=seed))
    except ParameterError as exc:
        if exc.name not in _ALIGNER_OPTIONS:
            raise
        _refuse(_ALIGNER_OPTIONS[exc.name], exc.value, exc.rule)


@app.command("align-maps")
def align_maps(
    ego: Annotated[Path, typer.Argument(help="Ego robot's map (.npz from ObjectMap.save).")],
    other: Annotated[Path, typer.Argument(help="Other robot's map (.npz).")],
    now: Annotated[float | None, typer.Option(
        help="Current time (s); default: the latest last_seen in either map.")] = None,
    kappa: Annotated[float, typer.Option(
        help="Use objects seen less than kappa seconds ago.")] = _ALIGNER.kappa,
    dim: Annotated[int, typer.Option(help="Match 2D (x, y) or 3D centroids.")] = _ALIGNER.dim,
    solutions: Annotated[int, typer.Option(
        help="MNO-CLIPPER solutions N.")] = _ALIGNER.n_solutions,
    min_associations: Annotated[int, typer.Option(
        help="Fewest associations kept.")] = _ALIGNER.min_associations,
    covariance: Annotated[str, typer.Option(
        help="'constant' (the original's R) or 'residual' (from the registration).")
    ] = _ALIGNER.covariance,
    seed: Annotated[int, typer.Option(
        help="Seed of CLIPPER's start vector.")] = _ALIGNER.clipper.seed,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")
                       ] = False,
) -> None:
    """Print the candidate alignments T_oi_oj (other's odometry frame into the ego's)."""
    import json

    import numpy as np

    from tcaff_gtsam.frame_aligner import FrameAligner
    from tcaff_gtsam.object_map import ObjectMap

    if now is not None and not math.isfinite(now):
        _refuse("--now", now, "must be a finite number of seconds")
    params = _aligner_params(kappa, dim, solutions, min_associations, covariance, seed)
    ego_map, other_map = ObjectMap.load(ego), ObjectMap.load(other)
    if now is None:
        stamps = np.r_[ego_map.last_seen, other_map.last_seen]
        now = float(stamps.max()) if stamps.size else 0.0
    aligner = FrameAligner(params)
    candidates = aligner.measurements(ego_map, other_map, now)
    if as_json:
        print(json.dumps([{"x": m.z[0], "y": m.z[1], "theta": m.z[2], "R": m.R.tolist(),
                           "associations": m.associations.tolist(), "score": m.score,
                           "rmse": m.rmse} for m in candidates], indent=2))
        return
    console = _console()
    if not candidates:
        console.print(f"no candidate alignment ({len(ego_map)} and {len(other_map)} objects, "
                      f"now = {now:.2f} s)")
        return
    console.print(_candidates_table(f"{len(candidates)} candidate alignments of {other.name} "
                                    f"into {ego.name}", candidates))


@app.command("make-maps")
def make_maps(
    out_dir: Annotated[Path, typer.Argument(help="Folder for ego.npz, other.npz, truth.json.")],
    objects: Annotated[int, typer.Option(help="Objects per map.")] = 40,
    overlap: Annotated[float, typer.Option(help="Share of objects both maps hold.")] = 0.6,
    noise: Annotated[float, typer.Option(help="Centroid noise per axis (m).")] = 0.1,
    clutter: Annotated[int, typer.Option(help="Spurious objects per map.")] = 10,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Write two simulated overlapping maps with a known alignment, for trying align-maps."""
    import json

    import numpy as np

    from tcaff_gtsam.geometry import se2_to_params

    from .sim.maps import overlapping_maps

    for option, count in (("--objects", objects), ("--clutter", clutter), ("--seed", seed)):
        if count < 0:
            _refuse(option, count, "must be an int >= 0")
    if not (math.isfinite(overlap) and 0 <= overlap <= 1):
        _refuse("--overlap", overlap, "must be a share in [0, 1]")
    if not (math.isfinite(noise) and noise >= 0):
        _refuse("--noise", noise, "must be a finite number >= 0 metres")
    _writable_folder(out_dir, "OUT_DIR")
    pair = overlapping_maps(np.random.default_rng(seed), objects, overlap, noise,
                            clutter=clutter)
    pair.ego.save(out_dir / "ego.npz")
    pair.other.save(out_dir / "other.npz")
    x, y, theta = se2_to_params(pair.T_oi_oj)
    (out_dir / "truth.json").write_text(json.dumps(
        {"T_oi_oj": {"x": x, "y": y, "theta": theta}, "now": pair.now}, indent=2))
    _console().print(f"wrote {out_dir}/ego.npz, other.npz and truth.json "
                     f"(true x={x:.2f} m, y={y:.2f} m, theta={math.degrees(theta):.1f} deg)")


@app.command("advise-kappa")
def advise_kappa(
    heading_rw: Annotated[float, typer.Option(
        help="Heading random walk of the odometry, deg per sqrt(minute) (VIO: about 1).")
    ] = 1.0,
    scale_std: Annotated[float, typer.Option(
        help="Std of its distance scale error (0.01: 1 % of the distance moved).")] = 0.01,
    speed: Annotated[float, typer.Option(help="The robot's speed, m/s.")] = 0.5,
    turn: Annotated[float, typer.Option(
        help="How much the robot turns: its heading's random walk, deg per sqrt(s).")] = 20.0,
    landmark_range: Annotated[float, typer.Option(
        "--range", help="How far ahead objects are seen, m.")] = 2.0,
    epsilon: Annotated[float, typer.Option(
        help="CLIPPER's epsilon, m: the maps must stay consistent within it."
    )] = _ALIGNER.clipper.epsilon,
    minutes: Annotated[float, typer.Option(help="Length of each simulated drive.")] = 20.0,
    seeds: Annotated[int, typer.Option(help="Drives (and drifts) to simulate.")] = 3,
    csv: Annotated[Path | None, typer.Option(
        help="Also write the table (span, RMS per seed, worst) to this CSV file.")] = None,
) -> None:
    """How many seconds of sightings a map may hold (kappa), from the odometry's drift.

    Simulates drives of a robot at --speed with the VIO-like drift given (heading random walk,
    distance scale error) and prints how far the odometry misplaces, in the robot's current
    frame, an object seen --range m ahead a span ago (root mean square over the drive), for
    spans of 5 s to 5 min; the advice is the longest span whose misplacement stays within
    epsilon / 2 for every seed (two objects of one map then keep their distance within
    epsilon). The MRCLAM config's spans follow the same rule (docs/datasets.md). In Python:
    tcaff_gtsam.span.misplacement on your own truth and odometry, then advise_kappa.
    """
    import numpy as np

    from tcaff_gtsam.span import SPANS, misplacement, random_drive, vio_like_odometry
    from tcaff_gtsam.span import advise_kappa as advise

    for option, value in (("--heading-rw", heading_rw), ("--scale-std", scale_std),
                          ("--speed", speed), ("--turn", turn), ("--range", landmark_range)):
        if not (math.isfinite(value) and value >= 0):
            _refuse(option, value, "must be a finite number >= 0")
    if not (math.isfinite(epsilon) and epsilon > 0):
        _refuse("--epsilon", epsilon, "must be a finite number > 0")
    if not (math.isfinite(minutes) and SPANS[-1] / 60.0 <= minutes <= 600.0):
        _refuse("--minutes", minutes, f"must be between {SPANS[-1] / 60.0:g} (the longest "
                "span tried) and 600")
    if seeds < 1:
        _refuse("--seeds", seeds, "must be an int >= 1")
    if csv is not None:
        _writable_folder(csv.parent, "--csv's folder")
    rms = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        times, T_true = random_drive(rng, 60.0 * minutes, speed, turn)
        T_odom = vio_like_odometry(rng, times, T_true, heading_rw, scale_std)
        rms.append(misplacement(times, T_true, T_odom, SPANS, landmark_range))
    worst = np.max(rms, axis=0)  # NaN stays NaN: a span longer than the drive
    advice = advise(worst, SPANS, epsilon)
    table = _table(f"RMS misplacement (m) of an object seen a span ago, {seeds} drives of "
                   f"{minutes:g} min at {speed:g} m/s; bound epsilon / 2 = {advice.bound:.3f} m")
    _add_columns(table, ("span [s]", *(f"seed {s}" for s in range(seeds)), "worst"))
    for k, span in enumerate(SPANS):
        table.add_row(f"{span:g}", *(f"{r[k]:.3f}" for r in rms), f"{worst[k]:.3f}")
    console = _console()
    console.print(_keep_numbers_whole(table))
    if csv is not None:
        header = "span_s," + ",".join(f"rms_seed{s}_m" for s in range(seeds)) + ",worst_m"
        np.savetxt(csv, np.column_stack([SPANS, *rms, worst]), delimiter=",", header=header,
                   comments="", fmt="%.6g")
    if advice.kappa is None:
        console.print(f"kappa: no span keeps the maps within epsilon / 2 ({worst[0]:.3f} m "
                      f"at {SPANS[0]:g} s already): the maps disagree with themselves; better "
                      f"odometry or a wider epsilon is needed")
    else:
        console.print(f"kappa: {advice.kappa:g} s (FrameAlignerParams(kappa=...) and "
                      f"MapperParams(kappa=...))")


def _bars() -> RichProgress:
    """Progress bars that vanish when done, elapsed time on the right."""
    from rich.progress import (
        BarColumn,
        SpinnerColumn,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
    )
    from rich.progress import Progress as RichProgress

    return RichProgress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                        TaskProgressColumn(), TimeElapsedColumn(), console=_console(),
                        transient=True)


def _study_bars(bars: RichProgress, n_jobs: int, title: str = "study"):
    """The progress of jobs as rich bars: one for them all, one per running job."""
    from rich.markup import escape

    from .study import Progress

    # Defined here: the base class lives in the study module, which loads the whole stack.
    class _Bars(Progress):
        def __init__(self) -> None:
            self.total = bars.add_task(title, total=n_jobs)
            self.tasks: dict[int, int] = {}
            self.labels: dict[int, str] = {}
            self.shares: dict[int, float] = {}

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

    return _Bars()


def _cell(report: dict, key: str, scale: float = 1.0, digits: int = 2) -> str:
    value = report.get(key)
    return "-" if value is None else f"{scale * value:.{digits}f}"


def _summary_table(summary: dict, methods: MethodsConfig) -> Table:
    """The study table of the methods a method set shows, labelled as in the figures."""
    from .registry import describe, shown_streams

    return _pooled_table(summary, {m: describe(m).label for m in shown_streams(methods)})


def _pooled_table(summary: dict, labels: dict[str, str]) -> Table:
    """summary: scenario -> method -> report; labels: method -> printed name, in table order."""
    from rich.markup import escape

    table = _table("Frame alignment, pooled over directed pairs and seeds (mean ± std)")
    _add_columns(table, ("method", "translation [m]", "heading [deg]", "available",
                         "false acc.", "1st correct [s]", "APE, RPE [m]", "ms"))
    for scenario, by_method in summary.items():
        table.add_row(f"[bold]{escape(scenario)}[/]")
        for row, (method, label) in enumerate(labels.items()):
            r = by_method[method]
            table.add_row(
                "  " + escape(label),
                f"{_cell(r, 'translation_error_m_mean')} ± {_cell(r, 'translation_error_m_std')}",
                f"{_cell(r, 'heading_error_deg_mean')} ± {_cell(r, 'heading_error_deg_std')}",
                f"{_cell(r, 'availability', 100, 0)} "
                f"({_cell(r, 'correct_availability', 100, 0)}) %",
                _cell(r, "false_accept", 100, 1) + " %",
                _cell(r, "time_to_first_correct_s", digits=0),
                f"{_cell(r, 'ape_m')}, {_cell(r, 'rpe_m')}",
                _cell(r, "ms_per_pair_step", digits=2),
                end_section=row == len(labels) - 1)
    return _keep_numbers_whole(table)


def _mot_table(mot_summary: dict) -> Table:
    from rich.markup import escape

    from . import plots

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

    from .executor import Executor
    from .study import run_study

    console, err_console = _console(), _console(stderr=True)
    executor = executor or Executor(workers=study_config.workers)
    n_jobs = len(study_config.scenarios) * len(study_config.seeds)
    console.print(f"study [bold]{study_config.name}[/]: {len(study_config.scenarios)} "
                  f"scenarios x {len(study_config.seeds)} seeds on {executor.describe()}")
    start = time.perf_counter()
    with _bars() as bars:
        outcome = run_study(study_config, _study_bars(bars, n_jobs), figures=figures,
                            executor=executor)
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
    console.print(f"results: {outcome.folder} ({time.perf_counter() - start:.0f} s)")
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
         "need tcaff-gtsam installed (see the README).", rich_help_panel="Where jobs run")]
_LocalClusterOption = Annotated[int | None, typer.Option(
    help="Start a Dask cluster of N worker processes on this machine for the jobs.", min=1,
    rich_help_panel="Where jobs run")]


def _executor(workers: int, scheduler: str | None, local_cluster: int | None):
    """Where the jobs run: local processes, or Dask by --scheduler or --local-cluster."""
    from tcaff_gtsam.errors import ConfigError

    from .executor import Executor

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
    workers: Annotated[int | None, typer.Option(help="Parallel processes.", min=1)] = None,
    output: Annotated[Path | None, typer.Option(
        help="Folder for results/<timestamp>/ and the results/latest link.")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look.")] = None,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    rerun: Annotated[Path | None, typer.Option(help=_RERUN_HELP)] = None,
    scheduler: _SchedulerOption = None,
    local_cluster: _LocalClusterOption = None,
) -> None:
    from .config import load_study

    _check_duration(duration)
    _check_recording(rerun)
    overrides = {"scenarios": scenario or None, "methods": methods,
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
    workers: Annotated[int, typer.Option(help="Parallel processes.", min=1)] = 2,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look.")] = None,
) -> None:
    """The study on every scenario with one seed (about a minute): table, metrics, figures."""
    from .config import load_study

    _check_duration(duration)
    study_config = load_study("demo", {"output": str(output), "workers": workers})
    _writable_folder(output, "--output")
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
        help="Local parallel processes (default: the study's).", min=1)] = None,
    output: Annotated[Path | None, typer.Option(
        help="Folder for <sweep name>/ (default: the sweep's output).")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Cap every scenario's duration (seconds), for a quick look; the jobs are other "
             "jobs than the full-length ones.")] = None,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    scheduler: _SchedulerOption = None,
    local_cluster: _LocalClusterOption = None,
) -> None:
    from .config import load_sweep, resolve_study

    _check_duration(duration)
    sweep_config, study_config = load_sweep(config)
    if scenario:
        study_config = resolve_study(study_config.model_copy(update={"scenarios": scenario}))
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

    from .sweep import jobs_to_run, plan_sweep, run_sweep

    console, err_console = _console(), _console(stderr=True)
    plan = plan_sweep(sweep_config, study_config, source)
    folder = Path(sweep_config.output) / sweep_config.name
    console.print(f"sweep [bold]{escape(sweep_config.name)}[/]: {len(plan.points)} points "
                  f"({', '.join(sweep_config.parameters)}) x {len(study_config.scenarios)} "
                  f"scenarios x {len(study_config.seeds)} seeds = {len(plan.jobs)} jobs on "
                  f"{executor.describe()}; results in {escape(str(folder))}", soft_wrap=True)
    start = time.perf_counter()
    with _bars() as bars:
        outcome = run_sweep(sweep_config, study_config, executor,
                            _study_bars(bars, len(jobs_to_run(plan, folder)), "sweep"),
                            figures, source, plan=plan)
    if outcome.reused:
        console.print(f"{outcome.reused} of {len(plan.jobs)} jobs done by an earlier run: "
                      f"reused")
    console.print(_sweep_table(outcome.rows, sweep_config))
    console.print(f"results: {outcome.folder} ({time.perf_counter() - start:.0f} s); "
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

    from . import plots

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


def _kimera_bars(bars: RichProgress):
    from rich.markup import escape

    from .recorded import KimeraProgress

    # Defined here: the base class lives in the recorded module, which loads the whole stack.
    class _KimeraBars(KimeraProgress):
        def __init__(self) -> None:
            self.tasks: dict[str, int] = {}

        def robot(self, robot: str, reused: bool) -> None:
            if reused:
                _console().print(f"{escape(robot)}: maps of an earlier run with the same "
                                 f"settings reused")
            else:
                self.tasks[robot] = bars.add_task(f"mapping {robot}", total=1.0)

        def mapping(self, robot: str, share: float) -> None:
            bars.update(self.tasks[robot], completed=share)

        def aligning(self, share: float) -> None:
            if "align" not in self.tasks:
                self.tasks["align"] = bars.add_task("aligning every pair", total=1.0)
            bars.update(self.tasks["align"], completed=share)

    return _KimeraBars()


@app.command("kimera-multi")
def kimera_multi(
    data: Annotated[Path, typer.Option(
        help="Folder with every robot's bags and <robot>_gt_odom.csv files.")],
    config: Annotated[str, typer.Option(
        help=f"A Kimera-Multi test YAML, or a shipped one: {_shipped('kimera_multi')}.")
    ] = "same_direction",
    output: Annotated[Path, typer.Option(
        help="Results go to OUTPUT/<test name>/.")] = Path("results/kimera_multi"),
    resume: Annotated[bool, typer.Option(
        help="Reuse robots' maps saved by an earlier run with the same settings and bags.")
    ] = True,
    duration: Annotated[float | None, typer.Option(
        help="Use only this many seconds of data, for a quick look.")] = None,
    methods: Annotated[str | None, typer.Option(
        help=f"Method set: a YAML path or a shipped name ({_shipped('methods')}).")] = None,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    rerun: Annotated[Path | None, typer.Option(help=_RERUN_HELP)] = None,
) -> None:
    """Offline evaluation on Kimera-Multi rosbags: map, align every pair, score.

    Maps each robot's RGB-D frames (depth segmenter, Open3D lifting, tracker), exchanges maps at
    1 Hz, aligns every directed pair with TCAFF, TCAFF + iSAM2 and the baselines, and scores
    them against the ground-truth CSVs.

    Prints the paper's table (mean +- std translation and heading error per method) and each
    robot's mapping throughput; writes maps/, metrics.json, metrics.csv, table.md and
    figures/ under OUTPUT/<test>/. Without ground truth the alignments are still written.
    """
    import time

    from rich.markup import escape

    from tcaff_gtsam.errors import TcaffError

    from .config import load_kimera_multi, load_methods
    from .recorded import run_kimera_multi

    console, err_console = _console(), _console(stderr=True)
    _check_duration(duration)
    _check_recording(rerun)
    test = load_kimera_multi(config)
    if duration is not None:
        test = test.model_copy(update={"duration": duration})
    if methods is not None:
        test = test.model_copy(update={"methods": load_methods(methods)})
    _writable_folder(output, "--output")
    console.print(f"Kimera-Multi test [bold]{escape(test.name)}[/]: robots "
                  f"{', '.join(test.robots)}; data {data}")
    start = time.perf_counter()
    try:
        with _bars() as bars:
            outcome = run_kimera_multi(test, data, output, resume, figures, _kimera_bars(bars))
    except TcaffError:
        maps = output / test.name / "maps"
        saved = sorted(p.stem for p in maps.glob("*.npz")) if maps.is_dir() else []
        if saved:
            err_console.print(f"the maps of {', '.join(saved)} are saved in {maps}; a rerun "
                              f"reuses them")
        raise
    throughput = _table("Mapping")
    _add_columns(throughput, ("robot", "frames", "seconds", "frames/s", "ms per frame: segment",
                              "lift", "track"))
    for m in outcome.mappings:
        ms = {k: 1e3 * v / max(m.frames, 1) for k, v in m.stage_seconds.items()}
        throughput.add_row(escape(m.robot) + (" (saved)" if m.robot in outcome.reused else ""),
                           str(m.frames), f"{m.seconds:.1f}",
                           "-" if m.frames_per_second is None else f"{m.frames_per_second:.1f}",
                           f"{ms.get('segment', 0):.1f}", f"{ms.get('lift', 0):.1f}",
                           f"{ms.get('track', 0):.2f}")
    console.print(_keep_numbers_whole(throughput))
    recorded = outcome.recorded
    if recorded.summary:
        console.print(_summary_table({test.name: recorded.summary}, recorded.methods))
    else:
        console.print("no ground truth for every robot: alignments written, not scored")
    console.print(f"results: {outcome.folder} ({time.perf_counter() - start:.0f} s)")
    _record(rerun, [recorded.job])


def _parse_pairs(text: str | None) -> list[tuple[int, int]] | None:
    """`--pairs 1:2,2:1` as directed pairs of robot subjects."""
    from tcaff_gtsam.errors import ConfigError

    if text is None:
        return None
    pairs = []
    for token in text.split(","):
        parts = token.strip().split(":")
        if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
            raise ConfigError(f"--pairs {text!r}: expected robot pairs like 1:2,2:1, got "
                              f"{token.strip()!r}")
        pairs.append((int(parts[0]), int(parts[1])))
    return pairs


def _pairs_table(recorded, shown: list[str]) -> Table:
    """Per directed pair: each shown method's false accepts and availability."""
    from .registry import describe

    table = _table("Per directed pair (robot names as in the data set): false accepts / "
                   "availability")
    _add_columns(table, ("pair", "overlap [s]", *(describe(m).label for m in shown)))
    names = recorded.job.info.get("robots") or []
    for i, j in recorded.job.pairs:
        label = f"{i}->{j}" if not names else f"{names[i]}->{names[j]}"
        cells = []
        for method in shown:
            r = recorded.job.metrics[method][f"{i}->{j}"]
            cells.append(f"{_cell(r, 'false_accept', 100, 0)} % / "
                         f"{_cell(r, 'availability', 100, 0)} %")
        overlap = recorded.job.metrics[shown[0]][f"{i}->{j}"]["n_overlap"]
        table.add_row(label, str(overlap), *cells)
    return _keep_numbers_whole(table)


@app.command()
def mrclam(
    data: Annotated[Path, typer.Option(
        help="An MRCLAM data set folder (Barcodes.dat, Landmark_Groundtruth.dat, "
             "Robot<N>_Odometry/Measurement/Groundtruth.dat).")],
    config: Annotated[str, typer.Option(
        help=f"An MRCLAM evaluation YAML, or a shipped one: {_shipped('mrclam')}.")
    ] = "default",
    odometry: Annotated[list[str] | None, typer.Option(
        help="raw (dead-reckoned commanded velocities) or vio (the truth with VIO-like "
             "drift); repeatable. Default: the config's.")] = None,
    seed: Annotated[list[int] | None, typer.Option(
        help="Seed of the VIO-like drift; repeatable (raw odometry runs once).")] = None,
    methods: Annotated[str | None, typer.Option(
        help=f"Method set: a YAML path or a shipped name ({_shipped('methods')}).")] = None,
    pairs: Annotated[str | None, typer.Option(
        help="Directed pairs of robots to align, like 1:2,2:1 (default: all 20).")] = None,
    kappa: Annotated[float | None, typer.Option(
        help="Seconds of sightings a map holds, with either odometry (default: the "
        "config's, per odometry: 20 s raw, 150 s vio).")] = None,
    duration: Annotated[float | None, typer.Option(
        help="Use only this many seconds of data, for a quick look.")] = None,
    output: Annotated[Path, typer.Option(
        help="Results go to OUTPUT/<set>-<odometry>[-seed<s>]/.")] = Path("results/mrclam"),
    resume: Annotated[bool, typer.Option(
        help="Reuse the results of an earlier run with the same settings and files.")] = True,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    rerun: Annotated[Path | None, typer.Option(help=_RERUN_HELP)] = None,
) -> None:
    """Real robots: align every directed pair of a UTIAS MRCLAM data set and score it.

    Each robot's landmark sightings of the last kappa seconds, placed in its odometry frame,
    are its map; maps are exchanged at 1 Hz and every method aligns every directed pair
    (landmark identities are used for scoring only). Prints the pooled and per-pair tables;
    writes metrics.json, metrics.csv, table.md and figures/ (the arena, errors over time and
    candidates against the truth per pair) under OUTPUT/<set>-<odometry>[-seed<s>]/.
    """
    import time

    from rich.markup import escape

    from .config import load_methods, load_mrclam, override
    from .recorded import run_mrclam

    console = _console()
    _check_duration(duration)
    _check_recording(rerun)
    settings = override(load_mrclam(config), "command line", duration=duration, kappa=kappa,
                        methods=None if methods is None else load_methods(methods))
    odometries = odometry or [settings.odometry]
    bad = [o for o in odometries if o not in ("raw", "vio")]
    if bad:
        from tcaff_gtsam.errors import ConfigError

        raise ConfigError(f"--odometry {bad[0]!r}: expected raw or vio")
    seeds = _check_seeds(seed)
    _writable_folder(output, "--output")
    console.print(f"MRCLAM [bold]{escape(data.name)}[/]: odometry {', '.join(odometries)}, "
                  f"seeds {seeds}; data {data}")
    start = time.perf_counter()
    with _bars() as bars:
        tasks: dict[str, int] = {}

        def progress(name: str, share: float) -> None:
            if name not in tasks:
                tasks[name] = bars.add_task(f"aligning {name}", total=1.0)
            bars.update(tasks[name], completed=share)

        outcomes = run_mrclam(settings, data, output, odometries, seeds, _parse_pairs(pairs),
                              resume, figures, progress)
    if outcomes and outcomes[0].skipped:
        console.print("skipped rows: " + ", ".join(f"{n} {what}" for what, n in
                                                   outcomes[0].skipped.items()))
    for outcome in outcomes:
        recorded = outcome.recorded
        note = " (saved results of an earlier run reused)" if outcome.reused else ""
        console.print(f"[bold]{escape(recorded.job.name)}[/]{note}")
        if recorded.summary:
            console.print(_summary_table({recorded.job.name: recorded.summary},
                                         recorded.methods))
            from .registry import describe, shown_streams

            shown = [m for m in shown_streams(recorded.methods)
                     if describe(m).causal and m != "ground_truth"]
            if shown:
                console.print(_pairs_table(recorded, shown))
        console.print(f"results: {recorded.folder}")
    console.print(f"({time.perf_counter() - start:.0f} s)")
    _record(rerun, [outcome.recorded.job for outcome in outcomes])


def _parse_ranges(text: str | None, n_data: int) -> list[tuple[int | None, int | None]]:
    """`--robots 0:500,500:1000` as frame-id ranges [start, stop); one range per --data folder
    when several are given (a bare `:` for a whole sequence)."""
    from tcaff_gtsam.errors import ConfigError

    if text is None:
        return [] if n_data == 1 else [(None, None)] * n_data
    ranges = []
    for token in text.split(","):
        parts = token.strip().split(":")
        ok = len(parts) == 2 and all(p.strip() == "" or p.strip().isdigit() for p in parts)
        if not ok:
            raise ConfigError(f"--robots {text!r}: expected frame ranges like 0:500,500:1000, "
                              f"got {token.strip()!r}")
        start, stop = (int(p) if p.strip() else None for p in parts)
        if start is not None and stop is not None and stop <= start:
            raise ConfigError(f"--robots {text!r}: the range {token.strip()!r} is empty")
        ranges.append((start, stop))
    if n_data > 1 and len(ranges) != n_data:
        raise ConfigError(f"--robots {text!r}: with {n_data} --data folders give one range per "
                          f"folder, got {len(ranges)}")
    if n_data == 1 and len(ranges) < 2:
        raise ConfigError(f"--robots {text!r}: one sequence needs two ranges or more (one "
                          f"robot each)")
    return ranges


def _walk_table(outcome, labels: dict[str, str]) -> Table:
    """The numbers of an RGB-D evaluation per estimate stream (pooled over pairs)."""
    table = _table(f"{outcome.recorded.job.name}: false accepts, availability from the "
                   f"first exchange TCAFF can answer at, median errors")
    _add_columns(table, ("method", "estimates", "false acc.", "false acc. (tight)",
                         "available", "median [m]", "median [deg]"))
    for stream, r in outcome.report.items():
        def share(key: str, r=r) -> str:
            return "-" if r[key] is None else f"{100 * r[key]:.1f} %"

        def number(key: str, digits: int, r=r) -> str:
            return "-" if r[key] is None else f"{r[key]:.{digits}f}"

        table.add_row(labels.get(stream, stream), str(r["estimates"]), share("false_accept"),
                      share("false_accept_tight"), share("availability_from_first"),
                      number("median_translation_m", 3), number("median_heading_deg", 2))
    return _keep_numbers_whole(table)


@app.command()
def rgbd(
    data: Annotated[list[Path], typer.Option(
        help="A recorded RGB-D sequence: a 7-Scenes folder (frame-XXXXXX.color.png|jpg, "
             ".depth.png, .pose.txt) or a TUM RGB-D folder (rgb.txt, depth.txt, "
             "groundtruth.txt). Repeatable: several sequences of one place, one robot each.")],
    robots: Annotated[str | None, typer.Option(
        help="Frame-id ranges, one robot each, like 0:500,500:1000 (default: the two halves "
             "of one sequence; with several --data, one range per folder, ':' for all).")
    ] = None,
    there_and_back: Annotated[bool, typer.Option(
        "--there-and-back", help="Each robot walks its frames forward, then back to its "
        "start (the time running on).")] = False,
    rate: Annotated[float | None, typer.Option(
        help="Frames per second to map (at most the folder's; default: every frame).")
    ] = None,
    odometry: Annotated[list[str] | None, typer.Option(
        help="exact (the sequence's poses) or vio (with VIO-like drift); repeatable. "
             "Default: the config's.")] = None,
    seed: Annotated[list[int] | None, typer.Option(
        help="Seed of the VIO-like drift; repeatable (exact odometry runs once).")] = None,
    gravity: Annotated[str | None, typer.Option(
        help="Gravity's direction in the sequence's world frame, like 0,0,-1, for a folder "
             "without gravity-direction.txt (TUM: else from accelerometer.txt).")] = None,
    fps: Annotated[float, typer.Option(
        help="7-Scenes frames per second (its files hold no time stamps).")] = 30.0,
    config: Annotated[str, typer.Option(
        help=f"An RGB-D evaluation YAML, or a shipped one: {_shipped('rgbd')}.")
    ] = "default",
    methods: Annotated[str | None, typer.Option(
        help=f"Method set: a YAML path or a shipped name ({_shipped('methods')}).")] = None,
    output: Annotated[Path, typer.Option(
        help="Results go to OUTPUT/<sequence>[-<ranges>][-<rate>hz][-back]-<odometry>"
             "[-seed<s>]/ (ranges unless the default ones).")
    ] = Path("results/rgbd"),
    resume: Annotated[bool, typer.Option(
        help="Reuse the results of an earlier run with the same settings and files.")] = True,
    figures: Annotated[bool, typer.Option(help="Draw the PNG figures.")] = True,
    rerun: Annotated[Path | None, typer.Option(help=_RERUN_HELP)] = None,
) -> None:
    """Real cameras: map recorded RGB-D sequences as robots, align every pair, score.

    Each robot walks frames of a sequence (a range of one sequence, or a whole sequence of the
    same place); every frame goes through the mapping front end (depth segmenter, Open3D
    lifting, objects merged over views) in the robot's gravity-aligned odometry frame, its map
    of the last kappa s is exchanged at 1 Hz, and every method aligns every directed pair.
    Prints the mapping speed, the pooled table and the false accepts (1 m / 5 deg and the
    config's tighter threshold), availability from the first exchange TCAFF can answer at
    and median errors; writes metrics.json, metrics.csv, table.md, walk_report.json,
    trajectories/ and figures/ (errors and candidates over time, a top view of both maps
    under the truth and under the estimate) under OUTPUT/<name>/.
    """
    import time

    import numpy as np
    from rich.markup import escape

    from tcaff_gtsam.errors import ConfigError

    from .config import load_methods, load_rgbd, override
    from .datasets.rgbd_robots import halves, walk
    from .datasets.rgbd_sequence import read_sequence
    from .recorded import run_rgbd
    from .registry import describe

    console = _console()
    _check_recording(rerun)
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        _refuse("--rate", rate, "must be a finite number > 0 frames per second")
    if not (math.isfinite(fps) and fps > 0):
        _refuse("--fps", fps, "must be a finite number > 0 frames per second")
    seeds = _check_seeds(seed)
    settings = override(load_rgbd(config), "command line",
                        methods=None if methods is None else load_methods(methods))
    odometries = odometry or [settings.odometry]
    bad = [o for o in odometries if o not in ("exact", "vio")]
    if bad:
        raise ConfigError(f"--odometry {bad[0]!r}: expected exact or vio")
    down = None
    if gravity is not None:
        try:
            down = [float(v) for v in gravity.split(",")]
        except ValueError:
            down = None
        if down is None or len(down) != 3:
            _refuse("--gravity", gravity, "expected three numbers like 0,0,-1")
    ranges = _parse_ranges(robots, len(data))
    sequences = [read_sequence(folder, down, fps) for folder in data]
    if len(data) == 1:
        ranges = ranges or halves(sequences[0].frame_ids)
        sequences = sequences * len(ranges)
    walks = [walk(seq, start, stop, rate, there_and_back)
             for seq, (start, stop) in zip(sequences, ranges, strict=True)]
    _writable_folder(output, "--output")
    console.print(f"RGB-D [bold]{escape(', '.join(str(d) for d in data))}[/]: robots "
                  f"{', '.join(escape(w.label) for w in walks)} "
                  f"({', '.join(str(w.positions.size) for w in walks)} frames); odometry "
                  f"{', '.join(odometries)}, seeds {seeds}")
    start_time = time.perf_counter()
    with _bars() as bars:
        tasks: dict[tuple[str, str], int] = {}

        def progress(name: str, stage: str, share: float) -> None:
            if (name, stage) not in tasks:
                tasks[name, stage] = bars.add_task(f"{name}: {stage}", total=1.0)
            bars.update(tasks[name, stage], completed=share)

        outcomes = run_rgbd(settings, walks, output, odometries, seeds, resume, figures,
                            progress)
    for outcome in outcomes:
        recorded = outcome.recorded
        note = " (saved results of an earlier run reused)" if outcome.reused else ""
        console.print(f"[bold]{escape(recorded.job.name)}[/]{note}")
        if outcome.frame_seconds is not None:
            speed = _table("Mapping: ms per frame, median (90th percentile)")
            stages = ("register", "segment", "filter", "lift", "track")
            _add_columns(speed, ("robot", "frames", *stages, "total"))
            for w, secs in zip(walks, outcome.frame_seconds, strict=True):
                cells = [f"{1e3 * np.median(c):.1f} ({1e3 * np.percentile(c, 90):.1f})"
                         for c in (*secs.T, secs.sum(axis=1))]
                speed.add_row(escape(w.label), str(secs.shape[0]), *cells)
            console.print(_keep_numbers_whole(speed))
        if recorded.summary:
            console.print(_summary_table({recorded.job.name: recorded.summary},
                                         recorded.methods))
            labels = {m: describe(m).label for m in outcome.report}
            console.print(_walk_table(outcome, labels))
        console.print(f"results: {recorded.folder}")
    console.print(f"({time.perf_counter() - start_time:.0f} s)")
    _record(rerun, [outcome.recorded.job for outcome in outcomes])


@app.command()
def view(
    results: Annotated[Path, typer.Argument(
        help="A results folder: a study's (results/latest) or a data set's "
             "(results/mrclam/<name>).")],
    output: Annotated[Path | None, typer.Option(
        help="The recording to write (default: RESULTS/recording.rrd).")] = None,
    reference: Annotated[int, typer.Option(
        help="The robot (index) the other robots' maps are aligned to.")] = 0,
    method: Annotated[str | None, typer.Option(
        help="The method whose alignments are shown as accepted (default: tcaff).")] = None,
) -> None:
    """Make a Rerun recording of saved runs: the world, each robot's map over time, the paths,
    the candidates, the accepted alignment and the truth on one timeline, errors over time.

    Needs the optional extra viz (pip install 'tcaff-gtsam[viz]'); open the file with
    `rerun FILE.rrd`. Runs saved before the maps were kept show no maps.
    """
    from .recording import record
    from .results import load_saved

    path = output or results / "recording.rrd"
    jobs = load_saved(results)
    record(path, jobs, reference, method)
    _console().print(f"wrote {path} ({len(jobs)} run{'s' if len(jobs) > 1 else ''}); open it "
                     f"with: rerun {path}", soft_wrap=True)


@app.command()
def export(
    results: Annotated[Path, typer.Argument(
        help="A results folder: a study's (results/latest) or a data set's "
             "(results/mrclam/<name>).")],
    fmt: Annotated[str, typer.Option(
        "--format", help="tum (one file per robot and method) or g2o (one pose graph per "
                         "method).")] = "tum",
    reference: Annotated[int, typer.Option(
        help="The robot (index) whose odometry frame the paths are expressed in.")] = 0,
) -> None:
    """Write every saved run's trajectories for evo and other tools, under RESULTS/trajectories/.

    Each robot's path is placed in the reference robot's odometry frame through each method's
    alignments, and through the true alignment for the ground truth (truth/). Compare them
    with evo, e.g. `evo_ape tum truth/1.tum tcaff/1.tum` in a frame_<reference>/ folder: the
    APE column of the table is that figure for the pair reference -> 1.
    """
    from .trajectories import export as export_trajectories

    folders = export_trajectories(results, fmt, reference)
    for folder in folders:
        _console().print(f"wrote {folder}", soft_wrap=True)


def _click_errors() -> tuple[type, type]:
    """(UsageError, ClickException) of the click that typer runs on: its own copy in recent
    typer releases, the click package in older ones."""
    bases = {c.__name__: c for c in typer.BadParameter.__mro__}
    return bases["UsageError"], bases["ClickException"]


# -- a live team -------------------------------------------------------------------------------

_TLS_HELP = ("PEM file: the team's certificate authority (with --tls-cert and --tls-key: "
             "mutual TLS).")
_TEAM_HELP = ("Also publish each pair's team-consistent alignment (those failing a cycle of "
              "three robots left out, missing ones chained through a third) on team/<other> "
              "keys and in <robot>.team.csv.")
_KIMERA_HELP = ("Or a folder of Kimera-Multi rosbags and <robot>_gt_odom.csv files to replay, "
                "mapped through the RGB-D front end (maps saved in OUTPUT/maps/ and reused).")
_KIMERA_TEST_HELP = (f"With --kimera: the Kimera-Multi test YAML or shipped name "
                     f"({_shipped('kimera_multi')}) naming the robots, topics and settings.")


def _tls(ca: Path | None, cert: Path | None, key: Path | None):
    """The team's TLS files, all three or none."""
    from tcaff_gtsam.node.link import TlsFiles

    given = [x is not None for x in (ca, cert, key)]
    if not any(given):
        return None
    if not all(given):
        _refuse("--tls-ca/--tls-cert/--tls-key", [str(x) for x in (ca, cert, key)],
                "give all three or none")
    return TlsFiles(ca, cert, key)


def _simulated(scenario: str, seed: int, duration: float | None):
    """The simulated run of a scenario (capped to `duration` s), the same in every process."""
    from .config import load_scenario, override
    from .sim.simulate import simulate

    _check_seeds([seed])
    _check_duration(duration)
    config = load_scenario(scenario)
    if duration is not None:
        config = override(config, "--duration", duration=min(duration, config.duration))
    return simulate(config, seed)


def _check_speed(speed: float) -> None:
    if not (math.isfinite(speed) and speed > 0):
        _refuse("--speed", speed, "must be a finite number > 0 (run seconds per wall second)")


@app.command()
def node(
    robot: Annotated[str, typer.Option(help="This robot's name: r0, r1, ... of the run.")],
    scenario: Annotated[str | None, typer.Option(
        help=f"Replay this robot of a simulated scenario: {_shipped('scenarios')} (or a "
             f"YAML).")] = None,
    replay: Annotated[Path | None, typer.Option(
        help="Replay this robot from a replay file (what `tcaff team` writes to "
             "<output>/replay/).")] = None,
    kimera: Annotated[Path | None, typer.Option(help=_KIMERA_HELP)] = None,
    kimera_test: Annotated[str, typer.Option(help=_KIMERA_TEST_HELP)] = "same_direction",
    team: Annotated[str, typer.Option(help="Team name: keys are tcaff/<team>/<robot>/...")
    ] = "team",
    listen: Annotated[list[str] | None, typer.Option(
        help="host:port to accept peers on (repeat for more).")] = None,
    connect: Annotated[list[str] | None, typer.Option(
        help="host:port of a peer to dial (repeat; retried until it is up).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the simulated run.")] = 0,
    duration: Annotated[float | None, typer.Option(help="Cap the run (s).")] = None,
    speed: Annotated[float, typer.Option(help="Run seconds per wall second.")] = 1.0,
    start_at: Annotated[float | None, typer.Option(
        help="Wall time (epoch s) of the run's first exchange, shared by the team; "
             "default: 1 s after every robot of the run is up. A node started after it "
             "joins where the run is.")] = None,
    output: Annotated[Path, typer.Option(
        help="Folder for <robot>.csv (every alignment), <robot>.json (counters) and, "
             "with --kimera, maps/ (each robot's maps, reused by later runs).")
    ] = Path("results/team"),
    state: Annotated[Path | None, typer.Option(
        help="Folder to save each filter after each step and restore them from on start.")
    ] = None,
    silence: Annotated[float, typer.Option(
        help="s without a neighbour's map before its filter steps without measurements.")
    ] = 3.0,
    clock_offset: Annotated[float, typer.Option(
        help="s added to this robot's clock (to try robots whose clocks differ).")] = 0.0,
    drop_share: Annotated[float, typer.Option(
        help="Share of neighbours' maps to discard on arrival (to try a lossy link).")] = 0.0,
    drop_seed: Annotated[int, typer.Option(help="Seed of the discards.")] = 0,
    team_consistency: Annotated[bool, typer.Option(help=_TEAM_HELP)] = False,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(
        help="PEM file: this node's certificate, signed by the team's authority.")] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: this node's private key.")
    ] = None,
) -> None:
    """One robot of a live team: publishes its maps over Zenoh, aligns to every neighbour.

    The robot's maps are replayed (--scenario, --kimera or --replay) on a wall-clock schedule
    that the robots of one run share through --start-at. From Python,
    `tcaff_gtsam.node.RobotNode` takes maps from a live mapping pipeline instead.
    """
    from tcaff_gtsam.node.link import Link
    from tcaff_gtsam.node.node import NodeParams
    from tcaff_gtsam.node.replay import RobotReplay, robot_names, run_replay
    from tcaff_gtsam.node.run import replay_node

    sources = [scenario, kimera and str(kimera), replay and str(replay)]
    if sum(x is not None for x in sources) != 1:
        _refuse("--scenario/--kimera/--replay", sources, "give exactly one")
    _check_speed(speed)
    _check_seeds([seed])
    if drop_seed < 0:
        _refuse("--drop-seed", drop_seed, "must be an int >= 0")
    link = Link(tuple(listen or ()), tuple(connect or ()), _tls(tls_ca, tls_cert, tls_key))
    params = NodeParams(silence=silence, lockstep=True, speed=speed, drop_share=drop_share,
                        seed=drop_seed, team_consistency=team_consistency)
    _writable_folder(output, "--output")
    if replay is not None:
        source = RobotReplay.load(replay)
        if robot != source.robots[source.robot]:
            _refuse("--robot", robot, f"{replay} replays {source.robots[source.robot]}")
    else:
        run = (_simulated(scenario, seed, duration) if kimera is None
               else _kimera_run(kimera, kimera_test, duration, output / "maps"))
        names = robot_names(run.n_robots)
        if robot not in names:
            _refuse("--robot", robot, f"the run's robots are {_named(run, names)}")
        source = run_replay(run, names.index(robot), names)
    node_ = replay_node(source, team, link, params, start_at, output, clock_offset, state)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(node_.counters.items()))
    print(f"{robot}: {counts}")


def _team_table(run, output: Path, names: tuple[str, ...], team: bool = False) -> Table:
    """Per directed pair: alignments made, accepted share, final and median error (the team
    alignments of `<robot>.team.csv` when `team`, with the share chained through a robot)."""
    import json

    import numpy as np
    from tcaff_gtsam.node.results import COLUMNS, TEAM_COLUMNS, read_alignments

    from tcaff_gtsam.errors import DataError
    from tcaff_gtsam.geometry import se2_to_params, wrap_angle

    table = _table("Per directed pair: the team-consistent alignments against the truth" if team
                   else "Per directed pair: the node's alignments against the truth")
    _add_columns(table, ("pair", "steps", "accepted", *(("chained",) if team else ()),
                         "median error [m, deg]", "last error [m, deg]"))
    for i, robot in enumerate(names):
        try:
            rows = (read_alignments(output / f"{robot}.team.csv", TEAM_COLUMNS) if team
                    else read_alignments(output / f"{robot}.csv", COLUMNS))
        except DataError:
            continue
        for j, other in enumerate(names):
            mine = rows["neighbour"] == other
            if i == j or not mine.any():
                continue
            seq = rows["seq"][mine].astype(int)
            accepted = rows["accepted"][mine] == 1
            truth = se2_to_params(run.T_true(i, j)[seq])
            x = np.column_stack([rows[c][mine] for c in ("x", "y", "theta")])
            dt = np.linalg.norm(x[:, :2] - truth[:, :2], axis=1)
            dh = np.degrees(np.abs(wrap_angle(x[:, 2] - truth[:, 2])))
            scored = accepted & np.isfinite(dt)  # a recorded run may lack the truth
            med = (f"{np.median(dt[scored]):.2f}, {np.median(dh[scored]):.1f}"
                   if scored.any() else "-")
            last = f"{dt[-1]:.2f}, {dh[-1]:.1f}" if scored[-1] else "-"
            chained = ([f"{100 * (rows['via'][mine][accepted] != '').mean():.0f} %"
                        if accepted.any() else "-"] if team else [])
            table.add_row(f"{robot}->{other}", str(mine.sum()),
                          f"{100 * accepted.mean():.0f} %", *chained, med, last)
    late = {"dropped_stale": 0, "silent_steps": 0}
    for robot in names:
        path = output / f"{robot}.json"
        counters = json.loads(path.read_text()) if path.exists() else {}
        for key in late:
            late[key] += counters.get(key, 0)
    if any(late.values()) and not team:
        table.caption = (f"{late['dropped_stale']} maps came too late and "
                         f"{late['silent_steps']} steps had no neighbour's map: the team fell "
                         f"behind its schedule (try a lower --speed) or lost maps")
    return _keep_numbers_whole(table)


def _kimera_run(data: Path, test: str, duration: float | None, maps: Path):
    """The Kimera-Multi test `test` on the bags in `data` as a recorded run: every robot's
    RGB-D frames through the front end, with progress bars; the maps are saved in `maps` and
    reused by a later call with the same settings and bags."""
    _check_duration(duration)
    if not Path(data).is_dir():
        _refuse("--kimera", str(data), "must be a folder of Kimera-Multi bags")
    from .config import load_kimera_multi
    from .datasets import kimera_multi  # the RGB-D front end: loaded only when needed

    config = load_kimera_multi(test)
    if duration is not None:
        config = config.model_copy(update={"duration": duration})
    with _bars() as bars:
        run, _, _ = kimera_multi.load_run(config, data, maps, True, _kimera_bars(bars))
    return run


def _named(run, names: tuple[str, ...]) -> str:
    """"r0, r1" or, for a data set that names its robots, "r0 (acl_jackal2), r1 (...)"."""
    own = getattr(run, "robot_names", ())
    if not own or tuple(own) == tuple(str(k) for k in range(len(names))):
        return ", ".join(names)
    return ", ".join(f"{n} ({o})" for n, o in zip(names, own, strict=True))


def _mrclam_run(data: Path, seed: int, duration: float | None):
    """The UTIAS MRCLAM data set in `data` as a recorded run (default settings, VIO-like
    odometry drawn with `seed`)."""
    _check_seeds([seed])
    from .config import load_mrclam
    from .datasets import mrclam
    from .recorded import load_mrclam_run

    _check_duration(duration)
    config = load_mrclam("default")
    return load_mrclam_run(mrclam.read_dataset(data), config, config.odometry, seed,
                           duration or None)


@app.command()
def team(
    scenario: Annotated[str | None, typer.Option(
        help=f"Simulated scenario to replay: {_shipped('scenarios')} (or a YAML).")] = None,
    mrclam: Annotated[Path | None, typer.Option(
        help="Or a UTIAS MRCLAM data set folder to replay (one node per robot; the "
             "'default' MRCLAM settings).")] = None,
    kimera: Annotated[Path | None, typer.Option(help=_KIMERA_HELP)] = None,
    kimera_test: Annotated[str, typer.Option(help=_KIMERA_TEST_HELP)] = "same_direction",
    seed: Annotated[int, typer.Option(
        help="Seed of the simulated run (MRCLAM: of its VIO-like odometry).")] = 0,
    speed: Annotated[float, typer.Option(help="Run seconds per wall second.")] = 1.0,
    duration: Annotated[float | None, typer.Option(help="Cap the run (s).")] = None,
    team_name: Annotated[str, typer.Option("--team", help="Team name.")] = "team",
    base_port: Annotated[int, typer.Option(
        help="Robot k listens on 127.0.0.1:<base-port + k>; 0: free ports.")] = 0,
    output: Annotated[Path, typer.Option(help="Folder for every node's CSV, counters, log.")
    ] = Path("results/team"),
    drop_share: Annotated[float, typer.Option(
        help="Share of maps each node discards on arrival (a lossy link).")] = 0.0,
    team_consistency: Annotated[bool, typer.Option(help=_TEAM_HELP)] = False,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(help="PEM file: the nodes' certificate.")
    ] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: the nodes' private key.")
    ] = None,
) -> None:
    """Start one node process per robot of a simulated or recorded run on this machine
    (Zenoh over loopback), wait for the run to end, and print every pair's alignments against
    the truth. Robots are named r0, r1, ... in the run's order.

    Kimera-Multi bags (--kimera) go through the RGB-D front end first, once for the team (each
    robot's maps saved in OUTPUT/maps/ and reused by a later run with the same settings and
    bags); the nodes then replay the maps at the 1 Hz exchanges every robot shares."""

    from tcaff_gtsam.node.replay import robot_names
    from tcaff_gtsam.node.run import free_ports, node_argv, save_replays, start_team, wait_team

    sources = [scenario, mrclam and str(mrclam), kimera and str(kimera)]
    if sum(x is not None for x in sources) != 1:
        _refuse("--scenario/--mrclam/--kimera", sources, "give exactly one")
    _check_speed(speed)
    _check_seeds([seed])
    tls = _tls(tls_ca, tls_cert, tls_key)
    _writable_folder(output, "--output")
    if scenario is not None:
        run = _simulated(scenario, seed, duration)
    elif mrclam is not None:
        run = _mrclam_run(mrclam, seed, duration)
    else:
        run = _kimera_run(kimera, kimera_test, duration, output / "maps")
    n = run.n_robots
    ports = free_ports(n) if base_port == 0 else list(range(base_port, base_port + n))
    if not all(0 < p < 65536 for p in ports):
        _refuse("--base-port", base_port, f"ports {ports[0]}..{ports[-1]} must be in 1..65535")
    replays = save_replays(run, output / "replay")
    argvs = [node_argv(replays[k], k, n, team_name, ports, None, output, speed, drop_share,
                       tls=tls, team_consistency=team_consistency) for k in range(n)]
    console = _console()
    console.print(f"robots: {_named(run, robot_names(n))}", soft_wrap=True)
    console.print(f"{n} nodes of team {team_name!r} on 127.0.0.1:{ports[0]}..{ports[-1]}; "
                  f"{len(run.times)} exchanges at {speed:g}x, about "
                  f"{len(run.times) / speed:.0f} s once every node is up. Watch with: tcaff "
                  f"listen --team "
                  f"{team_name} --connect 127.0.0.1:{ports[0]}")
    procs = start_team(argvs, output / "logs")
    codes = wait_team(procs, 180 + len(run.times) / speed)
    failed = [f"r{k}" for k, c in enumerate(codes) if c != 0]
    console.print(_team_table(run, output, robot_names(n)))
    if team_consistency:
        console.print(_team_table(run, output, robot_names(n), team=True))
    if failed:
        from tcaff_gtsam.errors import TcaffError

        raise TcaffError(f"nodes {', '.join(failed)} failed; see {output / 'logs'}")
    console.print(f"results: {output}")


@app.command()
def listen(
    team_name: Annotated[str, typer.Option("--team", help="Team name.")] = "team",
    connect: Annotated[list[str] | None, typer.Option(
        help="host:port of a team node to dial (repeat).")] = None,
    listen_on: Annotated[list[str] | None, typer.Option(
        "--listen", help="host:port to accept nodes on.")] = None,
    scenario: Annotated[str | None, typer.Option(
        help="The simulated scenario the team replays: shows each alignment's error.")] = None,
    seed: Annotated[int, typer.Option(help="Its seed.")] = 0,
    seconds: Annotated[float | None, typer.Option(help="Stop after this long (s).")] = None,
    tls_ca: Annotated[Path | None, typer.Option(help=_TLS_HELP)] = None,
    tls_cert: Annotated[Path | None, typer.Option(help="PEM file: this listener's certificate.")
    ] = None,
    tls_key: Annotated[Path | None, typer.Option(help="PEM file: its private key.")] = None,
) -> None:
    """A live table of every pair's latest alignment in a team (Ctrl-C to stop)."""
    import threading

    from rich.live import Live
    from tcaff_gtsam.node.link import Link
    from tcaff_gtsam.node.listener import TeamListener

    link = Link(tuple(listen_on or ()), tuple(connect or ()), _tls(tls_ca, tls_cert, tls_key))
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        _refuse("--seconds", seconds, "must be a finite number > 0")
    truth = None
    if scenario is not None:
        run = _simulated(scenario, seed, None)
        truth = run.T_true
    stop = threading.Event()
    with TeamListener(team_name, link, truth) as listener, \
            Live(listener.table(), console=_console(), refresh_per_second=4) as live:
        try:
            while not stop.wait(0.25):
                live.update(listener.table())
                if seconds is not None and listener.elapsed() >= seconds:
                    break
        except KeyboardInterrupt:
            pass


#: the characters str.splitlines breaks lines at
_LINE_BREAKS = frozenset("\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029")


def main() -> None:
    """Console entry point: library errors and bad options or arguments become a one-line
    message and exit status 2."""
    import logging

    from rich.markup import escape

    from tcaff_gtsam.errors import TcaffError

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    usage_error, click_exception = _click_errors()

    def refuse(message: str, code: int = 2) -> None:
        # one line whatever the message quotes (a file name may hold any line break)
        message = "".join(repr(c)[1:-1] if c in _LINE_BREAKS else c for c in message)
        _console(stderr=True).print(f"[red]error:[/] {escape(message)}", soft_wrap=True)
        raise SystemExit(code) from None

    try:
        code = app(standalone_mode=False)
    except TcaffError as exc:
        refuse(str(exc))
    except usage_error as exc:  # an unknown option, a value out of range, ...
        if type(exc).__name__ == "NoArgsIsHelpError":  # `tcaff` alone: the help
            exc.show()
            raise SystemExit(exc.exit_code) from None
        where = exc.ctx.command_path if exc.ctx is not None else "tcaff"
        refuse(f"{exc.format_message()} (see: {where} --help)", exc.exit_code)
    except click_exception as exc:
        refuse(exc.format_message(), exc.exit_code)
    except typer.Abort:  # Ctrl-C outside the commands that handle it themselves
        _console(stderr=True).print("interrupted", soft_wrap=True)
        raise SystemExit(130) from None
    raise SystemExit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
