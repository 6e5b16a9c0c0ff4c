"""PairwiseAligner: object maps over time in, T_oi_oj out."""

from __future__ import annotations

import numpy as np
import pytest
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import FrameAlignerParams, ObjectMap, PairwiseAligner, TCAFFParams
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_error, se2_from_params
from tcaff_gtsam.pairwise import fed_by, guided_search


@pytest.mark.parametrize("params", [TCAFFParams(), TCAFFParams.paper()],
                         ids=["default", "paper"])
def test_maps_over_time_give_the_true_alignment(params):
    """The maps first overlap at exchange 1. The paper's filter answers W steps later; the
    default, whose candidates explain 15 objects each, 2 steps later."""
    T_true = se2_from_params([4.0, -7.0, 2.5])
    rng = np.random.default_rng(0)
    pair_aligner = PairwiseAligner(tcaff_params=params)
    estimates = []
    for t in range(15):
        overlap = 0.5 if t % 5 else 0.0  # every fifth exchange shares no objects
        pair = overlapping_maps(rng, 30, overlap, 0.1, clutter=5, T_oi_oj=T_true, now=100.0 + t)
        estimates.append(pair_aligner.update(pair.now, pair.ego, pair.other))
    first = next(t for t, e in enumerate(estimates) if e is not None)
    assert first == (3 if params.sequential else 9)
    assert all(se2_error(T_true, e.T)[0] < 0.3 for e in estimates[first:])
    assert estimates[-1] is not None
    dt, dtheta = se2_error(T_true, estimates[-1].T)
    assert dt < 0.3 and np.degrees(dtheta) < 2.0
    assert pair_aligner.measurements  # the latest step's candidates are kept
    # the estimate's measurement indexes the candidates the filter was given
    taken = pair_aligner.taken
    assert set(map(id, taken)) <= set(map(id, pair_aligner.measurements))
    m = estimates[-1].measurement
    assert 0 <= m < len(taken)
    assert se2_error(taken[m].T, T_true)[0] < 0.5


def test_tracking_holds_an_alignment_through_steps_too_sparse_for_candidates():
    """Accepted on rich maps, then the maps share three objects for a while and nothing
    after: tracked, the estimate lasts while they are seen; without tracking it is dropped
    `drop_after` steps after the rich maps; unreported once nothing is seen (`report_after`),
    it comes back when the three objects are seen again."""
    T_true = se2_from_params([4.0, -7.0, 2.5])
    few = np.array([[0.0, 0.0], [3.0, 0.5], [1.0, 2.5]])

    def sparse(t):
        other = (few - T_true[:2, 2]) @ T_true[:2, :2]
        return (ObjectMap(np.column_stack([few, np.zeros(3)]), np.full(3, 0.5),
                          np.full(3, 0.5), np.full(3, t)),
                ObjectMap(np.column_stack([other, np.zeros(3)]), np.full(3, 0.5),
                          np.full(3, 0.5), np.full(3, t)))

    tcaff = TCAFFParams(drop_after=10, report_after=5)
    runs = {}
    for track_min in (None, 3):
        # three objects make weak candidates by default: here they make none
        pa = PairwiseAligner(FrameAlignerParams(track_min=track_min, min_associations=5),
                             tcaff)
        rng = np.random.default_rng(0)
        out = []
        for t in range(60):
            if t < 15:
                pair = overlapping_maps(rng, 30, 0.5, 0.05, T_oi_oj=T_true, now=float(t))
                maps = (pair.ego, pair.other)
            elif 35 <= t < 42:
                maps = (ObjectMap.empty(), ObjectMap.empty())
            else:
                maps = sparse(float(t))
            out.append(pa.update(float(t), *maps))
        runs[track_min] = out
    assert runs[None][14] is not None and all(e is None for e in runs[None][25:])
    tracked = runs[3]
    assert all(e is not None for e in tracked[15:35])
    assert all(e is None for e in tracked[40:42])  # nothing seen for report_after steps
    assert all(e is not None for e in tracked[42:])  # the same objects again: reported again
    assert tracked[-1].hypothesis == tracked[14].hypothesis
    dt, dtheta = se2_error(T_true, tracked[-1].T)
    assert dt < 0.1 and np.degrees(dtheta) < 1.0


