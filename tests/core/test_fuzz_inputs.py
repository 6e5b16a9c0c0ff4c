"""Junk thrown at the public functions that check their input: NaN, infinities, strings, None,
wrong shapes, complex numbers, huge values and wrong types. Every call must either return a
result or raise a `TcaffError` (`DataError`, `ConfigError`); any other exception (TypeError,
IndexError, MemoryError, a numpy warning turned error, ...) fails the test."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from tcaff_gtsam.eval.sim.maps import overlapping_maps
from tcaff_gtsam.mapping.camera import PinholeCamera

from tcaff_gtsam import (
    TCAFF,
    ClipperParams,
    FrameAligner,
    MapMemory,
    ObjectIdentities,
    ObjectMap,
    PairwiseAligner,
    TcaffError,
    clipper_solve,
    consistency_graph,
    mno_clipper,
    putative_associations,
    weighted_arun,
)
from tcaff_gtsam.clipper import ConsistencyGraph
from tcaff_gtsam.identities import recent_ids
from tcaff_gtsam.registration import arun_weights

FUZZ = settings(max_examples=100, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])

# -- junk --------------------------------------------------------------------------------------

junk_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**30), 10**30), st.floats(),
    st.complex_numbers(allow_nan=True), st.text(max_size=4), st.binary(max_size=3),
    st.sampled_from([10**400, -(10**400), 1e300, -1e300, 5e-324, math.nan, math.inf,
                     -math.inf, np.float32("nan"), np.int64(-1), np.uint64(2**64 - 1),
                     object(), {}, [], (), slice(1), Ellipsis]),
)
junk_arrays = hnp.arrays(
    dtype=st.sampled_from([np.float64, np.float32, np.int64, np.uint8, np.complex128, np.bool_,
                           np.dtype("U3")]),
    shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5),
)
junk = st.one_of(junk_scalars, junk_arrays, st.lists(junk_scalars, max_size=4),
                 st.just(ObjectMap.empty()))


def numbers(shape) -> st.SearchStrategy:
    """Float arrays of `shape` with any values: NaN, infinities, huge and tiny ones."""
    return hnp.arrays(np.float64, shape, elements=st.floats(width=64))


def finite(shape, bound: float = 1e12) -> st.SearchStrategy:
    return hnp.arrays(np.float64, shape, elements=st.floats(-bound, bound))


@st.composite
def maps(draw, max_objects: int = 12) -> ObjectMap:
    """Valid maps, at any magnitude a map accepts (centroids up to 1e300 metres)."""
    n = draw(st.integers(0, max_objects))
    bound = draw(st.sampled_from([20.0, 1e6, 1e300]))
    sizes = hnp.arrays(np.float64, n, elements=st.floats(0.0, 3.0))
    return ObjectMap(draw(finite((n, 3), bound)), draw(sizes), draw(sizes),
                     draw(finite(n, 1e3)))


def either(valid: st.SearchStrategy) -> st.SearchStrategy:
    """Mostly valid values, sometimes junk."""
    return st.one_of(valid, valid, junk)


def outcome(call):
    """The call's result, or None when it raised a TcaffError; anything else propagates."""
    try:
        return call()
    except TcaffError:
        return None


# -- object maps -------------------------------------------------------------------------------


@FUZZ
@given(either(finite((4, 3))), either(finite(4)), either(finite(4)), either(finite(4)))
def test_object_map_construction(centroids, widths, heights, last_seen):
    m = outcome(lambda: ObjectMap(centroids, widths, heights, last_seen))
    assert m is None or isinstance(m, ObjectMap)


@FUZZ
@given(maps(), either(st.floats(-1e3, 1e3)), either(st.floats(0.1, 100.0)), junk)
def test_object_map_methods(m, now, kappa, index):
    outcome(lambda: m.ages(now))
    outcome(lambda: m.recent(now, kappa))
    outcome(lambda: m.recent_indices(now, kappa))
    outcome(lambda: m.subset(index))


