"""The wire format: round trips, its size, and every malformed payload refused by name."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from tcaff_gtsam.node.messages import (
    BYTES_PER_OBJECT,
    MAX_OBJECTS,
    AlignmentMessage,
    MapMessage,
    MessageError,
    TeamMessage,
    decode,
    encode,
)
from team_estimates import edgy, team_takes

from tcaff_gtsam import ObjectMap
from tcaff_gtsam.errors import DataError
from tcaff_gtsam.team import usable_estimates

names = st.text(alphabet=st.characters(codec="utf-8", exclude_categories=("Cs",)),
                min_size=1, max_size=16).filter(lambda s: 1 <= len(s.encode()) <= 64)
coords = st.floats(-1e4, 1e4, width=32)
sizes = st.floats(0, 50, width=32)


@st.composite
def map_messages(draw) -> MapMessage:
    n = draw(st.integers(0, 40))
    return MapMessage(draw(names), draw(st.integers(0, 2**32 - 1)),
                      draw(st.integers(0, 2**32 - 1)), draw(st.floats(-1e9, 1e9)),
                      draw(arrays(np.float64, (n, 3), elements=coords)),
                      draw(arrays(np.float64, n, elements=sizes)),
                      draw(arrays(np.float64, n, elements=sizes)),
                      draw(arrays(np.float64, n, elements=st.floats(0, 1e3, width=32))))


def alignment(accepted: bool = True, P=None) -> AlignmentMessage:
    return AlignmentMessage("r0", 7, 12, 101.5, "r1", 11, 99.0, 12, 3, accepted,
                            np.array([1.0, -2.0, 0.3]),
                            np.diag([0.1, 0.2, 0.01]) if P is None else P)


@settings(max_examples=60, deadline=None)
@given(map_messages())
def test_a_map_survives_the_wire_in_24_bytes_per_object(m: MapMessage) -> None:
    payload = encode(m)
    header = 4 + 1 + 1 + 1 + len(m.sender.encode()) + 4 + 4 + 8 + 4
    assert len(payload) == header + BYTES_PER_OBJECT * len(m.centroids)
    back = decode(payload)
    assert isinstance(back, MapMessage)
    assert (back.sender, back.boot, back.seq, back.stamp) == (m.sender, m.boot, m.seq, m.stamp)
    # the values were drawn as float32: they come back exactly
    for field in ("centroids", "widths", "heights", "ages"):
        np.testing.assert_array_equal(getattr(back, field), getattr(m, field))


def test_a_map_is_put_on_the_receivers_clock_through_its_ages() -> None:
    sent = ObjectMap(np.array([[1.0, 2.0, 0.5], [3.0, -1.0, 0.2]]), np.array([0.4, 1.0]),
                     np.array([0.3, 0.8]), np.array([995.0, 1000.5]))
    # stamped at 1000 on the sender's clock, received at 20 on the receiver's
    message = decode(encode(MapMessage.of("r2", 1, 5, 1000.0, sent)))
    received = message.object_map(20.0)
    np.testing.assert_allclose(received.last_seen, [15.0, 20.0])  # a future stamp is age 0
    np.testing.assert_allclose(received.centroids, sent.centroids, rtol=1e-6)


def test_an_alignment_survives_the_wire() -> None:
    m = alignment()
    back = decode(encode(m))
    assert isinstance(back, AlignmentMessage)
    assert (back.sender, back.neighbour, back.seq, back.neighbour_seq, back.step,
            back.hypothesis, back.accepted) == ("r0", "r1", 12, 11, 12, 3, True)
    np.testing.assert_array_equal(back.x, m.x)
    np.testing.assert_array_equal(back.P, m.P)
    empty = decode(encode(alignment(False, np.full((3, 3), np.nan))))
    assert not empty.accepted and np.isnan(empty.P).all()


@settings(max_examples=60, deadline=None)
@given(names, names, st.lists(names, max_size=4), st.booleans(), st.data())
def test_a_team_alignment_survives_the_wire_and_every_truncation_is_malformed(
        sender, neighbour, via, accepted, data) -> None:
    x = np.array([1.5, -2.0, 0.3]) if accepted else np.full(3, np.nan)
    P = np.diag([0.1, 0.2, 0.01]) if accepted else np.full((3, 3), np.nan)
    m = TeamMessage(sender, 4, 9, 50.25, neighbour, tuple(via), accepted, x, P)
    payload = encode(m)
    back = decode(payload)
    assert isinstance(back, TeamMessage)
    assert ((back.sender, back.neighbour, back.via, back.seq, back.stamp, back.accepted)
            == (sender, neighbour, tuple(via), 9, 50.25, accepted))
    np.testing.assert_array_equal(back.x, x)
    np.testing.assert_array_equal(back.P, P)
    cut = data.draw(st.integers(0, len(payload) - 1))
    with pytest.raises(MessageError) as caught:
        decode(payload[:cut])
    assert caught.value.reason == "malformed"


@settings(max_examples=40, deadline=None)
@given(map_messages(), st.data())
def test_every_truncation_is_malformed(m: MapMessage, data) -> None:
    payload = encode(m)
    cut = data.draw(st.integers(0, len(payload) - 1))
    with pytest.raises(MessageError) as caught:
        decode(payload[:cut])
    assert caught.value.reason == "malformed"


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_crash_the_decoder(payload: bytes) -> None:
    try:
        decode(payload)
    except MessageError as exc:
        assert exc.reason in {"malformed", "version", "oversized"}


@settings(max_examples=100, deadline=None)
@given(map_messages(), st.data())
def test_a_flipped_byte_is_refused_or_read_as_a_valid_message(m: MapMessage, data) -> None:
    payload = bytearray(encode(m))
    at = data.draw(st.integers(0, len(payload) - 1))
    payload[at] ^= data.draw(st.integers(1, 255))
    try:
        back = decode(bytes(payload))
    except MessageError:
        return
    # what passes is a well-formed map: finite, sizes and ages >= 0
    assert isinstance(back, MapMessage | AlignmentMessage | TeamMessage)
    if isinstance(back, MapMessage):
        values = np.column_stack([back.centroids, back.widths, back.heights, back.ages])
        assert np.isfinite(values).all() and (values[:, 3:] >= 0).all()


def _map_bytes(n: int = 2) -> bytes:
    return encode(MapMessage("r1", 1, 2, 3.0, np.zeros((n, 3)), np.ones(n), np.ones(n),
                             np.zeros(n)))


@pytest.mark.parametrize(("edit", "reason", "words"), [
    (lambda b: b"XXXX" + b[4:], "malformed", "magic"),
    (lambda b: b[:4] + bytes([2]) + b[5:], "version", "format version 2"),
    (lambda b: b[:5] + bytes([9]) + b[6:], "malformed", "kind 9"),
    (lambda b: b + b"\0", "malformed", "after the end"),
    (lambda b: b[:6] + bytes([2]) + b"\xff\xfe" + b[9:], "malformed", "not UTF-8"),
    (lambda b: b[:6] + bytes([0]) + b[7:], "malformed", "sender of 0 bytes"),
    (lambda b: b[:-4] + struct.pack("<f", float("nan")), "malformed", "non-finite"),
    (lambda b: b[:-4] + struct.pack("<f", -1.0), "malformed", "negative"),
    (lambda b: b[:25] + struct.pack("<I", MAX_OBJECTS + 1) + b[29:], "oversized",
     "objects"),
])
def test_each_bad_map_is_refused_with_its_reason(edit, reason: str, words: str) -> None:
    with pytest.raises(MessageError, match=words) as caught:
        decode(edit(_map_bytes()))
    assert caught.value.reason == reason


def test_an_oversized_payload_is_refused_before_it_is_read() -> None:
    with pytest.raises(MessageError, match="bytes, at most 100") as caught:
        decode(_map_bytes(10), max_bytes=100)
    assert caught.value.reason == "oversized"


def test_an_accepted_alignment_needs_a_covariance() -> None:
    bad = alignment(P=np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(MessageError, match="symmetric positive definite"):
        decode(encode(bad))
    with pytest.raises(MessageError, match=r"x \(3,\) finite"):
        decode(encode(alignment(P=np.full((3, 3), np.nan))))


@settings(max_examples=300, deadline=None)
@given(x=st.lists(edgy, min_size=3, max_size=3), upper=st.lists(edgy, min_size=6, max_size=6),
       scale=st.sampled_from([None, 0.0, 1.0, 2e18, -3.0]))
@example(x=[1.0, 2.0, 0.3], upper=[0.0] * 6, scale=None)  # P = 0
@example(x=[2e9, 2.0, 0.3], upper=[1.0, 0, 0, 1.0, 0, 1.0], scale=None)
@example(x=[1.0, 2.0, 0.3], upper=[2e18, 0, 0, 2e18, 0, 2e18], scale=None)
def test_an_accepted_alignment_decodes_exactly_when_the_team_consistency_takes_it(
        x, upper, scale) -> None:
    """A node hands every accepted alignment it hears to TeamConsistency.update, which used
    to refuse ones decode had let in (P = 0, |x| > 1e9, P beyond 1e18), and with them every
    later team step."""
    x = np.array(x)
    P = np.zeros((3, 3))
    P[np.triu_indices(3)] = upper
    P = P + np.triu(P, 1).T
    if scale is not None:  # well-formed and not, beside the raw draws
        P = scale * np.diag([0.1, 0.2, 0.01])
    try:
        back = decode(encode(AlignmentMessage("r1", 1, 1, 10.0, "r2", 1, 9.0, 3, 1, True, x,
                                              P)))
    except MessageError as exc:
        assert exc.reason == "malformed"
        assert not team_takes(x, P)
    else:
        assert team_takes(back.x, back.P)
        np.testing.assert_array_equal(back.P, P)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.lists(edgy, min_size=3, max_size=3),
                          st.sampled_from([1.0, 0.0, -1.0, 1e19, np.nan]),
                          st.booleans()), min_size=1, max_size=6))
def test_usable_estimates_marks_each_estimate_as_the_team_consistency_judges_it_alone(
        drawn) -> None:
    """Every estimate judged, also those after the first that fails (a node leaves only the
    unusable ones out of its team step)."""
    X = np.array([x for x, _, _ in drawn])
    P = np.array([s * np.diag([0.1, 0.2, 0.01]) + (np.triu(np.ones((3, 3)), 1) * 0.01 if skew
                                                   else 0.0) for _, s, skew in drawn])
    np.testing.assert_array_equal(usable_estimates(X, P),
                                  [team_takes(x, p) for x, p in zip(X, P, strict=True)])


#: where an alignment of r0 to r1 (`alignment()`) holds its hypothesis, accepted flag and
#: the nine numbers of its estimate: after the header (25 bytes with sender r0), the
#: neighbour (3), its seq (4), stamp (8) and the step (4)
_HYPOTHESIS, _ACCEPTED, _NUMBERS = 44, 48, 49


def _alignment_bytes(accepted: int, hypothesis: int, numbers) -> bytes:
    """`alignment()`'s bytes with these fields in place of its own."""
    m = alignment()
    payload = bytearray(encode(m))
    # the layout patched is the encoder's
    assert len(payload) == _NUMBERS + 72 and struct.unpack_from("<iB9d", payload, _HYPOTHESIS) \
        == (m.hypothesis, 1, *m.x, *m.P[np.triu_indices(3)])
    struct.pack_into("<iB9d", payload, _HYPOTHESIS, hypothesis, accepted, *numbers)
    return bytes(payload)


