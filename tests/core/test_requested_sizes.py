"""Sizes a caller asks for are bounded: an argument that would allocate by its value (samples
of a drive, times of the misplacement, a filter's window and the caps on its trees,
MNO-CLIPPER's solutions) is taken up to its limit and refused beyond it by a TcaffError naming
the argument and its value, never by numpy's "Maximum allowed size exceeded" or a
MemoryError."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tcaff_gtsam import TCAFF, consistency_graph, mno_clipper
from tcaff_gtsam.errors import DataError
from tcaff_gtsam.filter_params import MAX_LEAVES, MAX_MEASUREMENTS, MAX_TREE_BYTES
from tcaff_gtsam.params import (
    MAX_SOLUTIONS,
    MAX_WINDOW,
    FrameAlignerParams,
    ParameterError,
    TCAFFParams,
)
from tcaff_gtsam.span import MAX_SAMPLES, misplacement, random_drive

positive = st.floats(min_value=1e-300, max_value=1e300, allow_nan=False, allow_infinity=False)
#: ints of any size, most of them beyond every limit
counts = st.one_of(st.integers(-3, 3 * MAX_SOLUTIONS), st.integers(-2**80, 2**80))


@settings(max_examples=80, deadline=None)
@given(duration=positive, step=positive)
@example(duration=1e300, step=0.5).via("the issue's call")
@example(duration=499_999.5, step=0.5).via("MAX_SAMPLES samples exactly")
@example(duration=500_000.0, step=0.5).via("one sample more")
def test_random_drive_draws_at_most_max_samples(duration, step):
    steps = duration / step
    if steps > MAX_SAMPLES - 1:
        with pytest.raises(DataError) as info:
            random_drive(np.random.default_rng(0), duration, 0.5, step=step)
        message = str(info.value)
        assert message.startswith("random_drive: ")
        assert f"duration = {duration!r} s" in message and f"step = {step!r} s" in message
        return
    times, T = random_drive(np.random.default_rng(0), duration, 0.5, step=step)
    assert times.shape == (math.ceil(steps) + 1,) and T.shape == (times.size, 3, 3)
    assert times.size <= MAX_SAMPLES


@settings(max_examples=60, deadline=None)
@given(every=positive)
@example(every=1e-300)
@example(every=5.0000001e-6).via("just under MAX_SAMPLES times")
@example(every=4.9999e-6).via("just over")
def test_misplacement_evaluates_at_most_max_samples_times_per_span(every):
    """A 10 s drive standing still, the span 5 s: 5 / every + 1 times."""
    times = np.arange(0.0, 10.0 + 1e-9, 0.5)
    T = np.tile(np.eye(3), (times.size, 1, 1))
    # the times of np.arange(5.0, 10.0 + 1e-9, every), as misplacement takes them
    n = (10.0 + 1e-9 - 0.0 - 5.0) / every
    if n > MAX_SAMPLES:
        with pytest.raises(DataError) as info:
            misplacement(times, T, T, [5.0], every=every)
        assert str(info.value).startswith(f"misplacement: every = {every!r} s ")
        return
    np.testing.assert_array_equal(misplacement(times, T, T, [5.0], every=every), [0.0])


def test_misplacement_pools_runs_without_keeping_each_error():
    """Two runs of one span: the RMS over both runs' times, as if they were one list."""
    times = np.arange(0.0, 30.0 + 1e-9, 0.5)
    still = np.tile(np.eye(3), (times.size, 1, 1))
    turned = still.copy()
    turned[:, :2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # a constant heading: no misplacement
    drifting = still.copy()
    drifting[:, 0, 2] = 0.01 * times  # a drift of 1 cm/s: 0.1 m over a 10 s span
    rms = misplacement([times, times[:41]], [still, still[:41]], [drifting, turned[:41]],
                       [10.0], every=1.0)
    # 21 times of the first run at 0.1 m, 11 of the second at 0
    np.testing.assert_allclose(rms, [math.sqrt(21 * 0.1**2 / 32)], rtol=1e-12)


@settings(max_examples=80, deadline=None)
@given(window=counts)
@example(window=MAX_WINDOW)
@example(window=MAX_WINDOW + 1)
@example(window=10**12).via("3.6 TiB of choices before")
def test_the_filter_window_is_bounded(window):
    if 1 <= window <= MAX_WINDOW:
        # small trees: with the default caps a long window is refused for their product
        filt = TCAFF(TCAFFParams(window=window, **SMALL_TREES))
        filt.update(np.zeros((1, 3)), 0.1 * np.eye(3)[None])
        assert filt.step == 1 and filt.params.window == window
        return
    with pytest.raises(ParameterError) as info:
        TCAFFParams(window=window)
    assert str(info.value).startswith(
        f"TCAFFParams.window = {window!r}: must be an int in [1, {MAX_WINDOW}]")


def square_graph():
    """Four corners matched to each other in every way: 16 associations."""
    p = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 2.0], [0.0, 2.0]])
    return consistency_graph(p, p, np.argwhere(np.ones((4, 4), bool)))


