"""The shared part of the `tcaff` command line: the typer `app` every command module registers
on, the stdout and stderr consoles, the tables of numbers (`_table`, `_add_columns`,
`_keep_numbers_whole`, the pooled study table several commands print), the progress bars, the
checks of common options (`_refuse`, `_check_seeds`, `_check_duration`, `_writable_folder`,
`_check_recording`) and the error a `tcaff` process it started wrote last (`_last_error`).
Like the rest of the command line it imports only typer when loaded; everything else is
imported by the function that uses it.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from typer.core import TyperCommand, TyperGroup

if TYPE_CHECKING:
    from rich.console import Console, Group
    from rich.progress import Progress as RichProgress
    from rich.table import Table

    from ..config import MethodsConfig

# The same folder as config.CONFIG_DIR, found without importing config (pydantic).
_CONFIG_DIR = Path(__file__).parents[1] / "configs"


def _shipped(kind: str) -> str:
    """The shipped configs of one kind (a folder of `configs/`), as a comma-separated list."""
    names = sorted(path.stem for path in (_CONFIG_DIR / kind).glob("*.yaml"))
    return ", ".join(names) if names else "none shipped"


#: perf_counter() when the entry point `main` took the command line; None outside a `main` call
_command_started: float | None = None


def _since_start(fallback: float) -> float:
    """Seconds since the entry point took the command line: the command's imports, data
    loading and workers' start-up included (the interpreter's own start, a few tenths of a
    second, is not). `fallback`, a perf_counter() reading, is the start when the command was
    called without the entry point."""
    import time

    started = fallback if _command_started is None else _command_started
    return time.perf_counter() - started


class _Untyped:
    """On/off flags (`--figures/--no-figures`, `--help`) drawn without a type in the help:
    typer 0.29 prints `<bool>` beside each, which reads as if the flag took a value."""

    def get_params(self, ctx):
        params = super().get_params(ctx)
        for param in params:
            if getattr(param, "is_flag", False) and param.metavar is None:
                param.metavar = ""
        return params


class _Command(_Untyped, TyperCommand):
    pass


class _Group(_Untyped, TyperGroup):
    pass


class _App(typer.Typer):
    """The typer app whose commands are `_Command`s."""

    def command(self, *args, **kwargs):
        kwargs.setdefault("cls", _Command)
        return super().command(*args, **kwargs)


app = _App(
    cls=_Group,
    help="Align the coordinate frames of robots from their object maps (TCAFF).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _console(stderr: bool = False) -> Console:
    """The rich console of stdout (or stderr), made on first use."""
    # The cache is the entry point's `cli._consoles`: tests replace it to make them again.
    from .. import cli

    consoles = cli._consoles
    if stderr not in consoles:
        from rich.console import Console

        console = Console(stderr=stderr)
        if not stderr and not console.is_terminal:
            # piped output and CI logs: room for the widest table (the study's, 123 columns)
            # with a few more digits in its timings on a busy machine, labels unwrapped
            console.width = 140
        consoles[stderr] = console
    return consoles[stderr]


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


def _check_positive(option: str, value: float | None, unit: str = "") -> None:
    """`option`: None (not given) or a finite number > 0, of `unit` (words for the message)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        _refuse(option, value, "must be a finite number > 0" + (f" {unit}" if unit else ""))


def _check_speed(speed: float) -> None:
    """`--speed`: a finite number of run seconds per wall second, > 0."""
    _check_positive("--speed", speed, "(run seconds per wall second)")


#: the latest wall time (epoch s, the year 2286) and the largest clock offset a node takes
MAX_EPOCH = 1e10


def _check_clock(start_at: float | None, clock_offset: float) -> None:
    """A node's --start-at (None, or a wall time) and --clock-offset, refused when beyond
    any clock."""
    if start_at is not None and not (math.isfinite(start_at) and 0 <= start_at <= MAX_EPOCH):
        _refuse("--start-at", start_at, f"must be a wall time in epoch seconds, 0 to "
                f"{MAX_EPOCH:g}")
    if not (math.isfinite(clock_offset) and abs(clock_offset) <= MAX_EPOCH):
        _refuse("--clock-offset", clock_offset, f"must be a finite number of seconds within "
                f"+-{MAX_EPOCH:g}")


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


def _last_error(log: Path, code: int | None) -> str:
    """Why a `tcaff` process whose output went to the file `log` ended with exit status `code`
    (None: stopped while still running): the last line `main` wrote as "error: ..." (a refusal,
    without that prefix), else its last line (a traceback's exception), else the status."""
    if code is None:
        return "still running when the run should have ended; stopped"
    try:
        with open(log, "rb") as file:  # its end only: a long run's log may be large
            file.seek(max(file.seek(0, os.SEEK_END) - 16384, 0))
            lines = [line.strip() for line in file.read().decode(errors="replace").splitlines()]
    except OSError:
        lines = []
    refusals = [line.removeprefix("error: ") for line in lines if line.startswith("error: ")]
    said = refusals or [line for line in lines if line]
    return said[-1] if said else f"exit status {code}, nothing written to {log}"


