"""TCAFF on generated measurement streams: acceptance, accuracy, rejection, recovery, presets."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from tcaff_gtsam.eval.sim.streams import alignment_stream, wrong_alignments
from tcaff_streams import (
    R_CONSTANT,
    R_HONEST,
    SLOW_DRIFT,
    errors,
    first_estimate,
    last_estimate,
    run,
)

from tcaff_gtsam import TCAFF, TCAFFParams
from tcaff_gtsam.errors import ConfigError, DataError, TcaffError
from tcaff_gtsam.geometry import wrap_angle


@pytest.mark.parametrize("params", [TCAFFParams.paper(), TCAFFParams.reference()],
                         ids=["paper", "reference"])
def test_no_estimate_before_the_window_has_passed(params):
    stream = alignment_stream(np.random.default_rng(0), 30, p_empty=0.0, outliers=(0, 0))
    estimates = run(TCAFF(params), stream.zs)
    W = params.window
    assert all(est is None for est in estimates[:W])
    assert first_estimate(estimates) == W + 1  # every step consistent: accepted at once


@pytest.mark.parametrize("Q, R, max_t, max_deg", [
    (None, R_CONSTANT, 0.1, 1.0),        # defaults, the aligner's constant R
    (SLOW_DRIFT, R_HONEST, 0.07, 1.0),   # Q and R telling the truth about the stream
], ids=["default", "tuned"])
def test_accuracy_after_acceptance(Q, R, max_t, max_deg):
    params = TCAFFParams() if Q is None else TCAFFParams(Q=Q)
    for seed in range(3):  # seeds 0-4 pass alike; the smallest margins are among these
        stream = alignment_stream(np.random.default_rng(seed), 300)
        estimates = run(TCAFF(params), stream.zs, R)
        err = errors(estimates, stream.truth)
        assert len(err) > 0.9 * len(stream)
        assert err[:, 0].mean() <= max_t, f"seed {seed}"
        assert err[:, 1].mean() <= max_deg, f"seed {seed}"


@pytest.mark.parametrize("params", [TCAFFParams(), TCAFFParams.reference()],
                         ids=["default", "reference"])
@pytest.mark.parametrize("spread", [15.0, 3.0])
def test_temporally_inconsistent_measurements_give_no_estimate(params, spread):
    rng = np.random.default_rng(7)
    zs = [wrong_alignments(rng, int(rng.integers(1, 5)), spread) for _ in range(1500)]
    estimates = run(TCAFF(params), zs)
    assert sum(est is not None for est in estimates) < 0.01 * len(zs)


def steps_to_recover(estimates, truth, start, tol_t=0.5, tol_deg=5.0):
    for i in range(start, len(estimates)):
        est = estimates[i]
        if est is not None:
            e = est.x - truth[i]
            if np.hypot(e[0], e[1]) < tol_t and abs(np.degrees(wrap_angle(e[2]))) < tol_deg:
                return i - start + 1
    return None


def test_recovers_after_a_jump_within_25_steps():
    """W (8) steps to judge the new hypothesis and 3 to confirm the switch: 11 steps when no
    step is empty; empty steps (20 % here) delay it (22 at most over 40 seeds)."""
    jump = (3.0, -2.0, np.radians(40.0))
    for seed in range(5, 10):  # of seeds 0-9, those whose empty steps delay the switch
        stream = alignment_stream(np.random.default_rng(seed), 300, jumps={150: jump})
        filt = TCAFF()
        estimates = run(filt, stream.zs)
        steps = steps_to_recover(estimates, stream.truth, 150)
        assert steps is not None and steps <= 25, f"seed {seed}: {steps}"
        assert estimates[-1].hypothesis == 2  # accepted once, switched once
        assert errors(estimates[150 + steps:], stream.truth[150 + steps:])[:, 0].max() < 0.5


def test_reference_preset_keeps_a_wrong_hypothesis_for_40_steps_after_a_jump():
    jump = (3.0, -2.0, np.radians(40.0))
    for seed in range(3):  # the quickest of seeds 0-4 to recover among them
        stream = alignment_stream(np.random.default_rng(seed), 300, jumps={150: jump})
        estimates = run(TCAFF(TCAFFParams.reference()), stream.zs)
        steps = steps_to_recover(estimates, stream.truth, 150)
        assert steps is not None and steps > 40, f"seed {seed}: {steps}"


def test_reference_deletes_the_main_tree_after_40_empty_windows():
    W = 8
    stream = alignment_stream(np.random.default_rng(3), 30, p_empty=0.0, outliers=(0, 0))
    zs = stream.zs + [np.empty((0, 3))] * 100
    estimates = run(TCAFF(TCAFFParams.reference()), zs)
    last = last_estimate(estimates)
    # The window holds step 30 until step 30 + W - 1; from step 30 + W on it is empty. As in
    # the released code the count of empty windows must exceed 40 (at step 30 + W + 40) before
    # the tree is deleted, at the start of the next step.
    assert last == 30 + W + 40
    assert all(est is None for est in estimates[last:])


def test_default_drops_the_main_tree_after_drop_after_steps_without_measurement():
    stream = alignment_stream(np.random.default_rng(3), 30, p_empty=0.0, outliers=(0, 0))
    zs = stream.zs + [np.empty((0, 3))] * 60
    filt = TCAFF(TCAFFParams(drop_after=25))
    estimates = run(filt, zs)
    assert last_estimate(estimates) == 30 + 25
    assert filt.estimate is None


TRUTH = np.array([4.0, -1.0, 0.7])
EMPTY = np.empty((0, 3))
HELD_Q = np.diag([1e-4, 1e-4, 2e-5])


def test_a_held_estimate_grows_by_Q_for_W_steps_then_by_held_Q():
    """Unmeasured, the main tree's covariance grows by Q for W steps, then by held_Q (None:
    by Q throughout, the paper's); with a jitter reference, only while the jitter was within
    it."""
    zs = [TRUTH[None]] * 20 + [EMPTY] * 30
    Q, W = TCAFFParams().Q, TCAFFParams().window
    for params, growth in [(TCAFFParams(held_Q=HELD_Q), lambda k: min(k, W) * Q
                            + max(0, k - W) * HELD_Q),
                           (TCAFFParams(), lambda k: k * Q)]:
        estimates = run(TCAFF(params), zs)
        measured = estimates[19]
        assert measured.measurement == 0
        for k in range(1, 30):
            np.testing.assert_allclose(estimates[19 + k].P, measured.P + growth(k), rtol=1e-9)
    # with a jitter reference, measurements that moved more than their R explains: by Q
    shift = np.array([0.4, 0.0, 0.02])
    jumpy = [(TRUTH + (shift if t % 2 else -shift))[None] for t in range(20)] + [EMPTY] * 30
    held, plain = (run(TCAFF(TCAFFParams(jitter_reference=0.15, held_Q=q)), jumpy)
                   for q in (HELD_Q, None))
    for a, b in zip(held[20:], plain[20:], strict=True):
        np.testing.assert_array_equal(a.P, b.P)


@pytest.mark.parametrize(("params", "held"), [
    # the jitter was 0: held for hold_for
    (TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q), 200),
    (TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q, hold_for=120), 120),
    (TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q, hold_for=None), 40),
    # never shorter than drop_after
    (TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q, hold_for=10), 40),
    (TCAFFParams(held_Q=HELD_Q), 40),  # no reference: no evidence of the drift
    (TCAFFParams(jitter_reference=0.15), 40),  # no held_Q: a long hold would grow by Q
])
def test_a_main_tree_is_held_for_hold_for_steps_only_while_its_jitter_was_within_reference(
        params, held):
    """The same measurement for 30 steps (a jitter of 0), then nothing: the main tree is
    reported until `hold_for` steps after its last measurement where the filter has a jitter
    reference and a held_Q, else until `drop_after`. Measurements that move between steps by
    more than their R explains (a jitter of about 0.4) are held for `drop_after` only."""
    filt = TCAFF(params)
    assert last_estimate(run(filt, [TRUTH[None]] * 30 + [EMPTY] * 250)) == 30 + held
    assert filt.estimate is None and filt.held is None
    shift = np.array([0.4, 0.0, 0.02])
    jumpy = [(TRUTH + (shift if t % 2 else -shift))[None] for t in range(30)]
    assert last_estimate(run(TCAFF(params), jumpy + [EMPTY] * 250)) == 30 + 40


def test_a_long_hold_survives_save_and_load_and_a_tampered_one_is_refused(tmp_path):
    """Saved 100 steps into a hold the jitter allows, a restored filter holds it as long; a
    state that claims the jitter was within its reference without a main tree, or says it
    with another number than 0 or 1, is refused; a state saved before the record loads
    with holds of `drop_after`."""
    params = TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q)
    zs = [TRUTH[None]] * 30 + [EMPTY] * 250
    a = TCAFF(params)
    run(a, zs[:130])
    a.save(tmp_path / "f.npz")
    b = TCAFF.load(tmp_path / "f.npz")
    assert b.params == params
    assert last_estimate(run(a, zs[130:])) == last_estimate(run(b, zs[130:])) == 100
    state = TCAFF(params)
    run(state, zs[:130])
    saved = state.state_dict()
    assert int(saved["drift_as_assumed"]) == 1
    older = TCAFF(params)
    older.load_state_dict({k: v for k, v in saved.items() if k != "drift_as_assumed"})
    # 100 steps unmeasured, past drop_after: dropped at its next step
    assert older.update(EMPTY, np.empty((0, 3, 3))) is None and older.held is None
    for bad in (2, -1):
        with pytest.raises(DataError, match=r"drift_as_assumed = -?\d must be 0 or 1"):
            TCAFF(params).load_state_dict(dict(saved, drift_as_assumed=np.array(bad)))
    empty = TCAFF(params)
    empty.update(EMPTY, np.empty((0, 3, 3)))
    with pytest.raises(DataError, match="0 without a main tree"):
        TCAFF(params).load_state_dict(dict(empty.state_dict(), drift_as_assumed=np.array(1)))
    # a filter without a reference keeps no record of the drift, loaded or not
    plain = TCAFF(TCAFFParams(held_Q=HELD_Q))
    plain.load_state_dict(saved)
    assert plain.update(EMPTY, np.empty((0, 3, 3))) is None


def test_a_newcomer_is_held_long_only_on_its_own_measurements():
    """The truth, measured alike at every step (a jitter of 0), is replaced by a far decoy
    seen every other step, 1.2 m apart between its sightings, which never gives a jitter of
    its own: the truth's record does not let the decoy be held past `drop_after`."""
    decoy, shift = TRUTH + np.array([20.0, -15.0, 2.0]), np.array([0.6, 0.0, 0.03])
    zs = ([TRUTH[None]] * 30
          + [(decoy + (shift if t % 4 else -shift))[None] if t % 2 == 0 else EMPTY
             for t in range(30)]
          + [EMPTY] * 250)
    estimates = run(TCAFF(TCAFFParams(jitter_reference=0.15, held_Q=HELD_Q)), zs)
    assert estimates[50] is not None and not np.allclose(estimates[50].x, TRUTH, atol=5.0)
    assert last_estimate(estimates) == 58 + 1 + 40  # its last sighting at step 58 (0-based)


