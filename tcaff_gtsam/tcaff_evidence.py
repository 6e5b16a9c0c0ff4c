"""TCAFF's rules on evidence beyond the paper's cost: how many objects back a path (object
support), how many distinct pieces of evidence it holds (`TCAFFParams.min_distinct`), how often
a rival was seen against the main hypothesis (`switch_support`), and when the main estimate is
withheld rather than reported (`withhold_contested`, `report_after`, a provisional
acceptance). A part of `TCAFF`, which holds the trees and the step records they read."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .hypothesis_tree import NO_MEASUREMENT, Leaves

if TYPE_CHECKING:
    from .tcaff import AlignmentEstimate

__all__: list[str] = []


class EvidenceRules:
    """The evidence counts and reporting rules of `TCAFF` (see the module's notes); every
    attribute they read is `TCAFF`'s."""

    def _object_support(self, choice: np.ndarray) -> np.ndarray:
        """(L,) nats of object support of paths (L, W + 2): `object_nats` times the objects
        explained by the path's best-supported measurement in the window, less `object_base`;
        0 for a path without measurements, or with sequential acceptance off. A path's root
        (its seed) does not count: it leaves the window when its tree is W steps old, and the
        support of an early acceptance must be the support the complete path would have."""
        prm = self.params
        support = np.zeros(choice.shape[0])
        if not prm.sequential or choice.shape[0] == 0:
            return support
        steps = list(self._objects)
        offset = self._columns - len(steps)  # columns before the first step seen
        first = max(self._columns - prm.window, offset)
        best = np.full(choice.shape[0], -1, np.int64)
        root = np.argmax(choice >= NO_MEASUREMENT, axis=1)
        for c in range(first, self._columns):
            taken = choice[:, c]
            measured = (taken >= 0) & (root != c)
            if not measured.any():
                continue
            counts = steps[c - offset]
            n = (np.full(measured.sum(), prm.object_base) if counts is None
                 else counts[taken[measured]])
            best[measured] = np.maximum(best[measured], n)
        has = best >= 0
        support[has] = prm.object_nats * (best[has] - prm.object_base)
        return support

    def _reported(self, estimate: AlignmentEstimate | None) -> AlignmentEstimate | None:
        """The main tree's estimate, or None while `withhold_contested` or `report_after`
        holds it back, or its acceptance is provisional (`_settle_provisional`)."""
        if estimate is None:
            return None
        report_after = self.params.report_after
        if (report_after is not None
                and self._main.since[np.argmin(self._main.cost)] >= report_after):
            return None
        if self._provisional is not None:
            return None
        if self.params.withhold_contested and self._contested():
            return None
        return estimate

    def _contested(self) -> bool:
        """Whether an exploring hypothesis inconsistent with the main tree's best path
        outvotes it over the steps since the rival's root (at a step given object ids: seen
        `_outvote_need` times by `_support`, with `switch_support`), or that path took no
        measurement this step while the rival holds more distinct evidence in the window (and
        at least `min_distinct` pieces; at a step without ids, only while that path holds
        fewer than `min_distinct`), or the dormant hypothesis was seen in the last W
        steps (`_recall`), or the main tree replaced one in a gap of its measurements (or the
        window accepted it, unmeasured, over the dormant hypothesis it contradicts) and has
        not been measured since the step it did (nothing contradicted the one it replaced:
        a decoy met while the robots were apart is not reported on its lead alone)."""
        if self._reclaiming or self._silent_switch is not None:
            return True
        main, explore = self._main, self._explore
        m = int(np.argmin(main.cost))
        if len(explore) == 0:
            return False
        taken = self._taken(explore.choice)
        if self._evidence[-1] is not None and self.params.switch_support is not None:
            # over the steps since the rival was first seen: a rival seen more often than the
            # main path since then is contested before its window fills
            need = self._outvote_need(m, self._steps_since_root(explore.choice))
            if any(self._support(explore.choice[r]) >= need[r]
                   for r in self._rivals_of(m, taken >= need)):
                return True
        if main.since[m] == 0:
            return False
        held = self._distinct(main.choice[m])[0]
        if self._evidence[-1] is None and held >= self.params.min_distinct:
            # without ids a rival's count is no measure of distinct evidence: a main path
            # still confirmed in its window is not contested by being seen less often
            return False
        need = max(held + 1, self.params.min_distinct)
        return any(self._distinct(explore.choice[r])[0] >= need
                   for r in self._rivals_of(m, taken >= need))

    def _rivals_of(self, m: int, candidates: np.ndarray) -> np.ndarray:
        """Indices of the open exploring leaves among `candidates` ((L,) bool) that are
        inconsistent with the main tree's leaf m."""
        rivals = np.flatnonzero(candidates)
        if rivals.size == 0:
            return rivals
        return rivals[~self._consistent(self._explore.take(rivals), self._main.take([m]))]

    def _outvote_need(self, m: int, span):
        """How often a rival must be seen (`_support`) over its last `span` steps (an int, or
        (L,) ints, one per rival; in [1, W]: W for a complete tree, its steps since its root
        for an open one) to outvote the main tree's leaf m: `switch_support` more times than
        m's path took a measurement over the same steps (the main path's measurements count
        as they are: a true alignment re-matching the same objects while the robots stand
        still is not to be outvoted for it). An int, or (L,) ints, like `span`."""
        path, prm = self._main.choice[m], self.params
        seen = np.cumsum(path[::-1][:prm.window] >= 0)  # in the last 1 .. W steps
        return seen[np.clip(span, 1, prm.window) - 1] + prm.switch_support

    @staticmethod
    def _steps_since_root(choice: np.ndarray) -> np.ndarray:
        """(L,) steps of paths (L, W + 2) from their root's step to this one, both counted."""
        return np.count_nonzero(choice >= NO_MEASUREMENT, axis=1)

    def _support(self, path: np.ndarray) -> int:
        """How often a rival's hypothesis was seen in the window: its measurements, or one
        when together they bring fewer than two distinct pieces of evidence (a look-alike
        cluster re-matched again and again). A path with two or more counts every
        measurement, repeats included."""
        distinct = self._distinct(path)[0]
        return distinct if distinct < 2 else self._taken(path)

    def _taken(self, choice: np.ndarray):
        """Measurements in the window: (L,) ints for paths (L, W + 2), an int for one path
        (W + 2,)."""
        taken = np.count_nonzero(choice[..., -self.params.window:] >= 0, axis=-1)
        return int(taken) if choice.ndim == 1 else taken

    def _distinct_enough(self, leaves: Leaves, index: int, without_root: bool = False) -> bool:
        """Whether leaf `index`'s path holds `min_distinct` distinct pieces of evidence; with
        `without_root`, not counting its root (its seed)."""
        need = self.params.min_distinct
        if need <= 1:
            return True
        path = leaves.choice[index]
        if without_root:
            path = path.copy()
            path[np.argmax(path >= NO_MEASUREMENT)] = NO_MEASUREMENT
        return self._distinct(path)[0] >= need

    def _distinct(self, path: np.ndarray) -> tuple[int, bool]:
        """Distinct pieces of evidence on a path over the window, and whether the path's
        measurement at the current step is one: a measurement is distinct when one of its
        pairs joins an ego object and an other object that the path's earlier measurements
        in the window did not use (a measurement without ids always is)."""
        evidence = self._evidence
        offset = self._columns - len(evidence)  # columns before the first step seen
        used_ego: set[int] = set()
        used_other: set[int] = set()
        count, new = 0, False
        for c in range(max(self._columns - self.params.window, offset), self._columns):
            j = int(path[c])
            if j < 0:
                continue
            pairs = evidence[c - offset][j] if evidence[c - offset] is not None else None
            new = pairs is None or any(a not in used_ego and b not in used_other
                                       for a, b in pairs)
            count += new
            if pairs is not None:
                used_ego.update(a for a, _ in pairs)
                used_other.update(b for _, b in pairs)
        return count, bool(new and path[-1] >= 0)