def test_time_must_increase_and_be_finite():
    pair = overlapping_maps(np.random.default_rng(1), 20, 0.5)
    aligner = PairwiseAligner()
    aligner.update(10.0, pair.ego, pair.other)
    with pytest.raises(DataError, match="not after"):
        aligner.update(10.0, pair.ego, pair.other)
    with pytest.raises(DataError, match="not finite"):
        aligner.update(float("nan"), pair.ego, pair.other)


def test_needs_an_se2_state():
    params = TCAFFParams(Q=np.eye(2) * 0.01, P0=np.eye(2), angle_indices=())
    with pytest.raises(ConfigError, match="d = 2"):
        PairwiseAligner(tcaff_params=params)


def test_reference_uses_both_released_presets():
    ref = PairwiseAligner.reference()
    assert ref.filter.params.cost_model == "reference"
    assert ref.aligner.params.max_rmse is None


# ---------------------------------------------------------------------------------------------
# a failed step changes nothing


def far_away(objects):
    """The same map 2e9 m off: consistent, but beyond any odometry (the registration refuses)."""
    from tcaff_gtsam import ObjectMap

    return ObjectMap(objects.centroids + np.array([2e9, 0.0, 0.0]), objects.widths, objects.heights,
                     objects.last_seen)


@pytest.mark.parametrize("bad", [None, "other.npz", np.zeros((5, 3))])
def test_a_step_refused_for_a_bad_map_can_be_retried_at_the_same_t(bad):
    pair = overlapping_maps(np.random.default_rng(1), 20, 0.5)
    aligner = PairwiseAligner()
    with pytest.raises(DataError, match=rf"^PairwiseAligner\.update: other_map must be an "
                                        rf"ObjectMap, got {type(bad).__name__}"):
        aligner.update(10.0, pair.ego, bad)
    aligner.update(10.0, pair.ego, pair.other)  # used to be refused as "not after" t = 10
    assert aligner.filter.step == 1


@pytest.mark.parametrize("tcaff_params", [TCAFFParams(),
                                          TCAFFParams(min_distinct=2, switch_stale=True)],
                         ids=["default", "evidence"])
def test_a_step_that_failed_inside_the_aligner_leaves_no_trace(tcaff_params):
    """Every step is first tried with maps the registration refuses; the aligner then runs
    exactly like one that never saw them: same estimates, memory, identities and filter."""
    T_true = se2_from_params([4.0, -7.0, 2.5])
    rng = np.random.default_rng(0)
    clean, tried = PairwiseAligner(tcaff_params=tcaff_params), PairwiseAligner(
        tcaff_params=tcaff_params)
    failures = 0
    for t in range(14):
        pair = overlapping_maps(rng, 30, 0.5, 0.1, clutter=5, T_oi_oj=T_true, now=100.0 + t)
        try:
            tried.update(pair.now, pair.ego, far_away(pair.other))
        except DataError:
            failures += 1
        a = clean.update(pair.now, pair.ego, pair.other)
        b = tried.update(pair.now, pair.ego, pair.other)
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_array_equal(a.x, b.x)
            np.testing.assert_array_equal(a.P, b.P)
        assert len(clean.measurements) == len(tried.measurements)
        for m, n in zip(clean.measurements, tried.measurements, strict=True):
            np.testing.assert_array_equal(m.z, n.z)
    assert failures >= 10  # the maps overlap: the registration is reached and refuses
    assert a is not None
    for key, value in clean.filter.state_dict().items():
        np.testing.assert_array_equal(value, tried.filter.state_dict()[key])
    assert [t for t, _ in clean._memory[0].snapshots()] == [
        t for t, _ in tried._memory[0].snapshots()]


