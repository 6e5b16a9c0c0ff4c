"""Parameter objects: every field refuses values of the wrong kind with a ConfigError naming the
field and the value, and the objects compare and hash by value, matrices included."""

from __future__ import annotations

import math
import pickle
from dataclasses import fields, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import (
    ClipperParams,
    FrameAlignerParams,
    GraphParams,
    ParameterError,
    TCAFFParams,
)

CLASSES = [ClipperParams, FrameAlignerParams, TCAFFParams, GraphParams]
#: fields where None is a valid value (it means "off" or "the default")
OPTIONAL = {("FrameAlignerParams", "max_rmse"), ("FrameAlignerParams", "min_inliers"),
            ("FrameAlignerParams", "track_min"), ("FrameAlignerParams", "guide_radius"),
            ("FrameAlignerParams", "size_partial"), ("FrameAlignerParams", "height_epsilon"),
            ("FrameAlignerParams", "repeat_Q"), ("FrameAlignerParams", "sparse_associations"),
            ("TCAFFParams", "report_after"), ("TCAFFParams", "recall_for"),
            ("TCAFFParams", "hold_for"), ("TCAFFParams", "held_Q"),
            ("TCAFFParams", "gate_box"), ("TCAFFParams", "jitter_reference"),
            ("FrameAlignerParams", "jitter_reference"),
            ("TCAFFParams", "switch_after"), ("TCAFFParams", "switch_support"),
            ("GraphParams", "Q"),
            ("GraphParams", "odometry_cov"), ("GraphParams", "horizon"),
            ("GraphParams", "history")}
#: fields that are switches
SWITCHES = {("TCAFFParams", "root_in_window"), ("TCAFFParams", "switch_stale"),
            ("TCAFFParams", "withhold_contested"), ("TCAFFParams", "sequential"),
            ("TCAFFParams", "neutral_empty_steps"),
            ("FrameAlignerParams", "check_ambiguity"),
            ("FrameAlignerParams", "descriptor_prior"), ("FrameAlignerParams", "refit"),
            ("GraphParams", "shared_maps"), ("GraphParams", "cycle_check")}
#: values of the wrong kind for a number, a choice, a matrix or a nested parameter object
JUNK = ("8", "huge", b"1", [["a"]], {}, object(), float("nan"))


def cases(values):
    return [(cls, f.name, v) for cls in CLASSES for f in fields(cls) for v in values]


def short(value) -> str:
    """A test id that is the same in every process (parallel workers must agree on them)."""
    if isinstance(value, type):
        return value.__name__
    return "object()" if type(value) is object else repr(value)


@pytest.mark.parametrize(("cls", "name", "value"), cases(JUNK), ids=short)
def test_every_field_refuses_junk_with_a_config_error_naming_it(cls, name, value):
    with pytest.raises(ConfigError, match=f"^{cls.__name__}.{name} = "):
        cls(**{name: value})


@pytest.mark.parametrize(("cls", "name", "value"), cases([None, True]), ids=short)
def test_none_and_bools_only_where_the_field_takes_them(cls, name, value):
    takes = ((cls.__name__, name) in OPTIONAL if value is None
             else (cls.__name__, name) in SWITCHES)
    if takes:
        cls(**{name: value})
    else:
        with pytest.raises(ConfigError, match=f"^{cls.__name__}.{name} = "):
            cls(**{name: value})


@pytest.mark.parametrize(("make", "message"), [
    (lambda: TCAFFParams(tau=None), "TCAFFParams.tau = None: must be a finite number"),
    (lambda: TCAFFParams(tau="8"), "TCAFFParams.tau = '8': must be a finite number"),
    (lambda: ClipperParams(sigma="a"),
     "ClipperParams.sigma = 'a': must be a finite number >= 1e-9"),
    (lambda: FrameAlignerParams(kappa=None), "FrameAlignerParams.kappa = None: must be a number"),
    (lambda: ClipperParams(seed=-1), "ClipperParams.seed = -1: must be an int >= 0"),
    (lambda: FrameAlignerParams(dim=2.0), "FrameAlignerParams.dim = 2.0: must be 2 or 3"),
    (lambda: GraphParams(free_sigmas=["a", 1.0]), "GraphParams.free_sigmas = ['a', 1.0]"),
    (lambda: TCAFFParams(gate_box=["a", 1, 1]), "TCAFFParams.gate_box = ['a', 1, 1]"),
    (lambda: TCAFFParams(angle_indices=2), "TCAFFParams.angle_indices = 2"),
    (lambda: TCAFFParams(P0=[[1.0], [1.0, 2.0]]), "TCAFFParams.P0 = "),
    (lambda: GraphParams(history=10), "GraphParams.history = 10: needs a horizon"),
    (lambda: GraphParams(horizon=5, history=-1), "GraphParams.history = -1: must be an int"),
])
def test_wrong_kinds_are_config_errors_not_type_errors(make, message):
    with pytest.raises(ConfigError) as info:
        make()
    assert str(info.value).startswith(message)