def test_report_after_hides_a_quiet_main_tree_that_a_measurement_then_revives():
    """Unreported after `report_after` empty steps, the main tree is still held until
    `drop_after`; a measurement within that time brings the same hypothesis back."""
    stream = alignment_stream(np.random.default_rng(3), 30, p_empty=0.0, outliers=(0, 0))
    quiet = [np.empty((0, 3))] * 20
    filt = TCAFF(TCAFFParams(drop_after=50, report_after=10))
    estimates = run(filt, stream.zs + quiet + [stream.zs[-1]])
    # reported while the best path's last measurement is < 10 steps old
    assert last_estimate(estimates[:-1]) == 30 + 9
    assert filt.held is not None and estimates[-1] is not None
    assert estimates[-1].hypothesis == estimates[29].hypothesis
    assert estimates[-1].measurement == 0
    # without a measurement the tree is dropped at drop_after as before
    filt = TCAFF(TCAFFParams(drop_after=25, report_after=10))
    run(filt, stream.zs + [np.empty((0, 3))] * 30)
    assert filt.held is None and filt.estimate is None


def test_held_is_the_estimate_whenever_it_is_reported():
    stream = alignment_stream(np.random.default_rng(4), 60, p_empty=0.3)
    filt = TCAFF(TCAFFParams(report_after=3))
    hidden = 0
    for zs in stream.zs:
        est = filt.update(zs, np.broadcast_to(R_CONSTANT, (len(zs), 3, 3)))
        assert est is None or est is filt.held
        hidden += est is None and filt.held is not None
    assert hidden > 0  # some steps held an estimate it did not report