@pytest.mark.parametrize("t", ["10", None, np.array([10.0]), 1j, float("inf")])
def test_t_must_be_a_finite_number(t):
    pair = overlapping_maps(np.random.default_rng(1), 20, 0.5)
    aligner = PairwiseAligner()
    with pytest.raises(DataError, match=r"^PairwiseAligner\.update: t must be a finite number "
                                        r"of seconds, got "):
        aligner.update(t, pair.ego, pair.other)
    aligner.update(10.0, pair.ego, pair.other)


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"aligner_params": "reference"}, "PairwiseAligner.aligner_params"),
    ({"tcaff_params": {"window": 8}}, "PairwiseAligner.tcaff_params"),
])
def test_parameters_of_the_wrong_type_are_config_errors(kwargs, field):
    with pytest.raises(ConfigError, match=rf"^{field} = "):
        PairwiseAligner(**kwargs)


T_TRUE, T_DECOY = se2_from_params([4.0, -7.0, 2.5]), se2_from_params([-6.0, 3.0, -1.0])


def decoy_scene(n_decoy: int):
    """maps(t, alone) -> (ego, other): the other robot's 30 objects, and the ego robot's view of
    its first `n_decoy` placed under T_DECOY (a look-alike cluster), with all 30 under T_TRUE
    beside them unless `alone`; 3 cm of noise, every object seen at t."""
    rng = np.random.default_rng(3)
    other = np.column_stack([rng.uniform(0, 25, (30, 2)), np.zeros(30)])
    widths, heights = rng.uniform(0.3, 1.5, 30), rng.uniform(0.3, 1.5, 30)
    decoy, everything = np.arange(n_decoy), np.arange(30)

    def placed(T, rows):  # the other robot's objects `rows` in the ego frame under T
        xy = other[rows, :2] @ T[:2, :2].T + T[:2, 2] + rng.normal(0, 0.03, (len(rows), 2))
        return np.column_stack([xy, np.zeros(len(rows))])

    def maps(t: float, alone: bool) -> tuple[ObjectMap, ObjectMap]:
        if alone:
            return (ObjectMap(placed(T_DECOY, decoy), widths[decoy], heights[decoy],
                              np.full(n_decoy, t)),
                    ObjectMap(other[decoy], widths[decoy], heights[decoy], np.full(n_decoy, t)))
        rows = np.r_[decoy, everything]
        return (ObjectMap(np.vstack([placed(T_DECOY, decoy), placed(T_TRUE, everything)]),
                          widths[rows], heights[rows], np.full(len(rows), t)),
                ObjectMap(other, widths, heights, np.full(30, t)))

    return maps


def run_decoy_scene(pa: PairwiseAligner, n_decoy: int, steps: int, alone: int):
    """`decoy_scene(n_decoy)` through `pa` for `steps` steps at 1 s, the decoy alone for the
    first `alone`: per step the estimate, the filter's held estimate, whether it is
    provisional and whether the step was guided, each a list."""
    maps = decoy_scene(n_decoy)
    out = []
    for t in range(steps):
        estimate = pa.update(float(t), *maps(float(t), alone=t < alone))
        out.append((estimate, pa.filter.held, pa.filter.provisional, pa.guided))
    return [list(each) for each in zip(*out, strict=True)]


