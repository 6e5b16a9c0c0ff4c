"""The calibrated measurement covariance (`frame_aligner.calibrated_covariance`): honest for the
errors it models, larger where the geometry or the maps say less, and wired into the aligner."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import FrameAligner, FrameAlignerParams
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.frame_aligner import calibrated_covariance
from tcaff_gtsam.geometry import se2_from_params, se2_to_params, wrap_angle
from tcaff_gtsam.registration import arun_weights, weighted_arun

NEES_95 = 7.815  # chi-square, 3 dof
NO_DRIFT = (0.0, 0.0)


def calibrated(**changes) -> FrameAlignerParams:
    """FrameAlignerParams with covariance="calibrated" and any other field in `changes`."""
    return replace(FrameAlignerParams(), covariance="calibrated", **changes)


def scene(rng: np.random.Generator, k: int, spread: float, offset: float):
    """A registration problem: the true T (3, 3), other points q (k, 2) around `offset`
    metres from the other frame's origin, spread `spread` m, and Arun weights (k,) from
    random ages."""
    T = se2_from_params([rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-np.pi, np.pi)])
    direction = rng.uniform(0, 2 * np.pi)
    q = rng.normal(0, spread, (k, 2)) + offset * np.array([np.cos(direction), np.sin(direction)])
    w = arun_weights(rng.uniform(0, 3, k), rng.uniform(0, 3, k))
    return T, q, w


def nees(z: np.ndarray, truth: np.ndarray, R: np.ndarray) -> float:
    e = z - truth
    e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(R, e))


def monte_carlo_nees(rng, T, q, w, sigma, trials, **settings_) -> np.ndarray:
    """NEES (trials,) of the covariance of registrations of q's images under T observed with
    isotropic point noise sigma (each map half of it), under `settings_`."""
    p_true = q @ T[:2, :2].T + T[:2, 2]
    truth = se2_to_params(T)
    out = np.empty(trials)
    for n in range(trials):
        p = p_true + rng.normal(0, sigma / math.sqrt(2), p_true.shape)
        q_seen = q + rng.normal(0, sigma / math.sqrt(2), q.shape)
        T_est = weighted_arun(p, q_seen, w)
        R = calibrated_covariance(T_est, p, q_seen, w, **settings_)
        out[n] = nees(se2_to_params(T_est), truth, R)
    return out


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(6, 14),
       sigma=st.floats(0.02, 0.1), offset=st.floats(0.0, 20.0))
@example(seed=1, k=6, sigma=0.1, offset=15.0).via("the scene that left the linearisation")
def test_point_noise_part_is_chi_square(seed, k, sigma, offset):
    """Known isotropic point noise (a prior of overwhelming weight), no drift, no inflation:
    the NEES of R against the true transform is chi-square(3) within sampling error.

    R is the registration's first-order covariance, so this holds while the noise is small
    against the scene's 2 m spread (up to 5 %: over 300 random scenes the means lay within
    0.38 of 3). Beyond it six unevenly weighted points bend the registration away from its
    linearisation: seed 1, k = 6 at 0.19 m gives a mean of 3.58 over 5000 trials (3.11 at
    0.1 m)."""
    rng = np.random.default_rng(seed)
    T, q, w = scene(rng, k, 2.0, offset)
    trials = 300
    values = monte_carlo_nees(rng, T, q, w, sigma, trials, kappa=20.0, noise_prior=sigma,
                              prior_dof=1e9, map_drift=NO_DRIFT, repeat_inflation=0.0)
    # chi-square(3): variance 6; 5 standard errors, and a little for the linearisation
    assert abs(values.mean() - 3.0) < 5 * math.sqrt(6 / trials) + 0.1
    assert abs(np.mean(values < NEES_95) - 0.95) < 5 * math.sqrt(0.95 * 0.05 / trials)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(8, 14), sigma=st.floats(0.03, 0.2))
@example(seed=1_697_956_035, k=13, sigma=0.125).via("a mean of 2.48, 3.7 standard errors low")
def test_residual_pooled_with_its_prior_stays_calibrated(seed, k, sigma):
    """The noise estimated from the residual (pooled with a prior of the right size worth the
    default 4 degrees of freedom): NEES mean near 3, below it by no more than 5 standard errors
    of a chi-square(3) mean (over 300 scenes the means ranged 2.62-3.58). A noisy s^2 makes
    its inverse a little larger on average, so the mean may exceed 3 by a few tenths, not by
    a factor."""
    rng = np.random.default_rng(seed)
    T, q, w = scene(rng, k, 2.0, 5.0)
    trials = 300
    values = monte_carlo_nees(rng, T, q, w, sigma, trials, kappa=20.0, noise_prior=sigma,
                              map_drift=NO_DRIFT, repeat_inflation=0.0)
    # chi-square(3) has variance 6; an estimated s^2 only widens it
    assert 3.0 - 5 * math.sqrt(6 / trials) < values.mean() < 3.9


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), offset=st.floats(0.0, 30.0),
       kappa=st.floats(10.0, 200.0))
def test_map_drift_part_is_chi_square(seed, offset, kappa):
    """A shared error of the whole other map, the model's: a heading error about its objects
    and a shift, with the variance the map drift gives over kappa / 2. The NEES of R (no
    point noise to speak of, no inflation) is chi-square(3): this fixes the sign of the
    coupling of heading and translation through the lever arm."""
    rng = np.random.default_rng(seed)
    T, q, w = scene(rng, 8, 2.0, offset)
    d_t, d_theta = 0.01, math.radians(0.25)
    trials = 300
    p_true = q @ T[:2, :2].T + T[:2, 2]
    truth = se2_to_params(T)
    values = np.empty(trials)
    c = (w @ p_true) / w.sum()  # the objects' weighted centroid in the ego frame
    for n in range(trials):
        delta = rng.normal(0, d_theta * math.sqrt(kappa / 2))
        shift = rng.normal(0, d_t * math.sqrt(kappa / 2), 2)
        turn = se2_from_params([0.0, 0.0, delta])
        p = (p_true - c) @ turn[:2, :2].T + c + shift + rng.normal(0, 1e-4, p_true.shape)
        T_est = weighted_arun(p, q, w)
        R = calibrated_covariance(T_est, p, q, w, kappa=kappa, noise_prior=1e-4,
                                  prior_dof=1e9, map_drift=(d_t, d_theta),
                                  repeat_inflation=0.0)
        values[n] = nees(se2_to_params(T_est), truth, R)
    assert abs(values.mean() - 3.0) < 5 * math.sqrt(6 / trials) + 0.1


def kalman_step(P: np.ndarray, R: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCAFF's per-hypothesis Kalman filter (identity motion, Q added per step): P after one
    update with measurement covariance R, and the update's state transition I - K."""
    prior = P + Q
    gain = prior @ np.linalg.inv(prior + R)
    return prior - gain @ prior, np.eye(3) - gain


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(5, 12), spread=st.floats(0.3, 5.0),
       offset=st.floats(0.0, 30.0), q_m=st.floats(0.01, 0.3), q_deg=st.floats(0.05, 2.0))