@pytest.mark.parametrize("bad", [0, -1, 2.5, "4", True])
def test_bad_report_after_is_a_config_error(bad):
    with pytest.raises(ConfigError, match="report_after"):
        TCAFFParams(report_after=bad)


def test_a_gap_shorter_than_drop_after_keeps_the_estimate_and_its_accuracy():
    stream = alignment_stream(np.random.default_rng(11), 200, p_empty=0.1)
    zs = [z if not 80 <= t < 110 else np.empty((0, 3)) for t, z in enumerate(stream.zs)]
    estimates = run(TCAFF(), zs)
    assert all(est is not None for est in estimates[80:110])
    assert estimates[109].P[0, 0] > estimates[79].P[0, 0]  # uncertainty grew over the gap
    err = errors(estimates[115:], stream.truth[115:])
    assert err[:, 0].mean() < 0.1 and err[:, 1].mean() < 1.0


def test_a_long_gap_drops_and_then_reacquires():
    """The paper's filter forgets a dropped hypothesis and needs W + 1 steps to accept it
    again; the default recalls it on its second confirming step, under its old id."""
    stream = alignment_stream(np.random.default_rng(12), 200, p_empty=0.0)
    zs = [z if not 50 <= t < 120 else wrong_alignments(np.random.default_rng(t), 2)
          for t, z in enumerate(stream.zs)]
    paper = run(TCAFF(TCAFFParams.paper()), zs)
    assert paper[100] is None
    assert steps_to_recover(paper, stream.truth, 120) == TCAFFParams().window + 1
    assert paper[-1].hypothesis == 2
    default = run(TCAFF(), zs)
    assert default[100] is None
    assert steps_to_recover(default, stream.truth, 120) == 2
    assert default[-1].hypothesis == default[49].hypothesis == 1


