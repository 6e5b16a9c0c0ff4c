"""Tests for tcaff_gtsam.eval.tracker: the multi-object tracker of people on the floor plane
(constant-velocity Kalman tracks, optimal association per detection set, confirmation and
deletion), on hand-made walks whose right answer is known."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.tracker import MultiObjectTracker, TrackerParams

from tcaff_gtsam.errors import ConfigError, DataError

FEW = settings(max_examples=25, deadline=None)

DT = 0.2  # s between frames
#: the tracker of the shipped `mot` scenario
MOT = TrackerParams(accel_noise=1.5, detection_noise=0.3, initial_speed=1.5, gate=9.21,
                    confirm_hits=3, tentative_misses=1, max_coast=1.0)


def tracker(**update) -> MultiObjectTracker:
    return MultiObjectTracker(replace(MOT, **update))


def line(start, velocity, times) -> np.ndarray:
    """(F, 2) positions of a walk in a straight line at constant velocity."""
    return np.asarray(start, dtype=float) + np.outer(times, velocity)


def nearest_id(ids, xy, point) -> int:
    return int(ids[np.argmin(np.linalg.norm(xy - point, axis=1))])


def none() -> np.ndarray:
    return np.zeros((0, 2))


# -- association -----------------------------------------------------------------------------


def test_two_people_crossing_keep_their_ids():
    """Two people crossing in an X at 1 m/s, seen every 0.2 s without noise by one source:
    from the confirming frame on there are exactly two confirmed tracks every frame, and the
    id nearest each person stays the same through the crossing (the two detections even
    coincide at the crossing frame)."""
    times = DT * np.arange(61)                       # 12 s; they meet at t = 6 s, frame 30
    s = 1 / np.sqrt(2)
    a = line((-6 * s, -6 * s), (s, s), times)       # south-west to north-east
    b = line((-6 * s, 6 * s), (s, -s), times)       # north-west to south-east
    assert np.allclose(a[30], b[30])
    mot = tracker()
    ids_a, ids_b = [], []
    for f, t in enumerate(times):
        ids, xy = mot.step(t, [np.stack([a[f], b[f]])])
        if f < MOT.confirm_hits - 1:
            assert len(ids) == 0
            continue
        assert len(ids) == 2, f"frame {f}: {len(ids)} confirmed tracks"
        assert len(mot) == 2
        ids_a.append(nearest_id(ids, xy, a[f]))
        ids_b.append(nearest_id(ids, xy, b[f]))
    before, after = 30 - 10, 30 + 10                 # frames, in the lists: minus the first 2
    k_before, k_after = before - MOT.confirm_hits + 1, after - MOT.confirm_hits + 1
    assert ids_a[k_before] == ids_a[k_after]
    assert ids_b[k_before] == ids_b[k_after]
    assert ids_a[k_before] != ids_b[k_before]
    # and not only either side of the crossing: at every frame but the one where they meet
    meet = 30 - MOT.confirm_hits + 1
    assert len({i for k, i in enumerate(ids_a) if k != meet}) == 1
    assert len({i for k, i in enumerate(ids_b) if k != meet}) == 1


def test_two_sources_seeing_one_person_make_one_track():
    """One person seen in every frame by two or three sources with slightly different noise:
    one track, not one per source."""
    rng = np.random.default_rng(3)
    times = DT * np.arange(30)
    truth = line((0.0, 0.0), (0.8, 0.3), times)
    for n_sources in (2, 3):
        mot = tracker()
        for f, t in enumerate(times):
            sets = [(truth[f] + rng.normal(0.0, 0.05, 2))[None] for _ in range(n_sources)]
            ids, xy = mot.step(t, sets)
            assert len(mot) == 1, f"{n_sources} sources, frame {f}: {len(mot)} tracks"
            if f >= MOT.confirm_hits - 1:
                assert len(ids) == 1
                assert np.linalg.norm(xy[0] - truth[f]) < 0.2


def test_hits_count_frames_not_detections():
    """A person seen by 3 sources in one frame has one frame with a detection: with
    confirm_hits = 3 the track is confirmed at the third frame, not the first."""
    mot = tracker(confirm_hits=3)
    p = np.array([[1.0, 2.0]])
    for f in range(3):
        ids, _ = mot.step(f * DT, [p, p + 0.01, p - 0.01])
        assert len(mot) == 1
        assert len(ids) == (1 if f == 2 else 0), f"frame {f}"


def test_false_positive_far_away_is_never_confirmed():
    """One isolated detection far from a tracked person, in a single frame, never gives a
    confirmed track, and its tentative track is gone in the next frame (tentative_misses 1)."""
    times = DT * np.arange(25)
    truth = line((0.0, 0.0), (1.0, 0.0), times)
    mot = tracker()
    person_id = None
    for f, t in enumerate(times):
        dets = truth[f][None]
        if f == 10:
            dets = np.vstack([dets, [[20.0, -15.0]]])
        ids, xy = mot.step(t, [dets])
        if f >= MOT.confirm_hits - 1:
            assert len(ids) == 1, f"frame {f}: {ids}"
            person_id = ids[0] if person_id is None else person_id
            assert ids[0] == person_id
            assert np.linalg.norm(xy[0] - truth[f]) < 0.1
        assert len(mot) == (2 if f == 10 else 1)


@pytest.mark.parametrize("confirm_hits", [1, 2, 3, 5])
def test_confirmed_exactly_at_the_confirm_hits_th_frame(confirm_hits):
    """A track is reported at the frame of its confirm_hits-th detection, not before."""
    mot = tracker(confirm_hits=confirm_hits)
    for f in range(confirm_hits + 2):
        ids, xy = mot.step(f * DT, [np.array([[0.5 * f * DT, 1.0]])])
        if f + 1 < confirm_hits:
            assert len(ids) == 0, f"frame {f}"
        else:
            assert len(ids) == 1, f"frame {f}"
            assert np.linalg.norm(xy[0] - [0.5 * f * DT, 1.0]) < 0.1


def test_confirmation_counts_frames_with_a_detection_across_gaps():
    """With tentative_misses = 2 a tentative track survives a missed frame; frames without a
    detection do not count towards confirm_hits: detections at frames 0, 2 and 4 confirm at
    frame 4."""
    mot = tracker(confirm_hits=3, tentative_misses=2)
    p = np.array([[1.0, 1.0]])
    for f in range(5):
        ids, _ = mot.step(f * DT, [p] if f % 2 == 0 else [none()])
        assert len(mot) == 1
        assert len(ids) == (1 if f == 4 else 0), f"frame {f}"


# -- coasting and deletion -------------------------------------------------------------------


@pytest.mark.parametrize("gap", [1, 2])
def test_missed_detections_coast_and_keep_the_id(gap):
    """A person missed for one or two frames (less than max_coast): the track is still reported
    during the gap, at the constant-velocity prediction and near the person, and the person
    keeps the same id after the gap."""
    times = DT * np.arange(40)
    velocity = np.array([0.9, -0.5])
    truth = line((-3.0, 2.0), velocity, times)
    missed = set(range(20, 20 + gap))
    mot = tracker()
    the_id, before = None, None
    for f, t in enumerate(times):
        ids, xy = mot.step(t, [none() if f in missed else truth[f][None]])
        if f < MOT.confirm_hits - 1:
            continue
        assert len(ids) == 1, f"frame {f}"
        the_id = ids[0] if the_id is None else the_id
        assert ids[0] == the_id, f"frame {f}: id {ids[0]}, was {the_id}"
        if f == min(missed) - 1:
            before = mot.x[0].copy()
        if f in missed:
            predicted = before[:2] + before[2:] * (t - times[min(missed) - 1])
            assert np.allclose(xy[0], predicted, atol=1e-9)
            assert np.linalg.norm(xy[0] - truth[f]) < 0.05
            assert np.allclose(mot.x[0, 2:], before[2:], atol=1e-12)


def test_confirmed_track_deleted_after_max_coast():
    """A confirmed track is reported while it has gone up to max_coast without a detection and
    deleted at the first frame after that."""
    dt = 0.25                                       # exact in binary: no rounding at the edge
    mot = tracker(max_coast=1.0)
    p = np.array([[2.0, -1.0]])
    for f in range(4):
        ids, _ = mot.step(f * dt, [p])
    assert len(ids) == 1
    last = 3 * dt
    for k in range(1, 5):                            # 0.25 .. 1.0 s without a detection
        ids, _ = mot.step(last + k * dt, [none()])
        assert len(ids) == 1, f"{k * dt} s after the last detection"
    ids, xy = mot.step(last + 5 * dt, [])
    assert len(ids) == 0 and xy.shape == (0, 2)
    assert len(mot) == 0


def test_confirmed_track_deleted_after_max_coast_with_uneven_frames():
    """Deletion depends on the time since the last detection, not on a count of frames."""
    mot = tracker(max_coast=1.0)
    p = np.array([[0.0, 0.0]])
    for f in range(3):
        mot.step(f * 0.1, [p])
    assert len(mot) == 1 and mot.confirmed.all()
    ids, _ = mot.step(0.2 + 0.9, [])
    assert len(ids) == 1
    ids, _ = mot.step(0.2 + 1.1, [])
    assert len(ids) == 0 and len(mot) == 0


def test_coasting_exactly_max_coast_does_not_depend_on_rounding():
    """A confirmed track whose last detection is max_coast = 5 frames ago is still reported,
    whichever frame of a 5 Hz clock the detection came at."""
    times = 0.2 * np.arange(60)
    deleted = []
    for last in range(2, 50):
        mot = tracker(max_coast=1.0)
        for f in range(last + 1):
            mot.step(times[f], [np.array([[0.0, 0.0]])])
        for f in range(last + 1, last + 6):
            ids, _ = mot.step(times[f], [])
        if len(ids) == 0:
            deleted.append((times[last], times[last + 5]))
    assert not deleted, f"deleted exactly max_coast after the last detection: {deleted[:3]}"


@pytest.mark.parametrize("tentative_misses", [1, 2, 4])
def test_tentative_track_deleted_after_tentative_misses(tentative_misses):
    """An unconfirmed track lives through tentative_misses - 1 frames without a detection and
    is deleted at the tentative_misses-th."""
    mot = tracker(confirm_hits=3, tentative_misses=tentative_misses, max_coast=100.0)
    mot.step(0.0, [np.array([[1.0, 1.0]])])
    assert len(mot) == 1
    for f in range(1, tentative_misses + 1):
        ids, _ = mot.step(f * DT, [none()])
        assert len(ids) == 0
        assert len(mot) == (0 if f == tentative_misses else 1), f"miss {f}"


def test_tentative_misses_must_be_in_a_row():
    """A detection resets the run of misses of a tentative track."""
    mot = tracker(confirm_hits=10, tentative_misses=2)
    p = np.array([[1.0, 1.0]])
    for f in range(8):
        mot.step(f * DT, [p] if f % 2 == 0 else [none()])
        assert len(mot) == 1, f"frame {f}"


# -- the Kalman filter -----------------------------------------------------------------------


@FEW
@given(speed=st.floats(0.1, 2.5), heading=st.floats(-np.pi, np.pi),
       x0=st.floats(-20.0, 20.0), y0=st.floats(-20.0, 20.0))
def test_velocity_converges_on_a_constant_velocity_target(speed, heading, x0, y0):
    """Noiseless detections of a target at constant velocity: after 10 s the velocity estimate
    is within 1 mm/s of the truth and the position within 0.1 mm."""
    velocity = speed * np.array([np.cos(heading), np.sin(heading)])
    times = DT * np.arange(51)
    truth = line((x0, y0), velocity, times)
    mot = tracker()
    for f, t in enumerate(times):
        ids, xy = mot.step(t, [truth[f][None]])
    assert len(mot) == 1 and len(ids) == 1
    assert np.linalg.norm(mot.x[0, 2:] - velocity) < 1e-3
    assert np.linalg.norm(xy[0] - truth[-1]) < 1e-4


def test_covariances_stay_symmetric_positive_definite():
    """The track covariances stay symmetric and positive definite through predictions, several
    updates per frame and coasting."""
    rng = np.random.default_rng(0)
    times = DT * np.arange(40)
    truth = line((0.0, 0.0), (1.0, 0.5), times)
    mot = tracker()
    for f, t in enumerate(times):
        sets = [] if 15 <= f < 18 else [truth[f][None] + rng.normal(0, 0.1, (1, 2))
                                        for _ in range(3)]
        mot.step(t, sets)
        assert np.allclose(mot.P, np.swapaxes(mot.P, 1, 2))
        assert np.all(np.linalg.eigvalsh(mot.P) > 0)


# -- against a plain reference -------------------------------------------------------------


@FEW
@given(rows=st.integers(1, 7), extra=st.integers(0, 4), ties=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_min_cost_assignment_is_scipys(rows, extra, ties, seed):
    """The compiled assignment is scipy's, on random matrices with many ties (small integers)
    or none: optimal, and equal costs split the same way (duplicate tracks get the same ids)."""
    from scipy.optimize import linear_sum_assignment
    from tcaff_gtsam.eval.tracker import _min_cost_assignment

    rng = np.random.default_rng(seed)
    shape = (rows, rows + extra)
    cost = (rng.integers(0, 3, shape).astype(float) if ties
            else rng.normal(0.0, 10.0, shape))
    _, expected = linear_sum_assignment(cost)
    np.testing.assert_array_equal(_min_cost_assignment(cost), expected)


@FEW
@given(n=st.integers(1, 4), k=st.integers(1, 4), seed=st.integers(0, 2**32 - 1))
def test_association_has_the_most_pairs_in_the_gate_then_the_least_cost(n, k, seed):
    """Against every partial matching of a few tracks and detections (more of either): the
    compiled association matches as many pairs inside the gate as any, none outside, at the
    least total d^2 + ln|S| among those."""
    from itertools import permutations

    from tcaff_gtsam.eval.tracker import _associate

    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(-2.0, 2.0, (n, 2)), np.zeros((n, 2))])
    P = np.stack([np.diag([v, v, 1.0, 1.0]) for v in rng.uniform(0.01, 1.0, n)])
    z = rng.uniform(-2.0, 2.0, (k, 2))
    r, gate = 0.09, 4.0
    S = P[:, :2, :2] + r * np.eye(2)
    diff = z[None] - x[:, None, :2]
    d2 = np.einsum("nki,nij,nkj->nk", diff, np.linalg.inv(S), diff)
    cost = d2 + np.log(np.linalg.det(S))[:, None]
    best = (0, 0.0)
    for cols in permutations([*range(k), *[-1] * n], n):  # -1: the track takes nothing
        pairs = [(i, j) for i, j in enumerate(cols) if j >= 0]
        if all(d2[i, j] <= gate for i, j in pairs):
            best = max(best, (len(pairs), -sum(cost[i, j] for i, j in pairs)))
    taken = _associate(x, P, z, r, gate)
    pairs = [(i, int(j)) for i, j in enumerate(taken) if j >= 0]
    assert len({j for _, j in pairs}) == len(pairs)
    assert all(d2[i, j] <= gate for i, j in pairs)
    assert len(pairs) == best[0]
    assert sum(cost[i, j] for i, j in pairs) == pytest.approx(-best[1], abs=1e-9)


def test_a_detection_reported_twice_leaves_the_first_of_its_two_tracks():
    """One set holding the same detection twice starts two identical tracks; the next frame's
    detection ties exactly between them and goes to the first (as scipy's assignment splits
    ties), and the second, tentative and missed, is deleted."""
    mot = tracker()
    mot.step(0.0, [np.array([[1.0, 1.0], [1.0, 1.0]])])
    assert mot.ids.tolist() == [0, 1]
    mot.step(DT, [np.array([[1.05, 1.0]])])
    assert mot.ids.tolist() == [0] and mot.hits.tolist() == [2]


def test_detections_too_far_out_for_the_numbers_start_tracks():
    """A detection at 1e200 m overflows the gating distance: it is outside every gate and
    starts a track of its own, and the tracker goes on."""
    mot = tracker()
    mot.step(0.0, [np.array([[0.0, 0.0]])])
    mot.step(DT, [np.array([[0.1, 0.0], [1e200, -1e200]])])
    assert len(mot) == 2
    assert mot.x[0, 0] < 1.0 and mot.x[1, 0] == 1e200


class PlainTracker:
    """The tracker written plainly, one track and one detection set at a time, with scipy's
    assignment: the reference the compiled frame must reproduce."""

    def __init__(self, p: TrackerParams) -> None:
        self.p, self.tracks, self.next_id, self.time = p, [], 0, None

    def step(self, t, sets):
        from scipy.optimize import linear_sum_assignment

        p, r = self.p, self.p.detection_noise ** 2
        dt = 0.0 if self.time is None else t - self.time
        self.time = t
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        G = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
        for tr in self.tracks:
            tr["x"] = F @ tr["x"]
            tr["P"] = F @ tr["P"] @ F.T + p.accel_noise**2 * G @ G.T
            tr["hit"] = False
        for z in sets:
            cost = np.full((len(self.tracks), len(z)), 1e12)
            for i, tr in enumerate(self.tracks):
                S = tr["P"][:2, :2] + r * np.eye(2)
                for j, zj in enumerate(z):
                    e = zj - tr["x"][:2]
                    d2 = e @ np.linalg.solve(S, e)
                    if d2 <= p.gate:
                        cost[i, j] = d2 + np.log(np.linalg.det(S))
            taken = set()
            for i, j in zip(*linear_sum_assignment(cost), strict=True):
                if cost[i, j] < 1e12:
                    tr = self.tracks[i]
                    K = tr["P"][:, :2] @ np.linalg.inv(tr["P"][:2, :2] + r * np.eye(2))
                    tr["x"] = tr["x"] + K @ (z[j] - tr["x"][:2])
                    tr["P"] = tr["P"] - K @ tr["P"][:2, :]
                    tr["hit"] = True
                    taken.add(j)
            for j in sorted(set(range(len(z))) - taken):
                self.tracks.append(dict(
                    x=np.array([*z[j], 0.0, 0.0]), id=self.next_id, hits=0, misses=0,
                    last=t, confirmed=False, hit=True,
                    P=np.diag([r, r, p.initial_speed**2, p.initial_speed**2])))
                self.next_id += 1
        alive = []
        for tr in self.tracks:
            tr["hits"] += tr["hit"]
            tr["misses"] = 0 if tr["hit"] else tr["misses"] + 1
            tr["last"] = t if tr["hit"] else tr["last"]
            tr["confirmed"] = tr["confirmed"] or tr["hits"] >= p.confirm_hits
            if not (t - tr["last"] > p.max_coast + 1e-9 if tr["confirmed"]
                    else tr["misses"] >= p.tentative_misses):
                alive.append(tr)
        self.tracks = alive


@pytest.mark.parametrize("seed", range(4))
def test_frames_match_the_plain_reference(seed):
    """Six people walking and turning, seen by three sources with noise (one of them twice the
    tracker's assumed noise, so that detections fall either side of the gate), misses and false
    detections for 60 s at 5 Hz: at every frame the compiled tracker has the reference's
    tracks, ids, counters, states and covariances."""
    rng = np.random.default_rng(seed)
    mot, ref = tracker(), PlainTracker(MOT)
    people = rng.uniform(-5.0, 5.0, (6, 2))
    velocity = rng.normal(0.0, 0.8, (6, 2))
    crowded = 0
    for f in range(300):
        t = DT * f
        velocity += rng.normal(0.0, 0.3, velocity.shape) * DT
        people += velocity * DT
        sets = []
        for noise in (0.1, 0.3, 0.6):
            seen = people[rng.uniform(size=6) < 0.7]
            seen = seen + rng.normal(0.0, noise, seen.shape)
            false = rng.uniform(-8.0, 8.0, (rng.poisson(0.3), 2))
            sets.append(np.vstack([seen, false])[rng.permutation(len(seen) + len(false))])
        ids, xy = mot.step(t, sets)
        ref.step(t, sets)
        assert mot.ids.tolist() == [tr["id"] for tr in ref.tracks], f"frame {f}"
        assert mot.hits.tolist() == [tr["hits"] for tr in ref.tracks]
        assert mot.misses.tolist() == [tr["misses"] for tr in ref.tracks]
        assert mot.confirmed.tolist() == [tr["confirmed"] for tr in ref.tracks]
        assert np.allclose(mot.last_hit, [tr["last"] for tr in ref.tracks], rtol=0, atol=0)
        assert np.allclose(mot.x, [tr["x"] for tr in ref.tracks], rtol=0, atol=1e-9)
        assert np.allclose(mot.P, [tr["P"] for tr in ref.tracks], rtol=0, atol=1e-9)
        assert np.array_equal(ids, mot.ids[mot.confirmed])
        assert np.array_equal(xy, mot.x[mot.confirmed, :2])
        crowded += len(mot) > 8
    assert crowded > 10  # the scenes had rivals for the detections


def stacked(frames: list[list[np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, S sets (k, 2) -> (detections (D, 2), bounds (F, S + 1)) for `run`."""
    sizes = np.array([[len(z) for z in sets] for sets in frames]).reshape(len(frames), -1)
    edges = np.concatenate([[0], np.cumsum(sizes)])
    n_sets = sizes.shape[1]
    bounds = edges[np.arange(len(frames))[:, None] * n_sets + np.arange(n_sets + 1)]
    return np.concatenate([z for sets in frames for z in sets]).reshape(-1, 2), bounds


@pytest.mark.parametrize("seed", range(3))
def test_a_whole_run_in_one_call_is_every_frame_stepped(seed):
    """`run` over 200 frames of three sets each (often empty, people and clutter) gives the
    confirmed tracks `step` gives at every frame, to the bit, and leaves the same tracker;
    a run continues where the previous step or run stopped."""
    rng = np.random.default_rng(seed)
    times = DT * np.arange(200)
    people = rng.uniform(-4.0, 4.0, (5, 2)) + np.cumsum(rng.normal(0, 0.1, (200, 5, 2)), axis=0)
    frames = [[np.vstack([people[f][rng.uniform(size=5) < 0.6] + rng.normal(0, 0.2, (1, 2)),
                          rng.uniform(-6.0, 6.0, (rng.poisson(0.4), 2))])
               for _ in range(3)] for f in range(200)]
    stepped = tracker()
    expected = [stepped.step(t, sets) for t, sets in zip(times, frames, strict=True)]
    ran = tracker()
    ids, xy, starts = ran.run(times[:80], *stacked(frames[:80]))
    more_ids, more_xy, more_starts = ran.run(times[80:], *stacked(frames[80:]))
    ids, xy = np.concatenate([ids, more_ids]), np.concatenate([xy, more_xy])
    starts = np.concatenate([starts, more_starts[1:] + starts[-1]])
    assert starts[-1] == sum(len(i) for i, _ in expected) > 100
    for f, (want_ids, want_xy) in enumerate(expected):
        rows = slice(starts[f], starts[f + 1])
        assert np.array_equal(ids[rows], want_ids), f"frame {f}"
        assert np.array_equal(xy[rows], want_xy), f"frame {f}"
    for name in ("x", "P", "ids", "hits", "misses", "last_hit", "confirmed", "time", "_next_id"):
        assert np.array_equal(getattr(ran, name), getattr(stepped, name)), name


def test_a_run_without_frames_changes_nothing():
    mot = tracker()
    mot.step(0.0, [np.array([[1.0, 1.0]])])
    ids, xy, starts = mot.run(np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2), np.int64))
    assert ids.shape == (0,) and xy.shape == (0, 2) and starts.tolist() == [0]
    assert len(mot) == 1 and mot.time == 0.0


