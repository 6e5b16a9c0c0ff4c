"""Collaborative tracking and its MOTA: a small case scored by hand, the rolling window, the
alignment each frame uses, and whole runs where a wrong alignment must cost tracking accuracy."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tcaff_gtsam.eval.config import MethodsConfig, StudyConfig, load_scenario
from tcaff_gtsam.eval.jobs import simulated_job
from tcaff_gtsam.eval.methods import estimate_names
from tcaff_gtsam.eval.mot import (
    NO_SHARING,
    Tracks,
    collaborative_mot,
    held_alignment,
    mot_methods,
    rolling_mota,
    score_tracks,
)
from tcaff_gtsam.eval.sim.simulate import simulate
from tcaff_gtsam.eval.study import run_study

from tcaff_gtsam.errors import DataError
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, transform_points_batch


def tracks_of(*frames):
    """Per frame, {track id: (x, y)} -> (ids (m,), xy (m, 2))."""
    return [(np.array(list(f), dtype=np.int64), np.array(list(f.values()), dtype=float)
             .reshape(-1, 2)) for f in frames]


# Two people, five frames, scored by hand:
#   f0: both tracked (ids 10, 11), 0.1 m and 0.2 m off     2 people, 0 errors
#   f1: person 1 not tracked                               2 people, 1 miss
#   f2: both tracked, plus track 12 far from everyone      2 people, 1 false positive
#   f3: person 0 now tracked by 12 instead of 10           2 people, 1 identity switch
#   f4: person 1 out of everyone's view, track 11 on them  1 person, 0 errors (not a FP)
TRUTH = np.tile(np.array([[0.0, 0.0], [5.0, 0.0]]), (5, 1, 1))
IN_VIEW = np.array([[True, True]] * 4 + [[True, False]])
TRACKS = tracks_of({10: (0.1, 0.0), 11: (5.0, 0.2)},
                   {10: (0.0, 0.1)},
                   {10: (0.0, 0.0), 11: (5.0, 0.0), 12: (9.0, 9.0)},
                   {12: (0.0, 0.0), 11: (5.0, 0.0)},
                   {12: (0.0, 0.0), 11: (5.0, 0.1)})


def test_mota_of_a_small_case_computed_by_hand():
    counts, report = score_tracks(TRUTH, IN_VIEW, TRACKS, match_distance=1.0)
    # objects, false positives, misses, switches per frame
    assert counts.tolist() == [[2, 0, 0, 0], [2, 0, 1, 0], [2, 1, 0, 0], [2, 0, 0, 1],
                               [1, 0, 0, 0]]
    assert report["objects"] == 9
    assert (report["false_positives"], report["misses"], report["switches"]) == (1, 1, 1)
    assert report["mota"] == pytest.approx(1 - 3 / 9)
    # mean distance of the 8 matched tracks: 0.1 + 0.2 + 0.1 in metres, the rest exact
    assert report["motp"] == pytest.approx(0.4 / 8)


def test_a_track_beyond_the_match_distance_is_a_miss_and_a_false_positive():
    truth = np.zeros((1, 1, 2))
    counts, report = score_tracks(truth, np.ones((1, 1), bool), tracks_of({3: (1.5, 0.0)}),
                                  match_distance=1.0)
    assert counts.tolist() == [[1, 1, 1, 0]]
    assert report["mota"] == pytest.approx(-1.0)
    counts, report = score_tracks(truth, np.ones((1, 1), bool), tracks_of({3: (1.5, 0.0)}),
                                  match_distance=2.0)
    assert report["mota"] == pytest.approx(1.0)


def test_a_hidden_person_next_to_a_visible_one_does_not_take_its_track():
    truth = np.array([[[0.0, 0.0], [0.5, 0.0]]])
    counts, report = score_tracks(truth, np.array([[True, False]]), tracks_of({7: (0.0, 0.0)}),
                                  match_distance=1.0)
    assert counts.tolist() == [[1, 0, 0, 0]] and report["mota"] == 1.0
    # a second track, on the hidden person, is left out rather than counted as false
    counts, _ = score_tracks(truth, np.array([[True, False]]),
                             tracks_of({7: (0.0, 0.0), 8: (0.6, 0.0)}), match_distance=1.0)
    assert counts.tolist() == [[1, 0, 0, 0]]


def test_two_tracks_that_swap_people_are_two_switches():
    truth = np.tile(np.array([[0.0, 0.0], [3.0, 0.0]]), (2, 1, 1))
    tracks = tracks_of({1: (0.0, 0.0), 2: (3.0, 0.0)}, {1: (3.0, 0.0), 2: (0.0, 0.0)})
    counts, report = score_tracks(truth, np.ones((2, 2), bool), tracks, match_distance=1.0)
    assert counts.tolist() == [[2, 0, 0, 0], [2, 0, 0, 2]]
    assert report["switches"] == 2 and report["mota"] == pytest.approx(0.5)


def test_without_people_to_track_mota_is_none():
    counts, report = score_tracks(np.zeros((2, 1, 2)), np.zeros((2, 1), bool),
                                  tracks_of({}, {}), match_distance=1.0)
    assert counts.sum() == 0 and report["mota"] is None and report["motp"] is None


def test_tracks_in_flat_arrays_are_the_frames_and_score_alike():
    tracks = Tracks.of(TRACKS)
    assert len(tracks) == 5 and tracks.starts.tolist() == [0, 2, 3, 6, 8, 10]
    for (ids, xy), (want_ids, want_xy) in zip(tracks, TRACKS, strict=True):
        assert np.array_equal(ids, want_ids) and np.array_equal(xy, want_xy)
    assert Tracks.of(tracks) is tracks and Tracks.of([]).starts.tolist() == [0]
    counts, report = score_tracks(TRUTH, IN_VIEW, tracks, match_distance=1.0)
    want_counts, want_report = score_tracks(TRUTH, IN_VIEW, TRACKS, match_distance=1.0)
    assert np.array_equal(counts, want_counts) and report == want_report
    with pytest.raises(DataError, match="as many positions"):
        Tracks.of([(np.array([1, 2]), np.zeros((1, 2)))])


def test_rolling_mota_by_hand():
    counts, _ = score_tracks(TRUTH, IN_VIEW, TRACKS, match_distance=1.0)
    times = np.arange(5.0)
    # a 2 s window holds the frame itself and the one before
    expected = [1.0, 1 - 1 / 4, 1 - 2 / 4, 1 - 2 / 4, 1 - 1 / 3]
    assert rolling_mota(times, counts, 2.0) == pytest.approx(expected)
    # a window over everything ends at the run's MOTA; stacked robots are scored apiece
    both = rolling_mota(times, np.stack([counts, counts]), 100.0)
    assert both.shape == (2, 5)
    assert both[:, -1] == pytest.approx([1 - 3 / 9] * 2)
    assert np.isnan(rolling_mota(times, np.zeros((5, 4)), 2.0)).all()


def test_the_rolling_window_holds_exactly_its_frames_on_a_real_clock():
    """On the simulator's clock (0.2 k s, not exact in binary) a 10 s window holds 50 frames."""
    times = 0.1 * np.arange(2, 602, 2)
    counts = np.zeros((300, 4))
    counts[:, 0] = 1
    counts[::7, 2] = 1  # a miss every 7th frame
    frame = np.arange(300)
    first = np.maximum(frame - 49, 0)
    misses = np.array([np.sum(np.arange(a, b + 1) % 7 == 0)
                       for a, b in zip(first, frame, strict=True)])
    expected = 1 - misses / (frame - first + 1)
    assert rolling_mota(times, counts, 10.0) == pytest.approx(expected)


