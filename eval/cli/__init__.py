"""The `tcaff` command line: its entry point `main`.

Building the app loads typer and the aligner's parameter defaults (numpy) only; every command
imports what it uses (gtsam, Open3D, numba, matplotlib, the study), so `tcaff --help` is instant.
The `app` and the helpers the commands share are in common; the commands, by subject, in
maps (align-maps, make-maps, advise-kappa), studies (study, demo, sweep), data
(kimera-multi, mrclam, rgbd), results (view, export) and team (node, team, listen).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import typer

# isort: off
# Importing a command module registers its commands on `app`; this order is the order of
# `tcaff --help`.
from . import common, maps, studies, data, results, team  # noqa: F401
# isort: on

# Re-exported: the names tests and other callers use as `cli.<name>`.
from .common import (  # noqa: F401
    _CONFIG_DIR,
    _console,
    _nees_cell,
    _pooled_table,
    _summary_table,
    app,
)
from .data import _parse_pairs, _parse_ranges  # noqa: F401
from .maps import _aligner_params  # noqa: F401

if TYPE_CHECKING:
    from rich.console import Console

#: the consoles `_console` made, by stderr (tests replace it to make them again)
_consoles: dict[bool, Console] = {}


def _click_errors() -> tuple[type, type]:
    """(UsageError, ClickException) of the click that typer runs on: its own copy in recent
    typer releases, the click package in older ones."""
    bases = {c.__name__: c for c in typer.BadParameter.__mro__}
    return bases["UsageError"], bases["ClickException"]


#: the characters str.splitlines breaks lines at
_LINE_BREAKS = frozenset("\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029")


def main() -> None:
    """Console entry point: library errors and bad options or arguments become a one-line
    message and exit status 2."""
    import logging
    import time

    from rich.markup import escape

    from tcaff_gtsam.errors import TcaffError

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    usage_error, click_exception = _click_errors()

    def refuse(message: str, code: int = 2) -> None:
        # one line whatever the message quotes (a file name may hold any line break)
        message = "".join(repr(c)[1:-1] if c in _LINE_BREAKS else c for c in message)
        _console(stderr=True).print(f"[red]error:[/] {escape(message)}", soft_wrap=True)
        raise SystemExit(code) from None

    common._command_started = time.perf_counter()
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
    finally:
        common._command_started = None
    raise SystemExit(code if isinstance(code, int) else 0)