@pytest.mark.parametrize(("times", "detections", "bounds", "match"), [
    ([0.0, float("nan")], np.zeros((0, 2)), [[0, 0], [0, 0]], "times must be"),
    ([0.2, 0.0], np.zeros((0, 2)), [[0, 0], [0, 0]], "times must be"),
    ([0.0], np.zeros((1, 3)), [[0, 1]], r"detections must be \(D, 2\)"),
    ([0.0], np.array([[0.0, np.inf]]), [[0, 1]], r"detections must be \(D, 2\) finite"),
    ([0.0], np.zeros((2, 2)), [[0, 1]], "bounds must be"),        # a detection left over
    ([0.0, 0.2], np.zeros((2, 2)), [[0, 1], [0, 2]], "bounds must be"),  # frames overlap
    ([0.0], np.zeros((2, 2)), [[0, 2, 1]], "bounds must be"),     # a set ends before it starts
    ([0.0, 0.2], np.zeros((1, 2)), [[0, 1]], "bounds must be"),   # a frame without bounds
])
def test_a_run_refuses_bad_input(times, detections, bounds, match):
    with pytest.raises(DataError, match=match):
        tracker().run(np.array(times), detections, np.array(bounds))


def test_a_run_does_not_go_back_before_the_last_step():
    mot = tracker()
    mot.step(1.0, [])
    with pytest.raises(DataError, match=r"not before 1\.0 s"):
        mot.run(np.array([0.8]), np.zeros((0, 2)), np.zeros((1, 2), np.int64))


