"""The covariance of a registered alignment (x [m], y [m], theta [rad]) of T_oi_oj, from the
registration's residuals and geometry: `residual_covariance` (the weighted least-squares
sandwich) and `calibrated_covariance` (the frame aligner's default: that, with its point noise
pooled with a prior, the odometries' drift over the map's span, and an inflation for a filter
that registers the same objects every step); and `held_drift`, how an alignment held without
registrations drifts per second."""

from __future__ import annotations

import math

import numpy as np

from .aligner_params import as_map_drift
from .errors import ConfigError, DataError
from .inputs import real_array, shown
from .params import _alignment_process_noise, _finite, _spd
from .registration import MAX_COORDINATE, MAX_WEIGHT

__all__ = ["calibrated_covariance", "held_drift", "residual_covariance"]


def residual_covariance(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray, weights: np.ndarray,
                        floor: float) -> np.ndarray:
    """Covariance (3, 3) of (x, y, theta) of a weighted 2D registration, from its residuals.

    Model p_k = R(theta) q_k + t + e_k with isotropic point noise e_k ~ N(0, s^2 I). Linearised
    at the estimate, each point contributes the rows A_k = [I_2, perp(R q_k)] (perp rotates by
    90 degrees) with weight w_k, and weighted least squares has the sandwich covariance
        cov(z) = s^2 B (A' W^2 A) B,   B = (A' W A)^-1.
    s^2 is the residual sum of squares divided by its expectation factor for this oblique fit,
    2k - 6 + tr(B A'W^2A B A'A) (2k - 3 for equal weights), floored at `floor`^2 because a
    handful of points can fit by chance. Few, clustered, distant or old (low-weight)
    associations therefore give a larger R.

    Args:
        T_i_j: (3, 3) estimated SE(2) transform; p: (k, 2) ego points; q: (k, 2) other points;
        weights: (k,) Arun weights >= 0; floor: metres, >= 0.
    Raises:
        DataError: an argument not real, not finite, or of the wrong shape; negative weights
            or floor; coordinates beyond `registration.MAX_COORDINATE` or weights beyond
            `registration.MAX_WEIGHT`.
    """
    o = "residual_covariance"
    T_i_j, p, q, weights = _registration_arrays(o, T_i_j, p, q, weights)
    if not (_finite(floor) and floor >= 0):
        raise DataError(f"{o}: floor must be a finite number >= 0 metres, got {shown(floor)}")
    return _residual_covariance(T_i_j, p, q, weights, float(floor))


def _registration_arrays(o: str, T_i_j, p, q, weights) -> tuple[np.ndarray, ...]:
    """T_i_j (3, 3), p and q (k, 2), weights (k,) >= 0 as checked float arrays; DataError
    naming `o` and the argument otherwise."""
    T_i_j = real_array(o, "T_i_j", T_i_j)
    p, q = real_array(o, "p", p), real_array(o, "q", q)
    weights = real_array(o, "weights", weights)
    if T_i_j.shape != (3, 3):
        raise DataError(f"{o}: T_i_j must be a (3, 3) SE(2) matrix, got shape {T_i_j.shape}")
    if p.ndim != 2 or p.shape[1] != 2 or q.shape != p.shape or weights.shape != p.shape[:1]:
        raise DataError(f"{o}: need p and q of shape (k, 2) and weights (k,), got "
                        f"{p.shape}, {q.shape} and {weights.shape}")
    for name, arr in (("T_i_j", T_i_j), ("p", p), ("q", q), ("weights", weights)):
        if not np.isfinite(arr).all():
            raise DataError(f"{o}: {name} holds non-finite values")
    if (weights < 0).any():
        raise DataError(f"{o}: weights must be >= 0, got {shown(weights)}")
    # beyond these the squared sums overflow into a covariance of inf and nan
    for name, arr in (("T_i_j", T_i_j[:2, 2]), ("p", p), ("q", q)):
        if arr.size and np.abs(arr).max() > MAX_COORDINATE:
            raise DataError(f"{o}: {name} holds coordinates beyond {MAX_COORDINATE:g} m")
    if weights.size and weights.max() > MAX_WEIGHT:
        raise DataError(f"{o}: weights must be <= {MAX_WEIGHT:g}, got {shown(weights)}")
    return T_i_j, p, q, weights