def test_each_frame_uses_the_latest_exchange_at_or_before_it():
    exchange_times = np.array([1.0, 2.0, 3.0])
    a, c = np.array([1.0, 2.0, 0.5]), np.array([-1.0, 0.0, -0.2])
    estimate = np.array([a, [np.nan] * 3, c])
    frames = np.array([0.5, 1.0, 1.5, 2.2, 3.0, 4.0])
    held = held_alignment(frames, exchange_times, estimate)
    assert held.shape == (6, 3, 3)
    assert np.isnan(held[[0, 3], :2]).all()  # the rows of R and t
    for f, params in ((1, a), (2, a), (4, c), (5, c)):
        assert np.allclose(held[f], se2_from_params(params))
    assert np.isnan(held_alignment(frames, np.zeros(0), np.zeros((0, 3)))[:, :2]).all()
    with pytest.raises(DataError, match=r"one row per exchange, got \(2, 3\)"):
        held_alignment(frames, exchange_times, estimate[:2])


def test_smoothed_estimates_are_not_tracked_with():
    names = estimate_names(MethodsConfig())
    tracked = mot_methods(names)
    assert tracked[0] == NO_SHARING
    assert "tcaff_isam2_smoothed" in names and "tcaff_isam2_smoothed" not in tracked
    assert "tcaff_isam2_causal" in tracked and "ground_truth" in tracked


