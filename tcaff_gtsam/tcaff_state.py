"""Saving and restoring a TCAFF filter: `FilterState`, the part of `TCAFF` that turns its
state into arrays (`state_dict`, `save`, `snapshot`) and back (`load_state_dict`, `load`),
checking a state whole before anything is restored."""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Mapping
from dataclasses import asdict
from itertools import pairwise
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import DataError
from .hypothesis_tree import (
    BEFORE_ROOT,
    LEAF_DTYPES,
    NO_MEASUREMENT,
    Leaves,
    not_positive_definite,
    seed,
)
from .inputs import output_path, read_npz
from .params import TCAFFParams

if TYPE_CHECKING:
    from .tcaff import TCAFF

__all__ = ["FilterState", "write_snapshot"]

#: the largest jitter a pair of measurements records (`TCAFFParams.jitter_reference`)
JITTER_CAP = 1e6


class FilterState:
    """The state of a `TCAFF` filter as arrays, for a node that restarts where it stopped.
    Mixed into `TCAFF`; it reads and sets the filter's own attributes."""

    _COUNTERS = ("step", "hypothesis", "_next_tree", "_switch_streak", "_empty_windows",
                 "_fresh")
    _TREES = ("main", "explore", "rival")

    def state_dict(self) -> dict[str, np.ndarray]:
        """Everything the filter remembers, as arrays (restore with `load_state_dict`)."""
        state = {c: np.array(getattr(self, c), dtype=np.int64) for c in self._COUNTERS}
        for name in self._TREES:
            leaves = getattr(self, f"_{name}")
            if leaves is not None:
                for f in LEAF_DTYPES:
                    state[f"{name}.{f}"] = getattr(leaves, f).copy()
        d = self.params.dim
        state["bank.sizes"] = np.array([zs.shape[0] for zs, _ in self._bank], dtype=np.int64)
        state["bank.zs"] = np.concatenate([zs for zs, _ in self._bank] or [np.empty((0, d))])
        state["bank.Rs"] = np.concatenate([Rs for _, Rs in self._bank]
                                          or [np.empty((0, d, d))])
        # evidence per step: -1 for a step without, else its measurements; per measurement the
        # number of pairs, -1 for none given
        steps = list(self._evidence)
        state["steps.sizes"] = np.array(self._sizes, dtype=np.int64)
        state["evidence.sizes"] = np.array([-1 if e is None else len(e) for e in steps],
                                           dtype=np.int64)
        per = [p for e in steps if e is not None for p in e]
        state["evidence.counts"] = np.array([-1 if p is None else len(p) for p in per],
                                            dtype=np.int64)
        state["evidence.pairs"] = np.array([ab for p in per if p is not None for ab in p],
                                           dtype=np.int64).reshape(-1, 2)
        # objects per step: -1 for a step without, else its measurements' counts
        state["objects.sizes"] = np.array([-1 if o is None else o.size for o in self._objects],
                                          dtype=np.int64)
        state["objects.counts"] = np.concatenate(
            [o for o in self._objects if o is not None] or [np.empty(0, np.int64)])
        if self._dormant is not None:
            state["dormant.x"] = self._dormant.x.copy()
            state["dormant.P"] = self._dormant.P.copy()
            state["dormant.age"] = np.array(self._dormant_age, dtype=np.int64)
            state["dormant.peak"] = np.array(self._dormant_peak, dtype=np.int64)
            state["dormant.hypothesis"] = np.array(self._dormant.tree[0], dtype=np.int64)
        state["peak"] = np.array(self._peak, dtype=np.int64)
        state["highest_reported"] = np.array(self._highest_reported, dtype=np.int64)
        state["drift_as_assumed"] = np.array(self._drift_as_assumed, dtype=np.int64)
        state["reclaiming"] = np.array(self._reclaiming, dtype=np.int64)
        state["returning"] = np.array(self._returning, dtype=np.int64)
        if self._silent_switch is not None:
            state["silent_switch"] = np.array(self._silent_switch, dtype=np.int64)
        if self._provisional is not None:
            state["provisional"] = np.array(self._provisional, dtype=np.int64)
        state["jitter.steps"] = np.array([k for k, _, _ in self._jitter], dtype=np.int64)
        state["jitter.values"] = np.array([v for _, v, _ in self._jitter], dtype=np.float64)
        state["jitter.hypotheses"] = np.array([h for _, _, h in self._jitter], dtype=np.int64)
        if self._last_taken is not None:
            step, hypothesis, z, R = self._last_taken
            state["jitter.last"] = np.array([step, hypothesis], dtype=np.int64)
            state["jitter.last_z"], state["jitter.last_R"] = z.copy(), R.copy()
        return state

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Restore a state from `state_dict` of a filter with the same parameters.

        The state is checked whole before anything is restored, so that a refused state
        leaves the filter as it was.

        Raises:
            DataError: missing entries, arrays of the wrong kind or shape, or values no filter
                reaches: non-finite states, costs or measurements; covariances that are not
                symmetric positive definite; negative counters, steps since a measurement
                below 0 or beyond the step, counters of 2^62 or more; hypotheses at step 0;
                tree ids out of range (main tree ids other than the hypothesis counter,
                exploring ids not below the next id or not grouped, a highest reported id
                above the hypothesis counter); measurement choices
                before the first step or beyond the step's measurements; jitters beyond
                `JITTER_CAP`, object counts of 2^31 or more. Anything else that fails while
                a checked state is restored, with the filter's own state restored.
        """
        if not isinstance(state, Mapping):
            raise DataError(f"TCAFF state: must be a mapping of names to arrays, got "
                            f"{type(state).__name__}")
        d, columns = self.params.dim, self._columns
        try:
            counters = {c: _counter(state[c], c) for c in self._COUNTERS}
            evidence = self._evidence_from(state)
            trees = {name: Leaves(*(_state_array(state[f"{name}.{f}"], f"{name}.{f}", dtype)
                                    for f, dtype in LEAF_DTYPES.items()))
                     for name in self._TREES if f"{name}.x" in state}
            sizes = _state_array(state["bank.sizes"], "bank.sizes", np.int64)
            # absent from states saved before it was recorded
            steps = (_state_array(state["steps.sizes"], "steps.sizes", np.int64)
                     if "steps.sizes" in state else None)
            bank_zs = _state_array(state["bank.zs"], "bank.zs", np.float64)
            bank_Rs = _state_array(state["bank.Rs"], "bank.Rs", np.float64)
            objects = self._objects_from(state, steps)  # absent from earlier states
            dormant = self._dormant_from(state)
            # absent from states saved before a recall could displace a main tree
            peak = _counter(state.get("peak", 0), "peak")
            reclaiming = _counter(state.get("reclaiming", 0), "reclaiming")
            if not 0 <= peak <= self.params.window or reclaiming not in (0, 1):
                raise DataError(f"TCAFF state: peak = {peak} must be in [0, window "
                                f"{self.params.window}] and reclaiming = {reclaiming} 0 or 1")
            if reclaiming and (dormant[0] is None or "main.x" not in state):
                raise DataError("TCAFF state: reclaiming needs a dormant hypothesis beside a "
                                "main tree")
            # absent from states saved before it was recorded: any id issued may have been
            highest_reported = _counter(state.get("highest_reported", counters["hypothesis"]),
                                        "highest_reported")
            if highest_reported > counters["hypothesis"]:
                raise DataError(f"TCAFF state: highest_reported = {highest_reported} is above "
                                f"the hypothesis counter {counters['hypothesis']}")
            # absent from states saved before holds were lengthened: a hold of drop_after
            drift_as_assumed = _counter(state.get("drift_as_assumed", 0), "drift_as_assumed")
            if drift_as_assumed not in (0, 1) or (drift_as_assumed and "main.x" not in state):
                raise DataError(f"TCAFF state: drift_as_assumed = {drift_as_assumed} must be "
                                f"0 or 1, and 0 without a main tree")
            # absent from states saved before a return from a gap was counted
            returning = _counter(state.get("returning", 0), "returning")
            if returning >= self.params.early_measurements or (
                    returning and "main.x" not in state):
                raise DataError(f"TCAFF state: returning = {returning} must be below "
                                f"early_measurements = {self.params.early_measurements}, and "
                                f"0 without a main tree")
            silent_switch = self._main_mark_from(state, counters, "silent_switch", 1)
            # a provisional acceptance is settled before its tree is W steps old
            provisional = self._main_mark_from(
                state, counters, "provisional",
                max(1, counters["step"] - self.params.window + 1))
            jitter, last_taken = self._jitter_from(state, counters)
        except KeyError as exc:
            raise DataError(f"TCAFF state: missing entry {exc}") from None
        except DataError:  # refused on purpose, with its own message
            raise
        except (TypeError, ValueError, OverflowError) as exc:
            raise DataError(f"TCAFF state: an entry has the wrong kind or is out of range "
                            f"({exc})") from None
        if "explore" not in trees:
            raise DataError("TCAFF state: missing entry 'explore.x'")
        for name, leaves in trees.items():
            counts = {f: np.shape(getattr(leaves, f))[:1] for f in LEAF_DTYPES}
            if len(set(counts.values())) != 1:
                raise DataError(f"TCAFF state: the {name} arrays disagree on the number of "
                                f"leaves: {counts}")
            L = len(leaves)
            if name != "explore" and L == 0:
                raise DataError(f"TCAFF state: the {name} tree has no leaves")
            shapes = {"x": (L, d), "P": (L, d, d), "choice": (L, columns),
                      "edge": (L, columns), "since": (L,), "tree": (L,)}
            for f, shape in shapes.items():
                if getattr(leaves, f).shape != shape:
                    raise DataError(f"TCAFF state: {name}.{f} has shape "
                                    f"{getattr(leaves, f).shape}, expected {shape} (window "
                                    f"{self.params.window}, d = {d})")
        if (sizes.ndim != 1 or sizes.size > self.params.window + 1 or np.any(sizes < 0)
                or bank_zs.shape != (sizes.sum(), d) or bank_Rs.shape != (sizes.sum(), d, d)):
            raise DataError("TCAFF state: the stored measurements do not match bank.sizes")
        self._check_values(counters, trees, sizes, bank_zs, bank_Rs, evidence, steps)
        if objects is not None:
            known = self._sizes_of(evidence, steps)
            offset = self._columns - len(objects)
            if len(objects) != len(evidence) or any(
                    o is not None and (
                        (n >= 0 and o.size != n)
                        or any(int(t.choice[:, offset + c].max(initial=-1)) >= o.size
                               for name, t in trees.items() if name != "rival"))
                    for c, (o, n) in enumerate(zip(objects, known, strict=True))):
                raise DataError("TCAFF state: the stored objects do not match the steps' "
                                "measurements")
        if counters["step"] == 0 and ("main" in trees or len(trees["explore"])
                                      or dormant[0] is not None or counters["hypothesis"]
                                      or counters["_next_tree"]):
            raise DataError("TCAFF state: hypotheses at step 0, before any measurement")
        before = self.state_dict()
        try:
            for c, value in counters.items():
                setattr(self, c, value)
            self._main, self._explore, self._rival = (trees.get(n) for n in self._TREES)
            bounds = np.r_[0, np.cumsum(sizes)]
            self._bank = deque(((bank_zs[a:b], bank_Rs[a:b]) for a, b in pairwise(bounds)),
                               maxlen=self.params.window + 1)
            self._evidence = deque(evidence, maxlen=self._columns)
            self._sizes = deque([-1] * len(evidence) if steps is None else steps.tolist(),
                                maxlen=self._columns)
            self._objects = deque(objects if objects is not None else [None] * len(evidence),
                                  maxlen=self._columns)
            self._dormant, self._dormant_age, self._dormant_peak = dormant
            self._peak, self._reclaiming, self._returning = peak, bool(reclaiming), returning
            self._highest_reported = highest_reported
            # (a filter without a reference keeps no record of the drift either)
            self._drift_as_assumed = (bool(drift_as_assumed)
                                      and self.params.jitter_reference is not None)
            self._silent_switch, self._provisional = silent_switch, provisional
            # a filter without a reference keeps no record (it would never trim one)
            self._jitter, self._last_taken = ((jitter, last_taken)
                                              if self.params.jitter_reference is not None
                                              else (deque(), None))
            self._held = self._jittered(self._main_estimate())
            self._estimate = self._reported(self._held)
        except Exception as exc:  # a state the checks above missed: the filter as it was
            self.reset()
            self.load_state_dict(before)
            raise DataError(f"TCAFF state: could not be restored ({type(exc).__name__}: "
                            f"{exc}); the filter is as it was") from None

    def _check_values(self, counters: dict[str, int], trees: dict[str, Leaves],
                      sizes: np.ndarray, bank_zs: np.ndarray, bank_Rs: np.ndarray,
                      evidence: list, steps: np.ndarray | None) -> None:
        """DataError unless a state of the right shapes holds values a filter can reach."""
        prm, columns = self.params, self._columns
        for c, value in counters.items():
            if value < 0:
                raise DataError(f"TCAFF state: {c} = {value} must be >= 0")
        step = counters["step"]
        if counters["_fresh"] > step:
            raise DataError(f"TCAFF state: _fresh = {counters['_fresh']} is after step = "
                            f"{step}")
        seen = min(step, columns)  # columns of steps that happened
        if len(evidence) != seen:
            raise DataError(f"TCAFF state: evidence of {len(evidence)} steps, expected {seen} "
                            f"at step {step}")
        banked = min(step, prm.window + 1) if prm.promotion == "reseed" else 0
        if sizes.size != banked:
            raise DataError(f"TCAFF state: {sizes.size} banked steps, expected {banked} at "
                            f"step {step}")
        _check_covariances("bank.zs", bank_zs, "bank.Rs", bank_Rs)
        # per column, the number of measurements its step had, where the state knows it
        # (-1: not known, for states saved before steps.sizes was recorded)
        known = np.full(columns, -1, np.int64)
        known[: columns - seen] = 0  # steps before the first one
        if steps is not None:
            if steps.shape != (seen,) or np.any(steps < -1):
                raise DataError(f"TCAFF state: steps.sizes must hold {seen} counts at step "
                                f"{step}, got {steps.tolist()}")
            known[columns - seen:] = steps
        sources = [(c, len(e)) for c, e in enumerate(evidence, start=columns - seen)
                   if e is not None]
        sources += list(zip(range(columns - sizes.size, columns), sizes.tolist(), strict=True))
        for c, count in sources:
            if known[c] not in (-1, count):
                raise DataError(f"TCAFF state: step column {c} had {known[c]} measurements "
                                f"by steps.sizes, {count} by the stored evidence or bank")
            known[c] = count
        limit = np.where(known < 0, np.iinfo(np.int32).max, known)
        if "main" not in trees and "rival" in trees:
            raise DataError("TCAFF state: a rival without a main tree")
        for name, leaves in trees.items():
            _check_covariances(f"{name}.x", leaves.x, f"{name}.P", leaves.P)
            if not np.all(np.isfinite(leaves.edge)):
                raise DataError(f"TCAFF state: {name}.edge holds non-finite costs")
            if np.any(leaves.since < 0) or np.any(leaves.since > step):
                raise DataError(f"TCAFF state: {name}.since holds step counts below 0 or "
                                f"beyond step = {step}")
            choice = leaves.choice
            # before its root a path holds BEFORE_ROOT, from the root on a choice (>= -1)
            rooted = choice >= NO_MEASUREMENT
            if (np.any(choice < BEFORE_ROOT) or np.any(rooted[:, :-1] & ~rooted[:, 1:])
                    or not np.all(rooted[:, -1])):
                raise DataError(f"TCAFF state: {name}.choice is not a path (values must be "
                                f"{BEFORE_ROOT} before the root, then >= {NO_MEASUREMENT})")
            over = choice >= limit
            if name != "rival" and over.any():  # a rival may be from an earlier step
                leaf, c = np.argwhere(over)[0]
                raise DataError(f"TCAFF state: {name}.choice[{leaf}, {c}] = {choice[leaf, c]}"
                                f" is not a measurement of its step (it had {limit[c]})")
            tree = leaves.tree
            if name == "main":
                if not np.all(tree == counters["hypothesis"]) or counters["hypothesis"] < 1:
                    raise DataError(f"TCAFF state: main.tree ids must all be the hypothesis "
                                    f"counter {counters['hypothesis']} (>= 1)")
            elif tree.size and (tree.min() < 0 or tree.max() >= counters["_next_tree"]):
                raise DataError(f"TCAFF state: {name}.tree ids must lie in [0, _next_tree = "
                                f"{counters['_next_tree']})")
        runs = trees["explore"].tree
        runs = runs[np.r_[True, runs[1:] != runs[:-1]]] if runs.size else runs
        if np.unique(runs).size != runs.size:
            raise DataError("TCAFF state: the leaves of each exploring tree must be adjacent")

    def _evidence_from(self, state: dict[str, np.ndarray]
                       ) -> list[list[list[tuple[int, int]] | None] | None]:
        """The evidence bank of a `state_dict`; DataError when its arrays disagree."""
        sizes, counts, pairs = (_state_array(state[f"evidence.{name}"], f"evidence.{name}",
                                             np.int64) for name in ("sizes", "counts", "pairs"))
        if (sizes.ndim != 1 or sizes.size > self._columns or counts.ndim != 1
                or np.any(sizes < -1) or np.any(counts < -1)
                or counts.size != sizes[sizes > 0].sum() or pairs.ndim != 2
                or pairs.shape != (counts[counts > 0].sum(), 2)):
            raise DataError("TCAFF state: the stored evidence does not match evidence.sizes")
        steps, m, row = [], 0, 0
        for size in sizes:
            if size < 0:
                steps.append(None)
                continue
            step = []
            for count in counts[m:m + size]:
                step.append(None if count < 0 else
                            [(int(a), int(b)) for a, b in pairs[row:row + count]])
                row += max(int(count), 0)
            m += int(size)
            steps.append(step)
        return steps

    @staticmethod
    def _sizes_of(evidence: list, steps: np.ndarray | None) -> list[int]:
        """Per stored step, its number of measurements (-1 where the state does not say)."""
        if steps is not None:
            return steps.tolist()
        return [-1 if e is None else len(e) for e in evidence]

    def _objects_from(self, state: Mapping, steps: np.ndarray | None
                      ) -> list[np.ndarray | None] | None:
        """The objects of a `state_dict`'s steps (None when the state has none); DataError
        when they disagree with each other or with the steps' sizes."""
        if "objects.sizes" not in state:
            return None
        sizes = _state_array(state["objects.sizes"], "objects.sizes", np.int64)
        counts = _state_array(state["objects.counts"], "objects.counts", np.int64)
        if (sizes.ndim != 1 or sizes.size > self._columns or np.any(sizes < -1)
                or counts.shape != (sizes[sizes > 0].sum(),) or np.any(counts < 0)
                or np.any(counts >= 2**31)  # as `update` takes them
                or (steps is not None and (steps.shape != sizes.shape or np.any(
                    (sizes >= 0) & (steps >= 0) & (sizes != steps))))):
            raise DataError("TCAFF state: the stored objects do not match objects.sizes and "
                            "steps.sizes")
        out, start = [], 0
        for size in sizes.tolist():
            out.append(None if size < 0 else counts[start:start + size])
            start += max(size, 0)
        return out

    def _main_mark_from(self, state: Mapping, counters: dict[str, int], key: str,
                        first: int) -> tuple[int, int] | None:
        """The (step, hypothesis) of `key`, a mark on the main tree (`silent_switch`: a
        switch from a silent main tree, or the window's acceptance of an unmeasured hypothesis
        over the dormant one, not yet confirmed; `provisional`: an early acceptance
        not yet settled), or None (absent from states saved before it was recorded); a
        DataError unless it is of the current main tree, at a step in [first, the
        state's]."""
        if key not in state:
            return None
        value = _state_array(state[key], key, np.int64)
        if value.shape != (2,):
            raise DataError(f"TCAFF state: {key} must be (step, hypothesis), got shape "
                            f"{value.shape}")
        step, hypothesis = (int(v) for v in value)
        if ("main.x" not in state or hypothesis != counters["hypothesis"]
                or not first <= step <= counters["step"]):
            raise DataError(f"TCAFF state: {key} = ({step}, {hypothesis}) must name the main "
                            f"tree's hypothesis {counters['hypothesis']} at a step in "
                            f"[{first}, {counters['step']}]")
        return step, hypothesis

    def _jitter_from(self, state: Mapping, counters: dict[str, int]
                     ) -> tuple[deque, tuple | None]:
        """The jitter record of a `state_dict` and the latest measurement of the main
        hypothesis (empty and None in states saved before they were recorded); DataError
        when the steps are not increasing, from step 2, within the last `jitter_span`
        steps, the values outside [0, JITTER_CAP], or the measurement not a finite state with
        an SPD covariance of a step and hypothesis the filter has reached."""
        d, step = self.params.dim, counters["step"]
        if "jitter.steps" not in state:
            return deque(), None
        steps = _state_array(state["jitter.steps"], "jitter.steps", np.int64)
        values = _state_array(state["jitter.values"], "jitter.values", np.float64)
        if (steps.ndim != 1 or values.shape != steps.shape or np.any(np.diff(steps) <= 0)
                or np.any(steps > step) or np.any(steps <= step - self.params.jitter_span)
                or np.any(steps < 2)):  # a jitter takes two steps
            raise DataError(f"TCAFF state: jitter.steps must increase within the last "
                            f"jitter_span = {self.params.jitter_span} steps of step {step}, "
                            f"from step 2, one value each in jitter.values; got steps "
                            f"{steps.tolist()[:8]} and values of shape {values.shape}")
        bad = np.flatnonzero(~((values >= 0) & (values <= JITTER_CAP)))  # NaN too
        if bad.size:
            raise DataError(f"TCAFF state: jitter.values[{bad[0]}] = {values[bad[0]]!r} is not "
                            f"a jitter the filter records (in [0, {JITTER_CAP:g}])")
        # whose measurements each value is of: absent from states saved before (-1, none's)
        of = (_state_array(state["jitter.hypotheses"], "jitter.hypotheses", np.int64)
              if "jitter.hypotheses" in state else np.full(steps.shape, -1, np.int64))
        if of.shape != steps.shape or np.any(of < -1) or np.any(of == 0) or np.any(
                of > counters["hypothesis"]):
            raise DataError(f"TCAFF state: jitter.hypotheses must hold one hypothesis id in "
                            f"[1, {counters['hypothesis']}] per value of jitter.values; got "
                            f"{of.tolist()[:8]}")
        jitter = deque(zip(steps.tolist(), values.tolist(), of.tolist(), strict=True))
        if "jitter.last" not in state:
            return jitter, None
        last = _state_array(state["jitter.last"], "jitter.last", np.int64)
        z = _state_array(state["jitter.last_z"], "jitter.last_z", np.float64)
        R = _state_array(state["jitter.last_R"], "jitter.last_R", np.float64)
        if (last.shape != (2,) or not 1 <= last[0] <= step
                or not 1 <= last[1] <= counters["hypothesis"]
                or z.shape != (d,) or not np.all(np.isfinite(z))
                or R.shape != (d, d) or not np.all(np.isfinite(R)) or _not_spd(R[None])):
            raise DataError(f"TCAFF state: jitter.last must be (step, hypothesis) the filter "
                            f"reached, jitter.last_z a finite ({d},) state and "
                            f"jitter.last_R a ({d}, {d}) SPD covariance")
        return jitter, (int(last[0]), int(last[1]), z, R)

    def _dormant_from(self, state: Mapping) -> tuple[Leaves | None, int, int]:
        """The dormant hypothesis of a `state_dict`, its age and its peak (None, 0, 0 when it
        has none); DataError when its arrays are not a state and covariance, or its age, peak
        or id are out of range."""
        if "dormant.x" not in state:
            return None, 0, 0
        d, window = self.params.dim, self.params.window
        x = _state_array(state["dormant.x"], "dormant.x", np.float64)
        P = _state_array(state["dormant.P"], "dormant.P", np.float64)
        age = _counter(state["dormant.age"], "dormant.age")
        if x.shape != (1, d) or P.shape != (1, d, d):
            raise DataError(f"TCAFF state: dormant.x and dormant.P must have shapes (1, {d}) "
                            f"and (1, {d}, {d}), got {x.shape} and {P.shape}")
        hypothesis = int(np.asarray(state["hypothesis"]).item())
        # a main tree beside a dormant one was accepted after it, under a later id
        main = "main.x" in state
        default = hypothesis - 1 if main else hypothesis
        dormant_id = _counter(state.get("dormant.hypothesis", default), "dormant.hypothesis")
        if not 1 <= dormant_id <= default:
            raise DataError(f"TCAFF state: a dormant hypothesis needs a dropped one: "
                            f"dormant.hypothesis = {dormant_id} is not in [1, {default}] "
                            f"(hypothesis counter {hypothesis}"
                            f"{', with a main tree' if main else ''})")
        peak = _counter(state.get("dormant.peak", 0), "dormant.peak")
        if not 0 <= peak <= window:
            raise DataError(f"TCAFF state: dormant.peak = {peak} is more than the window "
                            f"{window}")
        recall_for = self.params.recall_for
        if recall_for is None or not 0 <= age <= recall_for:
            raise DataError(f"TCAFF state: dormant.age = {age} is not within recall_for = "
                            f"{recall_for}")
        _check_covariances("dormant.x", x, "dormant.P", P)
        leaf = seed(x, P[0], np.full(1, dormant_id, np.int64), np.full(1, NO_MEASUREMENT),
                    self._columns)
        return leaf, age, peak

    def save(self, path: str | Path) -> None:
        """Write parameters and state to an npz archive at exactly `path`.

        Raises:
            DataError: path not a str or path, a folder, in a missing folder, or not writable.
        """
        write_snapshot(output_path("TCAFF.save", path), self.snapshot())

    def snapshot(self) -> dict[str, np.ndarray]:
        """What `save` writes, the parameters and a copy of the state: a tenth of a
        millisecond, so that the writing (milliseconds) can happen on another thread
        (`write_snapshot`) while the filter goes on."""
        params = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                  for k, v in asdict(self.params).items()}
        return {"params": np.array(json.dumps(params)),
                **{k: np.array(v, copy=True) for k, v in self.state_dict().items()}}

    @classmethod
    def load(cls, path: str | Path) -> TCAFF:
        """Read a filter written by `save`.

        Raises:
            DataError: the file is missing, not a regular file (a FIFO is refused before it
                is opened for reading), empty, truncated, corrupt, not a saved filter, or
                holds a state `load_state_dict` refuses.
        """
        state = read_npz(path, "TCAFF filter")
        try:
            params = TCAFFParams(**json.loads(str(state.pop("params"))))
        except (ValueError, KeyError, TypeError, RecursionError) as exc:
            raise DataError(f"{path}: not a saved TCAFF filter ({exc})") from None
        filt = cls(params)
        filt.load_state_dict(state)
        return filt


