"""The study's figures (matplotlib, PNG).

- leave_and_return.png: the paper's figure: x, y and theta of T_oi_oj over time, MNO-CLIPPER
  candidates as dots, the ground truth and the TCAFF estimate (of indoor_return, or of the first
  scenario when the study has no indoor_return).
- errors_<scenario>.png: translation and heading error over time, one line per method.
- clipper_sweep.png: single-shot CLIPPER's false-accept share, availability and error against its
  association threshold k, with TCAFF as a reference line.
- scenarios.png: each world's objects and the robots' true paths.
- mot_<scenario>.png (scenarios with people): the paper's figure: MOTA over a rolling window,
  averaged over the robots, above the frame alignment error averaged over the directed pairs,
  with the single-shot CLIPPER threshold that tracked best.
- mot_sweep.png: MOTA against single-shot CLIPPER's threshold k, the other methods as
  horizontal lines.

A recorded data set draws errors_<i>_<j>.png, candidates_<i>_<j>.png and arena.png
(`draw_recorded`); RGB-D sequences also top_view_<i>_<j>.png (`top_view`): both maps from
above under the truth and under the estimate.

A sweep (see `sweep`) draws tradeoff.png and response_<parameter>.png (`draw_sweep`).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; never open a window

import matplotlib.pyplot as plt
import numpy as np

from tcaff_gtsam.geometry import se2_from_params, wrap_angle

from .config import MethodsConfig
from .metrics import step_errors
from .mot import NO_SHARING, rolling_mota
from .registry import Estimate, describe, shown_streams

__all__ = ["draw_all", "draw_sweep", "label", "top_view"]

#: the tracking baseline, which is not an alignment method
_NO_SHARING = Estimate("no sharing", "0.5", ":")


def _estimate(method: str) -> Estimate:
    return _NO_SHARING if method == NO_SHARING else describe(method)


def label(method: str) -> str:
    """An estimate stream's name as printed in tables and legends."""
    return _estimate(method).label


def _style(method: str) -> tuple[str, str]:
    estimate = _estimate(method)
    return estimate.color, estimate.line


def _title(job) -> str:
    return job.name if job.seed is None else f"{job.name} (seed {job.seed})"