@settings(max_examples=200, deadline=None)
@given(accepted=st.booleans(), hypothesis=st.integers(-2**31, 2**31 - 1))
@example(accepted=True, hypothesis=-7)
@example(accepted=False, hypothesis=-7)
@example(accepted=False, hypothesis=3)
@example(accepted=True, hypothesis=-1)
def test_a_hypothesis_is_minus_one_exactly_when_there_is_no_estimate(accepted, hypothesis
                                                                     ) -> None:
    numbers = [1.0, -2.0, 0.3, 0.1, 0.0, 0.0, 0.2, 0.0, 0.01] if accepted else [np.nan] * 9
    payload = _alignment_bytes(int(accepted), hypothesis, numbers)
    if (hypothesis >= 0) if accepted else (hypothesis == -1):
        assert decode(payload).hypothesis == hypothesis
    else:
        with pytest.raises(MessageError, match=f"hypothesis {hypothesis}") as caught:
            decode(payload)
        assert caught.value.reason == "malformed"


@settings(max_examples=200, deadline=None)
@given(numbers=st.lists(st.one_of(st.just(np.nan), st.floats(allow_nan=False)), min_size=9,
                        max_size=9))
@example(numbers=[np.nan] * 3 + [-3.0, 0.0, 0.0, -3.0, 0.0, -3.0])  # P = -3 I
@example(numbers=[np.nan] * 9)
def test_an_alignment_that_is_not_accepted_holds_nan_for_its_estimate(numbers) -> None:
    """The format says NaN; any other number is a damaged or forged message, not one to keep
    and show (it was let through whatever it held)."""
    payload = _alignment_bytes(0, -1, numbers)
    if np.isnan(numbers).all():
        back = decode(payload)
        assert not back.accepted and np.isnan(back.x).all() and np.isnan(back.P).all()
    else:
        with pytest.raises(MessageError, match="not accepted holds an estimate") as caught:
            decode(payload)
        assert caught.value.reason == "malformed"