def _sandwich(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray, weights: np.ndarray
              ) -> tuple[float, float, np.ndarray, np.ndarray]:
    """The parts of the registration's sandwich covariance (`residual_covariance`): the
    residual sum of squares [m^2], its expectation factor (degrees of freedom), G = B (A'W^2A)
    B (3, 3), the covariance for unit point noise, and the rotated other points R q (k, 2)."""
    k = p.shape[0]
    Rq = q @ T_i_j[:2, :2].T
    residual = p - (Rq + T_i_j[:2, 2])
    A = np.zeros((k, 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[:, 0, 2], A[:, 1, 2] = -Rq[:, 1], Rq[:, 0]
    A = A.reshape(2 * k, 3)
    w = np.repeat(weights, 2)
    bread = _pinv((A * w[:, None]).T @ A)
    meat = (A * (w**2)[:, None]).T @ A
    G = bread @ meat @ bread
    dof = 2 * k - 6 + float((G @ (A.T @ A)).trace())
    return float((residual**2).sum()), dof, G, Rq


def _pinv(a: np.ndarray) -> np.ndarray:
    """np.linalg.pinv(a) of a real (n, n) matrix with its default cutoff (singular values up to
    1e-15 of the largest dropped), in its arithmetic to the last bit, without the wrapper's
    argument handling: that costs as much as the SVD of a 3 x 3 matrix."""
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    large = s > 1e-15 * s.max()
    s = np.divide(1, s, where=large, out=s)
    s[~large] = 0
    return vt.T @ (s[:, None] * u.T)


def _residual_covariance(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray, weights: np.ndarray,
                         floor: float) -> np.ndarray:
    rss, dof, G, _ = _sandwich(T_i_j, p, q, weights)
    s_sq = max(rss / max(dof, 1e-9), floor**2)
    cov = s_sq * G
    return 0.5 * (cov + cov.T)


def calibrated_covariance(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray, weights: np.ndarray,
                          kappa: float, noise_prior: float = 0.05, prior_dof: float = 4.0,
                          map_drift: tuple[float, float] = (0.01, math.radians(0.25)),
                          repeat_inflation: float = 1.0, Q: np.ndarray | None = None
                          ) -> np.ndarray:
    """Covariance (3, 3) of (x [m], y [m], theta [rad]) of T_oi_oj registered from two maps,
    for a filter that takes a registration of (mostly) the same objects every step.

    Three parts, in the frame of the ego map (i):

    1. Point noise: the sandwich covariance of the weighted registration (see
       `residual_covariance`), s~^2 G, G = B (A'W^2A) B, with the residual's noise estimate
       pooled with a prior, s~^2 = (RSS + nu0 s0^2) / (dof + nu0): a handful of points
       can fit by chance, and 1 / s^2 from few degrees of freedom has a heavy tail.
    2. Map drift: each map holds objects placed through its robot's drifting odometry over the
       last kappa seconds, a shared error that no residual shows. Modelled as a random walk
       of the two odometries relative to each other at (d_t [m / sqrt(s)], d_theta
       [rad / sqrt(s)]) over half the span:
           R_map = kappa / 2 (d_t^2 diag(1, 1, 0) + d_theta^2 J J'),  J = (c_y, -c_x, 1),
       with c the weighted centroid of R q: the heading error turns the other map about its
       objects, where the registration pins it, which moves t by -theta perp(c).
       R_s = s~^2 G + R_map is one registration's covariance.
    3. Re-registration: the next steps register the same objects again, so their errors are
       shared and a filter averaging them would shrink its covariance below R_s. The
       measurement is inflated to
           R = R_s + rho R_s Q^-1 R_s,
       with which an identity-motion Kalman filter adding Q per step settles at P = R_s for
       rho = 1 (the error of one registration, which averaging does not reduce; lower rho
       lets consecutive registrations share part of their error). R = R_s for rho = 0.

    Few, clustered, distant or old (low-weight) associations, a large residual, a long span
    kappa and a small Q all give a larger R.

    Args:
        T_i_j: (3, 3) estimated SE(2) transform; p: (k, 2) ego points; q: (k, 2) other points
            (metres, each robot's odometry frame); weights: (k,) Arun weights >= 0.
        kappa: seconds (> 0), the span of the maps.
        noise_prior: s0, metres > 0, the prior per-point noise.
        prior_dof: nu0 >= 0, the prior's weight in degrees of freedom; 0 takes the residual
            alone, floored at noise_prior (`residual_covariance`).
        map_drift: (d_t, d_theta) >= 0.
        repeat_inflation: rho >= 0.
        Q: (3, 3) symmetric positive definite, the filter's drift per step (None: TCAFF's
            default, diag(0.1 m, 0.1 m, 0.5 deg)^2).
    Raises:
        DataError: an array not real, not finite, or of the wrong shape; negative weights;
            coordinates beyond `registration.MAX_COORDINATE` or weights beyond
            `registration.MAX_WEIGHT`.
        ConfigError: a setting out of range (naming it).
    """
    o = "calibrated_covariance"
    T_i_j, p, q, weights = _registration_arrays(o, T_i_j, p, q, weights)
    if not weights.sum() > 0:
        raise DataError(f"{o}: needs at least one association of weight > 0, got "
                        f"{shown(weights)}")
    for name, value, low in (("kappa", kappa, None), ("noise_prior", noise_prior, None),
                             ("prior_dof", prior_dof, 0.0),
                             ("repeat_inflation", repeat_inflation, 0.0)):
        if not (_finite(value) and (value > 0 if low is None else value >= low)):
            rule = "> 0" if low is None else f">= {low:g}"
            raise ConfigError(f"{o}: {name} must be a finite number {rule}, got {shown(value)}")
    drift = as_map_drift(o, map_drift)
    Q_inv = _inverse_Q(o, Q)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
        R = _calibrated_covariance(T_i_j, p, q, weights, float(kappa), float(noise_prior),
                                   float(prior_dof), drift, float(repeat_inflation), Q_inv)
    if not np.isfinite(R).all():
        raise ConfigError(f"{o}: kappa = {shown(kappa)}, map_drift = {shown(map_drift)}, "
                          f"noise_prior = {shown(noise_prior)} and repeat_inflation = "
                          f"{shown(repeat_inflation)} overflow the covariance")
    return R


def _inverse_Q(owner: str, Q) -> np.ndarray:
    """Q^-1 (3, 3) of the filter's drift per step (None: TCAFF's default); a ParameterError
    naming Q when it is not a symmetric positive definite (3, 3) matrix."""
    return np.linalg.inv(_alignment_process_noise() if Q is None else _spd(Q, 3, owner, "Q"))


#: the smallest eigenvalue of a calibrated R relative to its largest (`_calibrated_covariance`)
_MAX_CONDITION_INVERSE = 1e-9
#: diag(1, 1, 0): the translation's block of (x, y, theta)
_PLANE = np.diag([1.0, 1.0, 0.0])
_PLANE.flags.writeable = False


def _single_registration_parts(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray,
                               weights: np.ndarray, kappa: float, noise_prior: float,
                               prior_dof: float, drift: tuple[float, float]
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three parts (3, 3) of one registration's covariance R_s (`calibrated_covariance`,
    parts 1 and 2): the point noise s~^2 G, and the map drift's translation and heading
    (about the weighted centroid c of R q)."""
    rss, dof, G, Rq = _sandwich(T_i_j, p, q, weights)
    if prior_dof > 0:
        s_sq = (rss + prior_dof * noise_prior**2) / (max(dof, 0.0) + prior_dof)
    else:
        s_sq = max(rss / max(dof, 1e-9), noise_prior**2)
    total = float(weights.sum())
    c = (weights @ Rq) / total if total > 0 else Rq.mean(axis=0)
    J = np.array([c[1], -c[0], 1.0])
    d_t, d_theta = drift
    return (s_sq * G, 0.5 * kappa * d_t**2 * _PLANE,
            0.5 * kappa * d_theta**2 * (J[:, None] * J))


def _calibrated_covariance(T_i_j: np.ndarray, p: np.ndarray, q: np.ndarray, weights: np.ndarray,
                           kappa: float, noise_prior: float, prior_dof: float,
                           drift: tuple[float, float], repeat_inflation: float,
                           Q_inv: np.ndarray) -> np.ndarray:
    point, drift_translation, drift_heading = _single_registration_parts(
        T_i_j, p, q, weights, kappa, noise_prior, prior_dof, drift)
    R_s = point + drift_translation + drift_heading
    R = R_s + repeat_inflation * (R_s @ Q_inv @ R_s)
    R = 0.5 * (R + R.T)
    # Far from the odometry origin the heading's lever couples it to the translation, and the
    # inflation squares that: R can near a singular matrix that a factor graph refuses as a
    # factor. Lifting its smallest eigenvalues to 1e-9 of its largest claims only less.
    if np.isfinite(R).all():  # (an overflow is the caller's to report)
        eig = np.linalg.eigvalsh(R)
        # and a direction the registration does not observe at all is not known exactly
        least = max(_MAX_CONDITION_INVERSE * eig[-1], 1e-6 * noise_prior**2)
        if eig[0] < least:
            R = R + (least - eig[0]) * np.eye(3)
    return R


def held_drift(x, ego_point, other_point, map_drift) -> np.ndarray:
    """(3, 3) growth per second of the covariance of an alignment x = (x [m], y [m],
    theta [rad]) of T_oi_oj held without registrations, by the odometries' drift.

    `map_drift` (d_t, d_theta) is the pair's walk per square root of a second (both robots'
    together, as `FrameAlignerParams.map_drift`): d_t^2 in each translation axis, and the
    heading's d_theta^2 shared equally by the two robots, each turning about where it is. Robot
    j's frame turning by a about its point p_j (`other_point`, in o_j) moves x by
    a (u_y, -u_x, 1), u = R(theta) p_j; robot i's turning about p_i (`ego_point`, in o_i) by
    a (v_y, -v_x, 1), v = p_i - t. Far from its frame's origin a robot's heading walk moves
    the alignment's translation by the lever |u| or |v| times the turn, which a diagonal
    growth leaves out. Where the robots stand at one place (p_i = T_oi_oj p_j) the two levers
    are one, the lever `calibrated_covariance` gives a registration's heading drift.

    Args:
        x: (3,) the held alignment; ego_point: (2,) metres in o_i; other_point: (2,) metres
            in o_j.
        map_drift: (d_t, d_theta), metres and radians per square root of a second.
    Raises:
        DataError: an array not real, not finite, of the wrong shape, or beyond
            `registration.MAX_COORDINATE`; ConfigError: map_drift out of range.
    """
    o = "held_drift"
    arrays = []
    for name, value, size in (("x", x, 3), ("ego_point", ego_point, 2),
                              ("other_point", other_point, 2)):
        a = real_array(o, name, value)
        if a.shape != (size,):
            raise DataError(f"{o}: {name} must have shape ({size},), got {a.shape}")
        if not (np.isfinite(a).all() and np.abs(a).max() <= MAX_COORDINATE):
            raise DataError(f"{o}: {name} must be finite and within {MAX_COORDINATE:g} m "
                            f"(registration.MAX_COORDINATE), got {shown(value)}")
        arrays.append(a)
    return _held_drift(*arrays, as_map_drift(o, map_drift))


def _held_drift(x: np.ndarray, ego_point: np.ndarray, other_point: np.ndarray,
                drift: tuple[float, float]) -> np.ndarray:
    """`held_drift` of checked arguments."""
    c, s = math.cos(x[2]), math.sin(x[2])
    u = (c * other_point[0] - s * other_point[1], s * other_point[0] + c * other_point[1])
    v = (ego_point[0] - x[0], ego_point[1] - x[1])
    G = np.array([[u[1], -u[0], 1.0], [v[1], -v[0], 1.0]])
    d_t, d_theta = drift
    growth = d_t**2 * _PLANE + 0.5 * d_theta**2 * (G.T @ G)
    # far from the origins with little translation drift the levers leave a direction grown
    # too little to pass for positive definite: lifted, as a calibrated R is, to 1e-9 of the
    # largest growth, which claims only less
    eig = np.linalg.eigvalsh(growth)
    least = _MAX_CONDITION_INVERSE * eig[-1]
    if eig[0] < least:
        growth = growth + (least - eig[0]) * np.eye(3)
    return growth
