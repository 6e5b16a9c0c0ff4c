"""What `tcaff team` makes of its output folder: the table of a team run (each directed
pair's alignments, or team alignments, against the truth), and the previous run's files set
aside before a new run."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from tcaff_gtsam.errors import DataError

from .common import _add_columns, _keep_numbers_whole, _refuse, _table

if TYPE_CHECKING:
    from rich.table import Table


def _team_table(run, output: Path, names: tuple[str, ...], team: bool = False) -> Table:
    """Per directed pair: alignments made, accepted share, final and median error (the team
    alignments of `<robot>.team.csv` when `team`, with the share chained through a robot)."""
    import numpy as np
    from tcaff_gtsam.node.results import COLUMNS, TEAM_COLUMNS, read_alignments

    from tcaff_gtsam.geometry import se2_to_params, wrap_angle

    table = _table("Per directed pair: the team-consistent alignments against the truth" if team
                   else "Per directed pair: the node's alignments against the truth")
    _add_columns(table, ("pair", "steps", "accepted", *(("chained",) if team else ()),
                         "median error [m, deg]", "last error [m, deg]"))
    foreign: list[str] = []
    for i, robot in enumerate(names):
        path = output / (f"{robot}.team.csv" if team else f"{robot}.csv")
        try:
            rows = read_alignments(path, TEAM_COLUMNS if team else COLUMNS)
        except DataError:
            continue
        seq_all = rows["seq"]
        if seq_all.size and not 0 <= seq_all.min() <= seq_all.max() < len(run.times):
            foreign.append(path.name)  # exchanges this run does not have: another run's rows
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
    notes = []
    late = {"dropped_stale": 0, "silent_steps": 0}
    for robot in () if team else names:  # the nodes' counters, of their own alignments
        path = output / f"{robot}.json"
        counters = json.loads(path.read_text()) if path.exists() else {}
        for key in late:
            late[key] += counters.get(key, 0)
    if any(late.values()):
        notes.append(f"{late['dropped_stale']} maps came too late and {late['silent_steps']} "
                     f"steps had no neighbour's map: the team fell behind its schedule (try a "
                     f"lower --speed) or lost maps")
    if foreign:
        notes.append(f"left out {', '.join(foreign)}: exchanges beyond this run's "
                     f"{len(run.times)} (another run's rows)")
    table.caption = "; ".join(notes) or None
    return _keep_numbers_whole(table)


#: what a team run leaves in its --output folder, by folder (the Kimera maps in maps/ are
#: kept: a later run with the same settings reuses them)
_RUN_FILES = {".": re.compile(r"r\d+(\.team)?\.csv|r\d+\.json"),
              "logs": re.compile(r"node\d+\.log"), "replay": re.compile(r"r\d+\.npz")}


def _set_aside_previous_run(output: Path) -> int:
    """Move a previous team run's files from `output` into `output/previous/` (replacing the
    run files an earlier run left there; nothing else in it is touched): a node appends to
    its CSV, to carry on after a restart, so a new run into the folder would add to the old
    one's rows. Returns how many were moved.

    Raises:
        DataError: `previous` is there but is no folder (a file, a link), or a file cannot be
            moved; what was moved before stays there, the rest where it was.
    """
    def run_files(root: Path) -> list[Path]:
        return [path for folder, name in _RUN_FILES.items() if (root / folder).is_dir()
                for path in sorted((root / folder).iterdir())
                if name.fullmatch(path.name) and path.is_file()]

    old = run_files(output)
    if not old:
        return 0
    previous = output / "previous"
    if previous.is_symlink() or (previous.exists() and not previous.is_dir()):
        _refuse("--output", str(output), f"holds {previous}, which is no folder: the previous "
                "run's results are moved there", DataError)
    try:
        for path in run_files(previous):
            path.unlink()
        for path in old:
            moved = previous / path.relative_to(output)
            moved.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(path, moved)
    except OSError as exc:
        _refuse("--output", str(output), f"the previous run's results could not be moved to "
                f"{previous} ({exc})", DataError)
    return len(old)
