"""Bad input to the public entry points of `tcaff_gtsam.__all__` (the graph aside): each call is
refused with the right `TcaffError` subclass, its message names the argument, and an object
that refused a call goes on as if the call had never been made.

`test_fuzz_inputs.py` and `test_fuzz_public.py` accept any result or a `TcaffError`; these
tests ask for the refusal itself: an array of booleans, dates, complex numbers, strings or
objects, a NaN, an infinity or a value beyond the bounds the arithmetic takes, a wrong shape,
None or a list of junk where an array belongs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import (
    TCAFF,
    ClipperParams,
    ConfigError,
    ConsistencyGraph,
    DataError,
    FrameAligner,
    FrameAlignerParams,
    MapMemory,
    ObjectIdentities,
    ObjectMap,
    PairwiseAligner,
    TcaffError,
    TCAFFParams,
    TeamConsistency,
    TeamParams,
    clipper_solve,
    consistency_graph,
    mno_clipper,
    putative_associations,
    weighted_arun,
)
from tcaff_gtsam.aligner_params import (
    MAX_MAP_DRIFT,
    MAX_MEMORY_SEARCHES,
    MAX_POINT_NOISE,
    MIN_SIGMA,
)
from tcaff_gtsam.filter_params import MAX_WINDOW
from tcaff_gtsam.param_checks import (
    MAX_COORDINATE,
    MAX_FACTOR,
    MAX_ITERATIONS,
    MAX_NATS,
    MAX_OBJECTS,
    MAX_SECONDS,
    MAX_STEPS,
    MAX_VARIANCE,
    ParameterError,
)
from tcaff_gtsam.tcaff import AlignmentEstimate

CHECKS = settings(max_examples=40, deadline=None, derandomize=True,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                         HealthCheck.function_scoped_fixture])

PAIR = overlapping_maps(np.random.default_rng(0), 20, 0.6, 0.1, clutter=3)
EGO, OTHER, NOW = PAIR.ego, PAIR.other, PAIR.now
R3 = np.diag([0.25, 0.25, 0.01])

# -- bad arrays ----------------------------------------------------------------------------------

#: what each kind of bad array does to a good one (a float array of the right shape)
KINDS = ("bool", "complex", "object", "str", "datetime", "none", "junk_list", "nonfinite",
         "huge", "shape")


@st.composite
def spoiled(draw, good: np.ndarray, kinds=KINDS) -> tuple[str, object]:
    """(kind, a bad stand-in for the float array `good`)."""
    good = np.asarray(good, dtype=float)
    kind = draw(st.sampled_from(kinds))
    if kind == "bool":
        return kind, np.ones(good.shape, dtype=bool)
    if kind == "complex":
        return kind, good + 1j
    if kind == "object":
        return kind, good.astype(object)
    if kind == "str":
        return kind, good.astype(str)
    if kind == "datetime":
        return kind, np.zeros(good.shape, dtype="datetime64[s]")
    if kind == "none":
        return kind, None
    if kind == "junk_list":
        return kind, [draw(st.sampled_from(["a", None, object(), b"x", {}])) for _ in range(3)]
    if kind in ("nonfinite", "huge"):
        bad = good.copy()
        at = draw(st.integers(0, good.size - 1))
        value = (draw(st.sampled_from([math.nan, math.inf, -math.inf])) if kind == "nonfinite"
                 else draw(st.sampled_from([1e300, -1e300, 1.7e308, 1e200])))
        bad.flat[at] = value
        return kind, bad
    shapes = {(*good.shape, 1), good.shape[:-1], (good.shape[0] + 1, *good.shape[1:])}
    if good.ndim >= 2:
        shapes.add((*good.shape[:-1], good.shape[-1] + 2))
    shapes.discard(good.shape)
    return kind, np.zeros(draw(st.sampled_from(sorted(shapes))))


def refused(call, argument: str, error: type[TcaffError] = DataError) -> TcaffError:
    """The error `call` raises: of type `error`, naming `argument`."""
    with pytest.raises(TcaffError) as info:
        call()
    assert isinstance(info.value, error), repr(info.value)
    assert argument in str(info.value), (argument, str(info.value))
    return info.value


# -- ObjectMap -----------------------------------------------------------------------------------

FIELDS = {"centroids": EGO.centroids, "widths": EGO.widths, "heights": EGO.heights,
          "last_seen": EGO.last_seen}


@CHECKS
@given(st.data())
def test_object_map_refuses_bad_fields(data):
    """Booleans among them: an ObjectMap of True/False centroids was built (and aligned)."""
    name = data.draw(st.sampled_from(sorted(FIELDS)))
    # a map takes any finite magnitude: huge values are not bad here
    kind, bad = data.draw(spoiled(FIELDS[name], [k for k in KINDS if k != "huge"]))
    fields = {k: np.array(v) for k, v in FIELDS.items()}
    fields[name] = bad
    error = refused(lambda: ObjectMap(**fields), f"ObjectMap.{name}")
    if kind == "bool":
        assert "bool" in str(error)


def test_object_map_refuses_boolean_descriptors():
    n = len(EGO)
    with pytest.raises(DataError, match=r"ObjectMap\.descriptors must be real numbers.*bool"):
        ObjectMap(EGO.centroids, EGO.widths, EGO.heights, EGO.last_seen,
                  np.eye(n, 4, dtype=bool))


# -- the filter ----------------------------------------------------------------------------------


def stream(steps: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(3)
    return [(np.array([[3.0, -2.0, 1.0]]) + rng.normal(0, [0.05, 0.05, 0.005], (1, 3)),
             R3[None]) for _ in range(steps)]


GOOD_STEPS = stream(12)


def same_state(a: TCAFF, b: TCAFF) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sorted(sa) == sorted(sb)
    for key in sa:
        assert np.array_equal(sa[key], sb[key]), key


@CHECKS
@given(st.data())
def test_tcaff_update_refuses_bad_measurements_and_goes_on(data):
    """Boolean covariances (identity matrices of True) were taken as R = I; measurements of
    1e300 m were filtered into estimates there (and +-1.7e308 overflowed into NaN states)."""
    split = data.draw(st.integers(0, len(GOOD_STEPS) - 1))
    name = data.draw(st.sampled_from(["zs", "Rs"]))
    zs, Rs = GOOD_STEPS[split]
    kind, bad = data.draw(spoiled(zs if name == "zs" else Rs))
    if kind == "shape" and name == "zs":
        bad = np.zeros((1, 2))  # (k, 3) zs of another k are judged by Rs' shape
    filt, fresh = TCAFF(), TCAFF()
    for z, R in GOOD_STEPS[:split]:
        filt.update(z, R)
        fresh.update(z, R)
    args = {"zs": zs, "Rs": Rs, name: bad}
    refused(lambda: filt.update(args["zs"], args["Rs"]), name)
    same_state(filt, fresh)
    for z, R in GOOD_STEPS[split:]:
        a, b = filt.update(z, R), fresh.update(z, R)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)


@pytest.mark.parametrize(("evidence", "objects", "argument"), [
    ([[[0, 1], [2]]], None, "evidence[0]"),                 # ragged: numpy's ValueError before
    ([np.array([[0.5, 1.0]])], None, "evidence[0]"),
    ([np.array([[True, False]])], None, "evidence[0]"),
    ([[["a", "b"]]], None, "evidence[0]"),
    (None, [True], "objects"),
    (None, [2.5], "objects"),
    (None, np.array(["3"]), "objects"),
    (None, np.zeros(1, "datetime64[s]"), "objects"),
])
def test_tcaff_update_refuses_bad_evidence_and_counts(evidence, objects, argument):
    filt, fresh = TCAFF(), TCAFF()
    z, R = GOOD_STEPS[0]
    refused(lambda: filt.update(z, R, evidence, objects), argument)
    assert filt.update(z, R) is fresh.update(z, R)  # None both, nothing recorded before
    same_state(filt, fresh)


STATE = None


def loaded_state() -> dict[str, np.ndarray]:
    global STATE
    if STATE is None:
        filt = TCAFF()
        for z, R in GOOD_STEPS:
            filt.update(z, R)
        STATE = filt.state_dict()
    return STATE


@CHECKS
@given(st.data())
def test_load_state_dict_refuses_bad_arrays(data):
    state = dict(loaded_state())
    key = data.draw(st.sampled_from(sorted(k for k, v in state.items() if v.size)))
    value = state[key]
    kinds = ["bool", "complex", "object", "str", "datetime", "none", "junk_list"]
    if value.dtype.kind == "f":
        kinds.append("nonfinite")
    kind, bad = data.draw(spoiled(value.astype(float), kinds))
    if kind == "bool" and value.dtype == bool:
        return
    state[key] = bad
    target, fresh = TCAFF(), TCAFF()
    refused(lambda: target.load_state_dict(state), "TCAFF state")
    same_state(target, fresh)
    target.load_state_dict(loaded_state())  # the good state still loads, and runs
    z, R = GOOD_STEPS[0]
    target.update(z, R)


def test_load_refuses_junk_paths():
    for path in (None, 3.5, object()):
        refused(lambda path=path: TCAFF.load(path), "TCAFF filter")


# -- aligners ------------------------------------------------------------------------------------


@CHECKS
@given(st.data())
def test_measurements_refuse_a_bad_held_alignment(data):
    """A held alignment of booleans was taken as (1, 1, 1); one at 1e300 m crashed scipy's
    k-d tree in a guided search ("Encountering floating point overflow")."""
    _kind, bad = data.draw(spoiled(np.zeros(3), [k for k in KINDS if k != "none"]))
    aligner, fresh = FrameAligner(), FrameAligner()
    refused(lambda: aligner.measurements(EGO, OTHER, NOW, held=bad, guided=True), "held")
    found = aligner.measurements(EGO, OTHER, NOW)
    expected = fresh.measurements(EGO, OTHER, NOW)
    assert [m.z.tolist() for m in found] == [m.z.tolist() for m in expected]
    assert aligner.guided_misses == fresh.guided_misses


@CHECKS
@given(st.data())
def test_pairwise_update_refuses_bad_input_and_goes_on(data):
    name = data.draw(st.sampled_from(["t", "ego_map", "other_map"]))
    bad = data.draw(st.sampled_from([None, "1", math.nan, math.inf, True, 1 + 1j,
                                     np.array([NOW]), [EGO], EGO.centroids, object()]))
    if name == "t" and isinstance(bad, (list, np.ndarray)) and len(bad) == 1 \
            and not isinstance(bad[0], (float, np.floating)):
        bad = None
    pair, fresh = PairwiseAligner(), PairwiseAligner()
    times = [NOW - 3.0, NOW - 2.0, NOW - 1.0, NOW]
    for t in times[:2]:
        pair.update(t, EGO, OTHER)
        fresh.update(t, EGO, OTHER)
    args = {"t": times[2], "ego_map": EGO, "other_map": OTHER, name: bad}
    refused(lambda: pair.update(args["t"], args["ego_map"], args["other_map"]), name)
    for t in times[2:]:
        a, b = pair.update(t, EGO, OTHER), fresh.update(t, EGO, OTHER)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
    same_state(pair.filter, fresh.filter)


@CHECKS
@given(st.data())
def test_object_identities_refuse_bad_positions_and_go_on(data):
    """Boolean positions were given ids; positions of +-1e300 m overflowed numpy's norm."""
    xy = EGO.centroids[:, :2]
    kind, bad = data.draw(spoiled(xy))
    if kind == "shape" and bad.shape[1:] == (2,):
        bad = np.zeros((3, 3))  # any number of objects is fine
    ids, fresh = ObjectIdentities(), ObjectIdentities()
    assert np.array_equal(ids.update(xy), fresh.update(xy))
    refused(lambda: ids.update(bad), "xy")
    moved = xy + 0.05
    assert np.array_equal(ids.update(moved), fresh.update(moved))