_RERUN_HELP = ("Also write a Rerun recording of the runs to this .rrd file (needs the extra viz); "
               "open it with `rerun FILE.rrd`.")


def _check_recording(path: Path | None) -> None:
    """Before any work: rerun-sdk is there and `path` can become a recording file."""
    if path is None:
        return
    from ..rerun_recording import check_rerun

    check_rerun()
    if path.is_dir():
        _refuse("--rerun", str(path), "is a folder, not a file")
    _writable_folder(path.parent, "--rerun")


def _record(path: Path | None, jobs: list) -> None:
    """The runs into a Rerun recording, when asked for and there are runs."""
    if path is None or not jobs:
        return
    from ..rerun_recording import record

    record(path, jobs)
    _console().print(f"recording: {path} (open it with: rerun {path})", soft_wrap=True)


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


def _cell(report: dict, key: str, scale: float = 1.0, digits: int = 2) -> str:
    value = report.get(key)
    return "-" if value is None else f"{scale * value:.{digits}f}"


def _nees_cell(report: dict) -> str:
    """Mean NEES (the share of estimates under the chi-square 95 % bound), "-" without a
    covariance; short however large, as a wrong alignment's NEES can be 1e6."""
    nees = report.get("nees_mean")
    if nees is None:
        return "-"
    mean = f"{nees:.2f}" if nees < 10 else f"{nees:.0f}" if nees < 1e4 else f"{nees:.0e}"
    return f"{mean} ({_cell(report, 'nees_under_95', 100, 0)} %)"


def _false_accept_cell(report: dict, digits: int = 1) -> str:
    """False accepts (the confident ones among them), percent of the estimates."""
    return (f"{_cell(report, 'false_accept', 100, digits)} "
            f"({_cell(report, 'confident_false_accept', 100, digits)}) %")


def _overlap_cell(report: dict) -> str:
    """Median seconds to a correct estimate per overlap (the share of overlaps that got one)."""
    return (f"{_cell(report, 'time_to_first_correct_per_overlap_s_median', digits=0)} "
            f"({_cell(report, 'overlaps_found', 100, 0)} %)")


#: what the alignment tables' newer columns mean, printed under the pooled table
TABLE_KEY = ("false acc. (conf.): estimates beyond the thresholds (and outside their own "
             "99.7 % ellipse, NEES > 14.16). NEES: mean e' P^-1 e with the covariance the "
             "method reported (share under the chi-square 95 % bound 7.81; - without one). "
             "1st correct per overlap: median seconds from an overlap's start to a correct "
             "estimate (share of overlaps that got one). perfect judge: the overlap steps at "
             "which a judge who knows the truth holds a correct one of TCAFF's candidates.")


def _judge_availability(reports: list[dict]) -> float | None:
    """The perfect judge's availability the reports carry (the same on every judged one)."""
    return next((r["judge_availability"] for r in reports
                 if r.get("judge_availability") is not None), None)


def _summary_table(summary: dict, methods: MethodsConfig) -> Group:
    """The study table of the methods a method set shows, labelled as in the figures, and the
    key to its columns under it."""
    from rich.console import Group
    from rich.text import Text

    from ..registry import describe, shown_streams

    table = _pooled_table(summary, {m: describe(m).label for m in shown_streams(methods)})
    return Group(table, Text(TABLE_KEY))


def _pooled_table(summary: dict, labels: dict[str, str]) -> Table:
    """summary: scenario -> method -> report; labels: method -> printed name, in table order.
    Under each scenario's methods, the perfect judge of its TCAFF candidates when one of them
    was judged."""
    from rich.markup import escape

    table = _table("Frame alignment, pooled over directed pairs and seeds (mean ± std)")
    # headers over two lines: one line of them would make the table wider than its numbers
    _add_columns(table, ("method", "translation\n[m]", "heading\n[deg]", "available",
                         "false acc.\n(conf.)", "NEES\n(<95 %)", "1st correct\nper overlap [s]",
                         "APE, RPE\n[m]", "ms"))
    for scenario, by_method in summary.items():
        table.add_row(f"[bold]{escape(scenario)}[/]")
        judge = _judge_availability([by_method[m] for m in labels])
        for row, (method, label) in enumerate(labels.items()):
            r = by_method[method]
            table.add_row(
                "  " + escape(label),
                f"{_cell(r, 'translation_error_m_mean')} ± {_cell(r, 'translation_error_m_std')}",
                f"{_cell(r, 'heading_error_deg_mean')} ± {_cell(r, 'heading_error_deg_std')}",
                f"{_cell(r, 'availability', 100, 0)} "
                f"({_cell(r, 'correct_availability', 100, 0)}) %",
                _false_accept_cell(r),
                _nees_cell(r),
                _overlap_cell(r),
                f"{_cell(r, 'ape_m')}, {_cell(r, 'rpe_m')}",
                _cell(r, "ms_per_pair_step", digits=2),
                end_section=judge is None and row == len(labels) - 1)
        if judge is not None:
            share = f"{100 * judge:.0f}"
            table.add_row("  perfect judge", "", "", f"{share} ({share}) %", end_section=True)
    return _keep_numbers_whole(table)