@pytest.fixture(scope="module")
def mot_run():
    return simulate(load_scenario("mot").model_copy(update={"duration": 30.0}), seed=0)


def true_estimates(run, pairs, offset=(0.0, 0.0, 0.0)):
    """(n_pairs, S, 3) the true T_oi_oj of every pair, composed with a fixed error."""
    error = se2_from_params(np.asarray(offset))
    return np.array([se2_to_params(run.T_true(i, j) @ error) for i, j in pairs])


def test_neighbours_detections_land_on_the_truth_through_the_true_alignment(mot_run):
    people = mot_run.people
    i, j = 0, 2
    T = held_alignment(people.times, mot_run.times, true_estimates(mot_run, [(i, j)])[0])
    frame, xy, person = people.detections[j]
    ok = (person >= 0) & np.isfinite(T[frame, 0, 0])
    moved = transform_points_batch(T[frame[ok]], xy[ok])
    truth = people.truth_in_odom(i)[frame[ok], person[ok]]
    error = np.linalg.norm(moved - truth, axis=1)
    assert ok.sum() > 100
    # only the detector's noise is left: per axis 0.1 m + 0.02 m per m of range, so the
    # error in units of it follows a Rayleigh distribution (median 1.18); the alignment held
    # for up to a second adds a little
    detector = mot_run.scenario.pedestrians.detector
    distance = np.linalg.norm(people.xy[frame[ok], person[ok]]
                              - people.poses_true[j][frame[ok], :2], axis=1)
    sigma = detector.noise + detector.noise_per_m * distance
    assert 1.0 < np.median(error / sigma) < 1.4
    assert error.max() < 6 * sigma.max()


def test_a_wrong_alignment_costs_tracking_accuracy(mot_run):
    pairs = [(i, j) for i in range(4) for j in range(4) if i != j]
    estimates = {"ground_truth": true_estimates(mot_run, pairs),
                 "tcaff": true_estimates(mot_run, pairs, (2.5, 0.0, 0.3))}
    scores = collaborative_mot(mot_run.people, mot_run.times, pairs, estimates,
                               mot_run.scenario.pedestrians)
    assert list(scores) == [NO_SHARING, "ground_truth", "tcaff"]
    alone, truth, wrong = (scores[m] for m in scores)
    assert truth.counts.shape == (4, len(mot_run.people.times), 4)
    misses = {m: s.counts[..., 2].sum() for m, s in scores.items()}
    assert misses[NO_SHARING] > 2 * misses["ground_truth"]  # what one robot cannot see
    assert truth.mota > alone.mota + 0.2
    assert truth.mota > 0.75
    assert wrong.mota < truth.mota - 0.3
    fp = {m: sum(r["false_positives"] for r in s.robots) for m, s in scores.items()}
    assert fp["tcaff"] > 3 * fp["ground_truth"]  # the misplaced people are false tracks
    for s in scores.values():  # the saved counts are motmetrics' totals
        totals = s.counts.sum(axis=1)
        for robot, report in enumerate(s.robots):
            assert totals[robot].tolist() == [report["objects"], report["false_positives"],
                                              report["misses"], report["switches"]]