def test_map_memory_refuses_bad_input_and_goes_on():
    memory = MapMemory(100.0, 10.0)
    memory.add(NOW - 20.0, EGO)
    for t, objects, name in ((math.nan, EGO, "t"), (True, EGO, "t"), ("1", EGO, "t"),
                             (NOW, None, "objects"), (NOW, EGO.centroids, "objects")):
        refused(lambda t=t, objects=objects: memory.add(t, objects), name)
    memory.add(NOW, EGO)
    assert [t for t, _ in memory.snapshots()] == [NOW - 20.0, NOW]
    for span, every, name in ((math.nan, 1.0, "span"), (1.0, 0.0, "every"),
                              ("x", 1.0, "span"), (1.0, 1j, "every")):
        refused(lambda span=span, every=every: MapMemory(span, every), name, ConfigError)


# -- team consistency ----------------------------------------------------------------------------


def estimate(x, P) -> AlignmentEstimate:
    return AlignmentEstimate(np.asarray(x), np.asarray(P), 0.0, 0, 1, 1, 0)


def closing_estimates() -> dict:
    """Three alignments of a team of three that close their cycle."""
    from tcaff_gtsam.geometry import se2_from_params, se2_to_params

    T01, T12 = se2_from_params([1.0, 2.0, 0.3]), se2_from_params([-2.0, 0.5, -0.2])
    P = np.diag([0.01, 0.01, 0.001])
    return {(0, 1): estimate(se2_to_params(T01), P), (1, 2): estimate(se2_to_params(T12), P),
            (0, 2): estimate(se2_to_params(T01 @ T12), P)}


