"""The `tcaff` commands that evaluate on recorded data sets: kimera-multi (Kimera-Multi
rosbags), mrclam (the UTIAS MRCLAM data sets) and rgbd (7-Scenes and TUM RGB-D sequences), with
the parsing of their --pairs and --robots options, the Kimera-Multi progress bars (which
`tcaff node` and `tcaff team` use too) and the per-pair and per-stream tables they print.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from .common import (
    _RERUN_HELP,
    _add_columns,
    _bars,
    _cell,
    _check_duration,
    _check_positive,
    _check_recording,
    _check_seeds,
    _console,
    _false_accept_cell,
    _judge_availability,
    _keep_numbers_whole,
    _nees_cell,
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


def _kimera_bars(bars: RichProgress):
    from rich.markup import escape

    from ..dataset_runs import KimeraProgress

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
        help="Results go to OUTPUT/<test name>/; an earlier run's to OUTPUT/previous/.")
    ] = Path("results/kimera_multi"),
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

    _check_duration(duration)
    _check_recording(rerun)
    _writable_folder(output, "--output")
    from tcaff_gtsam.errors import TcaffError

    from ..config import load_kimera_multi, load_methods
    from ..dataset_runs import run_kimera_multi

    console, err_console = _console(), _console(stderr=True)
    test = load_kimera_multi(config)
    if duration is not None:
        test = test.model_copy(update={"duration": duration})
    if methods is not None:
        test = test.model_copy(update={"methods": load_methods(methods)})
    console.print(f"Kimera-Multi test [bold]{escape(test.name)}[/]: robots "
                  f"{', '.join(test.robots)}; data {data}")
    start, began = time.perf_counter(), time.time()
    try:
        with _bars() as bars:
            outcome = run_kimera_multi(test, data, output, resume, figures, _kimera_bars(bars))
    except TcaffError:
        maps = output / test.name / "maps"
        # only what this run mapped: older maps say nothing about it
        saved = (sorted(p.stem for p in maps.glob("*.npz") if p.stat().st_mtime >= began)
                 if maps.is_dir() else [])
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
    console.print(f"results: {outcome.folder} ({_since_start(start):.0f} s)")
    _record(rerun, [recorded.job])


def _whole(text: str) -> bool:
    """Whether `text` (spaces aside) is a whole number of ASCII digits (str.isdigit also takes
    superscripts, which int() refuses)."""
    text = text.strip()
    return text.isascii() and text.isdigit()


def _parse_pairs(text: str | None) -> list[tuple[int, int]] | None:
    """`--pairs 1:2,2:1` as directed pairs of robot subjects."""
    from tcaff_gtsam.errors import ConfigError

    if text is None:
        return None
    pairs = []
    for token in text.split(","):
        parts = token.strip().split(":")
        if len(parts) != 2 or not all(_whole(p) for p in parts):
            raise ConfigError(f"--pairs {text!r}: expected robot pairs like 1:2,2:1, got "
                              f"{token.strip()!r}")
        pairs.append((int(parts[0]), int(parts[1])))
    return pairs


def _pairs_table(recorded, shown: list[str]) -> Table:
    """Per directed pair: each shown method's false accepts and availability, and the perfect
    judge's availability (of TCAFF's candidates) when a shown method was judged."""
    from ..registry import describe

    table = _table("Per directed pair (robot names as in the data set): false accepts / "
                   "availability")
    judged = any(_judge_availability([r]) is not None
                 for m in shown for r in recorded.job.metrics[m].values())
    _add_columns(table, ("pair", "overlap [s]", *(describe(m).label for m in shown),
                         *(["perfect judge"] if judged else [])))
    names = recorded.job.info.get("robots") or []
    for i, j in recorded.job.pairs:
        label = f"{i}->{j}" if not names else f"{names[i]}->{names[j]}"
        reports = [recorded.job.metrics[method][f"{i}->{j}"] for method in shown]
        cells = [f"{_cell(r, 'false_accept', 100, 0)} % / {_cell(r, 'availability', 100, 0)} %"
                 for r in reports]
        if judged:
            judge = _judge_availability(reports)
            cells.append("-" if judge is None else f"{100 * judge:.0f} %")
        table.add_row(label, str(reports[0]["n_overlap"]), *cells)
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
        help="Results go to OUTPUT/<set>-<odometry>[-seed<s>]/; those a run replaces to "
             "OUTPUT/previous/.")] = Path("results/mrclam"),
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

    _check_duration(duration)
    _check_positive("--kappa", kappa, "(s)")
    _check_recording(rerun)
    seeds = _check_seeds(seed)
    _writable_folder(output, "--output")
    from ..config import load_methods, load_mrclam, override
    from ..dataset_runs import run_mrclam

    console = _console()
    settings = override(load_mrclam(config), "command line", duration=duration, kappa=kappa,
                        methods=None if methods is None else load_methods(methods))
    odometries = odometry or [settings.odometry]
    bad = [o for o in odometries if o not in ("raw", "vio")]
    if bad:
        from tcaff_gtsam.errors import ConfigError

        raise ConfigError(f"--odometry {bad[0]!r}: expected raw or vio")
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
            from ..registry import describe, shown_streams

            shown = [m for m in shown_streams(recorded.methods)
                     if describe(m).causal and m != "ground_truth"]
            if shown:
                console.print(_pairs_table(recorded, shown))
        console.print(f"results: {recorded.folder}")
    console.print(f"({_since_start(start):.0f} s)")
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
        ok = len(parts) == 2 and all(p.strip() == "" or _whole(p) for p in parts)
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
    _add_columns(table, ("method", "estimates", "false acc.\n(conf.)", "false acc.\n(tight)",
                         "NEES\n(<95 %)", "available", "median\n[m]", "median\n[deg]"))
    for stream, r in outcome.report.items():
        def share(key: str, r=r) -> str:
            return "-" if r[key] is None else f"{100 * r[key]:.1f} %"

        def number(key: str, digits: int, r=r) -> str:
            return "-" if r[key] is None else f"{r[key]:.{digits}f}"

        table.add_row(labels.get(stream, stream), str(r["estimates"]), _false_accept_cell(r),
                      share("false_accept_tight"), _nees_cell(r),
                      share("availability_from_first"), number("median_translation_m", 3),
                      number("median_heading_deg", 2))
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
        help="7-Scenes frames per second, 1 to 1000 (its files hold no time stamps).")
    ] = 30.0,
    config: Annotated[str, typer.Option(
        help=f"An RGB-D evaluation YAML, or a shipped one: {_shipped('rgbd')}.")
    ] = "default",
    methods: Annotated[str | None, typer.Option(
        help=f"Method set: a YAML path or a shipped name ({_shipped('methods')}).")] = None,
    output: Annotated[Path, typer.Option(
        help="Results go to OUTPUT/<sequence>[-<ranges>][-<rate>hz][-back]-<odometry>"
             "[-seed<s>]/ (ranges unless the default ones); those a run replaces to "
             "OUTPUT/previous/.")
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

    _check_recording(rerun)
    _check_positive("--rate", rate, "frames per second")
    if not (math.isfinite(fps) and 1.0 <= fps <= 1000.0):
        # below one frame a second most 1 Hz exchanges would see no new frame: a slip
        _refuse("--fps", fps, "must be between 1 and 1000 frames per second")
    seeds = _check_seeds(seed)
    import numpy as np
    from rich.markup import escape

    from tcaff_gtsam.errors import ConfigError

    from ..config import load_methods, load_rgbd, override
    from ..dataset_runs import run_rgbd
    from ..datasets.rgbd_robots import halves, walk
    from ..datasets.rgbd_sequence import read_sequence
    from ..registry import describe

    console = _console()
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
    console.print(f"({_since_start(start_time):.0f} s)")
    _record(rerun, [outcome.recorded.job for outcome in outcomes])
