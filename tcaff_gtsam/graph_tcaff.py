"""How `InterRobotGraph` takes a TCAFF filter's output: the candidate each step's estimate took
becomes an alignment factor tagged with its hypothesis, the factors of a hypothesis the
filter switched away from are removed once the new one has held (`GraphParams.switch_hold`),
and those of a hypothesis that the other pairs' estimates contradict around cycles of three
robots are held out of the graph while they do (`GraphParams.cycle_check`)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import DataError
from .geometry import _chi2_quantile
from .graph_inputs import _ROBOT_SHIFT, _check_cov, _check_index, _Factor
from .inputs import real_array, shown
from .tcaff import AlignmentEstimate
from .team import TeamConsistency

__all__ = ["HypothesisFactors"]

log = logging.getLogger(__name__)

_AGREE_CHI2 = _chi2_quantile(0.999, 3)


@dataclass
class _Abandoned:
    """A hypothesis TCAFF switched away from, whose factors wait for the new one to hold.

    Attributes:
        hypothesis: its tag; x (3,), P (3, 3): the graph's alignment of the pair when it was
            abandoned; held: steps the hypotheses after it have been reported.
    """

    hypothesis: int
    x: np.ndarray
    P: np.ndarray
    held: int = 0


@dataclass
class _Suspended:
    """A pair's hypothesis the cycle check left out: its factors, held out of the graph.

    Attributes:
        hypothesis: its tag; factors: its alignment factors of the steps still in the graph
            (`_marginalise` drops those of steps that leave), weighed as their update weighed
            them (committed then, or held out at their commit).
    """

    hypothesis: int
    factors: list[_Factor]


def _copied_switches(hypothesis: dict, abandoned: dict, suspended: dict
                     ) -> tuple[dict, dict, dict]:
    """What a failed update restores, as the last update that succeeded left it: copies of
    each pair's reported hypothesis and its abandoned one (`_Abandoned`, copied too: its
    `held` count goes on in the graph), so that a switch whose removal it dropped is still
    pending; and each held-out hypothesis (`_Suspended`) with the length of its factor list,
    which only grows within an update, so that one `remove_hypothesis` took out since comes
    back with what it held."""
    return (dict(hypothesis), {pair: replace(a) for pair, a in abandoned.items()},
            {pair: (held_out, len(held_out.factors)) for pair, held_out in suspended.items()})


class HypothesisFactors:
    """The part of `InterRobotGraph` that takes TCAFF's hypotheses (mixed into it; it uses the
    graph's own attributes)."""

    def remove_hypothesis(self, i: int, j: int, hypothesis: int) -> int:
        """Queue the removal of every factor tagged with (i, j, hypothesis); returns how many.

        Raises:
            DataError: unknown robot.
        """
        self._check_robot("i", i)
        self._check_robot("j", j)

        def tagged(f: _Factor) -> bool:
            return f.tag is not None and f.tag[0] != "free" and f.tag[1:] == (i, j, hypothesis)

        found = self._take_out(tagged)
        queued = len(self._queued)  # factors still waiting are dropped from the queue
        self._queued = [q for q in self._queued if not tagged(q)]
        held_out = self._suspended.get((i, j))
        suspended = 0
        if held_out is not None and held_out.hypothesis == hypothesis:
            suspended = len(self._suspended.pop((i, j)).factors)
        return len(found) + queued - len(self._queued) + suspended

    def add_tcaff_estimate(self, step: int, i: int, j: int,
                           estimate: AlignmentEstimate | None, zs, Rs) -> None:
        """Feed one step of a TCAFF filter for the pair (i, j).

        The factor is the candidate TCAFF's best path took at this step (zs[m], Rs[m] with
        m = estimate.measurement), not the filtered estimate: consecutive filtered estimates
        share their past measurements and would count them many times over.

        A main tree dropped for want of measurements is no evidence against it, so its factors
        stay. When the filter next reports a different hypothesis (after a drop, or by
        switching), the earlier hypothesis's factors are kept if the new estimate agrees with
        the graph's current alignment of the pair (squared Mahalanobis distance under the sum
        of both covariances within the chi-square 0.999 quantile). Otherwise they are removed
        once the new hypothesis has been reported at `switch_hold` steps; a switch back before
        then removes the short-lived hypothesis's factors instead, and a switch to a third one
        removes the one in between.

        With `GraphParams.cycle_check`, the next `update` tests the estimates given since the
        last one around every cycle of three robots (`TeamConsistency`). The factors of a
        hypothesis it leaves out, those committed and those to come, are held out of the
        graph until a later update's test does not leave it out (those whose step left the
        horizon meanwhile are dropped); the pair's alignment is then read through the others.

        Args:
            estimate: what `TCAFF.update(zs, Rs)` returned for this step (of a
                `PairwiseAligner`, its `filter.estimate`: the estimate `update` returns may
                cover the twins of a map that fits itself, `twins.Twins`, which the cycle
                check would then let through with the candidate's own R).
            zs: (k, 3) the candidates given to TCAFF; Rs: (k, 3, 3) their covariances.
        """
        if not self._planar:
            raise DataError("add_tcaff_estimate: TCAFF estimates are (x, y, theta); use a "
                            "planar graph (GraphParams(dim=2))")
        self._check_robot("i", i)
        self._check_robot("j", j)
        if i == j:
            raise DataError(f"add_tcaff_estimate: i and j are both {i}")
        if estimate is None:
            return
        if not isinstance(estimate, AlignmentEstimate):
            raise DataError(f"add_tcaff_estimate: estimate must be an AlignmentEstimate or "
                            f"None, got {shown(estimate)}")
        step = _check_index("add_tcaff_estimate: step", step, _ROBOT_SHIFT)
        if self._given_step is not None and step != self._given_step:
            # the cycle check tests one step's estimates, and a failed update restores the
            # switches as they were before that step's
            raise DataError(f"add_tcaff_estimate: step {step}, but the estimates given since "
                            f"the last update are of step {self._given_step}; update first")
        x = np.asarray(estimate.x)
        if not (x.shape == (3,) and np.isfinite(x).all()):
            raise DataError(f"add_tcaff_estimate: estimate needs a finite x (3,), got x = "
                            f"{shown(estimate.x)}")
        # the cycle check solves with it: a singular P is refused here, not deep in an update
        _check_cov("add_tcaff_estimate: estimate.P", estimate.P, 3)
        for name in ("measurement", "hypothesis"):
            value = getattr(estimate, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
                raise DataError(f"add_tcaff_estimate: estimate.{name} must be an int, got "
                                f"{shown(value)}")
        if estimate.measurement >= 0:
            zs = real_array("add_tcaff_estimate", "zs", zs)
            Rs = real_array("add_tcaff_estimate", "Rs", Rs)
            if not (zs.ndim == 2 and zs.shape[1:] == (3,) and Rs.shape == (len(zs), 3, 3)
                    and estimate.measurement < len(zs)):
                raise DataError(f"add_tcaff_estimate: estimate.measurement = "
                                f"{estimate.measurement} must index zs (k, 3) and Rs (k, 3, 3), "
                                f"got shapes {zs.shape} and {Rs.shape}")
        if estimate.measurement >= 0:  # first: what it refuses leaves the graph as it was
            m = estimate.measurement
            self.add_alignment(step, i, j, zs[m], Rs[m], hypothesis=estimate.hypothesis)
        pair = (int(i), int(j))
        self._given[pair], self._given_step = estimate, step
        previous = self._hypothesis.get(pair)
        current = estimate.hypothesis
        waiting = self._abandoned.get(pair)
        if previous is not None and previous != current:
            if waiting is not None and self._agrees(estimate, waiting.x, waiting.P):
                # back to the abandoned alignment before the hold ended: the short-lived
                # hypothesis goes, and TCAFF's new id for the old alignment continues it
                self.remove_hypothesis(i, j, previous)
                del self._abandoned[pair]
                waiting = None
            elif self._steps and self._agrees(estimate, *self._latest(i, j)):
                log.debug("pair (%d, %d): hypothesis %s agrees with %s, factors kept", i, j,
                          current, previous)
            elif waiting is not None:  # a third alignment: the one in between goes now
                self.remove_hypothesis(i, j, previous)
                waiting.held = 0
            elif self._steps:
                waiting = self._abandoned[pair] = _Abandoned(previous,
                                                              *self._latest(i, j))
        self._hypothesis[pair] = current
        if waiting is not None:
            waiting.held += 1
            if waiting.held >= self.params.switch_hold:
                removed = self.remove_hypothesis(i, j, waiting.hypothesis)
                log.debug("pair (%d, %d): hypothesis %s abandoned, %d factors removed", i, j,
                          waiting.hypothesis, removed)
                del self._abandoned[pair]

    def _cycle_checked(self, queued: list[_Factor]) -> tuple[list[_Factor], list[_Factor]]:
        """Apply the cycle check to the estimates given since the last update
        (`GraphParams.cycle_check`).

        Queues the removal of the committed factors of hypotheses it leaves out. Args: queued,
        the factors this update commits, already weighed (`shared_maps`). Returns them without
        those of held-out hypotheses (kept aside), and the kept-aside factors of hypotheses it
        keeps again, to be committed as they were weighed.
        """
        given, self._given, self._given_step = self._given, {}, None
        if not self.params.cycle_check or (len(given) < 3 and not self._suspended):
            return queued, []
        # the robots of this step's estimates, numbered from 0: a team of only those
        robots = sorted({r for pair in given for r in pair})
        rejected: set[tuple[int, int]] = set()
        if 3 <= len(robots) <= TeamConsistency.MAX_ROBOTS:
            number = {r: n for n, r in enumerate(robots)}
            # checked when they were given (add_tcaff_estimate)
            checked = {(number[i], number[j]): (np.asarray(e.x, dtype=float),
                                                np.asarray(e.P, dtype=float))
                       for (i, j), e in given.items()}
            rejected = {(robots[a], robots[b])
                        for a, b in TeamConsistency(len(robots))._rejected(checked)}
        restored: list[_Factor] = []
        for pair, estimate in given.items():
            held_out = self._suspended.get(pair)
            undirected = (min(pair), max(pair))
            if held_out is not None and held_out.hypothesis != estimate.hypothesis:
                del self._suspended[pair]  # the filter left that hypothesis: it stays out
                held_out = None
            if undirected in rejected and held_out is None:
                tag = ("alignment", *pair, estimate.hypothesis)
                self._suspended[pair] = _Suspended(estimate.hypothesis,
                                                   self._take_out(lambda f, tag=tag: f.tag == tag))
            elif undirected not in rejected and held_out is not None:
                del self._suspended[pair]
                restored.extend(held_out.factors)
        if not self._suspended:
            return queued, restored
        kept = []
        for q in queued:  # factors of held-out hypotheses committed now: aside too
            held_out = (self._suspended.get(q.tag[1:3])
                        if q.tag is not None and q.tag[0] == "alignment" else None)
            if held_out is not None and q.tag[3] == held_out.hypothesis:
                held_out.factors.append(q)
            else:
                kept.append(q)
        return kept, restored

    def _take_out(self, tagged) -> list[_Factor]:
        """Queue the removal of the committed factors `tagged(f)` picks; returns them."""
        found = [index for index, f in self._active.items()
                 if tagged(f) and index not in self._to_remove]
        self._to_remove.extend(found)
        return [self._active[index] for index in found]

    def settled(self, i: int, j: int) -> bool:
        """False while the pair (i, j) or (j, i) has an abandoned hypothesis whose factors wait
        for the new one to hold (`GraphParams.switch_hold`): the graph then still weighs both.

        Raises:
            DataError: i or j not a robot of this graph.
        """
        self._check_robot("i", i)
        self._check_robot("j", j)
        return (i, j) not in self._abandoned and (j, i) not in self._abandoned

    def _latest(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(x, y, theta) of the graph's latest T_oi_oj and its covariance."""
        T, cov = self.alignment(i, j)
        return self._params(T), cov

    @staticmethod
    def _agrees(estimate: AlignmentEstimate, x: np.ndarray, P: np.ndarray) -> bool:
        """Whether a TCAFF estimate is consistent with the alignment x (3,), covariance P."""
        residual = np.asarray(estimate.x, dtype=float) - x
        residual[2] = math.remainder(residual[2], 2 * math.pi)
        S = P + np.asarray(estimate.P, dtype=float)
        if not np.isfinite(S).all():  # an alignment the graph does not know agrees with none
            return False
        return float(residual @ np.linalg.solve(S, residual)) <= _AGREE_CHI2