def write_snapshot(path: str | Path, snapshot: dict[str, np.ndarray]) -> None:
    """Write a `TCAFF.snapshot` to an npz archive at exactly `path` (`TCAFF.load` reads it).

    Raises:
        DataError: the file cannot be written.
    """
    try:
        file = open(path, "wb")  # a file object stops numpy appending ".npz"
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
        raise DataError(f"TCAFF.save: cannot write {path} ({exc})") from None
    with file:
        np.savez_compressed(file, **snapshot)


def _counter(value, name: str) -> int:
    """A counter of a state dict: one integer below 2**62, which no run reaches (10^11 years
    of steps at 1 Hz) and which leaves the filter's int64 id and step arithmetic room."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iu":
        raise TypeError(f"{name} must be an integer, got dtype {arr.dtype}")
    count = int(arr.item())
    if count >= 2**62:
        raise ValueError(f"{name} = {count} is not below 2**62")
    return count


def _state_array(value, name: str, dtype) -> np.ndarray:
    """An array of a state dict as `dtype`: integers only from integers within its range,
    floats only from real numbers (no truncation, no wrap-around, no complex parts dropped)."""
    arr = np.asarray(value)
    target = np.dtype(dtype)
    if target.kind in "iu":
        # an empty float array (np.array([])) holds no fractions
        if arr.dtype.kind not in "iu" and not (arr.size == 0 and arr.dtype.kind == "f"):
            raise TypeError(f"{name} must hold integers, got dtype {arr.dtype}")
        info = np.iinfo(target)
        if arr.size and (arr.min() < info.min or arr.max() > info.max):
            raise ValueError(f"{name} holds values beyond {target}")
    elif arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    return np.array(arr, dtype=target)


def _check_covariances(states: str, x: np.ndarray, name: str, P: np.ndarray) -> None:
    """DataError unless the states (or measurements) x (n, d) named `states` are finite and
    their covariances P (n, d, d) named `name` finite, symmetric and positive definite."""
    for what, values in ((states, x), (name, P)):
        if not np.all(np.isfinite(values)):
            raise DataError(f"TCAFF state: {what} holds non-finite values")
    bad = _not_spd(P)
    if bad is not None and bad[1] == "symmetric":
        raise DataError(f"TCAFF state: {name} holds a covariance that is not symmetric")
    if bad is not None:
        raise DataError(f"TCAFF state: {name}[{bad[0]}] is not {bad[1]}")


def _not_spd(P: np.ndarray) -> tuple[int, str] | None:
    """The first of the finite matrices P (n, d, d) that is not symmetric positive definite,
    with what it is not ("symmetric", or "positive definite (smallest eigenvalue ...)");
    None when all are."""
    if P.shape[0] == 0:
        return None
    asym = np.abs(P - P.transpose(0, 2, 1)) > 1e-9 * (1.0 + np.abs(P))
    if asym.any():
        return int(np.argwhere(asym)[0, 0]), "symmetric"
    first = not_positive_definite(P)
    if first < 0:
        return None
    # the eigenvalue says how far from positive definite it is
    smallest = np.linalg.eigvalsh(P[first])[0]
    return first, f"positive definite (smallest eigenvalue {smallest:.3g})"
