"""The `tcaff` command line."""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from tcaff_gtsam.errors import TcaffError
from tcaff_gtsam.frame_aligner import AlignmentMeasurement, FrameAligner
from tcaff_gtsam.geometry import compose, invert, se2_to_params
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.params import ClipperParams, FrameAlignerParams

from .sim.maps import MapPair, grid_maps, overlapping_maps

app = typer.Typer(
    help="Align the coordinate frames of robots from their object maps (TCAFF).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()
if not console.is_terminal:
    console.width = 120  # piped output and CI logs: do not squeeze tables into 80 columns
err_console = Console(stderr=True)


def _alignment_error(T_true: np.ndarray, T_est: np.ndarray) -> tuple[float, float]:
    """(translation error [m], heading error [deg]) of T_true^-1 T_est."""
    dx, dy, dtheta = se2_to_params(compose(invert(T_true), T_est))
    return math.hypot(dx, dy), abs(math.degrees(dtheta))


def _candidates_table(title: str, candidates: list[AlignmentMeasurement],
                      T_true: np.ndarray | None = None) -> Table:
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD)
    for name in ("#", "x [m]", "y [m]", "theta [deg]", "assoc", "score", "rmse [m]",
                 "sd [m, deg]"):
        table.add_column(escape(name), justify="right")
    if T_true is not None:
        table.add_column(escape("error [m, deg]"), justify="right")
        table.add_column("verdict")
    for rank, meas in enumerate(candidates, start=1):
        x, y, theta = meas.z
        sd = np.sqrt(np.diag(meas.R))
        row = [str(rank), f"{x:.2f}", f"{y:.2f}", f"{math.degrees(theta):.1f}",
               str(len(meas.associations)), f"{meas.score:.2f}", f"{meas.rmse:.3f}",
               f"{max(sd[0], sd[1]):.2f}, {math.degrees(sd[2]):.1f}"]
        if T_true is not None:
            dt, dtheta = _alignment_error(T_true, meas.T)
            correct = dt <= 1.0 and dtheta <= 5.0
            row += [f"{dt:.2f}, {dtheta:.1f}",
                    "[green]correct[/]" if correct else "[red]wrong[/]"]
        table.add_row(*row)
    return table


def _aligner_params(kappa: float, dim: int, solutions: int, min_associations: int,
                    covariance: str, seed: int) -> FrameAlignerParams:
    return FrameAlignerParams(kappa=kappa, dim=dim, n_solutions=solutions,
                              min_associations=min_associations, covariance=covariance,
                              clipper=ClipperParams(seed=seed))


@app.command("align-maps")
def align_maps(
    ego: Annotated[Path, typer.Argument(help="Ego robot's map (.npz from ObjectMap.save).")],
    other: Annotated[Path, typer.Argument(help="Other robot's map (.npz).")],
    now: Annotated[float | None, typer.Option(
        help="Current time [s]; default: the latest last_seen in either map.")] = None,
    kappa: Annotated[float, typer.Option(help="Use objects seen less than kappa s ago.")] = 20.0,
    dim: Annotated[int, typer.Option(help="Match 2D (x, y) or 3D centroids.")] = 2,
    solutions: Annotated[int, typer.Option(help="MNO-CLIPPER solutions N.")] = 4,
    min_associations: Annotated[int, typer.Option(help="Fewest associations kept.")] = 5,
    covariance: Annotated[str, typer.Option(
        help="'constant' (the original's R) or 'residual' (from the registration).")
    ] = "constant",
    seed: Annotated[int, typer.Option(help="Seed of CLIPPER's start vector.")] = 0,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")
                       ] = False,
) -> None:
    """Print the candidate alignments T_oi_oj (other's odometry frame into the ego's)."""
    ego_map, other_map = ObjectMap.load(ego), ObjectMap.load(other)
    if now is None:
        stamps = np.r_[ego_map.last_seen, other_map.last_seen]
        now = float(stamps.max()) if stamps.size else 0.0
    aligner = FrameAligner(_aligner_params(kappa, dim, solutions, min_associations, covariance,
                                           seed))
    candidates = aligner.measurements(ego_map, other_map, now)
    if as_json:
        print(json.dumps([{"x": m.z[0], "y": m.z[1], "theta": m.z[2], "R": m.R.tolist(),
                           "associations": m.associations.tolist(), "score": m.score,
                           "rmse": m.rmse} for m in candidates], indent=2))
        return
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
    noise: Annotated[float, typer.Option(help="Centroid noise per axis [m].")] = 0.1,
    clutter: Annotated[int, typer.Option(help="Spurious objects per map.")] = 10,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Write two simulated overlapping maps with a known alignment, for trying align-maps."""
    pair = overlapping_maps(np.random.default_rng(seed), objects, overlap, noise,
                            clutter=clutter)
    out_dir.mkdir(parents=True, exist_ok=True)
    pair.ego.save(out_dir / "ego.npz")
    pair.other.save(out_dir / "other.npz")
    x, y, theta = se2_to_params(pair.T_oi_oj)
    (out_dir / "truth.json").write_text(json.dumps(
        {"T_oi_oj": {"x": x, "y": y, "theta": theta}, "now": pair.now}, indent=2))
    console.print(f"wrote {out_dir}/ego.npz, other.npz and truth.json "
                  f"(true x={x:.2f} m, y={y:.2f} m, theta={math.degrees(theta):.1f} deg)")


def _demo_case(title: str, pair: MapPair, aligner: FrameAligner) -> None:
    start = time.perf_counter()
    candidates = aligner.measurements(pair.ego, pair.other, pair.now)
    elapsed_ms = 1e3 * (time.perf_counter() - start)
    x, y, theta = se2_to_params(pair.T_oi_oj)
    console.print(f"\n[bold]{title}[/]: {len(pair.ego)} and {len(pair.other)} objects, "
                  f"{len(pair.true_pairs)} shared; truth x={x:.2f} m, y={y:.2f} m, "
                  f"theta={math.degrees(theta):.1f} deg; aligned in {elapsed_ms:.1f} ms")
    if candidates:
        console.print(_candidates_table("candidates", candidates, pair.T_oi_oj))
    else:
        console.print("no candidate alignment")


@app.command()
def demo(seed: Annotated[int, typer.Option(help="Random seed.")] = 0) -> None:
    """Align simulated map pairs with known truth and show the candidates against it."""
    aligner = FrameAligner()
    aligner.measurements(*_warmup_maps())
    rng = np.random.default_rng(seed)
    _demo_case("Overlapping maps with clutter", overlapping_maps(
        rng, 40, 0.6, 0.1, clutter=10), aligner)
    _demo_case("Little overlap", overlapping_maps(rng, 40, 0.2, 0.1, clutter=10), aligner)
    _demo_case("No overlap (every candidate is wrong)",
               overlapping_maps(rng, 40, 0.0, 0.1, clutter=10), aligner)
    _demo_case("Ambiguous grid of identical objects (needs temporal consistency)",
               grid_maps(2, 4), aligner)


def _warmup_maps() -> tuple[ObjectMap, ObjectMap, float]:
    """A small map pair that compiles the solver before anything is timed."""
    pair = overlapping_maps(np.random.default_rng(1), 12, 1.0, 0.05)
    return pair.ego, pair.other, pair.now


def main() -> None:
    """Console entry point: library errors become a one-line message and exit status 2."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        app()
    except TcaffError as exc:
        err_console.print(f"[red]error:[/] {escape(str(exc))}", soft_wrap=True)
        raise SystemExit(2) from None