@pytest.mark.parametrize("x_or_P", [
    ("x", np.zeros(3, dtype=bool)),
    ("P", np.zeros((3, 3))),                                   # not positive definite
    ("P", -np.eye(3)),
    ("P", np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])),  # not symmetric
    ("P", np.eye(3, dtype=bool)),
    ("P", np.full((3, 3), 1e300)),                             # numpy's LinAlgError before
    ("x", np.array([1.7e308, 0.0, 0.0])),
    ("x", np.array([math.nan, 0.0, 0.0])),
    ("x", ["a", "b", "c"]),
    ("x", np.zeros(0)),
])
def test_team_update_refuses_bad_estimates_and_goes_on(x_or_P):
    which, value = x_or_P
    good = closing_estimates()
    team, fresh = TeamConsistency(3), TeamConsistency(3)
    bad = dict(good)
    x, P = good[(0, 1)].x, good[(0, 1)].P
    bad[(0, 1)] = type("Estimate", (), {"x": value if which == "x" else x,
                                        "P": value if which == "P" else P})()
    refused(lambda: team.update(bad), "estimates[(0, 1)]")
    a, b = team.update(good), fresh.update(good)
    assert sorted(a) == sorted(b) and team.rejected == fresh.rejected == []
    for key in a:
        assert np.array_equal(a[key].x, b[key].x)