def test_an_alignment_that_is_not_accepted_is_sent_without_its_estimate() -> None:
    back = decode(encode(alignment(False, -3.0 * np.eye(3))))
    assert not back.accepted and back.hypothesis == -1
    assert np.isnan(back.x).all() and np.isnan(back.P).all()
    team = decode(encode(TeamMessage("r0", 1, 2, 3.0, "r2", ("r1",), False, np.zeros(3),
                                     np.eye(3))))
    assert np.isnan(team.x).all() and np.isnan(team.P).all()


@pytest.mark.parametrize(("message", "words"), [
    (MapMessage("x" * 65, 0, 0, 0.0, np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0)),
     "1 to 64 bytes"),
    (AlignmentMessage("r0", 0, 0, 0.0, "r1", 0, 0.0, 2**31, 1, True, np.zeros(3), np.eye(3)),
     "step = 2147483648"),
    (AlignmentMessage("r0", 0, 0, 0.0, "r1", 0, 0.0, -1, 1, True, np.zeros(3), np.eye(3)),
     "step = -1"),
    (AlignmentMessage("r0", 0, 0, 0.0, "r1", 0, 0.0, 1, -7, True, np.zeros(3), np.eye(3)),
     "hypothesis = -7"),
    (AlignmentMessage("r0", 0, 0, 0.0, "r1", 0, float("nan"), 1, 1, True, np.zeros(3),
                      np.eye(3)), "neighbour_stamp = nan"),
    (MapMessage("r", 2**32, 0, 0.0, np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0)),
     "boot = 4294967296"),
    (MapMessage("r", 0, 0, float("inf"), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
                np.zeros(0)), "stamp = inf"),
])
def test_encode_refuses_what_cannot_be_sent(message, words: str) -> None:
    with pytest.raises(DataError, match=words):
        encode(message)