@settings(max_examples=60, deadline=None)
@given(n=counts, downweight=st.sampled_from([0.0, 0.5]))
@example(n=MAX_SOLUTIONS, downweight=0.5)
@example(n=MAX_SOLUTIONS + 1, downweight=0.5)
@example(n=10**12, downweight=0.5).via("262 TiB of start draws before")
def test_mno_clipper_solutions_are_bounded(n, downweight):
    graph = square_graph()
    if 1 <= n <= MAX_SOLUTIONS:
        found = mno_clipper(graph, n, downweight=downweight)
        assert 1 <= len(found) <= (min(n, graph.m) if downweight == 0 else n)
        assert FrameAlignerParams(n_solutions=n).n_solutions == n
        return
    with pytest.raises(ParameterError) as info:
        mno_clipper(graph, n, downweight=downweight)
    assert str(info.value).startswith(
        f"mno_clipper.n_solutions = {n!r}: must be an int in [1, {MAX_SOLUTIONS}]")
    with pytest.raises(ParameterError) as info:
        FrameAlignerParams(n_solutions=n)
    assert str(info.value).startswith(
        f"FrameAlignerParams.n_solutions = {n!r}: must be an int in [1, {MAX_SOLUTIONS}]")


#: caps small enough that any one of them, or the window, may go to its limit within
#: MAX_TREE_BYTES
SMALL_TREES = {"max_leaves": 1, "explore_max_leaves": 1, "max_measurements": 1}

TREE_CAPS = [("max_leaves", MAX_LEAVES, "MAX_LEAVES"),
             ("explore_max_leaves", MAX_LEAVES, "MAX_LEAVES"),
             ("max_children", MAX_MEASUREMENTS, "MAX_MEASUREMENTS"),
             ("explore_max_children", MAX_MEASUREMENTS, "MAX_MEASUREMENTS"),
             ("max_measurements", MAX_MEASUREMENTS, "MAX_MEASUREMENTS")]


@pytest.mark.parametrize(("name", "limit", "limit_name"), TREE_CAPS,
                         ids=[name for name, _, _ in TREE_CAPS])
@settings(max_examples=40, deadline=None)
@given(value=counts)
@example(value=MAX_LEAVES).via("MAX_LEAVES exactly")
@example(value=MAX_MEASUREMENTS + 1).via("one more than MAX_MEASUREMENTS")
@example(value=10**12)
def test_tcaff_tree_caps_are_at_most_their_limit(name, limit, limit_name, value):
    """The caps on the trees and measurements decide how many leaves a step extends; each is
    an int in [1, its limit]."""
    if 1 <= value <= limit:
        assert getattr(TCAFFParams(**{**SMALL_TREES, name: value}), name) == value
        return
    with pytest.raises(ParameterError) as info:
        TCAFFParams(**{name: value})
    assert info.value.name == name and info.value.value == value
    assert info.value.rule == f"must be an int in [1, {limit}] ({limit_name})"