def test_heading_near_pi():
    """The truth sits at the wrap-around; measurements fall on both sides of it."""
    stream = alignment_stream(np.random.default_rng(5), 200, x0=(1.0, 2.0, np.pi - 0.01))
    assert (np.array([z[:, 2].min() for z in stream.zs if len(z)]) < -3.0).any()
    estimates = run(TCAFF(), stream.zs)
    err = errors(estimates, stream.truth)
    assert len(err) > 180
    assert err[:, 0].mean() < 0.1 and err[:, 1].mean() < 1.0
    assert all(-np.pi <= est.x[2] < np.pi for est in estimates if est is not None)


def test_estimate_fields_follow_the_best_path():
    stream = alignment_stream(np.random.default_rng(2), 40, p_empty=0.0, outliers=(2, 2))
    filt = TCAFF()
    estimates = run(filt, stream.zs)
    last = estimates[-1]
    assert last.step == 40 and last.hypothesis == 1
    assert last.measurement == stream.correct[-1]
    assert last.n_measurements == TCAFFParams().window
    assert last.T.shape == (3, 3)
    np.testing.assert_allclose(last.P, last.P.T)
    assert np.all(np.linalg.eigvalsh(last.P) > 0)


def test_generic_dimension_tracks_a_1d_level_among_clutter():
    """d = 1, no angles: a slowly varying level observed among uniform clutter."""
    rng = np.random.default_rng(4)
    params = TCAFFParams(Q=np.array([[1e-4]]), P0=np.array([[0.25]]), angle_indices=())
    filt = TCAFF(params)
    level, errs = 5.0, []
    for t in range(200):
        level += rng.normal(0, 0.01)
        zs = np.r_[level + rng.normal(0, 0.1), rng.uniform(-50, 50, 3)][:, None]
        est = filt.update(zs, np.full((4, 1, 1), 0.1**2))
        if t > 20:
            errs.append(abs(est.x[0] - level))
    assert np.mean(errs) < 0.05
    with pytest.raises(TcaffError, match="needs an"):
        _ = est.T