@pytest.mark.parametrize(("estimates", "pairs", "argument"), [
    ({(0, 1.0): None}, None, "estimates key"),
    ({(0, True): None}, None, "estimates key"),
    ({(0, 3): None}, None, "estimates key"),
    ({}, [(0, 1.5)], "pairs"),
    ({}, [(0, 0)], "pairs"),
    ({}, 5, "pairs"),
])
def test_team_update_names_bad_keys_and_pairs(estimates, pairs, argument):
    bad = {k: closing_estimates()[(0, 1)] for k in estimates}
    refused(lambda: TeamConsistency(3).update(bad, pairs), argument)


# -- CLIPPER and registration --------------------------------------------------------------------

P_PTS = np.random.default_rng(0).uniform(0.0, 5.0, (6, 2))
Q_PTS = P_PTS + 1.0
ALL_PAIRS = np.argwhere(np.ones((6, 6), dtype=bool))


@CHECKS
@given(st.data())
def test_weighted_arun_names_the_bad_argument(data):
    """Booleans were registered as 0/1 points; a NaN or a 1e300 m coordinate was reported as
    "points and weights" or "coordinates", not as p, q or weights."""
    name = data.draw(st.sampled_from(["p", "q", "weights"]))
    args = {"p": P_PTS, "q": Q_PTS, "weights": np.ones(6)}
    kinds = [k for k in KINDS if k != "shape" and not (name == "weights" and k == "none")]
    kind, args[name] = data.draw(spoiled(args[name], kinds))
    if name == "weights" and kind == "huge":
        args[name] = np.abs(args[name])
    refused(lambda: weighted_arun(args["p"], args["q"], args["weights"]), name)


@CHECKS
@given(st.data())
def test_consistency_graph_names_the_bad_argument(data):
    """Boolean points and priors were taken as 0/1; a NaN in either map was reported as
    "points must be finite"; priors of 1e300 made the solver return no clique at all."""
    name = data.draw(st.sampled_from(["ego_points", "other_points", "prior"]))
    args = {"ego_points": P_PTS, "other_points": Q_PTS, "prior": np.ones(len(ALL_PAIRS))}
    kinds = [k for k in KINDS if not (name == "prior" and k == "none")]
    kind, args[name] = data.draw(spoiled(args[name], kinds))
    if name == "prior" and kind == "huge":
        args[name] = np.abs(args[name])
    if name == "other_points" and kind == "shape":
        args[name] = np.zeros((6, 3))  # a third coordinate only here
    refused(lambda: consistency_graph(args["ego_points"], args["other_points"], ALL_PAIRS,
                                      prior=args["prior"]), name)


