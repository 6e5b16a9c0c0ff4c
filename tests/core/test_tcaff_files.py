"""TCAFF state files: damaged files and tampered states are refused, the filter left alone."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.streams import alignment_stream
from tcaff_streams import R_CONSTANT, run

from tcaff_gtsam import TCAFF, TCAFFParams
from tcaff_gtsam.errors import ConfigError, DataError


def a_running_filter(params: TCAFFParams | None = None, steps: int = 40) -> TCAFF:
    """A filter with a main tree, exploring trees and (for the reseed promotion) a bank."""
    stream = alignment_stream(np.random.default_rng(3), steps, outliers=(1, 3))
    filt = TCAFF(params or TCAFFParams())
    run(filt, stream.zs)
    assert filt.estimate is not None
    return filt


def test_empty_truncated_and_fifo_files_are_data_errors(tmp_path):
    """They used to raise EOFError, BadZipFile, or block forever (the FIFO)."""
    a_running_filter().save(tmp_path / "good.npz")
    raw = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "empty.npz").write_bytes(b"")
    with pytest.raises(DataError, match="empty file, not a saved TCAFF filter"):
        TCAFF.load(tmp_path / "empty.npz")
    for cut in (10, len(raw) // 3, len(raw) // 2, len(raw) - 10):
        (tmp_path / "cut.npz").write_bytes(raw[:cut])
        with pytest.raises(DataError, match="not a saved TCAFF filter"):
            TCAFF.load(tmp_path / "cut.npz")
    os.mkfifo(tmp_path / "fifo.npz")
    with pytest.raises(DataError, match="not a regular file"):
        TCAFF.load(tmp_path / "fifo.npz")
    with pytest.raises(DataError, match="not a regular file"):
        TCAFF.load(tmp_path)
    with pytest.raises(DataError, match="no such TCAFF filter file"):
        TCAFF.load(tmp_path / "missing.npz")


#: the archive the damage test flips bits in, saved once
SAVED: list[bytes] = []


@settings(max_examples=80, deadline=None)
@given(st.data())
def test_any_damaged_filter_file_loads_or_is_a_data_error(tmp_path_factory, data):
    """Flipped bits in the compressed archive used to raise BadZipFile or zlib.error."""
    path = tmp_path_factory.mktemp("flip") / "filter.npz"
    if not SAVED:
        a_running_filter(steps=20).save(path)
        SAVED.append(path.read_bytes())
    raw = bytearray(SAVED[0])
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= 1 << data.draw(st.integers(0, 7))
    path.write_bytes(bytes(raw[: data.draw(st.integers(1, len(raw)))]))
    try:
        filt = TCAFF.load(path)
    except DataError:
        return
    filt.update([[3.0, -2.0, 1.0]], R_CONSTANT[None])  # what loads, runs


def _scaled(key, factor):
    return lambda s: s.__setitem__(key, s[key] * factor)


def _set(key, index, value):
    def change(state):
        state[key] = state[key].copy()
        state[key][index] = value
    return change


@pytest.mark.parametrize(("tamper", "message"), [
    (_set("main.x", (0, 0), np.nan), "main.x holds non-finite values"),
    (_set("explore.x", (0, 2), np.inf), "explore.x holds non-finite values"),
    (_scaled("main.P", -1.0), r"main.P\[0\] is not positive definite"),
    (_set("main.P", (0, 0, 1), 5.0), "main.P holds a covariance that is not symmetric"),
    (_set("main.P", (0, 0, 0), 0.0), r"main.P\[0\] is not positive definite"),
    (_set("main.edge", (0, 4), np.nan), "main.edge holds non-finite costs"),
    (_set("main.since", 0, -1), "main.since holds step counts below 0 or beyond step"),
    # numba's since + 1 would wrap round to a negative count
    (_set("main.since", 0, 2**63 - 1), "main.since holds step counts below 0 or beyond step"),
    (lambda s: s.__setitem__("step", np.array(-3)), "step = -3 must be >= 0"),
    (lambda s: s.__setitem__("_next_tree", np.array(-1)), "_next_tree = -1 must be >= 0"),
    (lambda s: s.__setitem__("_fresh", s["step"] + 1), "_fresh = .* is after step"),
    (lambda s: s.update(step=np.array(9), _fresh=np.array(0)),
     "evidence of 10 steps, expected 9"),
    (_set("explore.tree", 0, 10**6), r"explore.tree ids must lie in \[0, _next_tree"),
    (_set("explore.tree", 0, -4), r"explore.tree ids must lie in \[0, _next_tree"),
    (_set("main.tree", 0, 99), "main.tree ids must all be the hypothesis counter"),
    (_set("main.choice", (0, -1), 50), r"main.choice\[0, 9\] = 50 is not a measurement of "
                                       r"its step"),
    (_set("explore.choice", (0, -1), 7), r"explore.choice\[0, 9\] = 7 is not a measurement"),
    (_set("main.choice", (0, -1), -3), "main.choice is not a path"),
    (_set("main.choice", (0, -1), -2), "main.choice is not a path"),
    (_set("steps.sizes", -1, -5), "steps.sizes must hold 10 counts"),
    (lambda s: s.__setitem__("main.choice", s["main.choice"] + 0.5),
     "main.choice must hold integers"),
    (lambda s: s.__setitem__("main.choice", s["main.choice"].astype(np.int64) + 2**33),
     "main.choice holds values beyond int32"),
    (lambda s: s.__setitem__("main.x", s["main.x"] + 1j), "main.x must hold real numbers"),
    (lambda s: s.__setitem__("step", np.array(40.5)), "step must be an integer"),
    # a switch from a silent main tree is of the main tree, at a step it has seen
    (lambda s: s.__setitem__("silent_switch", np.array([1, s["hypothesis"] + 1])),
     r"silent_switch = \(1, .*\) must name the main tree's hypothesis"),
    (lambda s: s.__setitem__("silent_switch", np.array([0, s["hypothesis"]])),
     r"silent_switch = \(0, .*\) must name"),
    (lambda s: s.__setitem__("silent_switch", np.array([s["step"] + 1, s["hypothesis"]])),
     r"silent_switch = .* at a step in \[1, "),
    (lambda s: s.__setitem__("silent_switch", np.array([1, 2, 3])),
     r"silent_switch must be \(step, hypothesis\)"),
    (lambda s: s.__setitem__("silent_switch", np.array([1.5, 1.0])),
     "silent_switch must hold integers"),
    # a provisional acceptance is of the main tree, seeded within the last W steps
    (lambda s: s.__setitem__("provisional", np.array([s["step"], s["hypothesis"] + 1])),
     r"provisional = .* must name the main tree's hypothesis"),
    (lambda s: s.__setitem__("provisional", np.array([s["step"] - 8, s["hypothesis"]])),
     r"provisional = .* at a step in \[\d+, "),
    (lambda s: s.__setitem__("provisional", np.array([s["step"] + 1, s["hypothesis"]])),
     r"provisional = .* at a step in "),
    (lambda s: s.__setitem__("provisional", np.array([1])),
     r"provisional must be \(step, hypothesis\)"),
])
def test_a_tampered_state_is_refused_and_the_filter_left_alone(tamper, message):
    source = a_running_filter()
    state = {key: value.copy() for key, value in source.state_dict().items()}
    tamper(state)
    target = TCAFF()
    with pytest.raises(DataError, match=f"^TCAFF state: .*{message}"):
        target.load_state_dict(state)
    assert target.step == 0 and target.estimate is None  # nothing was restored


def _first(key: str, value):
    """A tamper setting the first entry of `key` to `value`."""
    def tamper(state):
        state[key] = state[key].copy()
        state[key][0] = value
    return tamper


@pytest.mark.parametrize(("tamper", "message"), [
    (_first("jitter.steps", 10**6), "jitter.steps must increase within the last"),
    (_first("jitter.steps", -5), "jitter.steps must increase within the last"),
    (_first("jitter.steps", 1), "jitter.steps must increase within the last"),
    (_first("jitter.values", -1.0), r"jitter.values\[0\] = .*-1.0.* is not a jitter"),
    (_first("jitter.values", np.nan), r"jitter.values\[0\] = .*nan.* is not a jitter"),
    (_first("jitter.hypotheses", 0), "jitter.hypotheses must hold one hypothesis id"),
    (_first("jitter.hypotheses", 10**6), "jitter.hypotheses must hold one hypothesis id"),
    # a finite value beyond what the filter records would scale P to inf
    (_first("jitter.values", 1e308), r"jitter.values\[0\] = .*1e\+308.* is not a jitter"),
    (lambda s: s.__setitem__("jitter.values", s["jitter.values"][1:]),
     "one value each in jitter.values"),
    (_first("jitter.last", 10**6), r"jitter.last must be \(step, hypothesis\)"),
    (lambda s: s.__setitem__("jitter.last_R", -np.eye(3)), r"jitter.last_R a \(3, 3\) SPD"),
    (lambda s: s.__setitem__("jitter.last_z", np.zeros(2)), r"jitter.last_z a finite \(3,\)"),
])
def test_a_tampered_jitter_record_is_refused(tamper, message):
    params = TCAFFParams(jitter_reference=0.05)
    state = a_running_filter(params).state_dict()
    assert state["jitter.steps"].size > 1 and "jitter.last" in state
    tamper(state)
    target = TCAFF(params)
    with pytest.raises(DataError, match=f"^TCAFF state: .*{message}"):
        target.load_state_dict(state)
    assert target.step == 0 and target.estimate is None


def _same_state(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_hypotheses_before_the_first_step_are_refused_and_a_running_filter_left_alone():
    """Each entry of such a state is a legal one; together they used to pass every check and
    raise an IndexError half-way through restoring them."""
    target = a_running_filter()
    before, estimate = target.state_dict(), target.estimate
    state = {key: value.copy() for key, value in a_running_filter().state_dict().items()}
    state.update(step=np.array(0), _fresh=np.array(0))
    for key in ("evidence.sizes", "evidence.counts", "steps.sizes", "objects.sizes",
                "objects.counts"):
        state[key] = np.zeros(0, np.int64)
    state["evidence.pairs"] = np.zeros((0, 2), np.int64)
    for tree in ("main", "explore"):
        state[f"{tree}.since"] = np.zeros_like(state[f"{tree}.since"])
        choice = np.full_like(state[f"{tree}.choice"], -2)
        choice[:, -1] = -1
        state[f"{tree}.choice"] = choice
    with pytest.raises(DataError, match="hypotheses at step 0, before any measurement"):
        target.load_state_dict(state)
    assert _same_state(target.state_dict(), before) and target.estimate is estimate


def test_a_load_that_fails_after_its_checks_leaves_the_filter_as_it_was(monkeypatch):
    """Whatever the checks miss and fails while the state is being restored: a DataError,
    and the running filter as it was (the state it saved itself restored)."""
    target = a_running_filter(TCAFFParams(jitter_reference=0.05))
    before = target.state_dict()
    held = target.held
    other = a_running_filter(TCAFFParams(jitter_reference=0.05), steps=30).state_dict()
    calls = []

    def failing(self, estimate):
        calls.append(1)
        if len(calls) == 1:
            raise IndexError("a state no check foresaw")
        return estimate

    monkeypatch.setattr(TCAFF, "_reported", failing)
    with pytest.raises(DataError, match=r"could not be restored .*IndexError.* the filter "
                                        r"is as it was"):
        target.load_state_dict(other)
    assert _same_state(target.state_dict(), before)
    np.testing.assert_array_equal(target.held.P, held.P)


def test_measurements_far_apart_record_a_capped_jitter_and_a_finite_covariance():
    """A jitter that overflows (consecutive measurements 1e200 apart) is recorded at the cap:
    the reported covariance stays finite, and the filter's own state loads again."""
    from tcaff_gtsam.tcaff_state import JITTER_CAP

    params = TCAFFParams(jitter_reference=0.05)
    filt = a_running_filter(params)
    state = filt.state_dict()
    assert "jitter.last" in state
    state["jitter.last_z"] = state["jitter.last_z"] + 1e200
    filt.load_state_dict(state)
    z = filt.held.x[None]
    filt.update(z, np.broadcast_to(R_CONSTANT, (1, 3, 3)))
    assert filt.held.measurement == 0
    assert filt._jitter[-1] == (filt.step, JITTER_CAP, filt.hypothesis)
    assert np.all(np.isfinite(filt.held.P)) and np.all(np.linalg.eigvalsh(filt.held.P) > 0)
    TCAFF(params).load_state_dict(filt.state_dict())