def test_the_reported_covariance_grows_with_the_jitter_and_nothing_else_changes():
    """Consecutive measurements 0.2 m and 2 deg apart against R of 0.25-1 m and 2.5-10 deg
    (a scale drawn per step): a jitter of about 0.16. With a reference of 0.05 the reported P
    is scaled by the mean jitter of the last `jitter_span` steps over it (worked out here from
    the measurements the estimates took and their R), the held one too; with a reference of
    10 it is not scaled; the estimates, their hypotheses and measurements are the same as
    without."""
    rng = np.random.default_rng(5)
    stream = alignment_stream(rng, 150, jumps={80: (2.0, 0.0, 0.5)})
    plain, jittery = TCAFF(), TCAFF(TCAFFParams(jitter_reference=0.05, jitter_span=10))
    calm = TCAFF(TCAFFParams(jitter_reference=10.0))  # never above its reference
    taken, jitter, scaled = None, [], 0
    for step, zs in enumerate(stream.zs, start=1):
        Rs = np.broadcast_to(R_CONSTANT * rng.uniform(0.5, 2.0), (len(zs), 3, 3))
        plain.update(zs, Rs)
        jittery.update(zs, Rs)
        calm.update(zs, Rs)
        # the held estimates: a reported one may be withheld, its measurement still counts
        a, b = plain.held, jittery.held
        assert (a is None) == (b is None) and (plain.estimate is None) == (
            jittery.estimate is None)
        if a is None:
            continue
        assert (a.hypothesis, a.n_measurements, a.measurement, a.cost) == (
            b.hypothesis, b.n_measurements, b.measurement, b.cost)
        np.testing.assert_array_equal(a.x, b.x)
        np.testing.assert_array_equal(calm.held.P, a.P)
        if a.measurement >= 0:
            z, R = zs[a.measurement], Rs[a.measurement]
            if taken is not None and taken[:2] == (step - 1, a.hypothesis):
                d = z - taken[2]
                d[2] = wrap_angle(d[2])
                jitter.append((step, d @ np.linalg.solve(R + taken[3], d) / 3))
            taken = (step, a.hypothesis, z, R)
        recent = [value for k, value in jitter if k > step - 10]
        scale = max(1.0, np.mean(recent) / 0.05) if recent else 1.0
        np.testing.assert_allclose(b.P, a.P * scale, rtol=1e-12)
        if jittery.estimate is not None:
            np.testing.assert_array_equal(jittery.estimate.P, b.P)
        scaled += scale > 1.5
    assert scaled > 50


def test_state_save_and_restore_continue_identically(tmp_path):
    stream = alignment_stream(np.random.default_rng(9), 160, jumps={70: (2.0, 0.0, 0.5)})
    Rs = [np.broadcast_to(R_CONSTANT, (len(z), 3, 3)) for z in stream.zs]
    for params in (TCAFFParams(), TCAFFParams.reference(), TCAFFParams(jitter_reference=0.05)):
        a = TCAFF(params)
        for zs, R in zip(stream.zs[:60], Rs[:60], strict=True):
            a.update(zs, R)
        b = TCAFF(params)
        b.load_state_dict(a.state_dict())
        a.save(tmp_path / "filter.npz")
        c = TCAFF.load(tmp_path / "filter.npz")
        assert c.params.cost_model == params.cost_model
        for other in (b, c):  # restored as held and reported, the jitter's scale included
            for got, want in ((other.held, a.held), (other.estimate, a.estimate)):
                assert (got is None) == (want is None)
                if want is not None:
                    np.testing.assert_array_equal(got.P, want.P)
        changed = 0
        for zs, R in zip(stream.zs[60:], Rs[60:], strict=True):
            ea, eb, ec = a.update(zs, R), b.update(zs, R), c.update(zs, R)
            assert (ea is None) == (eb is None) == (ec is None)
            if ea is not None:
                for other in (eb, ec):
                    np.testing.assert_array_equal(ea.x, other.x)
                    np.testing.assert_array_equal(ea.P, other.P)
                    assert (ea.hypothesis, ea.n_measurements, ea.measurement) == (
                        other.hypothesis, other.n_measurements, other.measurement)
                changed += ea.hypothesis > 1
        assert changed, "the jump after the restore must be handled by the restored filters"