@FUZZ
@given(st.binary(max_size=300), junk)
def test_loading_any_bytes_or_any_path(tmp_path_factory, raw, path):
    file = tmp_path_factory.mktemp("junk") / "saved.npz"
    file.write_bytes(b"PK\x03\x04" + raw)
    for load in (ObjectMap.load, TCAFF.load):
        outcome(lambda load=load: load(file))
        outcome(lambda load=load: load(path))


# -- registration ------------------------------------------------------------------------------


@FUZZ
@given(either(maps()), either(maps()), either(st.floats(1.0, 3.0)), either(st.floats(0.0, 1.0)))
def test_putative_associations(ego, other, ratio, abs_diff):
    pairs = outcome(lambda: putative_associations(ego, other, ratio, abs_diff))
    assert pairs is None or (pairs.ndim == 2 and pairs.shape[1] == 2)


@FUZZ
@given(either(numbers((5, 2))), either(numbers((5, 2))), either(numbers(5)))
def test_weighted_arun(p, q, w):
    T = outcome(lambda: weighted_arun(p, q, w))
    assert T is None or np.all(np.isfinite(T))


@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")  # ages near 1e154 s and up
@FUZZ
@given(either(numbers(5)), either(numbers(5)), either(st.floats(1e-3, 1.0)))
def test_arun_weights(a, b, offset):
    outcome(lambda: arun_weights(a, b, offset))


# -- CLIPPER -----------------------------------------------------------------------------------


@FUZZ
@given(either(numbers((5, 2))), either(numbers((4, 2))),
       either(hnp.arrays(np.int64, (6, 2), elements=st.integers(-2, 6))),
       either(st.floats(0.01, 1.0)), either(st.floats(0.01, 1.0)),
       st.one_of(st.none(), either(numbers(6))))
def test_consistency_graph(p, q, associations, epsilon, sigma, prior):
    graph = outcome(lambda: consistency_graph(p, q, associations, epsilon, sigma, prior))
    if graph is not None:
        assert len(clipper_solve(graph)) <= graph.m


@FUZZ
@given(st.data())
def test_clipper_on_hand_made_graphs(data):
    """Graphs built field by field, the way the solver used to be crashed."""
    m = data.draw(st.integers(0, 6))
    indices = data.draw(either(hnp.arrays(np.int64, data.draw(st.integers(0, 8)),
                                          elements=st.integers(-2, m + 2))))
    n = np.size(indices) if isinstance(indices, np.ndarray) else 0
    indptr = data.draw(either(st.just(np.linspace(0, n, m + 1).astype(np.int64))))
    fields = {
        "associations": data.draw(either(hnp.arrays(np.int64, (m, 2),
                                                     elements=st.integers(0, 5)))),
        "indptr": indptr, "indices": indices,
        "weights": data.draw(either(numbers(n))), "diag": data.draw(either(numbers(m))),
    }
    graph = outcome(lambda: ConsistencyGraph(**fields))
    solve_with = data.draw(either(st.sampled_from([graph])))
    params = data.draw(st.one_of(st.none(), st.just(ClipperParams(seed=3)), junk))
    n_solutions = data.draw(either(st.integers(1, 4)))
    downweight = data.draw(either(st.floats(0.0, 0.9)))
    outcome(lambda: clipper_solve(solve_with, params))
    outcome(lambda: mno_clipper(solve_with, n_solutions, params, downweight))


@FUZZ
@given(st.dictionaries(st.sampled_from(["seed", "sigma", "epsilon", "max_outer", "beta"]),
                       junk, max_size=2))
def test_clipper_params(kwargs):
    params = outcome(lambda: ClipperParams(**kwargs))
    if params is not None:
        p = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])
        clipper_solve(consistency_graph(p, p, np.argwhere(np.ones((3, 3), bool))), params)


# -- aligner, pair aligner, filter -------------------------------------------------------------