def test_inflation_settles_the_filter_at_one_registration(seed, k, spread, offset, q_m, q_deg):
    """Re-registering the same objects every step: with repeat_inflation = 1 the filter's P
    settles at R_s, the covariance of one registration (which averaging shared errors cannot
    reduce); with 0 the measurement is R_s itself and the filter claims far less."""
    rng = np.random.default_rng(seed)
    T, q, w = scene(rng, k, spread, offset)
    p = q @ T[:2, :2].T + T[:2, 2] + rng.normal(0, 0.05, (k, 2))
    T_est = weighted_arun(p, q, w)
    Q = np.diag([q_m**2, q_m**2, math.radians(q_deg) ** 2])
    common = {"kappa": 20.0, "Q": Q}
    R_s = calibrated_covariance(T_est, p, q, w, repeat_inflation=0.0, **common)
    R = calibrated_covariance(T_est, p, q, w, repeat_inflation=1.0, **common)
    # R is the inflation R_s + R_s Q^-1 R_s up to the floor on its eigenvalues (1e-9 of its
    # largest, for a factor graph), which only adds
    inflated = R_s + R_s @ np.linalg.solve(Q, R_s)
    lift = np.linalg.eigvalsh(R - inflated)
    assert lift.min() > -1e-9 * np.abs(R).max()
    assert lift.max() <= 1.01 * max(1e-9 * np.linalg.eigvalsh(inflated)[-1], 1e-6 * 0.05**2)
    # R_s is the inflated filter's fixed point, and a stable one (the one it converges to)
    P, transition = kalman_step(R_s, inflated, Q)
    np.testing.assert_allclose(P, R_s, rtol=1e-8, atol=1e-12 * np.abs(R_s).max())
    assert np.abs(np.linalg.eigvals(transition)).max() < 1.0
    assert np.all(np.linalg.eigvalsh(R - R_s) > -1e-12 * np.abs(R).max())
    # without the inflation the filter claims less than one registration's error
    P = R_s
    for _ in range(200):
        P, _ = kalman_step(P, R_s, Q)
    assert np.trace(np.linalg.solve(P, R_s)) > 3.0