def test_consistency_graph_names_the_side_an_association_points_past():
    refused(lambda: consistency_graph(P_PTS, Q_PTS[:3], ALL_PAIRS), "other_points")
    refused(lambda: consistency_graph(P_PTS[:2], Q_PTS, ALL_PAIRS), "ego_points")


GRAPH = consistency_graph(P_PTS, Q_PTS, ALL_PAIRS)


@CHECKS
@given(st.data())
def test_consistency_graph_fields_are_checked(data):
    """Boolean weights were taken as 0/1; weights of 1e300 made the solver find nothing."""
    name = data.draw(st.sampled_from(["weights", "diag"]))
    fields = {f: getattr(GRAPH, f) for f in ("associations", "indptr", "indices", "weights",
                                             "diag")}
    kind, bad = data.draw(spoiled(fields[name], [k for k in KINDS if k != "shape"]))
    fields[name] = np.abs(bad) if kind == "huge" else bad
    refused(lambda: ConsistencyGraph(**fields), name)
    assert len(clipper_solve(GRAPH)) == 6


def test_float16_associations_need_no_warning():
    """index_pairs compared a float16 array with int64's maximum, which numpy casts to
    float16 with an overflow warning."""
    with np.errstate(over="raise"):
        graph = consistency_graph(P_PTS, Q_PTS, ALL_PAIRS.astype(np.float16))
    assert graph.m == len(ALL_PAIRS)


@pytest.mark.parametrize(("call", "argument", "error"), [
    (lambda: clipper_solve(None), "graph", DataError),
    (lambda: clipper_solve(GRAPH, "fast"), "params", ConfigError),
    (lambda: mno_clipper(GRAPH, 2.5), "n_solutions", ConfigError),
    (lambda: mno_clipper(GRAPH, True), "n_solutions", ConfigError),
    (lambda: mno_clipper(GRAPH, 2, None, math.nan), "downweight", ConfigError),
    (lambda: putative_associations(EGO, None), "other", DataError),
    (lambda: putative_associations(EGO, OTHER, math.nan), "ratio", ConfigError),
    (lambda: putative_associations(EGO, OTHER, 1.35, -1.0), "abs_diff", ConfigError),
])
def test_solvers_and_gates_name_the_bad_argument(call, argument, error):
    refused(call, argument, error)


# -- parameters ----------------------------------------------------------------------------------

NUMERIC = {
    ClipperParams: ("sigma", "epsilon", "beta", "max_outer", "seed"),
    FrameAlignerParams: ("kappa", "size_ratio", "n_solutions", "min_associations",
                         "weight_offset", "inlier_radius", "guide_radius"),
    TCAFFParams: ("window", "max_leaves", "tau", "p_no_measurement", "object_nats",
                  "drop_after"),
    TeamParams: ("cycle_probability", "max_chain", "exact_up_to"),
}


@CHECKS
@given(st.data())
def test_parameters_refuse_values_of_the_wrong_kind(data):
    """tau = 10**400 raised Python's OverflowError from math.isfinite."""
    cls = data.draw(st.sampled_from(list(NUMERIC)), label="class")
    name = data.draw(st.sampled_from(NUMERIC[cls]), label="field")
    bad = data.draw(st.sampled_from([math.nan, "1", 1 + 1j, [1.0], np.array([1.0]),
                                     np.array([True]), object(), -(10**400)]))
    if name == "tau":
        bad = data.draw(st.sampled_from([bad, 10**400]))
    error = refused(lambda: cls(**{name: bad}), name, ConfigError)
    assert getattr(error, "name", name) == name


# -- the bounds of every numeric field ----------------------------------------------------------

