"""Runners of the TCAFF methods: the default filter, the released code's preset, and the default
filter's output smoothed in one iSAM2 graph."""

from __future__ import annotations

import numpy as np

from tcaff_gtsam.geometry import se2_to_params
from tcaff_gtsam.graph import InterRobotGraph
from tcaff_gtsam.params import FrameAlignerParams, constant_alignment_covariance
from tcaff_gtsam.tcaff import TCAFF
from tcaff_gtsam.team import TeamConsistency

from ..config import MethodsConfig
from .stages import RunSetup, SharedStages

__all__ = ["GraphRunner", "ReferenceRunner", "TcaffRunner", "TeamRunner"]


class TcaffRunner:
    """`tcaff`: the default preset's estimate (the shared filter of `SharedStages.tcaff`)."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        self.n_pairs, self.stages = len(setup.pairs), stages
        self.estimates = {"tcaff": setup.empty()}
        self.covariances = {"tcaff": setup.empty_covariance()}
        self.step_streams, self.finish_streams = ["tcaff"], []

    def step(self, s: int, t: float) -> None:
        for p in range(self.n_pairs):
            est = self.stages.tcaff(p)[0]
            if est is not None:
                self.estimates["tcaff"][p, s] = est.x
                self.covariances["tcaff"][p, s] = est.P

    def finish(self) -> None:
        pass


class ReferenceRunner:
    """`tcaff_reference`: the released code's preset on every candidate (no residual check) of
    its minimum number of associations, each with the original's constant R."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        params = methods.tcaff_params(True, setup.run.settings.window)
        self.filters = [TCAFF(params) for _ in setup.pairs]
        self.stages = stages
        self.R = constant_alignment_covariance()
        self.min_associations = FrameAlignerParams.reference().min_associations
        self.estimates = {"tcaff_reference": setup.empty()}
        self.covariances = {"tcaff_reference": setup.empty_covariance()}
        self.step_streams, self.finish_streams = ["tcaff_reference"], []

    def step(self, s: int, t: float) -> None:
        for p, tcaff in enumerate(self.filters):
            found = [m for m in self.stages.candidates(p)
                     if len(m.associations) >= self.min_associations]
            zs = np.array([m.z for m in found]).reshape(-1, 3)
            est = tcaff.update(zs, np.broadcast_to(self.R, (len(found), 3, 3)))
            if est is not None:
                self.estimates["tcaff_reference"][p, s] = est.x
                self.covariances["tcaff_reference"][p, s] = est.P

    def finish(self) -> None:
        pass


class TeamRunner:
    """`tcaff_team`: the default TCAFF estimates of every pair, kept where they agree around
    cycles of three robots (`TeamConsistency`), chained through a third robot where a pair has
    none."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        self.team = TeamConsistency(setup.run.n_robots)
        self.pairs, self.stages = setup.pairs, stages
        self.estimates = {"tcaff_team": setup.empty()}
        self.covariances = {"tcaff_team": setup.empty_covariance()}
        self.step_streams, self.finish_streams = ["tcaff_team"], []

    def step(self, s: int, t: float) -> None:
        kept = self.team.update({pair: self.stages.tcaff(p)[0]
                                 for p, pair in enumerate(self.pairs)})
        for p, pair in enumerate(self.pairs):
            if pair in kept:
                self.estimates["tcaff_team"][p, s] = kept[pair].x
                self.covariances["tcaff_team"][p, s] = kept[pair].P

    def finish(self) -> None:
        pass


class GraphRunner:
    """`tcaff_isam2`: the default TCAFF output of one directed pair of each unordered pair in
    one iSAM2 graph ((i, j) with i < j when both are run: (j, i) aligns the same two maps, so
    its factors would count them twice). Causal: the graph's alignment at each step at which
    the pair's TCAFF has an estimate, factors link the two robots and no abandoned hypothesis
    of the pair waits for removal. Smoothed: once more at the end, when factors still link the
    two robots, the graph's alignment at every step from the pair's first TCAFF estimate to its
    last, gaps included (outside that span the graph would only extrapolate the drift). Each
    with the graph's covariance of the pair's (x, y, theta) at that step
    (`InterRobotGraph.alignment`: for a past step, the one it had as the latest)."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        settings = setup.run.settings
        self.graph = InterRobotGraph(setup.run.n_robots,
                                     methods.graph_params(settings.graph_drift))
        self.pairs, self.stages = setup.pairs, stages
        # one pair of each unordered pair gives the factors: (j, i) aligns the same two maps
        self.factored = [p for p, (i, j) in enumerate(self.pairs)
                         if i < j or (j, i) not in self.pairs]
        self.filtered = np.zeros((len(setup.pairs), setup.n_steps), dtype=bool)
        self.estimates = {"tcaff_isam2_causal": setup.empty(),
                          "tcaff_isam2_smoothed": setup.empty()}
        self.covariances = {"tcaff_isam2_causal": setup.empty_covariance(),
                            "tcaff_isam2_smoothed": setup.empty_covariance()}
        self.step_streams, self.finish_streams = ["tcaff_isam2_causal"], ["tcaff_isam2_smoothed"]

    def step(self, s: int, t: float) -> None:
        outputs = [self.stages.tcaff(p) for p in range(len(self.pairs))]
        for p in self.factored:
            i, j = self.pairs[p]
            # the filter's own estimate: the graph's cycle check weighs it against the
            # candidate it takes as a factor, which its twins do not widen
            _, zs, Rs = outputs[p]
            self.graph.add_tcaff_estimate(s, i, j, self.stages.filtered(p), zs, Rs)
        self.graph.update(s)
        causal = self.estimates["tcaff_isam2_causal"]
        for p, (est, _, _) in enumerate(outputs):
            self.filtered[p, s] = est is not None
            # Before its first factor a pair's graph alignment is only the gauge's guess; while
            # an abandoned hypothesis waits for removal it is a mixture of two.
            if (est is not None and self.graph.connected(*self.pairs[p])
                    and self.graph.settled(*self.pairs[p])):
                T, cov = self.graph.alignment(*self.pairs[p], s)
                causal[p, s] = se2_to_params(T)
                self.covariances["tcaff_isam2_causal"][p, s] = cov

    def finish(self) -> None:
        smoothed = self.estimates["tcaff_isam2_smoothed"]
        for p, pair in enumerate(self.pairs):
            held = np.flatnonzero(self.filtered[p])
            if held.size and self.graph.connected(*pair):
                steps, T = self.graph.alignment_history(*pair)
                span = (steps >= held[0]) & (steps <= held[-1])
                inside = steps[span]
                covs = np.array([self.graph.alignment(*pair, k)[1] for k in inside]
                                ).reshape(-1, 3, 3)  # none left in the graph's history: (0, 3, 3)
                # a step whose covariance the graph keeps from before the pair was linked
                # (`past_covariance="causal"`) has no alignment to report
                known = np.isfinite(covs).all(axis=(1, 2))
                smoothed[p, inside[known]] = se2_to_params(T[span][known])
                self.covariances["tcaff_isam2_smoothed"][p, inside[known]] = covs[known]