def test_shared_error_is_covered_only_with_inflation():
    """The worst case of re-registration: one registration error shared by every step. The
    filter's final NEES is chi-square-like with the default inflation and far beyond it
    without."""
    rng = np.random.default_rng(7)
    Q = np.diag([0.1**2, 0.1**2, math.radians(0.5) ** 2])
    runs, means = 300, {}
    default = FrameAlignerParams().repeat_inflation
    for rho in (0.0, default):
        values = []
        for _ in range(runs):
            T, q, w = scene(rng, 7, 1.5, 6.0)
            p = q @ T[:2, :2].T + T[:2, 2] + rng.normal(0, 0.05, (7, 2))
            T_est = weighted_arun(p, q, w)
            R_s = calibrated_covariance(T_est, p, q, w, kappa=150.0, repeat_inflation=0.0)
            R = calibrated_covariance(T_est, p, q, w, kappa=150.0, repeat_inflation=rho)
            error = rng.multivariate_normal(np.zeros(3), R_s)
            x, P = error + rng.multivariate_normal(np.zeros(3), R), R.copy()  # seeded by z_0
            for _ in range(40):
                prior = P + Q
                gain = prior @ np.linalg.inv(prior + R)
                x = x + gain @ (error - x)  # z_t = truth + the shared error; truth = 0
                P = prior - gain @ prior
            values.append(x @ np.linalg.solve(P, x))
        means[rho] = float(np.mean(values))
    assert 1.5 < means[default] < 3.6
    assert means[0.0] > 2 * means[default]


def base_case():
    rng = np.random.default_rng(3)
    T, q, w = scene(rng, 10, 2.0, 5.0)
    p = q @ T[:2, :2].T + T[:2, 2]
    return T, p, q, w


def covariance(T, p, q, w, **changes):
    settings_ = {"kappa": 20.0, "noise_prior": 0.05, "prior_dof": 1e9} | changes
    return calibrated_covariance(T, p, q, w, **settings_)


@pytest.mark.parametrize("rho", [0.0, FrameAlignerParams().repeat_inflation])
def test_less_informative_maps_give_a_larger_R(rho):
    """Fewer, clustered and more distant points, a longer map span, more residual and a
    smaller filter drift Q all give a larger R (each variance; a longer span without
    inflation in the matrix order too: a weighted fit that is not the efficient one need not
    lose precision in every direction when it loses a point)."""
    T, p, q, w = base_case()
    base = covariance(T, p, q, w, repeat_inflation=rho)

    def larger(R, components=(0, 1, 2), ordered=False):
        assert all(R[c, c] > base[c, c] * (1 + 1e-9) for c in components)
        if ordered:  # R - base positive semidefinite
            assert np.linalg.eigvalsh(R - base).min() > -1e-12 * np.abs(R).max()

    larger(covariance(T, p[:5], q[:5], w[:5], repeat_inflation=rho))      # fewer
    centre = q.mean(axis=0)
    q_tight = centre + 0.3 * (q - centre)
    p_tight = q_tight @ T[:2, :2].T + T[:2, 2]
    larger(covariance(T, p_tight, q_tight, w, repeat_inflation=rho))      # clustered
    q_far = q + 30.0 * centre / np.linalg.norm(centre)
    p_far = q_far @ T[:2, :2].T + T[:2, 2]
    # a lever arm carries the heading's uncertainty into the translation; the heading alone
    # is the same about the objects
    larger(covariance(T, p_far, q_far, w, repeat_inflation=rho), (0, 1))  # distant
    larger(covariance(T, p, q, w, kappa=150.0, repeat_inflation=rho),
           ordered=rho == 0.0)                                                # longer span
    noisy = p + np.random.default_rng(0).normal(0, 0.3, p.shape)
    larger(covariance(weighted_arun(noisy, q, w), noisy, q, w, prior_dof=4.0,
                      repeat_inflation=rho))                              # more residual
    if rho > 0:
        small_Q = np.diag([0.05**2, 0.05**2, math.radians(0.25) ** 2])
        larger(covariance(T, p, q, w, repeat_inflation=rho, Q=small_Q))   # slower drift