# -- bad input -------------------------------------------------------------------------------


def test_detections_of_the_wrong_shape_are_a_data_error():
    """A (k, 3) set or a flat (2,) set raises DataError naming the set and the (k, 2) shape."""
    mot = tracker()
    with pytest.raises(DataError, match=r"detections\[1\] must be \(k, 2\), got \(2, 3\)"):
        mot.step(0.0, [np.zeros((1, 2)), np.zeros((2, 3))])
    with pytest.raises(DataError, match=r"must be \(k, 2\)"):
        mot.step(0.0, [np.array([1.0, 2.0])])
    for empty in ((0, 3), (3, 0)):  # no detections, but still the wrong shape
        with pytest.raises(DataError, match=r"must be \(k, 2\)"):
            mot.step(0.0, [np.zeros(empty)])
    assert len(mot) == 0 and mot.time is None
    mot.step(0.0, [np.zeros((0, 2)), np.zeros(0)])  # both mean no detections


def test_non_finite_detections_are_a_data_error():
    """NaN or inf in a detection set raises DataError naming non-finite values."""
    mot = tracker()
    mot.step(0.0, [np.array([[0.0, 0.0]])])
    for bad in (np.nan, np.inf):
        with pytest.raises(DataError, match=r"detections\[0\] holds non-finite values"):
            mot.step(DT, [np.array([[bad, 1.0], [0.0, 0.0]])])
    assert len(mot) == 1 and mot.time == 0.0


