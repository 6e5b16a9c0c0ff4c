"""PairwiseAligner: FrameAligner + TCAFF for one directed robot pair."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from .covariance import _held_drift
from .errors import ConfigError, DataError
from .frame_aligner import AlignmentMeasurement, FrameAligner, MapMemory, _confirms
from .identities import ObjectIdentities, recent_ids
from .inputs import finite_time, shown
from .object_map import ObjectMap, as_object_map
from .param_checks import MAX_COORDINATE
from .params import FrameAlignerParams, TCAFFParams, _given_or_default, _require
from .registration import _weights
from .tcaff import TCAFF, AlignmentEstimate
from .twins import Twins

__all__ = ["HeldDrift", "PairwiseAligner", "admitted", "counted", "evidence_of", "explained",
           "fed_by", "feeding", "gives_ids", "guided_search", "unchecked"]


def unchecked(params: FrameAlignerParams) -> FrameAlignerParams:
    """`params` without the checks beyond MNO-CLIPPER's (residual, objects explained, spread,
    ambiguity) and with the paper's size gate: the candidates the released code sees, down to
    `min_associations` associations (the released code's is 5).

    Raises:
        ConfigError: params not a FrameAlignerParams.
    """
    _require(isinstance(params, FrameAlignerParams), "unchecked", "params", params,
             "must be a FrameAlignerParams")
    return replace(params, max_rmse=None, min_inliers=None, min_spread=0.0,
                   check_ambiguity=False, size_partial=None)


def feeding(aligner: FrameAlignerParams, tcaff: TCAFFParams) -> FrameAlignerParams:
    """`aligner` for candidates that feed a filter with `tcaff`'s parameters: a calibrated
    covariance inflated for that filter's Q (`repeat_Q`) unless it names its own.

    Raises:
        ConfigError: aligner not a FrameAlignerParams or tcaff not a TCAFFParams.
    """
    _require(isinstance(aligner, FrameAlignerParams), "feeding", "aligner", aligner,
             "must be a FrameAlignerParams")
    _require(isinstance(tcaff, TCAFFParams), "feeding", "tcaff", tcaff, "must be a TCAFFParams")
    if aligner.repeat_Q is not None or tcaff.dim != 3:
        return aligner
    return replace(aligner, repeat_Q=tcaff.Q)


def fed_by(tcaff: TCAFFParams, aligner: FrameAlignerParams) -> TCAFFParams:
    """`tcaff` for a filter of `aligner`'s candidates where the aligner's covariance counts the
    error consecutive registrations share (calibrated, `repeat_inflation` > 0): with the
    aligner's `jitter_reference` where the filter names none; and for (x, y, theta), where the
    filter holds by the drift (`hold_for`) and has a reference to judge the drift by, a
    `held_Q` of the aligner's `map_drift` over one second, diag(d_t^2, d_t^2, d_theta^2),
    where it names none.

    Raises:
        ConfigError: tcaff not a TCAFFParams or aligner not a FrameAlignerParams.
    """
    _require(isinstance(tcaff, TCAFFParams), "fed_by", "tcaff", tcaff, "must be a TCAFFParams")
    _require(isinstance(aligner, FrameAlignerParams), "fed_by", "aligner", aligner,
             "must be a FrameAlignerParams")
    if aligner.covariance != "calibrated" or aligner.repeat_inflation == 0:
        return tcaff
    if tcaff.jitter_reference is None and aligner.jitter_reference is not None:
        tcaff = replace(tcaff, jitter_reference=aligner.jitter_reference)
    held_Q = _map_drift_per_second(aligner)
    if (tcaff.held_Q is None and tcaff.dim == 3 and tcaff.hold_for is not None
            and tcaff.jitter_reference is not None and held_Q is not None):
        tcaff = replace(tcaff, held_Q=held_Q)
    return tcaff


def _map_drift_per_second(aligner: FrameAlignerParams) -> np.ndarray | None:
    """diag(d_t^2, d_t^2, d_theta^2) of the aligner's `map_drift`, or None where a part is 0
    (a covariance must be positive definite)."""
    d_t, d_theta = aligner.map_drift
    return np.diag([d_t**2, d_t**2, d_theta**2]) if d_t > 0 and d_theta > 0 else None


class HeldDrift:
    """Where a pair's two robots were last seen, and the growth of its held alignment's
    covariance about them: the aligner's `map_drift` over one second with each robot's heading
    turning about where the robot is (`covariance.held_drift`), for a filter whose `held_Q` is
    that drift's diagonal (`fed_by`'s; other filters keep their own). A robot is placed at the
    centroid of its map's objects weighted by how recently each was seen,
    1 / (weight_offset + age^2), age = now - last_seen in seconds (a registration weights an
    association 1 / (weight_offset + age_i age_j)); an empty map, as on a silent step, leaves
    the robot where it was last seen.
    """

    def __init__(self, aligner: FrameAlignerParams, tcaff: TCAFFParams) -> None:
        """For a pair of `aligner` and a filter of `tcaff` (as `fed_by` gave it).

        Raises:
            ConfigError: aligner not a FrameAlignerParams or tcaff not a TCAFFParams.
        """
        _require(isinstance(aligner, FrameAlignerParams), "HeldDrift", "aligner", aligner,
                 "must be a FrameAlignerParams")
        _require(isinstance(tcaff, TCAFFParams), "HeldDrift", "tcaff", tcaff,
                 "must be a TCAFFParams")
        self.params = aligner
        drift = _map_drift_per_second(aligner)
        #: whether the filter's held_Q is the map drift's diagonal, which this replaces
        self.applies = (tcaff.held_Q is not None and drift is not None
                        and np.array_equal(tcaff.held_Q, drift))
        #: (2,) where robot i was last seen, in o_i, and robot j, in o_j (None: not yet)
        self.points: tuple[np.ndarray | None, np.ndarray | None] = (None, None)

    def growth(self, held: AlignmentEstimate | None, ego_map: ObjectMap, other_map: ObjectMap,
               now: float) -> np.ndarray | None:
        """(3, 3) this step's growth of the held alignment's covariance (`TCAFF.update`'s
        held_Q), having placed each robot by its map; None where it does not apply, without a
        held alignment, or before both robots were seen.

        Raises:
            DataError: held neither None nor an AlignmentEstimate of an (x, y, theta) within
                MAX_COORDINATE, a map that is not an ObjectMap, or now not a finite number.
        """
        o = "HeldDrift.growth"
        maps = (as_object_map(o, "ego_map", ego_map), as_object_map(o, "other_map", other_map))
        now = finite_time(o, "now", now)
        if held is not None and not (isinstance(held, AlignmentEstimate)
                                     and isinstance(held.x, np.ndarray)
                                     and held.x.shape == (3,) and held.x.dtype.kind in "iuf"
                                     and np.all(np.abs(held.x) <= MAX_COORDINATE)):
            raise DataError(f"{o}: held must be None or an AlignmentEstimate of an (x, y, "
                            f"theta) within {MAX_COORDINATE:g} (MAX_COORDINATE), got "
                            f"{shown(held)}")
        offset = self.params.weight_offset
        self.points = tuple(_recent_centroid(m, now, offset) if len(m) else last
                            for m, last in zip(maps, self.points, strict=True))
        if not self.applies or held is None or self.points[0] is None or self.points[1] is None:
            return None
        return _held_drift(held.x, *self.points, self.params.map_drift)


def _recent_centroid(objects: ObjectMap, now: float, offset: float) -> np.ndarray:
    """(2,) the plane centroid of a map's objects (at least one), each weighted as a
    registration weights an object it pairs with itself (`registration.arun_weights`:
    1 / (offset + age^2)); where weights overflow, of the objects seen at `now`."""
    ages = objects.ages(now)
    with np.errstate(over="ignore", divide="ignore"):
        weights = _weights(ages * ages, offset)
    if not np.all(np.isfinite(weights)):
        weights = np.isinf(weights).astype(float)
    weights = weights / weights.max() if weights.max() > 0 else np.ones(len(objects))
    return weights @ objects.centroids[:, :2] / weights.sum()


def admitted(found: list[AlignmentMeasurement], estimate: AlignmentEstimate | None,
             params: FrameAlignerParams) -> list[AlignmentMeasurement]:
    """The candidates a TCAFF filter may take: every unambiguous one, and an ambiguous or
    tracked one only when it lies within `confirm_translation` and `confirm_heading` of the
    filter's estimate (it may confirm what the filter holds, never start or move a hypothesis).

    Raises:
        DataError: found not a list of AlignmentMeasurement, estimate neither an
            AlignmentEstimate nor None; ConfigError: params not a FrameAlignerParams.
    """
    found = _measurements("admitted", found)
    if estimate is not None and not isinstance(estimate, AlignmentEstimate):
        raise DataError(f"admitted: estimate must be an AlignmentEstimate or None, got "
                        f"{shown(estimate)}")
    _require(isinstance(params, FrameAlignerParams), "admitted", "params", params,
             "must be a FrameAlignerParams")
    held = None if estimate is None else estimate.x
    return [m for m in found if not (m.ambiguous or m.tracked) or _confirms(m.z, held, params)]


def evidence_of(found: list[AlignmentMeasurement], ids: tuple[np.ndarray, np.ndarray] | None,
                only: np.ndarray | None = None) -> list[np.ndarray | None] | None:
    """Per candidate, the (ego object id, other object id) pairs it associates (k, 2), from
    the two maps' persistent ids (`identities.recent_ids`, indexed like the maps); None without
    ids (a filter that does not count evidence needs none). With `only` ((k,) bool), the
    candidates it leaves out get None: distinct evidence whatever objects they use.

    Raises:
        DataError: found not a list of AlignmentMeasurement; ids neither None nor two 1-D
            integer arrays long enough for the associations' indices; only not one bool per
            candidate.
    """
    found = _measurements("evidence_of", found)
    if ids is None:
        return None
    if not isinstance(ids, (tuple, list)) or len(ids) != 2:
        raise DataError(f"evidence_of: ids must be None or (ego ids, other ids), got "
                        f"{shown(ids)}")
    ego_ids, other_ids = (np.asarray(each) for each in ids)
    for side, each in enumerate((ego_ids, other_ids)):
        if each.ndim != 1 or each.dtype.kind not in "iu":
            raise DataError(f"evidence_of: ids[{side}] must be a 1-D array of integer ids, "
                            f"got {shown(ids[side])}")
        reach = max((int(m.associations[:, side].max()) for m in found
                     if len(m.associations)), default=-1)
        if reach >= len(each):
            raise DataError(f"evidence_of: ids[{side}] has {len(each)} ids, an association "
                            f"refers to index {reach}")
    pairs = [np.column_stack([ego_ids[m.associations[:, 0]], other_ids[m.associations[:, 1]]])
             for m in found]
    if only is None:
        return pairs
    only = np.asarray(only)
    if only.shape != (len(found),) or only.dtype != bool:
        raise DataError(f"evidence_of: only must be {len(found)} booleans, one per candidate, "
                        f"got {shown(only)}")
    return [each if keep else None for each, keep in zip(pairs, only, strict=True)]


def counted(params: TCAFFParams, lookalike: bool, objects: np.ndarray) -> np.ndarray | None:
    """Which candidates' objects the filter counts as distinct evidence (`evidence_of`'s
    `only`), from the number of objects each explains (`explained`): all of them among
    look-alikes (`gives_ids`), elsewhere those explaining fewer than `object_base` objects,
    whose agreement a few look-alike objects re-matched at every step could make; None when
    none are counted (the filter does not count evidence, or nothing qualifies).

    Raises:
        ConfigError: params not a TCAFFParams; DataError: objects not a 1-D array of counts.
    """
    _require(isinstance(params, TCAFFParams), "counted", "params", params,
             "must be a TCAFFParams")
    objects = np.asarray(objects)
    if objects.ndim != 1 or objects.dtype.kind not in "iu":
        raise DataError(f"counted: objects must be a 1-D array of counts, got {shown(objects)}")
    if not params.counts_evidence:
        return None
    only = np.full(objects.shape, True) if lookalike else objects < params.object_base
    return only if only.any() else None


def explained(found: list[AlignmentMeasurement]) -> np.ndarray:
    """(k,) how many objects each candidate explains: its inliers where the aligner counted
    them, else its associations (the `objects` of `TCAFF.update`).

    Raises:
        DataError: found not a list of AlignmentMeasurement.
    """
    found = _measurements("explained", found)
    return np.array([m.inliers if m.inliers > 0 else len(m.associations) for m in found],
                    dtype=np.int64)


def gives_ids(aligner: FrameAligner, params: TCAFFParams, ego: ObjectMap, other: ObjectMap,
              now: float) -> bool:
    """Whether the filter is given object ids at this step: it counts distinct evidence and
    the maps are of look-alikes (`FrameAligner.lookalike_share` at least
    `TCAFFParams.lookalike_share`). Elsewhere every measurement is distinct evidence.

    Raises:
        ConfigError: params not a TCAFFParams; DataError: aligner not a FrameAligner, or maps
            and time `FrameAligner.lookalike_share` refuses.
    """
    _require(isinstance(params, TCAFFParams), "gives_ids", "params", params,
             "must be a TCAFFParams")
    if not isinstance(aligner, FrameAligner):
        raise DataError(f"gives_ids: aligner must be a FrameAligner, got {shown(aligner)}")
    return params.counts_evidence and aligner.lookalike_share(
        ego, other, now) >= params.lookalike_share


def guided_search(params: FrameAlignerParams, tcaff: TCAFF, since_full: int) -> bool:
    """Whether a pair's next search may be guided by the alignment its filter holds
    (`FrameAlignerParams.guide_radius`): the filter `tcaff` holds one, no rival hypothesis of
    the filter is open (`TCAFF.rivalled`: a search near the held alignment would starve it),
    its acceptance is not provisional (`TCAFF.provisional`: a guided step's candidates are
    judged ambiguous only among themselves, so a decoy would be settled by the search it
    guides) and fewer than `full_search_every` - 1 steps in a row were guided (`since_full`,
    counted by the caller: steps since the last step not guided).

    Raises:
        ConfigError: params not a FrameAlignerParams; DataError: tcaff not a TCAFF or
            since_full not an int >= 0.
    """
    _require(isinstance(params, FrameAlignerParams), "guided_search", "params", params,
             "must be a FrameAlignerParams")
    if not isinstance(tcaff, TCAFF):
        raise DataError(f"guided_search: tcaff must be a TCAFF, got {shown(tcaff)}")
    if not (isinstance(since_full, (int, np.integer)) and not isinstance(since_full, bool)
            and since_full >= 0):
        raise DataError(f"guided_search: since_full must be an int >= 0, got "
                        f"{shown(since_full)}")
    return (params.guide_radius is not None and tcaff.held is not None
            and since_full + 1 < params.full_search_every and not tcaff.rivalled
            and not tcaff.provisional)


def _measurements(owner: str, found) -> list[AlignmentMeasurement]:
    """`found` as a list of AlignmentMeasurement, else DataError naming `owner`."""
    if not isinstance(found, (list, tuple)) or not all(
            isinstance(m, AlignmentMeasurement) for m in found):
        raise DataError(f"{owner}: found must be a list of AlignmentMeasurement, got "
                        f"{shown(found)}")
    return list(found)


class PairwiseAligner:
    """Estimates T_oi_oj (robot j's odometry frame in robot i's) from the two robots' object
    maps, exchanged once per step (the paper uses 1 Hz).

    Attributes:
        aligner: the FrameAligner making candidate alignments.
        filter: the TCAFF filter choosing among them over time.
        measurements: the candidates of the latest step (ambiguous ones included).
        taken: those of them the filter was given (`admitted`), in the order it was given
            them: the latest estimate's `measurement` indexes this list (for
            `InterRobotGraph.add_tcaff_estimate`, with the filter's own estimate,
            `filter.estimate`: the graph weighs the candidate, which no twin widens).
        guided: whether the latest step's search was guided by the held alignment
            (`guided_search`; the aligner still searched in full when nothing guided
            confirmed the hold).
    """

    def __init__(self, aligner_params: FrameAlignerParams | None = None,
                 tcaff_params: TCAFFParams | None = None) -> None:
        """Both stages with their parameters (None: the defaults).

        Raises:
            ConfigError: aligner_params or tcaff_params of the wrong type, or TCAFF parameters
                not for (x, y, theta) states.
        """
        tcaff_params = _given_or_default(TCAFFParams, tcaff_params, "PairwiseAligner",
                                         "tcaff_params")
        if tcaff_params.dim != 3 or tcaff_params.angle_indices != (2,):
            raise ConfigError(f"PairwiseAligner needs TCAFFParams for (x, y, theta) states "
                              f"(d = 3, angle_indices = (2,)), got d = {tcaff_params.dim}, "
                              f"angle_indices = {tcaff_params.angle_indices}")
        self.aligner = FrameAligner(feeding(_given_or_default(
            FrameAlignerParams, aligner_params, "PairwiseAligner", "aligner_params"),
            tcaff_params))
        self.filter = TCAFF(fed_by(tcaff_params, self.aligner.params))
        self._held_drift = HeldDrift(self.aligner.params, self.filter.params)
        self._twins = Twins(self.aligner.params, self.filter.params.window)
        self.measurements: list[AlignmentMeasurement] = []
        self.taken: list[AlignmentMeasurement] = []
        self._last_time: float | None = None
        self._memory = (MapMemory.of(self.aligner.params), MapMemory.of(self.aligner.params))
        self._identities = (ObjectIdentities(), ObjectIdentities())
        self.guided = False
        self._since_full = 0  # steps in a row guided (`full_search_every`)

    @classmethod
    def reference(cls) -> PairwiseAligner:
        """Both stages with the authors' released settings."""
        return cls(FrameAlignerParams.reference(), TCAFFParams.reference())

    def update(self, t: float, ego_map: ObjectMap, other_map: ObjectMap
               ) -> AlignmentEstimate | None:
        """One step: align the maps, filter the candidates. With `guide_radius` set, the
        search is guided by the filter's held alignment while `guided_search` allows it.

        Args:
            t: seconds, the current time on the maps' `last_seen` clock; increasing.
            ego_map: robot i's map in its odometry frame; other_map: robot j's in its own.
        Returns:
            The TCAFF estimate of T_oi_oj, or None while no hypothesis has been accepted; its
            covariance covers the twins of a map that has fitted itself over the window
            (`twins.Twins`).
        Raises:
            DataError: t not a finite number (a string, None, an array, NaN) or not later than
                the previous step's; a map that is not an ObjectMap; or maps the aligner
                cannot register (see `FrameAligner.measurements`).
            ConfigError: aligner settings that give a candidate a covariance beyond
                `MAX_VARIANCE` (see `FrameAligner.measurements`).
            A call that raises leaves the aligner as it was: the same t may be given again.
        """
        o = "PairwiseAligner.update"
        t = finite_time(o, "t", t)
        ego_map = as_object_map(o, "ego_map", ego_map)
        other_map = as_object_map(o, "other_map", other_map)
        if self._last_time is not None and t <= self._last_time:
            raise DataError(f"{o}: t = {t} is not after the previous step's "
                            f"t = {self._last_time}")
        ego_memory, other_memory = self._memory
        held = None if self.filter.held is None else self.filter.held.x
        prm = self.aligner.params
        guided = guided_search(prm, self.filter, self._since_full)
        measurements = self.aligner.measurements(
            ego_map, other_map, t, ego_memory.snapshots(), other_memory.snapshots(), held,
            guided)
        kept = admitted(measurements, self.filter.confirmable, prm)
        zs = np.array([m.z for m in kept]).reshape(-1, 3)
        Rs = np.array([m.R for m in kept]).reshape(-1, 3, 3)
        objects = explained(kept)
        only = counted(self.filter.params, gives_ids(self.aligner, self.filter.params, ego_map,
                                                     other_map, t), objects)
        # (the identities match objects by position, so they bridge the steps without ids)
        identities, ids = self._identities, None
        if only is not None:
            # the identities advance on copies, kept only once the filter has taken the step
            identities = tuple(copy.copy(each) for each in self._identities)
            ids = tuple(recent_ids(each, objects, t, prm.kappa) for each, objects
                        in zip(identities, (ego_map, other_map), strict=True))
        # placed on a copy, kept as the identities are once the filter has taken the step
        held_drift = copy.copy(self._held_drift)
        growth = held_drift.growth(self.filter.held, ego_map, other_map, t)
        estimate = self.filter.update(zs, Rs, evidence_of(kept, ids, only), objects, growth)
        # (commits its own state last, and cannot raise on the checked maps and candidates)
        estimate = self._twins.update(estimate, kept, ego_map, other_map, t)
        # the step succeeded: only now does it count as taken
        self.measurements = measurements
        self.taken = kept
        ego_memory.add(t, ego_map)
        other_memory.add(t, other_map)
        self._identities = identities
        self._held_drift = held_drift
        self._last_time = t
        self.guided = guided
        self._since_full = self._since_full + 1 if guided else 0
        return estimate
