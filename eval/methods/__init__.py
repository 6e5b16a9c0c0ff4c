"""The compared methods: one runner per method behind one protocol, a registry keyed by name.

A method set (`MethodsConfig.methods`) names methods; each method produces one or more estimate
streams (T_oi_oj of every directed pair at every exchange), named and drawn as `METHODS` says:

- tcaff: the paper's filter (default preset) on MNO-CLIPPER candidates.
- tcaff_reference: the authors' released settings on the same candidates, without this project's
  residual check and with the original's constant R.
- tcaff_team: the TCAFF estimates of every pair that agree around cycles of three robots,
  and chains through a third robot for pairs without one (`tcaff_gtsam.TeamConsistency`).
- tcaff_isam2 -> tcaff_isam2_causal, tcaff_isam2_smoothed: the TCAFF output of every pair
  (i, j) with i < j in one iSAM2 graph ((j, i) aligns the same two maps), read for every
  directed pair at each step (causal) and once more at the end (smoothed), at the steps that
  pair's TCAFF has an estimate and the graph links the two robots.
- clipper -> clipper_k<k>: single-shot CLIPPER accepting a solution of at least k associations,
  one stream per k of `clipper_k`.
- icp: ICP on centroids from the true initial alignment.
- ground_truth: the true alignment (a check on the evaluation itself).

The MNO-CLIPPER candidates and the default TCAFF filter are computed once per pair and step
(`stages.SharedStages`) and handed to every runner that wants them. Adding a method means a
runner class (see `MethodRunner`) and one `Method` entry in `registry.METHODS`. Runners are
imported when a run needs them.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from tcaff_gtsam.errors import ConfigError

from ..registry import METHODS, Estimate, Method, describe, estimate_names

if TYPE_CHECKING:
    from ..config import MethodsConfig
    from ..runs import AlignmentRun

__all__ = ["METHODS", "Estimate", "Method", "MethodRunner", "MethodRuns", "describe",
           "estimate_names", "run_methods"]


class MethodRunner(Protocol):
    """One method over every directed pair of a run, one exchange at a time.

    Built as `Runner(setup, stages, methods)` (`stages.RunSetup`, `stages.SharedStages`, the
    method set). `estimates` maps each of its streams to a (P, S, 3) array of (x, y, theta) of
    T_oi_oj, NaN rows where it has no estimate, filled by `step` (and `finish`);
    `covariances` maps each of its streams that reports one to the (P, S, 3, 3) covariance of
    those three numbers, NaN where there is no estimate (a stream left out has none: its NEES
    is undefined). The run charges the time of `step` to the streams in `step_streams` and
    that of `finish` to `finish_streams`, less the shared stages' time.
    """

    estimates: dict[str, np.ndarray]
    covariances: dict[str, np.ndarray]
    step_streams: list[str]
    finish_streams: list[str]

    def step(self, s: int, t: float) -> None:
        """Estimate every pair at exchange s (time t, s)."""
        ...

    def finish(self) -> None:
        """After the last exchange (smoothing)."""
        ...


@dataclass
class MethodRuns:
    """What every method estimated over one run.

    Attributes:
        pairs: the directed pairs (i, j), i the ego robot.
        truth: (P, S, 3) the true (x, y, theta) of T_oi_oj (NaN where unknown).
        estimates: stream name -> (P, S, 3) (x, y, theta) of T_oi_oj; NaN rows where the
            method had no estimate.
        candidates: per pair, (steps (M,), z (M, 3)): every candidate the TCAFF filter saw.
        seconds: stream name (and shared stage, "candidates") -> compute time over the run.
        covariances: stream name -> (P, S, 3, 3) covariance of each estimate's (x, y, theta),
            NaN where there is none; only the streams whose method reports one.
    """

    pairs: list[tuple[int, int]]
    truth: np.ndarray
    estimates: dict[str, np.ndarray]
    candidates: list[tuple[np.ndarray, np.ndarray]]
    seconds: dict[str, float] = field(default_factory=dict)
    covariances: dict[str, np.ndarray] = field(default_factory=dict)


def _runner_class(name: str) -> type:
    module, cls = METHODS[name].runner.split(":")
    return getattr(importlib.import_module(f"{__name__}.{module}"), cls)


def run_methods(run: AlignmentRun, methods: MethodsConfig,
                progress: Callable[[float], None] | None = None) -> MethodRuns:
    """Every method of the set over every directed pair of the run, all advancing together one
    exchange at a time on the same maps.

    Args:
        run: a simulated (`SimRun`) or recorded (`RecordedRun`) run.
        progress: called after each step with the share of steps done.
    Raises:
        ConfigError: a method needs the truth at every step and the run does not have it.
    """
    from .stages import RunSetup, SharedStages, warm_up

    setup = RunSetup.of(run)
    needs_truth = [m for m in methods.methods if METHODS[m].needs_truth]
    if needs_truth and not setup.known.all():
        raise ConfigError(f"methods {sorted(needs_truth)} need the true alignment at every "
                          f"step, which this run does not have")
    warm_up()  # numba compiles on first use: keep it out of every method's time
    stages = SharedStages(setup, methods)
    runners: list[MethodRunner] = [_runner_class(m)(setup, stages, methods)
                                   for m in methods.methods]
    seconds = dict.fromkeys(["candidates", *estimate_names(methods)], 0.0)

    def timed(call: Callable[[], None], streams: list[str]) -> None:
        before, start = stages.seconds_total(), time.perf_counter()
        call()
        own = time.perf_counter() - start - (stages.seconds_total() - before)
        for stream in streams:
            seconds[stream] += own

    n_steps = len(run.times)
    for s, t in enumerate(run.times):
        stages.begin(s, float(t))
        for runner in runners:
            timed(lambda r=runner, s=s, t=float(t): r.step(s, t), runner.step_streams)
        if progress is not None:
            progress((s + 1) / n_steps)
    for runner in runners:
        timed(runner.finish, runner.finish_streams)
    seconds["candidates"] += stages.seconds["candidates"]
    # the default filter's time: TCAFF's own, or the graph's when TCAFF is not run by itself
    for stream in ("tcaff", "tcaff_team", "tcaff_isam2_causal"):
        if stream in seconds:
            seconds[stream] += stages.seconds["tcaff"]
            break
    estimates = {stream: est for r in runners for stream, est in r.estimates.items()}
    covariances = {stream: cov for r in runners for stream, cov in r.covariances.items()}
    return MethodRuns(setup.pairs, setup.truth, estimates, stages.candidate_history(), seconds,
                      covariances)