def test_a_snapshot_written_later_is_the_state_when_it_was_taken(tmp_path):
    """What a node hands its saving thread: the filter goes on stepping, the file written
    afterwards restores the filter as it was at the snapshot."""
    from tcaff_gtsam.tcaff import write_snapshot

    stream = alignment_stream(np.random.default_rng(4), 120, jumps={60: (2.0, 0.0, 0.5)})
    Rs = [np.broadcast_to(R_CONSTANT, (len(z), 3, 3)) for z in stream.zs]
    a = TCAFF()
    for zs, R in zip(stream.zs[:50], Rs[:50], strict=True):
        a.update(zs, R)
    b = TCAFF()
    b.load_state_dict(a.state_dict())
    snapshot = a.snapshot()
    for zs, R in zip(stream.zs[50:90], Rs[50:90], strict=True):
        a.update(zs, R)  # the filter goes on
    write_snapshot(tmp_path / "pair.npz", snapshot)
    c = TCAFF.load(tmp_path / "pair.npz")
    assert c.step == b.step == 50
    for zs, R in zip(stream.zs[50:], Rs[50:], strict=True):
        eb, ec = b.update(zs, R), c.update(zs, R)
        assert (eb is None) == (ec is None)
        if eb is not None:
            np.testing.assert_array_equal(eb.x, ec.x)
            assert eb.hypothesis == ec.hypothesis


def test_corrupt_state_is_a_data_error(tmp_path):
    filt = TCAFF()
    state = filt.state_dict()
    del state["step"]
    with pytest.raises(DataError, match="missing entry"):
        TCAFF().load_state_dict(state)
    state = filt.state_dict()
    state["explore.x"] = np.zeros((2, 3))
    with pytest.raises(DataError, match="explore arrays disagree"):
        TCAFF().load_state_dict(state)
    state = filt.state_dict()
    state["explore.choice"] = np.zeros((0, 4), np.int32)
    with pytest.raises(DataError, match=r"explore.choice has shape \(0, 4\), expected \(0, 10\)"):
        TCAFF().load_state_dict(state)
    state = filt.state_dict()
    state["step"] = np.zeros(2)
    with pytest.raises(DataError, match="wrong kind"):
        TCAFF().load_state_dict(state)
    (tmp_path / "bad.npz").write_bytes(b"not a zip file")
    with pytest.raises(DataError, match="not a saved TCAFF filter"):
        TCAFF.load(tmp_path / "bad.npz")


def test_zero_measurements_is_a_normal_step():
    filt = TCAFF()
    assert filt.update([], []) is None
    assert filt.update(np.empty((0, 3)), np.empty((0, 3, 3))) is None
    assert filt.step == 2


def _three_sightings_then(later_steps):
    """The truth at the first three steps (a seed and the two measurements `min_distinct`
    asks of a window), then `later_steps` (each a (k, 3) array)."""
    truth = np.array([3.0, -2.0, 1.0])
    return [truth[None], truth[None] + 0.05, truth[None] - 0.05, *later_steps]


def test_steps_without_any_measurement_do_not_count_against_a_hypothesis():
    W = TCAFFParams().window
    sparse = _three_sightings_then([np.zeros((0, 3))] * (W + 2))
    first = first_estimate(run(TCAFF(), sparse))
    assert first is not None and first <= W + 1
    # the paper charges a missed measurement at every step, with or without measurements
    assert first_estimate(run(TCAFF(TCAFFParams(neutral_empty_steps=False)), sparse)) is None
    assert first_estimate(run(TCAFF(TCAFFParams.paper()), sparse)) is None
    # a step that offered a measurement elsewhere still counts as a miss
    rng = np.random.default_rng(0)
    cluttered = _three_sightings_then(
        [rng.uniform([-30, -30, -3], [30, 30, 3], (1, 3)) for _ in range(W + 2)])
    assert first_estimate(run(TCAFF(), cluttered)) is None