PAIR = overlapping_maps(np.random.default_rng(0), 20, 0.6, 0.1, clutter=3)


@FUZZ
@given(either(st.one_of(maps(), st.just(PAIR.ego))), either(st.one_of(maps(), st.just(PAIR.other))),
       either(st.floats(-1e3, 1e3)), either(st.lists(st.tuples(st.floats(0, 200), maps()),
                                                     max_size=2)),
       st.one_of(st.none(), either(finite(3, 10.0))))
def test_frame_aligner_measurements(ego, other, now, past, held):
    found = outcome(lambda: FrameAligner().measurements(ego, other, now, past, (), held))
    assert found is None or all(np.all(np.isfinite(m.z)) for m in found)


@FUZZ
@given(st.lists(st.tuples(either(st.floats(-10.0, 10.0)), either(maps(6))), min_size=1,
                max_size=3))
def test_pairwise_aligner_update(steps):
    aligner = PairwiseAligner()
    last = PAIR.now
    for dt, other in steps:
        t = dt if not isinstance(dt, float) else PAIR.now + dt
        try:
            aligner.update(t, PAIR.ego, other)
            last = float(t)
        except TcaffError:
            pass
    # whatever was refused left no trace: the next valid step is taken (unless the last
    # accepted time was so near the largest float that no later finite time exists)
    after = last + max(1.0, abs(last) * 1e-9)
    if np.isfinite(after):
        aligner.update(after, PAIR.ego, PAIR.other)


@FUZZ
@given(either(st.floats(0.0, 100.0)), either(maps()), either(st.floats(-1e3, 1e3)),
       either(st.floats(1.0, 50.0)))
def test_map_memory_and_identities(t, objects, now, kappa):
    outcome(lambda: MapMemory(100.0, 10.0).add(t, objects))
    outcome(lambda: recent_ids(ObjectIdentities(), objects, now, kappa))


STATE = None


@FUZZ
@given(st.data())
def test_filter_load_state_dict(data):
    global STATE
    if STATE is None:
        filt = TCAFF()
        for step in range(30):
            filt.update([[3.0, -2.0, 1.0 + 0.001 * step]], np.diag([0.25, 0.25, 0.01])[None])
        STATE = filt.state_dict()
    state = dict(STATE)
    for key in data.draw(st.lists(st.sampled_from(sorted(STATE)), min_size=1, max_size=3)):
        original = STATE[key]
        state[key] = data.draw(st.one_of(
            junk, numbers(original.shape),
            hnp.arrays(original.dtype, original.shape) if original.dtype.kind in "iu" else junk))
    target = TCAFF()
    if outcome(lambda: target.load_state_dict(state)) is None and target.step == 0:
        return  # refused, and nothing was restored
    target.update([[3.0, -2.0, 1.0]], np.diag([0.25, 0.25, 0.01])[None])  # loaded: it runs


# -- camera ------------------------------------------------------------------------------------


@FUZZ
@given(either(st.integers(1, 2000)), either(st.integers(1, 2000)),
       either(st.floats(1e-3, 1e5)), either(st.floats(1e-3, 1e5)),
       either(st.floats(-1e4, 1e4)), either(st.floats(-1e4, 1e4)))
def test_pinhole_camera(width, height, fx, fy, cx, cy):
    cam = outcome(lambda: PinholeCamera(width, height, fx, fy, cx, cy))
    if cam is not None and cam.width * cam.height <= 10**6:
        for ray in cam.rays():
            assert np.all(np.isfinite(ray))


@pytest.mark.parametrize("call", [
    lambda: ObjectMap.empty().ages(np.array([1.0, 2.0])),
    lambda: putative_associations(None, None),
    lambda: weighted_arun(np.full((3, 2), 1e200), np.zeros((3, 2))),
])
def test_known_junk_is_refused(call):
    """A few of the reported cases, as plain examples."""
    with pytest.raises(TcaffError):
        call()