def test_the_aligner_gives_the_calibrated_covariance():
    """covariance="calibrated": each candidate's R is `calibrated_covariance` of its own
    registration (associations, Arun weights from the objects' ages, the aligner's kappa and
    residual_floor), symmetric positive definite, and larger than the sandwich alone."""
    pair = overlapping_maps(np.random.default_rng(3), 40, 0.6, 0.1)
    params = calibrated(kappa=30.0)
    candidates = FrameAligner(params).measurements(pair.ego, pair.other, pair.now)
    assert candidates
    for c in candidates:
        a = c.associations
        p, q = pair.ego.centroids[a[:, 0], :2], pair.other.centroids[a[:, 1], :2]
        w = arun_weights(pair.ego.ages(pair.now)[a[:, 0]], pair.other.ages(pair.now)[a[:, 1]],
                         params.weight_offset)
        expected = calibrated_covariance(c.T, p, q, w, kappa=30.0,
                                         noise_prior=params.residual_floor)
        np.testing.assert_allclose(c.R, expected, rtol=1e-9)
        assert np.allclose(c.R, c.R.T) and np.linalg.eigvalsh(c.R).min() > 0
        bare = calibrated_covariance(c.T, p, q, w, kappa=30.0, map_drift=NO_DRIFT,
                                     repeat_inflation=0.0, noise_prior=params.residual_floor)
        assert np.linalg.eigvalsh(c.R - bare).min() > 0


def test_the_aligner_reads_the_calibration_settings():
    """No drift and no inflation leave the pooled sandwich alone: smaller than the default."""
    pair = overlapping_maps(np.random.default_rng(5), 40, 0.6, 0.1)
    default = FrameAligner(calibrated()).measurements(pair.ego, pair.other, pair.now)
    bare = FrameAligner(calibrated(map_drift=NO_DRIFT, repeat_inflation=0.0)).measurements(
        pair.ego, pair.other, pair.now)
    assert default and len(bare) == len(default)
    for d, b in zip(default, bare, strict=True):
        assert np.trace(b.R) < np.trace(d.R)


def test_maps_that_keep_every_object_take_the_oldest_association_as_span():
    """kappa = inf: the map drift runs over the oldest association's age, not forever."""
    pair = overlapping_maps(np.random.default_rng(3), 40, 0.6, 0.1)
    candidates = FrameAligner(calibrated(kappa=math.inf)).measurements(pair.ego, pair.other,
                                                                       pair.now)
    assert candidates
    for c in candidates:
        assert np.isfinite(c.R).all() and np.linalg.eigvalsh(c.R).min() > 0


@pytest.mark.parametrize(("name", "value"), [
    ("repeat_inflation", -1.0), ("residual_prior_dof", math.nan), ("map_drift", (0.1,)),
    ("map_drift", (-0.1, 0.0)), ("map_drift", (1e160, 0.0)), ("map_drift", (0.0, 1e160)),
    ("repeat_Q", np.eye(2)), ("repeat_Q", -np.eye(3)),
])
def test_the_aligner_refuses_bad_settings(name, value):
    pair = overlapping_maps(np.random.default_rng(3), 40, 0.6, 0.1)
    with pytest.raises(ConfigError, match=name):
        FrameAligner(calibrated(**{name: value})).measurements(pair.ego, pair.other, pair.now)