def test_a_switch_from_an_early_decoy_happens_with_guided_search():
    """First the maps share only a look-alike cluster (the decoy, accepted); then the truth,
    three times the objects, appears beside it. Guided steps see only the decoy, but a full
    search comes within `full_search_every` steps, its truth opens a rival hypothesis and every
    step searches in full until the filter switches to the truth."""
    every = 4
    pa = PairwiseAligner(FrameAlignerParams(guide_radius=2.0, full_search_every=every))
    estimates, held, _, guided = run_decoy_scene(pa, 10, 60, alone=25)
    held_decoy = [e is not None and se2_error(T_DECOY, e.T)[0] < 0.3 for e in estimates]
    assert held_decoy[24]
    assert any(guided[:25])  # the decoy was held under guided search ...
    runs = np.diff(np.flatnonzero(np.r_[False, ~np.array(guided), False]))
    assert runs.max() <= every  # ... never more than every - 1 guided steps in a row
    assert se2_error(T_TRUE, estimates[-1].T)[0] < 0.3
    # the switch itself: the decoy, unmeasured since the truth appeared, was replaced in a gap
    # of its measurements, so the truth is reported from its next measurement on
    switched = next(t for t in range(25, 60) if se2_error(T_TRUE, held[t].T)[0] < 0.3)
    # the truth opened a rival at the first full search after it appeared: no guided step
    # from then until the switch
    first_full = next(t for t in range(25, 60) if not guided[t])
    assert not any(guided[first_full:switched])


def test_a_provisional_decoy_is_not_settled_by_the_search_it_guides():
    """A look-alike cluster (the decoy) seen alone for two steps is accepted provisionally;
    then the truth, twice its objects, appears beside it. A search guided by the decoy would
    find only the decoy, which would settle it; while it is provisional every step searches in
    full, where the truth is the decoy's rival, so the decoy is never reported, is dropped at
    W steps old, and the truth is reported from then on."""
    pa = PairwiseAligner(FrameAlignerParams(guide_radius=2.0))
    window = pa.filter.params.window
    estimates, _, provisional, guided = run_decoy_scene(pa, 15, 20, alone=2)
    assert provisional[1]
    assert not any(guided[t] for t in range(1, 20) if provisional[t - 1])
    assert all(e is None or se2_error(T_DECOY, e.T)[0] > 1.0 for e in estimates)
    dropped = provisional.index(False, 1)
    assert dropped <= 1 + window
    assert all(e is not None and se2_error(T_TRUE, e.T)[0] < 0.3
               for e in estimates[dropped + 1:])


def test_guided_search_keeps_the_alignment_of_full_search():
    """A held, correct alignment: the guided steps give the estimates the full search does,
    and every one of them found a candidate confirming the hold."""
    T_true = se2_from_params([4.0, -7.0, 2.5])
    runs = {}
    for radius in (None, 2.0):
        pa = PairwiseAligner(FrameAlignerParams(guide_radius=radius))
        rng = np.random.default_rng(1)
        out, guided = [], []
        for t in range(20):
            pair = overlapping_maps(rng, 40, 0.6, 0.05, T_oi_oj=T_true, now=float(t))
            out.append(pa.update(pair.now, pair.ego, pair.other))
            guided.append(pa.guided)
        runs[radius] = out, guided
    steered_aligner = pa
    (full, never), (steered, guided) = runs[None], runs[2.0]
    assert not any(never) and sum(guided) >= 8
    for a, b in zip(full, steered, strict=True):
        assert (a is None) == (b is None)
        if a is not None:
            assert np.allclose(a.x, b.x, atol=0.02) and a.hypothesis == b.hypothesis
    assert steered_aligner.aligner.guided_misses == 0


@pytest.mark.parametrize("since_full", [-1, 1.5, True, None, "2"])
def test_guided_search_refuses_a_bad_count(since_full):
    with pytest.raises(DataError, match="since_full"):
        guided_search(FrameAlignerParams(guide_radius=1.0), PairwiseAligner().filter,
                      since_full)


def test_guided_search_refuses_bad_parameters_and_filters():
    with pytest.raises(ConfigError, match="params"):
        guided_search(TCAFFParams(), PairwiseAligner().filter, 0)
    with pytest.raises(DataError, match="tcaff"):
        guided_search(FrameAlignerParams(), PairwiseAligner(), 0)