def test_the_jitter_never_scales_a_covariance_past_the_largest_float():
    params = TCAFFParams(jitter_reference=0.05)
    state = a_running_filter(params).state_dict()
    state["main.P"] = state["main.P"] * 1e305
    state["jitter.values"] = np.full_like(state["jitter.values"], 1e6)
    filt = TCAFF(params)
    filt.load_state_dict(state)
    unscaled = filt._main_estimate().P
    assert np.all(np.isfinite(filt.held.P))
    assert np.all(np.abs(filt.held.P) >= np.abs(unscaled))  # never shrunk either


def test_object_counts_update_would_refuse_are_refused_in_a_state():
    filt = TCAFF()
    for _ in range(3):
        filt.update(np.zeros((2, 3)), np.broadcast_to(R_CONSTANT, (2, 3, 3)), objects=[5, 7])
    state = filt.state_dict()
    TCAFF().load_state_dict(state)
    assert state["objects.counts"].size
    state["objects.counts"] = np.full_like(state["objects.counts"], 2**31)
    with pytest.raises(DataError, match="stored objects do not match"):
        TCAFF().load_state_dict(state)


def test_a_jitter_record_loaded_into_a_filter_without_a_reference_is_dropped():
    """Not used, and not kept: a record it never trims would, jitter_span steps later, make
    its own state one that no filter loads."""
    state = a_running_filter(TCAFFParams(jitter_reference=0.05)).state_dict()
    plain, source = TCAFF(), a_running_filter()
    plain.load_state_dict(state)
    np.testing.assert_array_equal(plain.held.P, source.held.P)  # the same stream, unscaled
    for _ in range(TCAFFParams().jitter_span + 1):
        plain.update(np.zeros((0, 3)), np.zeros((0, 3, 3)))
        source.update(np.zeros((0, 3)), np.zeros((0, 3, 3)))
        assert (plain.held is None) == (source.held is None)
        if source.held is not None:
            np.testing.assert_array_equal(plain.held.P, source.held.P)
    again = plain.state_dict()
    assert again["jitter.steps"].size == 0 and "jitter.last" not in again
    TCAFF().load_state_dict(again)