def _shade_overlap(ax, times: np.ndarray, overlap: np.ndarray | None, pair: int) -> None:
    """Grey bands where the maps of a pair overlap enough for an alignment (none when the run
    does not know)."""
    if overlap is None:
        return
    edges = np.flatnonzero(np.diff(np.r_[0, overlap[pair].astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(times[start] - 0.5, times[stop - 1] + 0.5, color="0.92", lw=0, zorder=0)


def leave_and_return(path: Path, job, pair: int = 0) -> None:
    """x, y, theta of T_oi_oj: candidates, ground truth, TCAFF estimate."""
    a = job.arrays
    times, truth = a["times"], a["truth"][pair].copy()
    est = a["est_tcaff"][pair].copy() if "est_tcaff" in a else None
    steps, z = a[f"cand_steps_{pair}"], a[f"cand_z_{pair}"].copy()
    # draw headings on the truth's unwrapped branch, so nothing jumps at +-180 degrees
    truth[:, 2] = np.unwrap(truth[:, 2])
    z[:, 2] = truth[steps, 2] + wrap_angle(z[:, 2] - truth[steps, 2])
    if est is not None:
        est[:, 2] = truth[:, 2] + wrap_angle(est[:, 2] - truth[:, 2])
    i, j = job.pairs[pair]
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    scale = (1.0, 1.0, 180 / np.pi)
    for k, (ax, name) in enumerate(zip(axes, ("x [m]", "y [m]", "theta [deg]"), strict=True)):
        _shade_overlap(ax, times, job.arrays.get("overlap"), pair)
        ax.plot(times[steps], z[:, k] * scale[k], ".", color="tab:blue", ms=3,
                label="MNO-CLIPPER candidates")
        ax.plot(times, truth[:, k] * scale[k], color="tab:green", lw=2, label="ground truth")
        if est is not None:
            ax.plot(times, est[:, k] * scale[k], color="tab:red", lw=1.5, label="TCAFF")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
        # wide enough to show wrong candidates, narrow enough to read the truth's drift
        lo, hi = np.nanmin(truth[:, k] * scale[k]), np.nanmax(truth[:, k] * scale[k])
        pad = max(hi - lo, 6.0 if k < 2 else 60.0)
        ax.set_ylim(lo - pad, hi + pad)
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[0].set_title(f"{_title(job)}: T_o{i}_o{j}; grey = maps overlap")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def errors_over_time(path: Path, job, methods: list[str], pair: int = 0) -> None:
    """Translation and heading error of each method over time for one pair."""
    a = job.arrays
    times = a["times"]
    T_true = se2_from_params(a["truth"][pair])
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for ax in axes:
        _shade_overlap(ax, times, job.arrays.get("overlap"), pair)
    for method in methods:
        err = step_errors(T_true, a[f"est_{method}"][pair])
        color, line = _style(method)
        axes[0].plot(times, err[:, 0], line, color=color, lw=1.3, label=label(method))
        axes[1].plot(times, np.degrees(err[:, 1]), line, color=color, lw=1.3)
    i, j = job.pairs[pair]
    axes[0].set_ylabel("translation error [m]")
    axes[1].set_ylabel("heading error [deg]")
    for ax in axes:
        ax.set_yscale("symlog", linthresh=0.1)
        ax.grid(alpha=0.3)
    if methods:  # none when the study ran only the ground truth, which is not drawn
        axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[0].set_title(f"{_title(job)}: error of T_o{i}_o{j}; gaps = no "
                      f"estimate; grey = maps overlap")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def clipper_sweep(path: Path, summary: dict, methods: MethodsConfig) -> None:
    """Single-shot CLIPPER against its threshold k, TCAFF as horizontal lines."""
    ks = methods.clipper_k
    panels = (("false_accept", "false-accept share"), ("availability", "availability"),
              ("translation_error_m_mean", "mean translation error [m]"))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, (scenario, by_method) in enumerate(summary.items()):
        color = colors[c % len(colors)]
        for ax, (key, name) in zip(axes, panels, strict=True):
            values = [by_method[f"clipper_k{k}"][key] for k in ks]
            ax.plot(ks, [np.nan if v is None else v for v in values], "o-", color=color,
                    ms=4, label=scenario)
            tcaff = by_method.get("tcaff", {}).get(key)
            if tcaff is not None:
                ax.axhline(tcaff, color=color, ls="--", lw=1)
            ax.set_title(name)
            ax.set_xlabel("k: fewest associations accepted")
            ax.grid(alpha=0.3)
    axes[2].set_yscale("log")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=len(summary),
               fontsize=8, title="solid: single-shot CLIPPER; dashed: TCAFF", title_fontsize=8)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def mot_over_time(path: Path, job, methods: list[str], window: float) -> None:
    """Rolling MOTA (robot average) above the alignment error (average over directed pairs
    with an estimate) of each method over time."""
    a = job.arrays
    T_true = se2_from_params(a["truth"])
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True,
                             gridspec_kw={"height_ratios": (2, 1, 1)})
    for method in methods:
        color, line = _style(method)
        rolling = rolling_mota(a["mot_times"], a[f"mot_counts_{method}"], window)
        err = (np.array([step_errors(T, est) for T, est in
                         zip(T_true, a[f"est_{method}"], strict=True)])
               if method != NO_SHARING else None)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # frames or steps with no value
            mota = np.nanmean(rolling, axis=0)  # over the robots
            mean = None if err is None else np.nanmean(err, axis=0)  # over the pairs
        axes[0].plot(a["mot_times"], mota, line, color=color, lw=1.3, label=label(method))
        if mean is None:
            continue
        axes[1].plot(a["times"], mean[:, 0], line, color=color, lw=1.3)
        axes[2].plot(a["times"], np.degrees(mean[:, 1]), line, color=color, lw=1.3)
    axes[0].set_ylabel(f"MOTA, last {window:g} s")
    axes[0].set_ylim(max(axes[0].get_ylim()[0], -1.0), 1.0)
    axes[1].set_ylabel("translation error [m]")
    axes[2].set_ylabel("heading error [deg]")
    for ax in axes[1:]:
        ax.set_yscale("symlog", linthresh=0.1)
        ax.set_ylim(bottom=0.0)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower right", fontsize=8, ncol=3)
    axes[0].set_title(f"{_title(job)}: MOTA averaged over the robots, "
                      f"alignment error over the pairs with an estimate", fontsize=10)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def mot_sweep(path: Path, mot_summary: dict, methods: MethodsConfig) -> None:
    """MOTA of single-shot CLIPPER against its threshold k; the other methods as lines."""
    ks = methods.clipper_k
    fig, axes = plt.subplots(1, len(mot_summary), figsize=(6 * len(mot_summary), 4.2),
                             squeeze=False)
    for ax, (scenario, by_method) in zip(axes[0], mot_summary.items(), strict=True):
        if all(f"clipper_k{k}" in by_method for k in ks):
            reports = [by_method[f"clipper_k{k}"] for k in ks]
            ax.errorbar(ks, [_none_nan(r["mota"]) for r in reports],
                        yerr=[_none_nan(r["mota_std"]) for r in reports], fmt="o-",
                        color=describe(f"clipper_k{ks[0]}").color, ms=4, capsize=3,
                        label="single-shot CLIPPER")
        for method, report in by_method.items():
            if method.startswith("clipper_k") or report["mota"] is None:
                continue
            color, line = _style(method)
            ax.axhline(report["mota"], color=color, ls=line if line != "-" else "--", lw=1.3,
                       label=f"{label(method)} {report['mota']:.3f}")
        ax.set_title(f"{scenario}: MOTA (mean over seeds, bars: std)", fontsize=10)
        ax.set_xlabel("k: fewest associations accepted")
        ax.set_ylabel("MOTA")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _none_nan(value: float | None) -> float:
    return np.nan if value is None else value


def top_view(path: Path, job, pair: int, stream: str = "tcaff") -> None:
    """Both robots' maps of one exchange from above, in the ego robot's odometry frame: the
    other map moved by the true alignment (left) and by the estimate (right). The exchange is
    the last one at which `stream` has an estimate (the last exchange when it never has one).
    Circles are sized by object width; ego objects blue, the other robot's red."""
    a = job.arrays
    i, j = job.pairs[pair]
    estimate = a[f"est_{stream}"][pair] if f"est_{stream}" in a else None
    has = np.zeros(len(a["times"]), bool) if estimate is None else ~np.isnan(estimate[:, 0])
    s = int(np.flatnonzero(has)[-1]) if has.any() else len(a["times"]) - 1

    def objects(r: int) -> tuple[np.ndarray, np.ndarray]:
        counts = a[f"map_counts_{r}"].astype(np.int64)
        start = int(counts[:s].sum())
        part = slice(start, start + int(counts[s]))
        return a[f"map_xy_{r}"][part].astype(float), a[f"map_widths_{r}"][part].astype(float)

    ego_xy, ego_w = objects(i)
    other_xy, other_w = objects(j)
    panels = [("truth", a["truth"][pair][s])]
    if has[s]:
        panels.append((label(stream), estimate[s]))
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    shown = []
    for ax, (title, z) in zip(axes, panels, strict=False):
        T = se2_from_params(z)
        moved = other_xy @ T[:2, :2].T + T[:2, 2]
        for xy, w, color, who in ((ego_xy, ego_w, "tab:blue", f"robot {i}"),
                                  (moved, other_w, "tab:red", f"robot {j}")):
            ax.scatter(xy[:, 0], xy[:, 1], s=400 * w**2 + 8, facecolors="none",
                       edgecolors=color, lw=1.2, label=f"{who} ({len(xy)})")
        err = step_errors(se2_from_params(a["truth"][pair][s:s + 1]), np.asarray(z)[None])[0]
        ax.set_title(f"{title}: {err[0]:.2f} m, {math.degrees(err[1]):.1f} deg off the truth"
                     if title != "truth" else "under the true alignment", fontsize=10)
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
        ax.set_xlabel(f"x in o{i} [m]")
        shown.append(np.vstack([ego_xy, moved]))
    if shown and np.concatenate(shown).size:  # one view in both panels, to compare them
        every = np.concatenate(shown)
        lo, hi = every.min(axis=0) - 0.5, every.max(axis=0) + 0.5
        for ax in axes:
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
    if len(panels) == 1:
        axes[1].text(0.5, 0.5, f"{label(stream)}: no estimate", ha="center", va="center",
                     transform=axes[1].transAxes)
    axes[0].set_ylabel(f"y in o{i} [m]")
    fig.suptitle(f"{_title(job)}: maps of exchange {s + 1} (t = {a['times'][s]:.0f} s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def scenarios_overview(path: Path, first: list) -> None:
    """Each scenario's objects (sized by width), walls and true robot paths, from one job of
    each scenario."""
    n = len(first)
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 4.5 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.axis("off")
    for ax, job in zip(axes.flat, first, strict=False):
        a = job.arrays
        for wall in a["walls"]:
            ax.plot(wall[:, 0], wall[:, 1], color="0.3", lw=2)
        ax.scatter(a["world_xy"][:, 0], a["world_xy"][:, 1], s=20 * a["world_widths"] ** 2 + 4,
                   color="0.55", marker="s", label="objects")
        for r, poses in enumerate(a["poses_true"]):
            # earlier robots drawn wider, so shared paths stay visible
            ax.plot(poses[:, 0], poses[:, 1], lw=3.0 - 0.6 * r, alpha=0.8, label=f"robot {r}")
            ax.plot(*poses[0, :2], "o", color=ax.lines[-1].get_color(), ms=5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(job.name, fontsize=10)
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def draw_all(folder: Path, jobs: list, summary: dict, methods: MethodsConfig,
             mot_summary: dict | None = None) -> list[Path]:
    """Every figure of a study into `folder`; returns the files written."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    shown = [m for m in shown_streams(methods) if m != "ground_truth"]
    first = {}
    for job in jobs:
        first.setdefault(job.name, job)
    return_job = first.get("indoor_return", next(iter(first.values())))
    if "est_tcaff" in return_job.arrays:
        leave_and_return(folder / "leave_and_return.png", return_job)
        written.append(folder / "leave_and_return.png")
    for scenario, job in first.items():
        path = folder / f"errors_{scenario}.png"
        errors_over_time(path, job, shown)
        written.append(path)
    if "clipper" in methods.methods:
        clipper_sweep(folder / "clipper_sweep.png", summary, methods)
        written.append(folder / "clipper_sweep.png")
    scenarios_overview(folder / "scenarios.png", list(first.values()))
    written.append(folder / "scenarios.png")
    for scenario, job in first.items():
        if job.mot:
            # as in the paper, the CLIPPER threshold with the best tracking
            sweep = {m: r["mota"] for m, r in (mot_summary or {}).get(scenario, {}).items()
                     if m.startswith("clipper_k") and r["mota"] is not None}
            tracked = [m for m in (NO_SHARING, "ground_truth", "tcaff", "tcaff_isam2_causal",
                                   "icp") if m in job.mot]
            path = folder / f"mot_{scenario}.png"
            mot_over_time(path, job, tracked + ([max(sweep, key=sweep.get)] if sweep else []),
                          float(job.arrays["mot_window"]))
            written.append(path)
    if mot_summary:
        mot_sweep(folder / "mot_sweep.png", mot_summary, methods)
        written.append(folder / "mot_sweep.png")
    return written


def draw_recorded(folder: Path, job, shown: list[str]) -> list[Path]:
    """A recorded run's figures into `folder`: every pair's errors over time (`shown` methods)
    and candidates against the truth, and the arena when the job has its objects."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for p, (i, j) in enumerate(job.pairs):
        written.append(folder / f"errors_{i}_{j}.png")
        errors_over_time(written[-1], job, shown, p)
        if f"cand_z_{p}" in job.arrays and "est_tcaff" in job.arrays:
            written.append(folder / f"candidates_{i}_{j}.png")
            leave_and_return(written[-1], job, p)
    if "world_xy" in job.arrays:
        written.append(folder / "arena.png")
        scenarios_overview(written[-1], [job])
    return written


# -- sweeps --------------------------------------------------------------------------------------

#: the metrics a sweep's response figure shows: report key, axis label, scale
_RESPONSES = (("false_accept", "false accepts [%]", 100.0),
              ("availability", "availability [%]", 100.0),
              ("translation_error_m_mean", "translation error [m]", 1.0),
              ("time_to_first_correct_s", "first correct [s]", 1.0))
_MAX_LINES = 8  # other parameters' combinations drawn as lines; more are averaged


def _short(path: str) -> str:
    return path.rsplit(".", 1)[-1]


def _axis(values: list) -> tuple[np.ndarray, list[str] | None]:
    """Positions of a parameter's values on an axis: the numbers themselves, or (anything
    else: None, strings, booleans) evenly spaced, with tick labels."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return np.asarray(values, dtype=float), None
    return np.arange(len(values), dtype=float), [str(v) for v in values]


def draw_sweep(folder: Path, points: list, reports: list[dict], parameters: list[str],
               method_label: str) -> list[Path]:
    """A sweep's figures: tradeoff.png (false accepts against availability, one dot per point
    labelled with its number, the default as a star, the points no other beats on both as a
    line) and response_<parameter>.png (each metric against the parameter's values, a line per
    combination of the other parameters, or their mean when there are many; the default as a
    dotted level).

    Args:
        points: the sweep's `SweepPoint`s.
        reports: per point, the pooled report of the shown method ({} when none finished).
    Returns:
        The files written.
    """
    folder.mkdir(parents=True, exist_ok=True)
    done = [(n, p, r) for n, (p, r) in enumerate(zip(points, reports, strict=True)) if r]
    if not done:
        return []
    written = [folder / "tradeoff.png"]
    _tradeoff(written[0], done, method_label)
    default = next((r for _, p, r in done if p.default), None)
    grid = [(p, r) for _, p, r in done if p.settings]
    for path in parameters:
        if grid:
            written.append(folder / f"response_{_short(path)}.png")
            _response(written[-1], grid, default, path, parameters, method_label)
    return written


def _tradeoff(path: Path, done: list, method_label: str) -> None:
    avail = np.array([_none_nan(r.get("availability")) for _, _, r in done]) * 100
    false = np.array([_none_nan(r.get("false_accept")) for _, _, r in done]) * 100
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    ok = np.isfinite(avail) & np.isfinite(false)
    # the front: no other point has more availability and fewer false accepts
    front = [k for k in np.flatnonzero(ok) if not np.any(
        ok & (avail >= avail[k]) & (false <= false[k]) & ((avail > avail[k]) | (false < false[k])))]
    front.sort(key=lambda k: avail[k])
    if len(front) > 1:
        ax.plot(avail[front], false[front], "-", color="0.6", lw=1, zorder=1,
                label="not beaten on both")
    labels: dict[tuple[float, float], list[str]] = {}  # points that land on one spot share it
    for k, (number, point, _) in enumerate(done):
        if not ok[k]:
            continue
        if point.default:
            ax.plot(avail[k], false[k], "*", color="tab:red", ms=16, zorder=3, label="default")
        else:
            ax.plot(avail[k], false[k], "o", color="tab:blue", ms=6, zorder=2)
        labels.setdefault((round(avail[k], 6), round(false[k], 6)), []).append(str(number))
    for (a, f), numbers in labels.items():
        ax.annotate(",".join(numbers), (a, f), textcoords="offset points", xytext=(4, 4),
                    fontsize=8, color="0.3")
    ax.set_ylim(bottom=0, top=max(1.0, 1.15 * np.nanmax(false, initial=0.0)))
    ax.set_xlabel("availability [%] (overlap steps with an estimate)")
    ax.set_ylabel("false accepts [%] (estimates beyond the thresholds)")
    ax.set_title(f"{method_label}: one dot per parameter point (numbered as in sweep.csv), "
                 f"pooled over scenarios, seeds and pairs", fontsize=9)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:  # nothing to label when no point has both figures
        ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mean_or_nan(values: list[float]) -> float:
    """Mean of the finite values; NaN, without numpy's empty-slice warning, when none is."""
    array = np.asarray(values, dtype=float)
    finite = array[np.isfinite(array)]
    return float(finite.mean()) if finite.size else math.nan


def _response(path: Path, grid: list, default: dict | None, parameter: str,
              parameters: list[str], method_label: str) -> None:
    values = list({repr(p.values[parameter]): p.values[parameter] for p, _ in grid}.values())
    x, ticks = _axis(values)
    position = {repr(v): x[k] for k, v in enumerate(values)}
    others = [p for p in parameters if p != parameter]
    lines: dict[str, list] = {}
    for point, report in grid:
        key = ", ".join(f"{_short(o)}={point.values[o]}" for o in others)
        lines.setdefault(key, []).append((position[repr(point.values[parameter])], report))
    if len(lines) > _MAX_LINES:
        lines = {f"mean over {len(lines)} combinations of the others":
                 [item for items in lines.values() for item in items]}
    fig, axes = plt.subplots(len(_RESPONSES), 1, figsize=(7.5, 2.2 * len(_RESPONSES)),
                             sharex=True)
    for ax, (key, name, scale) in zip(axes, _RESPONSES, strict=True):
        for label_, items in lines.items():
            xs = np.array(sorted({x_ for x_, _ in items}))
            ys = [_mean_or_nan([_none_nan(r.get(key)) * scale for x_, r in items if x_ == v])
                  for v in xs]
            ax.plot(xs, ys, "o-", ms=4, lw=1.2, label=label_ or method_label)
        if default is not None and default.get(key) is not None:
            ax.axhline(default[key] * scale, color="tab:red", ls=":", lw=1.2, label="default")
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(bottom=0)
    if ticks is not None:
        axes[-1].set_xticks(x, ticks)
    axes[-1].set_xlabel(parameter)
    axes[0].legend(fontsize=7, loc="best")
    axes[0].set_title(f"{method_label} against {parameter}, pooled over scenarios, seeds and "
                      f"pairs", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
