"""Settings of the TCAFF filter (`TCAFFParams`) and of the iSAM2 graph of accepted alignments
(`GraphParams`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .aligner_params import (
    MAX_SOLUTIONS,
    _alignment_process_noise,
    constant_alignment_covariance,
)
from .param_checks import (
    MAX_COORDINATE,
    MAX_FACTOR,
    MAX_NATS,
    MAX_OBJECTS,
    MAX_STEPS,
    _bound,
    _ByValue,
    _count,
    _int_at_least,
    _number,
    _one_of,
    _real,
    _reals,
    _require,
    _spd,
)

#: the longest window TCAFF takes, steps: every hypothesis keeps a choice per step of it, and
#: a thousand steps (17 minutes of exchanges at 1 Hz) is far past any test of consistency
MAX_WINDOW = 1000

#: the most leaves a tree keeps (`max_leaves`, `explore_max_leaves`): fifty times the default
#: main tree's; each leaf holds its path over the window
MAX_LEAVES = 10_000

#: the most measurements a step takes (`max_measurements`), and so the most children a leaf
#: can have (`max_children`, `explore_max_children`): as many as MNO-CLIPPER gives
#: (`MAX_SOLUTIONS`)
MAX_MEASUREMENTS = MAX_SOLUTIONS

#: the most bytes one filter's hypothesis trees may need at once (`TCAFFParams.tree_bytes`):
#: each cap is bounded on its own, but their product is what a step allocates; 1 GiB lets a
#: team of several robots run a filter per pair on one computer
MAX_TREE_BYTES = 1 << 30


@dataclass(frozen=True, eq=False)
class TCAFFParams(_ByValue):
    """Settings of the TCAFF filter (paper, "Multiple Hypothesis Formulation" and "Frame
    Alignment Filter"). The defaults are the paper's equations and values, and among
    look-alike objects (`lookalike_share`) they count distinct evidence (`min_distinct` = 2,
    `switch_stale`, `withhold_contested`): the same look-alikes re-matched at every step are
    one piece of evidence, not W. They accept a hypothesis as soon as its evidence makes the
    paper's decision certain (`sequential`), weigh a measurement by the objects it explains
    (`object_nats`), recall a dropped hypothesis on its first confirming measurement
    (`recall_for`) and charge no hypothesis for a step without any measurement
    (`neutral_empty_steps`). `paper()` is the paper's equations alone in every world;
    `reference()` the authors' released code, quirks included.

    The state x has dimension d = Q.shape[0] (3 for (x [m], y [m], theta [rad]) of T_oi_oj);
    motion and measurement models are the identity. Costs are in nats (negative log
    likelihoods); lower is better.

    Attributes:
        window: W, steps a hypothesis is judged over, at most `MAX_WINDOW`. Each measurement
            seeds an exploring tree that sees the next W steps; the main tree keeps W steps
            below its root (see `root_in_window`).
        max_leaves: B, leaves kept in the main tree, at most `MAX_LEAVES`.
        max_children: measurement children per main-tree leaf (the best gated ones), besides the
            one no-measurement child every leaf gets; at most `MAX_MEASUREMENTS`.
        explore_max_leaves, explore_max_children: the same for each exploring tree.
        max_measurements: the most measurements taken in one step, at most
            `MAX_MEASUREMENTS`; beyond it the first ones
            given are kept (`FrameAligner` lists the best score first) and it is logged. Each
            measurement seeds an exploring tree, so the step's cost grows with their number.
        p_no_measurement: p_NM; a no-measurement child costs -log p_NM - d/2 log 2 pi.
        tau: an exploring tree whose best path cost over W steps is below tau becomes the main
            tree when there is none.
        Q: (d, d) process noise per step (random-walk drift of the alignment).
        P0: (d, d) covariance of an exploring tree's root, which is the seeding measurement.
        angle_indices: state components that are angles (residuals and states are wrapped).
        gate: "mahalanobis" admits a measurement when its squared Mahalanobis distance under
            S = P + Q + R is within the chi-square quantile `gate_probability`; "box" when
            every |z_a - x_a| <= gate_box[a] (the original's rule; None is 2.0 for every
            component, as there, radians included).
        cost_model: "paper" is the cost of the paper's final equation with S = P + Q + R;
            "reference" reproduces the released code: squared Mahalanobis distance squared
            again, S = P + R, diagonal-only inverses and determinants, + d/2 log 2 pi on
            measurement children and -log p_NM on no-measurement children.
        root_in_window: False (paper): the main tree's root is the single node W steps back
            and all W steps after it stay open. True (released code): the root is the first
            step of the window, so W - 1 steps stay open.
        promotion: "branch" makes the accepted exploring tree the main tree as it is;
            "reseed" (released code) starts a fresh tree at the accepted tree's first state
            with covariance P0 and replays the window's measurements (one step twice).
        drop_rule, drop_after: the main tree is dropped when its best path has held no
            measurement for `drop_after` steps ("best_path"), or (released code, "window")
            when the best path's whole window has been empty for more than `drop_after`
            consecutive steps.
        hold_for: with `drop_rule` "best_path", a `held_Q` and a `jitter_reference`, a main
            tree whose own measurements' jitter was within the reference at its last
            measurement (its consecutive registrations moved no more than the odometries'
            assumed drift explains) is held, and reported, until its best path has held no
            measurement for this many steps instead of `drop_after`, where that is longer:
            its covariance grows by `held_Q`, which that drift is. None, or without either:
            `drop_after`.
        held_Q: (d, d) growth per step of a held leaf's covariance once it has gone W steps
            without a measurement (the first W steps grow it by Q): by then its error is the
            odometries' drift since its last measurements, which Q, sized to gate and
            follow an alignment that is being measured, overstates by far; for W steps Q
            also covers the registrations that ended an overlap, whose covariance is the
            least sure (docs/tcaff.md). With a `jitter_reference`, only while the jitter was
            within it at the main hypothesis's last measurement (above it, the alignment
            drifts faster than assumed: Q). `PairwiseAligner` gives its filter the aligner's
            `map_drift` over one second unless the filter names its own, and at each step that
            drift with each robot's heading turning about where the robot is
            (`pairwise.HeldDrift`, `TCAFF.update`'s held_Q). None: Q throughout.
        switch_after: while a main tree exists, switch to an exploring hypothesis that is
            inconsistent with it (Mahalanobis test at `gate_probability`), below tau, and
            better by `switch_margin` nats for this many consecutive steps. None never re-checks
            (released code).
        switch_margin: nats.
        switch_support: while a main tree exists, also switch to an exploring hypothesis that
            is inconsistent with it, below tau and cheaper, and whose best path was seen at
            least this many more times in the window than the main tree's best path, for
            `switch_after` consecutive steps, whether or not a measurement confirmed the main
            hypothesis at those steps: an early wrong alignment still seen now and then is
            outvoted by the truth seen more often, W + `switch_after` steps after the truth's
            first measurement. The main path's measurements count as they are; a rival's
            count as one when together they bring fewer than two distinct pieces of evidence
            (see `min_distinct`): a look-alike cluster re-matched at every step outvotes
            nothing (one that also matches other objects now and then counts in full). None:
            only the `switch_margin` rule. Like it, acts only with `switch_after` (None never
            re-checks).
        min_distinct: a hypothesis is accepted, or replaces the main one, only when its best
            path over the window holds at least this many distinct pieces of evidence: a
            measurement is distinct when it associates an object of each robot that no earlier
            measurement of the path used (objects named by the `evidence` ids given to
            `TCAFF.update`; a measurement without ids always counts). The same objects matched
            again a second later are one piece of evidence, not W. 1 counts every measurement.
        switch_stale: a main hypothesis confirmed by a measurement this step is not abandoned
            (in a repetitive world a wrong rival can hold a full window while the truth has
            gaps), unless (True) its best path has brought no distinct evidence for W steps:
            then it only re-matches objects it already used.
        withhold_contested: report no estimate while the main tree's best path took no
            measurement this step and a hypothesis it gates out holds more distinct pieces of
            evidence in the window than that path does (and at least `min_distinct`; at a
            step without ids, where each measurement counts, only while that path holds
            fewer than `min_distinct` in its window): the robots' frames have likely jumped, or
            the held alignment was a coincidence, and the old estimate would be wrong until
            the switch, W + `switch_after` steps later. With `switch_support`, at steps given
            object ids (`lookalike_share`), also while a hypothesis it gates out has been seen
            that many more times than the main path since its root (the steps since it was
            first seen), confirmed this step or not. With `recall_for`, also
            within W steps of a measurement of a dormant hypothesis (`recall_for`). At every
            step, from a switch away from a main tree in a gap of its measurements (W steps
            without one, or a return from such a gap not yet confirmed), or from the
            window's acceptance of a hypothesis that contradicts the dormant one at a step
            that did not measure it, until the hypothesis switched to (accepted) is measured
            at a later step: nothing contradicted the one it replaced.
        lookalike_share: the distinct-evidence rules (`min_distinct`, `switch_stale`,
            `withhold_contested`, `switch_support`) read object ids only at steps whose two
            maps are of look-alikes: `PairwiseAligner` gives ids when at least this share of
            the maps' object pairs pass the aligner's size and descriptor gates
            (`FrameAligner.lookalike_share`). Landmarks without sizes (MRCLAM) give 1; the
            simulator's streets and rooms 0.1-0.6, its grid of crates 0.7-1 (median 0.84);
            a camera's few objects of a small room 0.6-0.92 (median 0.73): the partial-view
            size gate lets many pairs through. At other steps every measurement is distinct
            evidence, so the rules change nothing there and a small static scene is accepted
            as the paper's filter accepts it. 0: ids at every step (and the rules always on).
        report_after: report no estimate once the main tree's best path has held no
            measurement for this many steps, while the tree itself is kept until it is
            dropped (`drop_after`, `hold_for`): unreported, it can still be confirmed
            (`TCAFF.held`), e.g. by the aligner's tracking when the robots see shared
            objects again. None: reported until dropped.
        sequential: accept a hypothesis as soon as its evidence makes acceptance certain,
            not only when its exploring tree is W steps old (docs/tcaff.md, "Sequential
            acceptance"). A hypothesis's score is its path cost less its object support
            (`object_nats`); it is accepted once the score plus the cost of W - a further
            steps without a measurement (a its tree's age) is below tau, so that no outcome
            of the remaining steps could keep the paper's rule from accepting it, when its
            path holds `early_measurements` measurements, `min_distinct` distinct pieces of
            evidence and every open hypothesis inconsistent with it scores at least
            `switch_margin` worse. When fewer than `min_distinct` of them are besides its seed
            (which a complete tree's window no longer holds) the acceptance is provisional
            (`TCAFF.provisional`): held, not reported until the path is measured again or
            holds them, and dropped if its tree turns W steps old first. False: only complete
            trees are judged (the paper).
        object_nats: nats of evidence per object a measurement explains beyond
            `object_base` (negative below it), given by the `objects` of `TCAFF.update`; a
            path's support is that of its best-supported measurement in the window (a
            maximum, not a sum: the same objects matched again a second later add nothing).
            The odds that one more object lands by chance within the aligner's inlier radius
            (0.3 m) of a compatible object under a wrong alignment are about
            density * pi * 0.3^2: e^-2 for 1.5 compatible objects per square metre, more
            than any map of ours holds. Only with `sequential`.
        object_base: objects a measurement must explain to count as plain evidence: the
            paper's minimum number of associations.
        early_measurements: measurements (at different steps, the seed's included) a path
            needs before it is accepted early: at least two, so the hypothesis has been
            seen consistent over time.
        recall_for: steps after a main tree is dropped (or replaced by a rival after W
            steps without a measurement, or before `early_measurements` measurements after
            such a gap confirmed its return: one stray measurement in its widened gate is no
            return) during which its last estimate stays dormant: an
            exploring hypothesis within its gate (its covariance grown by Q each step) that
            has taken `early_measurements` measurements, the latest at this step, recalls it
            as the main hypothesis with its id and history, unless an open hypothesis
            inconsistent with it holds more evidence. Within W steps of any such
            measurement, from the first, a main tree beside it is withheld
            (`withhold_contested`). With the default Q, 100 steps grow its standard deviation
            by 1 m and 5 degrees, the bounds of a correct alignment. None: a dropped
            hypothesis is forgotten.
        jitter_reference: the covariance `update` reports is P times max(1, j /
            jitter_reference), with j the jitter of the alignments the filter held: over the
            last `jitter_span` steps, the mean of d' (R_a + R_b)^-1 d / d_dim for every two
            consecutive steps at which the main hypothesis's best path took a measurement
            (z_a, z_b with covariances R_a, R_b; d = z_b - z_a, angles wrapped). For
            measurements whose covariances count the error consecutive ones share, as the
            aligner's calibrated R does (`FrameAlignerParams.jitter_reference`, which
            `PairwiseAligner` gives its filter when this is None): where that R holds, j stays
            below the reference, and above it the alignment moves between registrations more
            than R allows (docs/tcaff.md). Only the estimates reported (and `TCAFF.held`) are
            scaled: the hypotheses, their costs and every decision are the same. None: P as
            the filter has it (independent measurements with their own R: j is about 1 there
            by construction).
        jitter_span: steps over which the jitter is taken (`jitter_reference`).
        neutral_empty_steps: a step at which the aligner gave no measurement at all costs no
            hypothesis a missed measurement (-log p_NM): the maps shared too few objects for
            any candidate, which says nothing about which alignment is right, and a
            hypothesis seen at two steps of a sparse overlap is not judged as if it had been
            missed at the others. A step that offered measurements elsewhere still charges
            every hypothesis that took none. False: every step charges a miss (the paper).

    Bounds, checked when the object is made (a value beyond one is a `ParameterError` naming
    the field, as are NaN and infinities): the caps of the trees as above (`MAX_WINDOW`,
    `MAX_LEAVES`, `MAX_MEASUREMENTS`, and together `MAX_TREE_BYTES`); costs and evidence in
    nats (tau in [-1e6, 1e6], switch_margin and object_nats in [0, 1e6]) at most 1e6
    (`MAX_NATS`: a thousand-step window whose every step is as unlikely as the smallest
    positive float, e^-745); counts of steps (drop_after, hold_for, switch_after,
    report_after, recall_for, jitter_span) at most `MAX_STEPS`, 315 576 000 (a year of steps
    at 10 Hz); counts within a window (min_distinct, switch_support, early_measurements) at most
    `MAX_WINDOW`, which no path holds more measurements than; object_base at most 1e6
    (`MAX_OBJECTS`); jitter_reference at most 1e6 (`MAX_FACTOR`); gate_box entries (metres
    or radians) at most 1e9 (`MAX_COORDINATE`, the bound of every measurement); the entries
    of Q, held_Q and P0 at most 1e18 (`MAX_VARIANCE`, the bound of every measurement
    covariance) in magnitude. Probabilities and shares are bounded by their ranges.
    """

    window: int = 8
    max_leaves: int = 200
    max_children: int = 4
    explore_max_leaves: int = 50
    explore_max_children: int = 2
    max_measurements: int = 32
    p_no_measurement: float = 0.001
    tau: float = 8.0
    Q: np.ndarray = field(default_factory=_alignment_process_noise)
    P0: np.ndarray = field(default_factory=constant_alignment_covariance)
    angle_indices: tuple[int, ...] = (2,)
    gate: Literal["mahalanobis", "box"] = "mahalanobis"
    gate_probability: float = 0.999
    gate_box: tuple[float, ...] | None = None
    cost_model: Literal["paper", "reference"] = "paper"
    root_in_window: bool = False
    promotion: Literal["branch", "reseed"] = "branch"
    drop_rule: Literal["best_path", "window"] = "best_path"
    drop_after: int = 40
    hold_for: int | None = 200
    held_Q: np.ndarray | None = None
    switch_after: int | None = 3
    switch_margin: float = 5.0
    switch_support: int | None = 2
    min_distinct: int = 2
    switch_stale: bool = True
    withhold_contested: bool = True
    lookalike_share: float = 0.9
    report_after: int | None = None
    sequential: bool = True
    object_nats: float = 2.0
    object_base: int = 5
    early_measurements: int = 2
    recall_for: int | None = 100
    neutral_empty_steps: bool = True
    jitter_reference: float | None = None
    jitter_span: int = 40

    def __post_init__(self) -> None:
        o = "TCAFFParams"
        Q = _spd(self.Q, None, o, "Q", bounded=True)
        d = Q.shape[0]
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "P0", _spd(self.P0, d, o, "P0", bounded=True))
        for name, high, limit in (("max_leaves", MAX_LEAVES, "MAX_LEAVES"),
                                  ("explore_max_leaves", MAX_LEAVES, "MAX_LEAVES"),
                                  ("max_children", MAX_MEASUREMENTS, "MAX_MEASUREMENTS"),
                                  ("explore_max_children", MAX_MEASUREMENTS, "MAX_MEASUREMENTS"),
                                  ("max_measurements", MAX_MEASUREMENTS, "MAX_MEASUREMENTS")):
            _count(o, name, getattr(self, name), 1, high, limit)
        steps = dict(high=MAX_STEPS, limit="MAX_STEPS")
        _count(o, "drop_after", self.drop_after, 1, **steps)
        _count(o, "hold_for", self.hold_for, 1, **steps, none=True)
        if self.held_Q is not None:
            object.__setattr__(self, "held_Q", _spd(self.held_Q, d, o, "held_Q", bounded=True))
        _count(o, "window", self.window, 1, MAX_WINDOW, "MAX_WINDOW")
        for name in ("p_no_measurement", "gate_probability"):
            value = getattr(self, name)
            _require(_real(value) and 0 < value < 1, o, name, value, "must be in (0, 1)")
        _number(o, "tau", self.tau, -MAX_NATS, MAX_NATS, "nats", "MAX_NATS")
        angles = self.angle_indices
        if isinstance(angles, np.ndarray) and angles.ndim == 1:
            angles = angles.tolist()
        ok = (isinstance(angles, (tuple, list))
              and all(_int_at_least(a, 0) and a < d for a in angles)
              and len(set(angles)) == len(angles))
        _require(ok, o, "angle_indices", self.angle_indices, f"must be distinct ints in [0, {d})")
        object.__setattr__(self, "angle_indices", tuple(int(a) for a in angles))
        _require(_one_of(self.gate, ("mahalanobis", "box")), o, "gate", self.gate,
                 "must be 'mahalanobis' or 'box'")
        box = (2.0,) * d if self.gate_box is None else _reals(self.gate_box)
        _require(box is not None and len(box) == d
                 and all(0 < v <= MAX_COORDINATE for v in box), o, "gate_box", self.gate_box,
                 f"must hold {d} numbers > 0 and <= {_bound(MAX_COORDINATE)} (MAX_COORDINATE), "
                 "or be None")
        object.__setattr__(self, "gate_box", box)
        _require(_one_of(self.cost_model, ("paper", "reference")), o, "cost_model",
                 self.cost_model, "must be 'paper' or 'reference'")
        _require(isinstance(self.root_in_window, bool), o, "root_in_window",
                 self.root_in_window, "must be True or False")
        _require(_one_of(self.promotion, ("branch", "reseed")), o, "promotion", self.promotion,
                 "must be 'branch' or 'reseed'")
        _require(_one_of(self.drop_rule, ("best_path", "window")), o, "drop_rule",
                 self.drop_rule, "must be 'best_path' or 'window'")
        _count(o, "switch_after", self.switch_after, 1, **steps, none=True)
        _number(o, "switch_margin", self.switch_margin, 0, MAX_NATS, "nats", "MAX_NATS")
        window = dict(high=MAX_WINDOW, limit="MAX_WINDOW")
        _count(o, "min_distinct", self.min_distinct, 1, **window)
        _count(o, "switch_support", self.switch_support, 1, **window, none=True)
        _require(isinstance(self.switch_stale, bool), o, "switch_stale", self.switch_stale,
                 "must be True or False")
        _require(isinstance(self.withhold_contested, bool), o, "withhold_contested",
                 self.withhold_contested, "must be True or False")
        _require(_real(self.lookalike_share) and 0 <= self.lookalike_share <= 1, o,
                 "lookalike_share", self.lookalike_share, "must be a number in [0, 1]")
        _count(o, "report_after", self.report_after, 1, **steps, none=True)
        _require(isinstance(self.sequential, bool), o, "sequential", self.sequential,
                 "must be True or False")
        _require(isinstance(self.neutral_empty_steps, bool), o, "neutral_empty_steps",
                 self.neutral_empty_steps, "must be True or False")
        # the released code's promotion replays a full window, which a young tree has not
        _require(not (self.sequential and self.promotion == "reseed"), o, "sequential",
                 self.sequential, "must be False with promotion='reseed'")
        _number(o, "object_nats", self.object_nats, 0, MAX_NATS, "nats", "MAX_NATS")
        _count(o, "object_base", self.object_base, 0, MAX_OBJECTS, "MAX_OBJECTS")
        _count(o, "early_measurements", self.early_measurements, 2, **window)
        _count(o, "recall_for", self.recall_for, 1, **steps, none=True)
        _number(o, "jitter_reference", self.jitter_reference, 0, MAX_FACTOR, limit="MAX_FACTOR",
                above=True, none=True)
        _count(o, "jitter_span", self.jitter_span, 2, **steps)
        caps = ("window", "max_leaves", "max_children", "explore_max_leaves",
                "explore_max_children", "max_measurements")
        need = self.tree_bytes()
        _require(need <= MAX_TREE_BYTES, o, "(" + ", ".join(caps) + ")",
                 tuple(getattr(self, name) for name in caps),
                 f"the hypothesis trees could need {need / (1 << 30):.2f} GiB at once, more "
                 f"than MAX_TREE_BYTES ({MAX_TREE_BYTES / (1 << 30):g} GiB); lower the window "
                 f"or the caps")

    def tree_bytes(self) -> int:
        """Bytes the filter's hypothesis trees could need at once: every leaf of the main
        tree (`max_leaves`) and of every open exploring tree (`max_measurements` seeded per
        step, each open for `window` steps, `explore_max_leaves` each) given every child its
        caps allow (`max_children`, `explore_max_children`, at most `max_measurements`, and
        the child without a measurement), each leaf holding its state, covariance, and a
        choice (4 bytes) and an edge cost (8) per column of its path (W + 2)."""
        d, columns, cap = self.Q.shape[0], self.window + 2, self.max_measurements
        leaf = 8 * d + 8 * d * d + 12 * columns + 16
        main = self.max_leaves * (min(self.max_children, cap) + 1)
        exploring = (cap * self.window * self.explore_max_leaves
                     * (min(self.explore_max_children, cap) + 1))
        return leaf * (main + exploring)

    @property
    def dim(self) -> int:
        """d, the dimension of the state and of every measurement."""
        return self.Q.shape[0]

    @property
    def counts_evidence(self) -> bool:
        """Whether the filter reads the object evidence given to `update`."""
        return (self.min_distinct > 1 or self.switch_stale or self.withhold_contested
                or self.switch_support is not None)

    @classmethod
    def paper(cls) -> TCAFFParams:
        """The paper's equations alone: every measurement counts as evidence, and a main
        hypothesis confirmed at a step is never abandoned at that step."""
        return cls(min_distinct=1, switch_stale=False, withhold_contested=False,
                   switch_support=None, sequential=False, recall_for=None,
                   neutral_empty_steps=False, hold_for=None)

    @classmethod
    def reference(cls) -> TCAFFParams:
        """The authors' released code: its threshold, gate, cost, promotion and deletion."""
        return cls(tau=9.0, gate="box", cost_model="reference", root_in_window=True,
                   promotion="reseed", drop_rule="window", drop_after=40, switch_after=None,
                   switch_support=None, min_distinct=1, switch_stale=False,
                   withhold_contested=False, sequential=False, recall_for=None,
                   neutral_empty_steps=False, hold_for=None)


def _default_odometry_cov(dim: int) -> np.ndarray:
    deg = math.radians(1.0)
    if dim == 2:
        return np.diag([0.05**2, 0.05**2, deg**2])
    return np.diag([(0.5 * deg) ** 2, (0.5 * deg) ** 2, deg**2, 0.05**2, 0.05**2, 0.05**2])


@dataclass(frozen=True, eq=False)
class GraphParams(_ByValue):
    """Settings of `InterRobotGraph` (iSAM2 smoothing of frame alignments and trajectories).

    Attributes:
        dim: 2 for Pose2 (planar robots), 3 for Pose3 with gravity-aligned alignments
            (x, y, z, yaw).
        Q: drift of one pair's alignment per step, the covariance of (x, y, theta) (dim 2,
            (3, 3)) or (x, y, z, yaw) (dim 3, (4, 4)). Each robot's chain gets Q / 2, so the
            relative drift of two robots is Q, as TCAFF assumes. None: TCAFF's default Q
            (z drifting like x and y in 3D).
        robust: M-estimator of the alignment factors: "huber", "cauchy" or "none" (Gaussian).
        robust_k: its threshold, in standard deviations of the whitened residual.
        anchor_sigma: metres and radians; prior on robot 0's first alignment and keyframe.
        free_sigmas: (metres, radians) of the prior that fixes the gauge of robots (or
            groups of robots) not connected to robot 0 by any factor. It is placed on their
            latest variable at its current value and removed as soon as they connect, so it
            never biases an alignment.
        gravity_sigma: radians, roll and pitch uncertainty of a 3D alignment factor.
        odometry_cov: covariance of the odometry between consecutive keyframes in gtsam's
            tangent order ((vx, vy, omega) for Pose2; (wx, wy, wz, vx, vy, vz), rotation first,
            for Pose3). None: 5 cm and 1 deg (0.5 deg roll and pitch) per keyframe.
        relinearize_threshold, relinearize_skip: iSAM2's relinearisation settings. 0.05
            rather than 0.01: with 12 alignments per step, 0.01 kept relinearising old
            alignment variables as smoothing moved them and the update time grew tenfold
            over an hour of steps; noise-free alignments still come out exact.
        max_iterations, settle_threshold: extra iSAM2 iterations, at most `max_iterations`,
            run while a variable the update touched is more than `settle_threshold` (metres or
            radians, tangent) from its linearisation point: big corrections such as a first
            alignment or a removed hypothesis are nonlinear.
        switch_hold: when TCAFF switches a pair to a hypothesis that disagrees with the graph,
            the earlier hypothesis's factors are removed only once the new one has been
            reported at this many steps (the default window W): a late or passing switch then
            leaves the smoothed history in place. 1 removes them at the switch.
        shared_maps: each robot's map enters every alignment of that robot at a step, so
            those alignments share its error: around a cycle (robots 0-1, 1-2, 2-0) the
            graph would otherwise count it once per alignment and report a covariance too
            small. True inflates the alignment factors that one update commits for a step:
            in each block of their robot pairs (pairs joined by cycles, a biconnected
            component) with E pairs among V robots, each covariance times E / (V - 1), so
            that the block claims no more than V - 1 alignments, a tree's worth. Exact for a
            cycle or a complete graph of equal alignments whose errors are all their maps';
            cautious where part of the error is each pair's own; only approximate for other
            shapes (of two triangles sharing a pair, the shared pair reads 0.83 of one
            alignment's covariance, too sure, the other measured pairs 1.04). A pair on no
            cycle (two robots, a chain, a star, a pair hanging off a cycle) is unchanged, and
            the factors of one pair at a step (both directions, rival hypotheses) count as
            one pair: give one direction per pair, as two register the same maps. Factors
            added to a step already committed, or removed later, do not re-weigh the others.
            In 3D the roll and pitch of `gravity_sigma` are inflated with the rest. False
            counts every factor in full, for alignments from independent sources.
        cycle_check: `update` first tests the TCAFF estimates given since the last update
            (`add_tcaff_estimate`) around every cycle of three robots, as
            `TeamConsistency` does (chi-square 0.999 on the composed covariance; the largest
            set of pairs that no failed cycle lies inside is kept). The factors of a
            hypothesis left out, committed and to come, are held out of the graph until a
            later update's test does not leave it out, and the pair is read through the other
            robots. Not tested at an update whose estimates span over 1024 robots.
            Without it, one wrong pair measured more often than the pairs that contradict it
            pulls the graph to its side, and every pair of its robots with it. False weighs
            every hypothesis's factors by the M-estimator alone.
        past_covariance: what `alignment(i, j, step)` reports as the covariance of an
            earlier step. "causal": the marginal covariance the step had while it was the
            latest (kept for every step: (3 n)^2 numbers a step, 1.2 KB at four robots),
            with the smoothed mean. Consecutive registrations share most of their error, and
            TCAFF's R makes a filter reading forward settle at one registration's error; the
            smoothed marginal reads that evidence twice, from both sides, and comes out
            surer than the error (NEES 3.3-3.9 against 2.3-2.8 causal). A factor removed
            for good later (a hypothesis abandoned) makes the steps from its own to the
            removal report their marginal now. "smoothed": the marginal covariance in the
            current solution. With either, a step that left the horizon keeps the joint it
            left with.
        horizon: steps the graph keeps for long runs: `update(k)` marginalises the variables
            of the steps at or before k - horizon (alignment variables, and the keyframes
            committed with those steps) into a linear factor on what they were linked to, one
            step per update, so memory and update time stay bounded. Steps that left keep the
            estimate they had then, and the covariance they had as the latest step; keyframes
            keep their last pose. Factors that left can no longer be removed (a hypothesis
            switch removes only those within the horizon). None keeps every step (offline
            studies).
        history: with a horizon, how many of the steps that left it stay readable (the
            latest ones): their alignments and covariances, and the keyframes that left with
            them. Older ones are forgotten, and reading them raises `DataError`. What a step
            keeps is (3 n)^2 + 9 n numbers for n planar robots ((6 n)^2 + 16 n in 3D): 1.4 KB
            at four robots, 19 KB at 16, so 3600 steps (an hour at 1 Hz) 5 MB and 70 MB.
            None keeps them all. Needs a horizon.
    """

    dim: Literal[2, 3] = 2
    Q: np.ndarray | None = None
    robust: Literal["huber", "cauchy", "none"] = "huber"
    robust_k: float = 1.345
    anchor_sigma: float = 1e-3
    free_sigmas: tuple[float, float] = (1.0, 1.0)
    gravity_sigma: float = 1e-3
    odometry_cov: np.ndarray | None = None
    relinearize_threshold: float = 0.05
    relinearize_skip: int = 1
    max_iterations: int = 10
    settle_threshold: float = 0.5
    switch_hold: int = TCAFFParams.window
    shared_maps: bool = True
    cycle_check: bool = True
    past_covariance: Literal["causal", "smoothed"] = "causal"
    horizon: int | None = None
    history: int | None = None

    def __post_init__(self) -> None:
        o = "GraphParams"
        _require(_one_of(self.dim, (2, 3)), o, "dim", self.dim, "must be 2 or 3")
        n_param = 3 if self.dim == 2 else 4
        if self.Q is None:
            q = np.diag(_alignment_process_noise())
            Q = np.diag(q if self.dim == 2 else [q[0], q[1], q[0], q[2]])
        else:
            Q = _spd(self.Q, n_param, o, "Q")
        object.__setattr__(self, "Q", Q)
        odo = (_default_odometry_cov(self.dim) if self.odometry_cov is None
               else _spd(self.odometry_cov, 3 if self.dim == 2 else 6, o, "odometry_cov"))
        object.__setattr__(self, "odometry_cov", odo)
        _require(_one_of(self.robust, ("huber", "cauchy", "none")), o, "robust", self.robust,
                 "must be 'huber', 'cauchy' or 'none'")
        for name in ("robust_k", "anchor_sigma", "gravity_sigma", "relinearize_threshold",
                     "settle_threshold"):
            value = getattr(self, name)
            _require(_real(value) and math.isfinite(value) and value > 0, o,
                     name, value, "must be a finite number > 0")
        sig = _reals(self.free_sigmas)
        _require(sig is not None and len(sig) == 2 and all(0 < v < math.inf for v in sig), o,
                 "free_sigmas", self.free_sigmas, "must be (metres, radians), finite and > 0")
        object.__setattr__(self, "free_sigmas", sig)
        _require(_int_at_least(self.relinearize_skip, 1), o, "relinearize_skip",
                 self.relinearize_skip, "must be an int >= 1")
        _require(_int_at_least(self.max_iterations, 0), o, "max_iterations",
                 self.max_iterations, "must be an int >= 0")
        _require(_int_at_least(self.switch_hold, 1), o, "switch_hold", self.switch_hold,
                 "must be an int >= 1")
        for name in ("shared_maps", "cycle_check"):
            _require(isinstance(getattr(self, name), bool), o, name, getattr(self, name),
                     "must be True or False")
        _require(_one_of(self.past_covariance, ("causal", "smoothed")), o, "past_covariance",
                 self.past_covariance, "must be 'causal' or 'smoothed'")
        _require(self.horizon is None or _int_at_least(self.horizon, 2), o, "horizon",
                 self.horizon, "must be an int >= 2 (steps) or None")
        _require(self.history is None or _int_at_least(self.history, 0), o, "history",
                 self.history, "must be an int >= 0 (steps) or None")
        _require(self.history is None or self.horizon is not None, o, "history",
                 self.history, "needs a horizon: without one no step leaves the graph")