@pytest.mark.parametrize("params", [TCAFFParams(), replace(TCAFFParams.reference(),
                                                            promotion="reseed")])
def test_the_bank_of_a_reseeding_filter_is_checked(params):
    state = a_running_filter(params).state_dict()
    state["bank.Rs"] = -state["bank.Rs"]
    if params.promotion == "reseed":
        with pytest.raises(DataError, match=r"bank.Rs\[0\] is not positive definite"):
            TCAFF(params).load_state_dict(state)
    state = a_running_filter(params).state_dict()
    state["bank.sizes"] = np.array([0, 0, 0], np.int64)
    with pytest.raises(DataError, match="bank"):
        TCAFF(params).load_state_dict(state)


def test_a_state_saved_before_step_sizes_were_recorded_still_loads():
    source = a_running_filter()
    state = source.state_dict()
    del state["steps.sizes"]
    restored = TCAFF()
    restored.load_state_dict(state)
    np.testing.assert_array_equal(restored.estimate.x, source.estimate.x)
    zs = [[3.0, -2.0, 1.0]]
    np.testing.assert_array_equal(restored.update(zs, R_CONSTANT[None]).x,
                                  source.update(zs, R_CONSTANT[None]).x)


@pytest.mark.parametrize("state", [None, "state", [("step", 1)]])
def test_a_state_that_is_not_a_mapping_is_a_data_error(state):
    with pytest.raises(DataError, match=r"^TCAFF state: must be a mapping"):
        TCAFF().load_state_dict(state)


@pytest.mark.parametrize("params", ["reference", {"window": 8}, 1])
def test_filter_params_of_the_wrong_type_are_a_config_error(params):
    with pytest.raises(ConfigError, match=r"^TCAFF\.params = "):
        TCAFF(params)
