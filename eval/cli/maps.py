"""The `tcaff` commands on object maps: align-maps (the candidate alignments of two saved
maps), make-maps (two simulated overlapping maps to try it on) and advise-kappa (how many
seconds of sightings a map may hold, from the odometry's drift), with the align-maps options'
check against the library's `FrameAlignerParams`, whose defaults are the options' defaults.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

# The align-maps defaults are the library's own; params needs numpy only.
from tcaff_gtsam.errors import DataError
from tcaff_gtsam.params import FrameAlignerParams

from .common import (
    _add_columns,
    _check_positive,
    _console,
    _keep_numbers_whole,
    _refuse,
    _table,
    _writable_folder,
    app,
)

if TYPE_CHECKING:
    from rich.table import Table

    from tcaff_gtsam.frame_aligner import AlignmentMeasurement

_ALIGNER = FrameAlignerParams()
#: most drives `advise-kappa` simulates (each a few seconds)
MAX_ADVICE_SEEDS = 100
#: how far `align-maps --now` may lie before the maps' latest `last_seen` (s): two robots'
#: clocks are a little out of step, but a time on another clock (or in other units) is not
NOW_TOLERANCE = 1.0


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


#: FrameAlignerParams fields (ClipperParams' seed) -> the align-maps option that sets them
_ALIGNER_OPTIONS = {"kappa": "--kappa", "dim": "--dim", "n_solutions": "--solutions",
                    "min_associations": "--min-associations", "covariance": "--covariance",
                    "seed": "--seed"}


def _aligner_params(kappa: float, dim: int, solutions: int, min_associations: int,
                    covariance: str, seed: int) -> FrameAlignerParams:
    from tcaff_gtsam.params import ParameterError

    try:
        # one registration, no filter after it: no inflation for repeated registrations
        return replace(_ALIGNER, kappa=kappa, dim=dim, n_solutions=solutions,
                       min_associations=min_associations, covariance=covariance,
                       clipper=replace(_ALIGNER.clipper, seed=seed), repeat_inflation=0.0)
    except ParameterError as exc:
        if exc.name == "max_associations":  # checked against --min-associations
            _refuse("--min-associations", min_associations,
                    f"must be at most {_ALIGNER.max_associations}")
        if exc.name not in _ALIGNER_OPTIONS:
            raise
        _refuse(_ALIGNER_OPTIONS[exc.name], exc.value, exc.rule)


@app.command("align-maps")
def align_maps(
    ego: Annotated[Path, typer.Argument(help="Ego robot's map (.npz from ObjectMap.save).")],
    other: Annotated[Path, typer.Argument(help="Other robot's map (.npz).")],
    now: Annotated[float | None, typer.Option(
        help="Current time (s); default: the latest last_seen in either map. On the maps' "
             f"clock: at most {NOW_TOLERANCE:g} s before that latest last_seen.")] = None,
    kappa: Annotated[float, typer.Option(
        help="Use objects seen less than kappa seconds ago.")] = _ALIGNER.kappa,
    dim: Annotated[int, typer.Option(help="Match 2D (x, y) or 3D centroids.")] = _ALIGNER.dim,
    solutions: Annotated[int, typer.Option(
        help="MNO-CLIPPER solutions N.")] = _ALIGNER.n_solutions,
    min_associations: Annotated[int, typer.Option(
        help="Fewest associations kept.")] = _ALIGNER.min_associations,
    covariance: Annotated[str, typer.Option(
        help="'calibrated' (the residuals pooled with a prior, and the map drift over "
             "kappa), 'residual' (the registration's alone) or 'constant' (the original's R).")
    ] = _ALIGNER.covariance,
    seed: Annotated[int, typer.Option(
        help="Seed of CLIPPER's start vector.")] = _ALIGNER.clipper.seed,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")
                       ] = False,
) -> None:
    """Print the candidate alignments T_oi_oj (other's odometry frame into the ego's).

    Each comes with its covariance; 'calibrated' gives that of this one registration (a
    filter that registers the same objects every step inflates it,
    `FrameAlignerParams.repeat_inflation`; here nothing follows)."""
    import json

    import numpy as np

    from tcaff_gtsam.frame_aligner import FrameAligner
    from tcaff_gtsam.object_map import ObjectMap

    if now is not None and not math.isfinite(now):
        _refuse("--now", now, "must be a finite number of seconds")
    params = _aligner_params(kappa, dim, solutions, min_associations, covariance, seed)
    ego_map, other_map = ObjectMap.load(ego), ObjectMap.load(other)
    stamps = np.r_[ego_map.last_seen, other_map.last_seen]
    latest = float(stamps.max()) if stamps.size else None
    if now is None:
        now = 0.0 if latest is None else latest
    elif latest is not None and now < latest - NOW_TOLERANCE:
        # every object would then count as just seen, whatever kappa says
        _refuse("--now", now, f"is {latest - now:.6g} s before the latest last_seen of the "
                f"maps ({latest:.6g} s): a time on their clock is at most "
                f"{NOW_TOLERANCE:g} s earlier")
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

    from ..sim.maps import MAX_OBJECTS, overlapping_maps

    for option, count, most in (("--objects", objects, MAX_OBJECTS),
                                ("--clutter", clutter, MAX_OBJECTS), ("--seed", seed, None)):
        if count < 0:
            _refuse(option, count, "must be an int >= 0")
        if most is not None and count > most:
            _refuse(option, count, f"the simulator makes at most {most} objects per map")
    if not (math.isfinite(overlap) and 0 <= overlap <= 1):
        _refuse("--overlap", overlap, "must be a share in [0, 1]")
    if not (math.isfinite(noise) and noise >= 0):
        _refuse("--noise", noise, "must be a finite number >= 0 metres")
    _writable_folder(out_dir, "OUT_DIR")
    for name in ("ego.npz", "other.npz", "truth.json"):
        if (out_dir / name).is_dir():
            _refuse("OUT_DIR", str(out_dir), f"holds a folder {name}, where the file goes",
                    DataError)
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
    seeds: Annotated[int, typer.Option(
        help=f"Drives (and drifts) to simulate, 1 to {MAX_ADVICE_SEEDS}.")] = 3,
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
    _check_positive("--epsilon", epsilon)
    if not (math.isfinite(minutes) and SPANS[-1] / 60.0 <= minutes <= 600.0):
        _refuse("--minutes", minutes, f"must be between {SPANS[-1] / 60.0:g} (the longest "
                "span tried) and 600")
    if not 1 <= seeds <= MAX_ADVICE_SEEDS:
        _refuse("--seeds", seeds, f"must be an int in [1, {MAX_ADVICE_SEEDS}]")
    if csv is not None:
        if csv.is_dir():
            _refuse("--csv", str(csv), "is a folder, not a file", DataError)
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
        try:
            np.savetxt(csv, np.column_stack([SPANS, *rms, worst]), delimiter=",",
                       header=header, comments="", fmt="%.6g")
        except OSError as exc:  # the table above is printed: only the file is lost
            _refuse("--csv", str(csv), f"could not be written ({exc.strerror or exc})",
                    DataError)
    if advice.kappa is None:
        console.print(f"kappa: no span keeps the maps within epsilon / 2 ({worst[0]:.3f} m "
                      f"at {SPANS[0]:g} s already): the maps disagree with themselves; better "
                      f"odometry or a wider epsilon is needed")
    elif advice.kappa == SPANS[-1]:  # the longest span tried: longer ones may do as well
        console.print(f"kappa: {advice.kappa:g} s or more (the longest span tried; "
                      f"FrameAlignerParams(kappa=...) and MapperParams(kappa=...))")
    else:
        console.print(f"kappa: {advice.kappa:g} s (FrameAlignerParams(kappa=...) and "
                      f"MapperParams(kappa=...))")
