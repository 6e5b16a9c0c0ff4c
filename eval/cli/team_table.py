"""The table `tcaff team` prints of a team run: each directed pair's alignments (or team
alignments) against the truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from .common import _add_columns, _keep_numbers_whole, _table

if TYPE_CHECKING:
    from rich.table import Table


def _team_table(run, output: Path, names: tuple[str, ...], team: bool = False) -> Table:
    """Per directed pair: alignments made, accepted share, final and median error (the team
    alignments of `<robot>.team.csv` when `team`, with the share chained through a robot)."""
    import numpy as np
    from tcaff_gtsam.node.results import COLUMNS, TEAM_COLUMNS, read_alignments

    from tcaff_gtsam.errors import DataError
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
    late = {"dropped_stale": 0, "silent_steps": 0}
    for robot in names:
        path = output / f"{robot}.json"
        counters = json.loads(path.read_text()) if path.exists() else {}
        for key in late:
            late[key] += counters.get(key, 0)
    notes = []
    if any(late.values()) and not team:
        notes.append(f"{late['dropped_stale']} maps came too late and {late['silent_steps']} "
                     f"steps had no neighbour's map: the team fell behind its schedule (try a "
                     f"lower --speed) or lost maps")
    if foreign:
        notes.append(f"left out {', '.join(foreign)}: exchanges beyond this run's "
                     f"{len(run.times)} (another run's rows)")
    table.caption = "; ".join(notes) or None
    return _keep_numbers_whole(table)