#: (class, field) -> (kind, low, high, low excluded): the documented range of every numeric field
#: of the public parameter objects that had no upper bound before ("int", "real", or "vector" /
#: "matrix" for the entries of a tuple or a covariance). Left out: the fields bounded already,
#: the probabilities and shares (in (0, 1) or [0, 1]), the trees' caps and n_solutions
#: (test_requested_sizes.py) and TeamParams.exact_up_to; and ClipperParams.seed: any int >= 0
#: names a stream.
M, S, F, N, C, T = MAX_COORDINATE, MAX_SECONDS, MAX_FACTOR, MAX_NATS, MAX_OBJECTS, MAX_STEPS
BOUNDS = {
    **{(ClipperParams, name): spec for name, spec in {
        "sigma": ("real", MIN_SIGMA, M, False), "epsilon": ("real", 0, M, True),
        "tol_u": ("real", 0, 1, True), "eps": ("real", 0, 1, True),
        "max_outer": ("int", 1, MAX_ITERATIONS, False),
        "max_inner": ("int", 1, MAX_ITERATIONS, False),
        "max_line_search": ("int", 1, MAX_ITERATIONS, False),
        "power_iterations": ("int", 0, MAX_ITERATIONS, False)}.items()},
    **{(FrameAlignerParams, name): spec for name, spec in {
        "kappa": ("real", 0, S, True), "size_ratio": ("real", 1, F, False),
        "size_abs_diff": ("real", 0, M, False), "size_partial": ("real", 1, F, False),
        "min_associations": ("int", 2, C, False), "sparse_associations": ("int", 2, C, False),
        "sparse_objects": ("int", 1, C, False), "max_associations": ("int", 5, C, False),
        "pairs_per_object": ("int", 1, C, False), "weight_offset": ("real", 0, S * S, True),
        "max_rmse": ("real", 0, M, True), "R_constant": ("matrix", 0, MAX_VARIANCE, True),
        "residual_floor": ("real", 0, MAX_POINT_NOISE, True),
        "residual_prior_dof": ("real", 0, F, False),
        "map_drift": ("vector", 0, MAX_MAP_DRIFT[0], False),
        "epsilon_drift": ("real", 0, F, False),
        "repeat_inflation": ("real", 0, F, False), "jitter_reference": ("real", 0, F, True),
        "repeat_Q": ("matrix", 0, MAX_VARIANCE, True), "min_inliers": ("int", 2, C, False),
        "inlier_radius": ("real", 0, M, True), "min_spread": ("real", 0, M, False),
        "distinct_translation": ("real", 0, M, True),
        "distinct_heading": ("real", 0, math.pi, True), "memory_span": ("real", 0, S, False),
        "memory_searches": ("int", 0, MAX_MEMORY_SEARCHES, False),
        "confirm_translation": ("real", 0, M, True),
        "confirm_heading": ("real", 0, math.pi, True), "track_min": ("int", 2, C, False),
        "guide_radius": ("real", 0, M, True), "full_search_every": ("int", 1, T, False),
        "height_epsilon": ("real", 0, M, True)}.items()},
    **{(TCAFFParams, name): spec for name, spec in {
        "tau": ("real", -N, N, False), "Q": ("matrix", 0, MAX_VARIANCE, True),
        "P0": ("matrix", 0, MAX_VARIANCE, True), "gate_box": ("vector", 0, M, True),
        "drop_after": ("int", 1, T, False), "switch_after": ("int", 1, T, False),
        "switch_margin": ("real", 0, N, False), "switch_support": ("int", 1, MAX_WINDOW, False),
        "min_distinct": ("int", 1, MAX_WINDOW, False), "report_after": ("int", 1, T, False),
        "object_nats": ("real", 0, N, False), "object_base": ("int", 0, C, False),
        "early_measurements": ("int", 2, MAX_WINDOW, False),
        "recall_for": ("int", 1, T, False), "jitter_reference": ("real", 0, F, True),
        "jitter_span": ("int", 2, T, False)}.items()},
    (TeamParams, "max_chain"): ("int", 1, 1023, False),
}

#: what a field at the top of its range needs of the others: max_associations is at least
#: min_associations
ALONGSIDE = {(FrameAlignerParams, "min_associations"): {"max_associations": MAX_OBJECTS}}

#: the huge values every field refuses by name: floats up to 1e308, ints up to 10**400,
#: infinities and NaN (kappa takes inf: no limit)
NONFINITE = (math.inf, -math.inf, math.nan)


def as_field(cls, name: str, kind: str, value):
    """The keyword arguments that give `cls`'s field `name` the number `value` (for a tuple or
    a covariance, as one of its entries)."""
    if kind == "vector":
        value = (value, 0.01) if name == "map_drift" else (1.0, 1.0, value)
    elif kind == "matrix":
        value = np.diag([value, 1.0, 1.0])
    return {name: value, **ALONGSIDE.get((cls, name), {})}