junk = st.one_of(st.none(), st.booleans(), st.floats(allow_nan=True, allow_infinity=True),
                 st.integers(-5, 5), st.text(max_size=4), st.binary(max_size=2),
                 st.lists(st.integers(-2, 4), max_size=4), st.dictionaries(st.text(max_size=2),
                                                                           st.integers()))


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(cases([None])), junk)
def test_any_value_is_taken_or_refused_by_a_config_error_naming_the_field(case, value):
    cls, name, _ = case
    try:
        made = cls(**{name: value})
    except ParameterError as exc:
        assert (exc.owner, exc.name) == (cls.__name__, name)
        assert str(exc).startswith(f"{cls.__name__}.{name} = {value!r}: ")
    else:
        assert made == made and hash(made) == hash(replace(made))


@pytest.mark.parametrize("cls", CLASSES)
def test_parameters_compare_and_hash_by_value(cls):
    a, b = cls(), cls()
    assert a == b and not a != b
    assert hash(a) == hash(b) and len({a, b}) == 1
    assert a != "params" and a is not None


def test_matrices_compare_by_value():
    default = TCAFFParams()
    assert TCAFFParams(Q=default.Q.tolist(), P0=tuple(map(tuple, default.P0))) == default
    assert TCAFFParams(Q=2 * default.Q) != default
    assert replace(default, tau=9.0) != default
    negative_zero = default.Q.copy()
    negative_zero[0, 1] = negative_zero[1, 0] = -0.0
    assert TCAFFParams(Q=negative_zero) == default
    assert hash(TCAFFParams(Q=negative_zero)) == hash(default)
    assert FrameAlignerParams(R_constant=2 * default.P0) != FrameAlignerParams()
    assert GraphParams(Q=np.eye(3)) != GraphParams()
    assert GraphParams(free_sigmas=[1.0, 1.0]) == GraphParams()


def test_parameters_hold_their_own_copy_of_a_matrix():
    Q = np.diag([0.01, 0.01, 1e-4])
    params = TCAFFParams(Q=Q)
    before = hash(params)
    Q[0, 0] = 5.0
    assert params.Q[0, 0] == 0.01 and hash(params) == before


def test_a_hot_path_reads_the_stored_array():
    """The matrix is converted once, when the parameters are made, not on every read."""
    Q = np.diag([0.01, 0.01, 0.0001]).astype(np.float32)
    params = TCAFFParams(Q=Q)
    assert params.Q.dtype == np.float64 and params.Q.shape == (3, 3)
    assert params.Q is params.Q and params.Q is not Q


def test_parameter_errors_name_the_field_and_survive_pickling():
    with pytest.raises(ParameterError) as info:
        FrameAlignerParams(n_solutions=0)
    exc = info.value
    assert (exc.owner, exc.name, exc.value, exc.rule) == (
        "FrameAlignerParams", "n_solutions", 0, "must be an int in [1, 1000] (MAX_SOLUTIONS)")
    again = pickle.loads(pickle.dumps(exc))
    assert isinstance(again, ConfigError) and str(again) == str(exc)
    assert (again.name, again.value) == ("n_solutions", 0)


def test_infinite_values_where_they_mean_no_limit():
    assert FrameAlignerParams(kappa=math.inf).kappa == math.inf
    with pytest.raises(ConfigError, match=r"TCAFFParams\.tau = inf"):
        TCAFFParams(tau=math.inf)


def test_a_value_without_a_repr_is_still_a_config_error_naming_the_field():
    """An int beyond Python's 4300-digit conversion limit raised ValueError from the message."""
    with pytest.raises(ConfigError, match="power_iterations = <int that has no repr>"):
        ClipperParams(power_iterations=10**5000)
