"""The `tcaff` commands on saved results: view (a Rerun recording of the saved runs) and export
(their trajectories for evo and other tools).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .common import _console, app


@app.command()
def view(
    results: Annotated[Path, typer.Argument(
        help="A results folder: a study's (results/latest) or a data set's "
             "(results/mrclam/<name>).")],
    output: Annotated[Path | None, typer.Option(
        help="The recording to write (default: RESULTS/recording.rrd).")] = None,
    reference: Annotated[int, typer.Option(
        help="The robot (index) the other robots' maps are aligned to; runs without it "
             "are left out.")] = 0,
    method: Annotated[str | None, typer.Option(
        help="The method whose alignments are shown as accepted (default: tcaff).")] = None,
) -> None:
    """Make a Rerun recording of saved runs: maps, paths, alignments and errors over time.

    The world, each robot's map over time, the paths, the candidates, the accepted alignment
    and the truth on one timeline, and the errors over time.

    Needs the optional extra viz (pip install 'tcaff-gtsam\\[viz]'); open the file with
    `rerun FILE.rrd`. Runs saved before the maps were kept show no maps.
    """
    from ..rerun_recording import record
    from ..results import load_saved

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
        "--format", help="tum (one file per robot and method), g2o (one pose graph per "
                         "method) or rosbag2 (every pair's alignments and the truth as a ROS 2 "
                         "bag, MCAP; see docs/team.md#ros-2).")] = "tum",
    reference: Annotated[int, typer.Option(
        help="The robot (index) whose odometry frame the paths are expressed in; runs "
             "without it are left out (but for rosbag2, which holds every pair).")] = 0,
) -> None:
    """Write every saved run's trajectories for evo and other tools, under RESULTS/trajectories/.

    Each robot's path is placed in the reference robot's odometry frame through each method's
    alignments, and through the true alignment for the ground truth (truth/). Compare them
    with evo, e.g. `evo_ape tum truth/1.tum tcaff/1.tum` in a frame_<reference>/ folder: the
    APE column of the table is that figure for the pair reference -> 1.
    """
    from ..trajectories import export as export_trajectories

    folders = export_trajectories(results, fmt, reference)
    for folder in folders:
        _console().print(f"wrote {folder}", soft_wrap=True)