@pytest.mark.parametrize(("cls", "name"), list(BOUNDS), ids=lambda x: getattr(x, "__name__", x))
@CHECKS
@given(data=st.data())
def test_every_numeric_field_refuses_huge_values_by_name(cls, name, data):
    """kappa, size_ratio, size_abs_diff, weight_offset, tol_u and eps at 10**400 raised
    OverflowError, as did residual_floor and inlier_radius at 1e300 and object_nats and
    object_base at 2**63; most other fields took 1e300 and failed later, or were refused as
    another argument (TCAFF.update's Rs)."""
    kind, low, high, _ = BOUNDS[(cls, name)]
    if kind == "matrix":  # an entry beyond MAX_VARIANCE; not one of a float's
        bad = data.draw(st.floats(high, 1e308, exclude_min=True), label="entry")
    else:
        huge = [st.floats(high, 1e308, exclude_min=True),
                st.integers(math.floor(high) + 1, 10**400),
                st.sampled_from([v for v in NONFINITE
                                 if not (name == "kappa" and v == math.inf)])]
        if low < 0:  # tau: as far below
            huge += [st.floats(-1e308, low, exclude_max=True),
                     st.integers(-(10**400), math.ceil(low) - 1)]
        bad = data.draw(st.one_of(huge), label="value")
    with pytest.raises(ParameterError) as info:
        cls(**as_field(cls, name, kind, bad))
    error = info.value
    assert (error.owner, error.name) == (cls.__name__, name), str(error)
    assert str(error).startswith(f"{cls.__name__}.{name} = "), str(error)


@pytest.mark.parametrize(("cls", "name"), list(BOUNDS), ids=lambda x: getattr(x, "__name__", x))
@CHECKS
@given(data=st.data())
def test_every_numeric_field_takes_any_value_within_its_bound(cls, name, data):
    """...and the same field takes every value up to its documented bound, the bound itself
    included; one step past it (the next float, the next int) is refused, as none was
    before."""
    kind, low, high, open_low = BOUNDS[(cls, name)]
    if kind == "int":
        value = data.draw(st.one_of(st.integers(low, high), st.sampled_from([low, high])))
        past = high + 1
    else:
        values = [st.floats(low, high, exclude_min=open_low), st.just(high)]
        if math.floor(low) + 1 <= math.floor(high):
            values.append(st.integers(math.floor(low) + 1, math.floor(high)))
        value = data.draw(st.one_of(values), label="value")
        past = math.nextafter(high, math.inf)
    made = cls(**as_field(cls, name, kind, value))
    assert isinstance(made, cls)
    with pytest.raises(ParameterError) as info:
        cls(**as_field(cls, name, kind, past))
    assert info.value.name == name, str(info.value)


def test_map_drift_bounds_its_heading_part_too():
    """The table above draws map_drift's metres; its radians have their own bound, 0.1."""
    metres, radians = MAX_MAP_DRIFT
    assert FrameAlignerParams(map_drift=(metres, radians)).map_drift == (metres, radians)
    for drift in ((0.0, math.nextafter(radians, math.inf)), (0.0, 1.0), (0.0, math.inf)):
        with pytest.raises(ParameterError) as info:
            FrameAlignerParams(map_drift=drift)
        assert info.value.name == "map_drift", str(info.value)


@pytest.mark.parametrize("settings", [
    dict(kappa=MAX_SECONDS, map_drift=MAX_MAP_DRIFT),
    dict(repeat_inflation=MAX_FACTOR, repeat_Q=np.eye(3) * 1e-22),
], ids=["kappa and drift", "inflation and Q"])
def test_settings_that_together_overflow_a_covariance_are_named(settings):
    """Each field within its bound, together they put a candidate's R past MAX_VARIANCE: the
    aligner names its settings (the filter used to refuse `Rs`, which the user never gave),
    and a refused step leaves the pair's filter as it was."""
    pair = PairwiseAligner(FrameAlignerParams(**settings))
    with pytest.raises(ConfigError) as info:
        pair.update(NOW, EGO, OTHER)
    message = str(info.value)
    assert "MAX_VARIANCE" in message and "repeat_inflation" in message, message
    assert all(name in message for name in settings), message
    same_state(pair.filter, PairwiseAligner().filter)
