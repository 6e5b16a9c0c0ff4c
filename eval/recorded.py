"""Recorded data sets: a run from a loader in `datasets/`, every method over every directed pair,
scored where the data set has the truth, written to one folder.

Results of a data set `name` go to `<output>/<name>/`:
- `<name>.npz` / `.json`: every method's estimate of every pair at every exchange (`JobResult`);
- `metrics.json`, `metrics.csv`, `table.md` (the paper's table: mean +- std translation and
  heading error, availability), when there is truth;
- `figures/errors_<i>_<j>.png`, when there is truth and figures are asked for.
A loader may keep its own files there too (Kimera-Multi: `maps/`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import KimeraMultiConfig, MethodsConfig
from .datasets import kimera_multi
from .jobs import evaluate
from .methods import METHODS, describe, estimate_names
from .results import JobResult, summarize, thresholds_of, write_tables
from .runs import RecordedRun, planar_poses

__all__ = ["KimeraOutcome", "RecordedOutcome", "evaluate_recorded", "run_kimera_multi"]


@dataclass
class RecordedOutcome:
    """What the evaluation of a recorded run produced.

    Attributes:
        folder: where the results are.
        job: every method's estimates (and metrics, with truth).
        summary: estimate stream -> pooled report ({} without truth).
        methods: the method set that ran (without the methods that need the truth, when the
            run has none).
    """

    folder: Path
    job: JobResult
    summary: dict[str, dict]
    methods: MethodsConfig


def evaluate_recorded(run: RecordedRun, methods: MethodsConfig, folder: Path,
                      figures: bool = True, header: dict | None = None,
                      progress: Callable[[float], None] | None = None) -> RecordedOutcome:
    """Every method over every directed pair of a recorded run; results into `folder`.

    Without truth for every robot, the methods that need it are left out and nothing is scored;
    the estimates are still written.

    Args:
        header: extra entries of metrics.json (the data set's own facts).
    """
    if not run.has_truth:
        kept = [m for m in methods.methods if not METHODS[m].needs_truth]
        methods = methods.model_copy(update={"methods": kept})
    T_world_body = run.T_world_odom @ run.T_odom_body
    job = evaluate(run, methods, run.name, None, {
        "times": run.times - run.times[0], "t0": np.array(run.times[0]),
        "poses_true": planar_poses(T_world_body), "poses_odom": planar_poses(run.T_odom_body),
    }, progress)
    folder.mkdir(parents=True, exist_ok=True)
    job.save(folder)
    summary: dict[str, dict] = {}
    if job.metrics:
        summary = summarize([job], estimate_names(methods), thresholds_of(methods))[run.name]
        write_tables(folder, {"name": run.name, "robots": list(run.robot_names),
                              **(header or {})}, [job], {run.name: summary})
        _write_markdown(folder / "table.md", run.name, summary)
        if figures:
            from . import plots

            shown = [m for m in estimate_names(methods) if m in (
                "tcaff", "tcaff_isam2_smoothed", f"clipper_k{methods.clipper_k_shown}")]
            (folder / "figures").mkdir(exist_ok=True)
            for p, (i, j) in enumerate(job.pairs):
                plots.errors_over_time(folder / "figures" / f"errors_{i}_{j}.png", job, shown, p)
    return RecordedOutcome(folder, job, summary, methods)


def _write_markdown(path: Path, name: str, summary: dict[str, dict]) -> None:
    """The paper's table: mean +- std translation and heading error, and availability."""
    lines = [f"| {name} | translation error [m] | heading error [deg] | available |",
             "|---|---|---|---|"]
    for method, r in summary.items():
        if r["translation_error_m_mean"] is None:
            cells = ["-", "-"]
        else:
            cells = [f"{r['translation_error_m_mean']:.2f} +- {r['translation_error_m_std']:.2f}",
                     f"{r['heading_error_deg_mean']:.2f} +- {r['heading_error_deg_std']:.2f}"]
        available = "-" if r["availability"] is None else f"{100 * r['availability']:.0f} %"
        lines.append(f"| {describe(method).label} | {cells[0]} | {cells[1]} | {available} |")
    path.write_text("\n".join(lines) + "\n")


# -- Kimera-Multi ------------------------------------------------------------------------------


class KimeraProgress(kimera_multi.KimeraProgress):
    """The loader's hooks, and the alignment's."""

    def aligning(self, share: float) -> None: ...


@dataclass
class KimeraOutcome:
    """What a Kimera-Multi run produced.

    Attributes:
        folder: where the results are.
        mappings: the robots mapped (also those of an earlier run that were reused).
        reused: robots whose saved maps were reused.
        recorded: the evaluation (None when mapping failed).
    """

    folder: Path
    mappings: list[kimera_multi.RobotMapping] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    recorded: RecordedOutcome | None = None


def run_kimera_multi(config: KimeraMultiConfig, data: Path, output: Path,
                     resume: bool = True, figures: bool = True,
                     progress: KimeraProgress | None = None) -> KimeraOutcome:
    """Map every robot (reusing saved maps when `resume`), align, score, write the results to
    `<output>/<test name>/`.

    Raises:
        DataError: a robot's data cannot be read. The robots mapped before it are saved.
    """
    progress = progress or KimeraProgress()
    folder = Path(output) / config.name
    run, mappings, reused = kimera_multi.load_run(config, data, folder / "maps", resume,
                                                  progress)
    methods = config.methods
    assert isinstance(methods, MethodsConfig)
    header = {"frames_per_second": {m.robot: m.frames_per_second for m in mappings}}
    recorded = evaluate_recorded(run, methods, folder, figures, header, progress.aligning)
    return KimeraOutcome(folder, mappings, reused, recorded)