@pytest.mark.parametrize("zs, Rs, match", [
    (np.zeros((2, 2)), np.zeros((2, 3, 3)), r"zs must have shape \(k, 3\)"),
    (np.zeros((2, 3)), np.broadcast_to(np.eye(3), (3, 3, 3)), r"Rs must have shape \(2, 3, 3\)"),
    (np.array([[0.0, np.nan, 0.0]]), np.eye(3)[None], r"zs\[0, 1\] = nan"),
    (np.zeros((1, 3)), np.diag([1.0, np.inf, 1.0])[None], r"Rs\[0, 1, 1\] = inf"),
    (np.zeros((1, 3)), np.diag([1.0, -1.0, 1.0])[None], "not positive definite"),
    (np.zeros((1, 3)), np.array([[[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]]), "not symmetric"),
    ("abc", np.eye(3)[None], "real numbers"),
])
def test_bad_input_is_a_data_error(zs, Rs, match):
    with pytest.raises(DataError, match=match):
        TCAFF().update(zs, Rs)


@pytest.mark.parametrize("kwargs, field", [
    ({"window": 0}, "window"),
    ({"max_leaves": 2.5}, "max_leaves"),
    ({"p_no_measurement": 1.0}, "p_no_measurement"),
    ({"Q": np.eye(2) * -1}, "Q"),
    ({"P0": np.eye(2)}, "P0"),
    ({"angle_indices": (3,)}, "angle_indices"),
    ({"gate": "ellipse"}, "gate"),
    ({"gate_box": (1.0, 1.0)}, "gate_box"),
    ({"switch_after": 0}, "switch_after"),
    ({"tau": float("nan")}, "tau"),
])
def test_bad_parameters_are_config_errors(kwargs, field):
    with pytest.raises(ConfigError, match=f"TCAFFParams.{field}"):
        TCAFFParams(**kwargs)


def test_reference_preset_values():
    ref = TCAFFParams.reference()
    assert (ref.window, ref.max_leaves, ref.p_no_measurement, ref.tau) == (8, 200, 0.001, 9.0)
    assert ref.switch_after is None and ref.gate_box == (2.0, 2.0, 2.0)
    default = TCAFFParams()
    assert (default.window, default.max_leaves, default.tau) == (8, 200, 8.0)


def test_main_tree_keeps_w_open_steps_below_a_single_root():
    """Paper: the root is the single node W steps back; all W steps after it stay open. The
    released code's root is the first step of the window (W - 1 open steps)."""
    rng = np.random.default_rng(8)
    W = 3
    zs = []
    for _ in range(30):  # two candidates 0.3 m apart: both pass every gate
        z = np.array([1.0, 2.0, 0.5]) + rng.normal(0, [0.05, 0.05, 0.005])
        zs.append(np.vstack([z, z + np.array([0.3, 0.0, 0.0])]))
    for root_in_window, open_steps in ((False, W), (True, W - 1)):
        filt = TCAFF(TCAFFParams(window=W, root_in_window=root_in_window))
        run(filt, zs)
        choice = filt._main.choice
        columns = choice.shape[1]
        root = columns - open_steps - 1
        assert len(np.unique(choice[:, root])) == 1
        assert len(np.unique(choice[:, root + 1])) > 1


def test_leaves_of_each_exploring_tree_stay_adjacent():
    stream = alignment_stream(np.random.default_rng(6), 60, outliers=(2, 4), spread=2.0)
    filt = TCAFF(TCAFFParams(switch_after=None))  # keeps seeding from every candidate
    for zs in stream.zs:
        filt.update(zs, np.broadcast_to(R_CONSTANT, (len(zs), 3, 3)))
        tree = filt._explore.tree
        assert np.all(np.diff(tree) >= 0)
        counts = np.bincount(tree - tree.min()) if tree.size else np.zeros(1)
        assert counts.max() <= TCAFFParams().explore_max_leaves


def test_switch_needs_the_same_rival_for_switch_after_steps():
    """Two wrong hypotheses that alternate never build a streak; a persistent one does."""
    truth = np.array([0.0, 0.0, 0.0])
    rng = np.random.default_rng(1)

    def steps(n, rivals):
        out = []
        for t in range(n):
            z = [truth + rng.normal(0, [0.05, 0.05, 0.01])] if t < 20 else []
            rival = rivals[t % len(rivals)] if t >= 20 else None
            if rival is not None:
                z.append(rival + rng.normal(0, [0.05, 0.05, 0.01]))
            out.append(np.array(z).reshape(-1, 3))
        return out

    far_a, far_b = np.array([8.0, 0.0, 1.0]), np.array([-8.0, 0.0, -1.0])
    alternating = run(TCAFF(TCAFFParams(switch_after=3)), steps(80, [far_a, far_b]))
    persistent = run(TCAFF(TCAFFParams(switch_after=3)), steps(80, [far_a]))
    assert persistent[-1].hypothesis == 2
    assert np.hypot(*(persistent[-1].x - far_a)[:2]) < 0.3
    assert all(e is None or e.hypothesis == 1 for e in alternating[20:59])


def test_a_main_hypothesis_confirmed_every_other_step_is_not_abandoned():
    """A rival with a full window beats a main tree with gaps on cost; while measurements keep
    confirming the main tree it stays under the margin rule alone (a repetitive world makes
    such rivals). Outvoting, the default, lets a rival seen twice as often take over."""
    rng = np.random.default_rng(3)
    truth, rival = np.array([0.0, 0.0, 0.0]), np.array([5.0, 0.0, 2.0])

    def noisy(x):
        return x + rng.normal(0, [0.05, 0.05, 0.01])

    zs = []
    for t in range(100):
        z = [noisy(truth)] if t < 20 or t % 2 == 0 else []
        if t >= 20:
            z.append(noisy(rival))
        zs.append(np.array(z).reshape(-1, 3))
    margin_only = TCAFFParams(switch_support=None)
    estimates = run(TCAFF(margin_only), zs)
    assert all(e.hypothesis == 1 and np.hypot(*e.x[:2]) < 0.3 for e in estimates[20:])
    outvoted = run(TCAFF(), zs)
    assert outvoted[-1].hypothesis == 2 and np.hypot(*(outvoted[-1].x - rival)[:2]) < 0.3
    # the same rival does win once the truth stops appearing
    zs[60:] = [np.array([noisy(rival)]) for _ in range(40)]
    estimates = run(TCAFF(margin_only), zs)
    assert estimates[-1].hypothesis == 2 and np.hypot(*(estimates[-1].x - rival)[:2]) < 0.3


def test_save_writes_exactly_the_path_given(tmp_path):
    """numpy appends .npz to a path without it; a saved filter must load from its own path."""
    f = TCAFF()
    f.update(np.array([[1.0, 2.0, 0.3]]), np.broadcast_to(np.eye(3) * 0.1, (1, 3, 3)))
    f.save(tmp_path / "filter.state")
    assert not (tmp_path / "filter.state.npz").exists()
    assert TCAFF.load(tmp_path / "filter.state").step == 1


# -- the cap on measurements per step --------------------------------------------------------


def test_a_step_takes_only_the_first_max_measurements(caplog):
    """Measurements beyond the cap are not seen: the truth given third is never accepted with
    a cap of 2, and is with the truth given first; the cap is logged once, then at debug."""
    rng = np.random.default_rng(5)
    truth = np.array([3.0, -1.0, 0.4])
    decoys = [rng.uniform(-40, 40, (2, 3)) for _ in range(20)]  # fresh ones each step

    def stream(first: bool):
        for d in decoys:
            z = truth + rng.normal(0, [0.05, 0.05, 0.005])
            yield np.vstack([z, d]) if first else np.vstack([d, z])

    capped = TCAFF(TCAFFParams(max_measurements=2))
    with caplog.at_level(logging.DEBUG, logger="tcaff_gtsam.tcaff"):
        late = run(capped, stream(first=False))
    assert all(e is None for e in late)
    records = [r for r in caplog.records if "max_measurements=2" in r.getMessage()]
    assert [r.levelno for r in records] == [logging.WARNING] + [logging.DEBUG] * 19
    assert "3 measurements given" in records[0].getMessage()
    assert capped.capped_steps == 20
    early = run(TCAFF(TCAFFParams(max_measurements=2)), stream(first=True))
    assert early[-1] is not None and np.allclose(early[-1].x, truth, atol=0.2)


def test_the_cap_cuts_the_evidence_with_the_measurements():
    filt = TCAFF(TCAFFParams(max_measurements=1, min_distinct=2))
    z = np.array([[1.0, 2.0, 0.1], [5.0, 5.0, 1.0]])
    evidence = [np.array([[0, 0]]), np.array([[1, 1]])]
    filt.update(z, np.broadcast_to(R_CONSTANT, (2, 3, 3)), evidence)
    assert filt.capped_steps == 1 and filt._sizes[-1] == 1


@pytest.mark.parametrize("value", [0, -1, 2.5, None])
def test_max_measurements_is_an_int_of_at_least_one(value):
    with pytest.raises(ConfigError, match="max_measurements"):
        TCAFFParams(max_measurements=value)


@pytest.mark.parametrize("counter", ["_next_tree", "step", "hypothesis"])
def test_a_state_with_a_counter_past_int64s_room_is_refused(counter):
    filt = TCAFF()
    for _ in range(3):
        filt.update([[3.0, -2.0, 1.0]], np.diag([0.25, 0.25, 0.01])[None])
    state = filt.state_dict()
    state[counter] = np.uint64(2**64 - 1)
    target = TCAFF()
    with pytest.raises(DataError, match=counter):
        target.load_state_dict(state)
    assert target.step == 0  # nothing was restored