def test_bad_input_is_named():
    T, p, q, w = base_case()
    with pytest.raises(DataError, match="calibrated_covariance: weights must be >= 0"):
        calibrated_covariance(T, p, q, -w, kappa=20.0)
    with pytest.raises(DataError, match="p and q of shape"):
        calibrated_covariance(T, p, q[:3], w, kappa=20.0)
    with pytest.raises(DataError, match="non-finite"):
        calibrated_covariance(T, np.full_like(p, np.nan), q, w, kappa=20.0)
    for name, value in (("kappa", 0.0), ("noise_prior", -1.0), ("prior_dof", -1.0),
                        ("repeat_inflation", math.inf)):
        with pytest.raises(ConfigError, match=name):
            calibrated_covariance(T, p, q, w, **({"kappa": 20.0} | {name: value}))
    for drift in ((0.1, "x"), (1e160, 0.0)):  # a drift whose square overflows too
        with pytest.raises(ConfigError, match="map_drift"):
            calibrated_covariance(T, p, q, w, kappa=20.0, map_drift=drift)
    with pytest.raises(ConfigError, match=r"(?s)calibrated_covariance\.Q = .*must be a symmetric"):
        calibrated_covariance(T, p, q, w, kappa=20.0, Q=np.diag([1.0, 1.0, 0.0]))
    with pytest.raises(ConfigError, match="overflow"):
        calibrated_covariance(T, p, q, w, kappa=1e300)
    with pytest.raises(DataError, match="coordinates beyond"):
        calibrated_covariance(T, p * 1e12, q, w, kappa=20.0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), offset=st.floats(200.0, 3000.0))
def test_objects_far_from_the_origin_give_a_covariance_a_graph_takes(seed, offset):
    """Objects kilometres from the odometry origin couple heading and translation through the
    lever arm, and the inflation squares that: the raw R neared a singular matrix (condition
    number 1e11 on the simulator's same_direction) that the factor graph refused, failing the
    study's job. Its smallest eigenvalue is lifted to 1e-9 of its largest, and only lifted."""
    from tcaff_gtsam.graph import InterRobotGraph

    rng = np.random.default_rng(seed)
    T, q, w = scene(rng, 5, 3.0, offset)
    p = q @ T[:2, :2].T + T[:2, 2] + rng.normal(0, 0.05, q.shape)
    R = calibrated_covariance(T, p, q, w, kappa=15.0)
    eig = np.linalg.eigvalsh(R)
    assert eig[0] >= 0.99e-9 * eig[-1]
    bare = calibrated_covariance(T, p, q, w, kappa=15.0, repeat_inflation=0.0)
    assert np.linalg.eigvalsh(R - bare).min() > -1e-9 * eig[-1]  # never more confident
    InterRobotGraph(2).add_alignment(0, 0, 1, T, R)  # accepted


def test_a_registration_of_no_weight_is_a_data_error_and_no_direction_is_known_exactly():
    T, p, q, w = base_case()
    with pytest.raises(DataError, match="at least one association of weight > 0"):
        calibrated_covariance(T, p, q, np.zeros_like(w), kappa=20.0)
    with pytest.raises(DataError, match="at least one association"):
        calibrated_covariance(T, p[:0], q[:0], w[:0], kappa=20.0)
    # one point fixes no heading: without drift that direction still gets a variance
    R = calibrated_covariance(T, p[:1], q[:1], w[:1], kappa=20.0, map_drift=(0.0, 0.0))
    assert np.linalg.eigvalsh(R).min() >= 1e-6 * 0.05**2 * 0.999


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(-12, 12), st.sampled_from([3, 2, 1, 0]))
def test_the_sandwich_pseudo_inverse_is_numpys_to_the_last_bit(seed, scale, rank):
    """`_pinv` stands in for np.linalg.pinv in the sandwich, on full-rank and singular
    matrices alike (the latter a registration that does not observe some direction)."""
    from tcaff_gtsam.covariance import _pinv

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, max(rank, 1))) * 10.0**scale
    matrix = a @ a.T if rank else np.zeros((3, 3))
    assert np.array_equal(_pinv(matrix), np.linalg.pinv(matrix))