def test_a_method_that_never_shares_tracks_as_no_sharing(mot_run):
    """A method without an estimate at any exchange gives every robot its own detections
    only: the counts and reports of no sharing, each its own copy."""
    pairs = [(i, j) for i in range(4) for j in range(4) if i != j]
    never = np.full((len(pairs), len(mot_run.times), 3), np.nan)
    scores = collaborative_mot(mot_run.people, mot_run.times, pairs,
                               {"icp": never, "ground_truth": true_estimates(mot_run, pairs)},
                               mot_run.scenario.pedestrians)
    alone, never_shared = scores[NO_SHARING], scores["icp"]
    assert np.array_equal(never_shared.counts, alone.counts)
    assert never_shared.robots == alone.robots
    assert all(a is not b for a, b in zip(never_shared.robots, alone.robots, strict=True))
    assert not np.array_equal(scores["ground_truth"].counts, alone.counts)


QUICK_METHODS = MethodsConfig(clipper_k=[3, 5], clipper_k_shown=5)


@pytest.mark.slow
def test_a_study_with_people_writes_mota_tables_and_figures(tmp_path):
    mot = load_scenario("mot")
    # 10 s and three of the four robots: the study's MOTA bookkeeping is the same, its jobs'
    # alignment and scoring (by the pair and the robot) a fraction
    scenario = mot.model_copy(update={"duration": 10.0,
                                      "layout": mot.layout.model_copy(update={"robots": 3})})
    cfg = StudyConfig(name="t", scenarios=[scenario], methods=QUICK_METHODS, seeds=[0, 1],
                      workers=1, output=str(tmp_path))
    outcome = run_study(cfg)
    assert not outcome.failed
    tracked = mot_methods(estimate_names(QUICK_METHODS))
    assert list(outcome.mot_summary["mot"]) == tracked
    motas = [j.mot["ground_truth"]["mota"] for j in outcome.jobs]
    truth = outcome.mot_summary["mot"]["ground_truth"]
    assert truth["mota"] == pytest.approx(np.mean(motas))
    assert truth["mota_std"] == pytest.approx(np.std(motas))
    folder = outcome.folder
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["mot_summary"]["mot"]["tcaff"]["seeds"] == 2
    rows = (folder / "mot.csv").read_text().splitlines()
    # per seed and method: the robot mean and 3 robots; then one summary row per method
    assert len(rows) == 1 + 2 * len(tracked) * 4 + len(tracked)
    figures = {p.name for p in (folder / "figures").glob("*.png")}
    assert {"mot_mot.png", "mot_sweep.png"} <= figures
    saved = json.loads((folder / "runs" / "mot-seed0.json").read_text())
    assert saved["mot"]["ground_truth"]["mota"] == pytest.approx(motas[0])
    with np.load(folder / "runs" / "mot-seed0.npz") as arrays:
        assert arrays["mot_counts_tcaff"].shape == (3, 50, 4)  # robots, frames at 5 Hz
        assert float(arrays["mot_window"]) == 10.0


def test_a_job_without_people_has_no_tracking():
    scenario = load_scenario("four_robots").model_copy(update={"duration": 10.0})
    job = simulated_job(scenario, QUICK_METHODS, seed=0)
    assert job.mot == {} and "mot_times" not in job.arrays