def tree_bytes(window, max_leaves, max_children, explore_max_leaves, explore_max_children,
               max_measurements, d=3):
    """The trees' worst case, counted leaf by leaf: x (d) and P (d, d) in float64, per column
    of the path (W + 2) an int32 choice and a float64 edge cost, and two int64s."""
    leaf = 8 * (d + d * d) + (4 + 8) * (window + 2) + 2 * 8
    main = max_leaves * (1 + min(max_children, max_measurements))
    open_trees = max_measurements * window  # seeded each step, each open W steps
    exploring = open_trees * explore_max_leaves * (1 + min(explore_max_children,
                                                           max_measurements))
    return leaf * (main + exploring)


CAP_ORDER = ("window", "max_leaves", "max_children", "explore_max_leaves",
             "explore_max_children", "max_measurements")
caps = st.fixed_dictionaries({
    "window": st.integers(1, MAX_WINDOW), "max_leaves": st.integers(1, MAX_LEAVES),
    "max_children": st.integers(1, MAX_MEASUREMENTS),
    "explore_max_leaves": st.integers(1, MAX_LEAVES),
    "explore_max_children": st.integers(1, MAX_MEASUREMENTS),
    "max_measurements": st.integers(1, MAX_MEASUREMENTS)})


@settings(max_examples=150, deadline=None)
@given(caps=caps)
@example(caps={"window": 8, "max_leaves": 200, "max_children": 4, "explore_max_leaves": 50,
               "explore_max_children": 2, "max_measurements": 32}).via("the defaults")
@example(caps={"window": 1000, "max_leaves": 200, "max_children": 4, "explore_max_leaves": 50,
               "explore_max_children": 2, "max_measurements": 32}).via("54 GiB")
@example(caps={"window": 8, "max_leaves": 10_000, "max_children": 1000,
               "explore_max_leaves": 10_000, "explore_max_children": 1000,
               "max_measurements": 1000}).via("every cap at its limit")
def test_the_caps_together_are_bounded(caps):
    """Each cap within its limit, a TCAFFParams is refused exactly when the trees they allow
    could outgrow MAX_TREE_BYTES, by a ParameterError naming the caps and their values."""
    need = tree_bytes(**caps)
    if need <= MAX_TREE_BYTES:
        params = TCAFFParams(**caps)
        assert params.tree_bytes() == need
        return
    with pytest.raises(ParameterError) as info:
        TCAFFParams(**caps)
    assert info.value.name == "(" + ", ".join(CAP_ORDER) + ")"
    assert info.value.value == tuple(caps[name] for name in CAP_ORDER)
    assert f"could need {need / 2**30:.2f} GiB at once" in info.value.rule


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), window=st.integers(1, 6),
       max_leaves=st.integers(1, 6), explore_max_leaves=st.integers(1, 4),
       max_measurements=st.integers(1, 5))
def test_the_trees_hold_no_more_leaves_than_their_caps_allow(seed, window, max_leaves,
                                                             explore_max_leaves,
                                                             max_measurements):
    """Measurements bunched so that every leaf gates most of them: the main tree keeps at
    most max_leaves leaves, the exploring trees (max_measurements seeded a step, open for W
    steps) at most explore_max_leaves each, the counts `tree_bytes` is built on."""
    params = TCAFFParams(window=window, max_leaves=max_leaves, max_children=3,
                         explore_max_leaves=explore_max_leaves, explore_max_children=3,
                         max_measurements=max_measurements)
    filt = TCAFF(params)
    rng = np.random.default_rng(seed)
    for _ in range(4 * window + 6):
        zs = rng.normal(0.0, [0.05, 0.05, 0.005], (int(rng.integers(0, 8)), 3))
        filt.update(zs, np.broadcast_to(0.1 * np.eye(3), (len(zs), 3, 3)))
        if filt._main is not None:
            assert len(filt._main) <= max_leaves
        assert len(filt._explore) <= max_measurements * window * explore_max_leaves
        assert len(np.unique(filt._explore.tree)) <= max_measurements * window


@pytest.mark.parametrize("name", [name for name, _, _ in TREE_CAPS])
@pytest.mark.parametrize("bad", [True, 2.0, math.nan, "3", None])
def test_tcaff_tree_caps_are_ints(name, bad):
    with pytest.raises(ParameterError, match=rf"^TCAFFParams\.{name} = "):
        TCAFFParams(**{name: bad})