# a small room seen by both robots standing still: six objects, irregularly placed
ROOM = np.array([[0.0, 0.0], [2.5, 0.4], [1.2, 3.1], [4.0, 2.2], [-1.5, 2.0], [3.1, -1.8]])
ROOM_T = se2_from_params([1.5, -0.8, 0.7])


def still_room(t: float, widths: np.ndarray) -> tuple[ObjectMap, ObjectMap]:
    """Both robots' maps of ROOM at time t, every object just seen, nothing new."""
    other = (ROOM - ROOM_T[:2, 2]) @ ROOM_T[:2, :2]
    return tuple(ObjectMap(np.column_stack([xy, widths / 2]), widths, widths, np.full(6, t))
                 for xy in (ROOM, other))


def test_a_small_still_scene_of_distinct_objects_is_accepted_with_the_defaults():
    """Nothing new is ever seen, so every measurement re-matches the same objects; the
    objects differ in size, so the maps are not of look-alikes and each one counts."""
    distinct = np.array([0.3, 0.8, 1.6, 0.5, 2.4, 1.1])
    pa = PairwiseAligner()
    assert pa.aligner.lookalike_share(*still_room(0.0, distinct), 0.0) < 0.7
    estimates = [pa.update(float(t), *still_room(float(t), distinct)) for t in range(12)]
    assert estimates[-1] is not None
    dt, dtheta = se2_error(ROOM_T, estimates[-1].T)
    assert dt < 0.05 and np.degrees(dtheta) < 0.5


def test_a_still_scene_of_look_alikes_is_recognised_and_not_accepted_on_repeats():
    """Six objects of one size: any object could be any other (the share of gated pairs is
    1), so the same objects re-matched at every step are one piece of evidence and the
    defaults wait for a second; the paper's filter takes each repeat as new evidence."""
    alike = np.full(6, 0.5)
    pa = PairwiseAligner()
    assert pa.aligner.lookalike_share(*still_room(0.0, alike), 0.0) == 1.0
    assert all(pa.update(float(t), *still_room(float(t), alike)) is None for t in range(30))
    paper = PairwiseAligner(tcaff_params=TCAFFParams.paper())
    assert [paper.update(float(t), *still_room(float(t), alike)) for t in range(12)][-1]


def test_look_alikes_seen_anew_are_accepted_with_the_defaults():
    """Maps of one-size objects that change from step to step (robots driving past new
    landmarks) bring distinct evidence: accepted, correctly."""
    T_true = se2_from_params([4.0, -7.0, 2.5])
    rng = np.random.default_rng(3)
    pa = PairwiseAligner()
    estimates = []
    for t in range(16):
        pair = overlapping_maps(rng, 20, 0.5, 0.05, T_oi_oj=T_true, now=float(t))
        ego, other = (ObjectMap(m.centroids, np.full(len(m), 0.5), np.full(len(m), 0.5),
                                m.last_seen) for m in (pair.ego, pair.other))
        estimates.append(pa.update(float(t), ego, other))
    assert pa.aligner.lookalike_share(ego, other, 15.0) == 1.0
    assert estimates[-1] is not None
    dt, dtheta = se2_error(T_true, estimates[-1].T)
    assert dt < 0.3 and np.degrees(dtheta) < 2.0


def test_the_calibrated_covariance_is_inflated_for_the_filter_it_feeds():
    """repeat_Q unset: the pair's aligner inflates R for its filter's Q, so a filter that
    assumes less drift gets larger R (R_s Q^-1 R_s grows as Q shrinks); a repeat_Q given is
    kept."""
    slow = TCAFFParams(Q=np.diag([0.02**2, 0.02**2, np.radians(0.1) ** 2]))
    assert PairwiseAligner(tcaff_params=slow).aligner.params.repeat_Q.tolist() == slow.Q.tolist()
    own = np.diag([1.0, 1.0, 0.1])
    given = PairwiseAligner(FrameAlignerParams(repeat_Q=own), slow)
    assert given.aligner.params.repeat_Q.tolist() == own.tolist()
    pair = overlapping_maps(np.random.default_rng(2), 30, 0.5, 0.1)
    R = {}
    for name, params in (("default", TCAFFParams()), ("slow", slow)):
        pa = PairwiseAligner(tcaff_params=params)
        pa.update(pair.now, pair.ego, pair.other)
        R[name] = pa.measurements[0].R
    assert np.linalg.eigvalsh(R["slow"] - R["default"]).min() > 0