def test_time_going_backwards_is_a_data_error():
    """A step before the previous one raises DataError naming the time, and leaves the tracker
    as it was; a step at the same time is allowed."""
    mot = tracker()
    for f in range(3):
        mot.step(1.0 + f * DT, [np.array([[0.0, 0.0]])])
    x, P, ids = mot.x.copy(), mot.P.copy(), mot.ids.copy()
    with pytest.raises(DataError, match="time must be finite and not before"):
        mot.step(1.0, [np.array([[0.0, 0.0]])])
    with pytest.raises(DataError, match="time"):
        mot.step(np.nan, [])
    assert np.array_equal(mot.x, x) and np.array_equal(mot.P, P)
    assert np.array_equal(mot.ids, ids)
    ids, _ = mot.step(mot.time, [np.array([[0.0, 0.0]])])
    assert len(ids) == 1


def test_a_settled_track_keeps_a_detection_a_new_track_is_nearer_to_by_mahalanobis():
    """Association weighs how uncertain a track is (d^2 + ln|S|): a detection between a settled
    track and a brand-new one goes to the settled track although its Mahalanobis distance to
    the new one is smaller, so one person does not end up with two tracks."""
    mot = tracker(max_coast=100.0)
    for f in range(20):
        mot.step(f * DT, [np.array([[0.0, 0.0]])])
    t = 20 * DT
    mot.step(t, [np.array([[0.0, 0.0]]), np.array([[2.0, 0.0]])])  # a new track at 2 m
    assert len(mot) == 2
    settled, new = (int(np.flatnonzero(mot.ids == i)[0]) for i in np.sort(mot.ids))
    S = mot.P[[settled, new], :2, :2] + MOT.detection_noise**2 * np.eye(2)
    # on the line between them, where d^2 prefers the new track and d^2 + ln|S| the settled one
    x = np.linspace(0.0, 2.0, 2001)
    d2 = np.array([x**2 / S[0, 0, 0], (2.0 - x) ** 2 / S[1, 0, 0]])
    nll = d2 + np.log(np.linalg.det(S))[:, None]
    contested = (d2[1] < d2[0]) & (nll[0] < nll[1]) & (d2.max(axis=0) <= MOT.gate)
    assert contested.any()
    z = x[contested][contested.sum() // 2]
    old_id = mot.ids[settled]
    mot.step(t, [np.array([[z, 0.0]])])  # the same instant: no prediction in between
    assert old_id in mot.ids
    assert mot.x[mot.ids == old_id, 0][0] > 0.05  # the settled track took the detection
    assert len(mot) == 1  # the new track got nothing and was dropped as a tentative miss


# -- parameters ----------------------------------------------------------------------------------

#: values of the wrong kind for every field: the tracker must refuse them, naming the field
JUNK = (None, "1", [1.0], {}, True, float("nan"))


@pytest.mark.parametrize("field", [f for f in vars(MOT)])
@pytest.mark.parametrize("value", JUNK, ids=repr)
def test_tracker_params_refuse_junk_naming_the_field(field, value):
    with pytest.raises(ConfigError, match=f"^TrackerParams.{field} = "):
        TrackerParams(**{field: value})


@pytest.mark.parametrize(("field", "value"), [
    ("accel_noise", 0.0), ("detection_noise", float("inf")), ("initial_speed", -1.0),
    ("gate", 0), ("gate", float("inf")), ("confirm_hits", 0), ("confirm_hits", 2.0),
    ("tentative_misses", 0),
    ("max_coast", -0.1),
])
def test_tracker_params_refuse_values_out_of_range(field, value):
    with pytest.raises(ConfigError, match=f"TrackerParams.{field} = {value!r}"):
        TrackerParams(**{field: value})


def test_tracker_params_defaults_are_the_mot_scenarios_and_compare_by_value():
    assert TrackerParams() == MOT and hash(TrackerParams()) == hash(MOT)
    assert MultiObjectTracker().params == MOT


def test_tracker_takes_only_tracker_params():
    with pytest.raises(ConfigError, match=r"MultiObjectTracker\.params = "):
        MultiObjectTracker({"gate": 9.21})
