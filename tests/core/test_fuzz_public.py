"""Every public function, constructor and method of the library's core, called with junk and
with plausible values mixed: each call returns a result or raises a `TcaffError`, nothing else.

The entry points are found, not listed: the `__all__` of each core module, and the public
methods of an instance of each class. A new public function is fuzzed without touching this
file; one that cannot take junk fails here."""

from __future__ import annotations

import importlib
import inspect
import math
import os
import tempfile
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tcaff_gtsam import (
    TCAFF,
    FrameAligner,
    InterRobotGraph,
    MapMemory,
    ObjectIdentities,
    ObjectMap,
    PairwiseAligner,
    TcaffError,
    TeamConsistency,
)

#: the modules whose `__all__` is the library's public surface (the hypothesis tree's numba
#: kernels are TCAFF's internals, reached only through `TCAFF.update`)
MODULES = ("association", "clipper", "clipper_graph", "frame_aligner", "geometry", "graph",
           "identities", "inputs", "object_map", "pairwise", "params", "registration", "tcaff",
           "team")

#: examples per entry point; raise it for a longer search (TCAFF_FUZZ_EXAMPLES=1000)
FUZZ = settings(max_examples=int(os.environ.get("TCAFF_FUZZ_EXAMPLES", "60")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def small_map(n: int = 6) -> ObjectMap:
    rng = np.random.default_rng(n)
    return ObjectMap(rng.uniform(-5, 5, (n, 3)), np.full(n, 0.5), np.full(n, 0.5),
                     np.full(n, 10.0))


INSTANCES = {
    "ObjectMap": lambda: small_map(),
    "TCAFF": TCAFF,
    "FrameAligner": FrameAligner,
    "PairwiseAligner": PairwiseAligner,
    "InterRobotGraph": lambda: InterRobotGraph(3),
    "TeamConsistency": lambda: TeamConsistency(3),
    "MapMemory": lambda: MapMemory(100.0, 10.0),
    "ObjectIdentities": ObjectIdentities,
}


def entry_points() -> list[tuple[str, object]]:
    """(name, callable or instance factory + method name) of every public entry point."""
    found: dict[str, object] = {}
    for module_name in MODULES:
        module = importlib.import_module(f"tcaff_gtsam.{module_name}")
        for name in module.__all__:
            value = getattr(module, name)
            if callable(value) and not (isinstance(value, type)
                                        and issubclass(value, BaseException)):
                found.setdefault(f"{module_name}.{name}", value)
    for cls_name, make in INSTANCES.items():
        instance = make()
        for name, _ in inspect.getmembers(type(instance)):
            if name.startswith("_") or not callable(getattr(instance, name, None)):
                continue
            found[f"{cls_name}.{name}"] = (make, name)
    return sorted(found.items())


ENTRIES = entry_points()

junk = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**20), 10**20), st.floats(),
    st.complex_numbers(allow_nan=True), st.text(max_size=3), st.binary(max_size=2),
    st.sampled_from([math.nan, math.inf, -1, 10**400, 1e300, np.int64(-1), object(), {}, [],
                     (), Ellipsis, "x.npz"]),
    hnp.arrays(st.sampled_from([np.float64, np.int64, np.complex128, np.bool_]),
               hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4)),
)
plausible = st.one_of(
    st.integers(0, 3), st.floats(0.0, 20.0), st.just(small_map()), st.just(ObjectMap.empty()),
    st.just(np.eye(3)), st.just(np.diag([0.25, 0.25, 0.01])),
    hnp.arrays(np.float64, st.sampled_from([(3,), (3, 3), (2, 3), (4, 2), (2, 3, 3)]),
               elements=st.floats(-10, 10)),
    st.just([(1.0, small_map())]), st.just({(0, 1): None}),
)
argument = st.one_of(junk, plausible, plausible)


@contextmanager
def inside(folder: str):
    """Run with `folder` as the working directory: junk strings become file names there."""
    before = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def arity(target) -> tuple[int, int]:
    """(required, total) positional parameters of a callable."""
    try:
        params = list(inspect.signature(target).parameters.values())
    except (TypeError, ValueError):
        return 0, 3
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    required = [p for p in positional if p.default is p.empty]
    return len(required), len(positional)


def test_the_surface_is_found():
    names = {name for name, _ in ENTRIES}
    assert {"registration.putative_associations", "TCAFF.update", "InterRobotGraph.update",
            "PairwiseAligner.update", "TeamConsistency.update", "ObjectMap.save",
            "geometry.se2_from_params"} <= names
    assert len(ENTRIES) > 60


@pytest.mark.parametrize(("name", "entry"), ENTRIES, ids=[name for name, _ in ENTRIES])
@FUZZ
@given(data=st.data())
def test_a_result_or_a_tcaff_error(name, entry, data):
    target = getattr(entry[0](), entry[1]) if isinstance(entry, tuple) else entry
    required, total = arity(target)
    n = data.draw(st.integers(required, max(required, total)), label="number of arguments")
    args = [data.draw(argument, label=f"argument {k}") for k in range(n)]
    with tempfile.TemporaryDirectory() as folder, inside(folder):
        try:
            target(*args)
        except TcaffError:
            pass