@pytest.mark.parametrize(("aligner", "tcaff", "expected"), [
    (FrameAlignerParams(), TCAFFParams(), 0.15),
    (FrameAlignerParams(jitter_reference=0.3), TCAFFParams(), 0.3),
    (FrameAlignerParams(), TCAFFParams(jitter_reference=0.4), 0.4),  # the filter's own
    (FrameAlignerParams(), TCAFFParams.paper(), 0.15),  # the aligner's R, whatever the filter
    (FrameAlignerParams(jitter_reference=None), TCAFFParams(), None),
    (FrameAlignerParams(covariance="residual"), TCAFFParams(), None),  # independent errors
    (FrameAlignerParams(repeat_inflation=0.0), TCAFFParams(), None),
    (FrameAlignerParams.reference(), TCAFFParams.reference(), None),
])
def test_the_pairs_filter_takes_the_jitter_its_aligners_covariance_allows(aligner, tcaff,
                                                                         expected):
    assert PairwiseAligner(aligner, tcaff).filter.params.jitter_reference == expected
    assert fed_by(tcaff, aligner).jitter_reference == expected
    with pytest.raises(ConfigError, match=r"fed_by\.tcaff = "):
        fed_by(aligner, aligner)
    with pytest.raises(ConfigError, match=r"fed_by\.aligner = "):
        fed_by(tcaff, tcaff)


def test_counted_and_evidence_of_refuse_malformed_arguments():
    from tcaff_gtsam.pairwise import counted, evidence_of
    with pytest.raises(DataError, match="counted: objects"):
        counted(TCAFFParams(), False, [1.5, 7.0])
    np.testing.assert_array_equal(counted(TCAFFParams(), False, np.array([1, 7])), [True, False])
    assert counted(TCAFFParams(), False, np.array([6, 7])) is None
    pair = overlapping_maps(np.random.default_rng(1), 30, 0.5, 0.1)
    found = PairwiseAligner().aligner.measurements(pair.ego, pair.other, pair.now)
    ids = (np.arange(len(pair.ego)), np.arange(len(pair.other)))
    with pytest.raises(DataError, match="evidence_of: only"):
        evidence_of(found, ids, np.ones(len(found) + 1, bool))


def test_the_pairs_filter_grows_a_held_estimate_by_its_aligners_map_drift():
    """`fed_by` gives the filter held_Q = the map drift over one second where the aligner's
    covariance is calibrated, the filter holds by the drift with a reference to judge it by,
    and names none; never a singular one."""
    d_t, d_theta = FrameAlignerParams().map_drift
    np.testing.assert_allclose(PairwiseAligner().filter.params.held_Q,
                               np.diag([d_t**2, d_t**2, d_theta**2]))
    own = np.diag([1e-3, 1e-3, 1e-5])
    np.testing.assert_array_equal(fed_by(TCAFFParams(held_Q=own), FrameAlignerParams()).held_Q,
                                  own)
    for aligner, tcaff in [(FrameAlignerParams(covariance="residual"), TCAFFParams()),
                           (FrameAlignerParams(map_drift=(0.0, 0.01)), TCAFFParams()),
                           (FrameAlignerParams.reference(), TCAFFParams.reference()),
                           (FrameAlignerParams(), TCAFFParams.paper()),
                           (FrameAlignerParams(jitter_reference=None), TCAFFParams())]:
        assert fed_by(tcaff, aligner).held_Q is None
