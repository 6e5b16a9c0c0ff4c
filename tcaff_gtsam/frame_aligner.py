"""FrameAligner: two object maps -> candidate alignment measurements z = (x, y, theta) of T_oi_oj.

Pipeline (paper, "Map Alignment" and Algorithm 1): keep objects seen within kappa seconds, gate
putative associations by size, build the consistency graph, draw N near-optimal CLIPPER
solutions, register each by weighted Arun, keep the good ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .clipper import consistency_graph, mno_clipper
from .geometry import se2_from_params, se2_to_params, se3_to_se2
from .object_map import ObjectMap
from .params import FrameAlignerParams
from .registration import arun_weights, putative_associations, registration_rmse, weighted_arun

__all__ = ["AlignmentMeasurement", "FrameAligner", "residual_covariance"]


@dataclass(frozen=True, eq=False)
class AlignmentMeasurement:
    """One candidate alignment of the other robot's odometry frame into the ego's.

    Attributes:
        z: (3,) (x [m], y [m], theta [rad]) of T_oi_oj (i = ego, j = other), theta wrapped.
        R: (3, 3) measurement covariance of z.
        associations: (k, 2) int64 (ego index, other index) into the maps that were aligned.
        score: MNO-CLIPPER score of the association set (u'Mu / u'u on the original affinity).
        rmse: metres, registration residual RMS of the associated centroids.
    """

    z: np.ndarray
    R: np.ndarray
    associations: np.ndarray
    score: float
    rmse: float

    @property
    def T(self) -> np.ndarray:
        """(3, 3) SE(2) matrix T_oi_oj."""
        return se2_from_params(self.z)


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
        weights: (k,) Arun weights; floor: metres.
    """
    k = p.shape[0]
    Rq = q @ T_i_j[:2, :2].T
    residual = p - (Rq + T_i_j[:2, 2])
    A = np.zeros((k, 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[:, 0, 2], A[:, 1, 2] = -Rq[:, 1], Rq[:, 0]
    A = A.reshape(2 * k, 3)
    w = np.repeat(weights, 2)
    bread = np.linalg.pinv((A * w[:, None]).T @ A)
    meat = (A * (w**2)[:, None]).T @ A
    dof = 2 * k - 6 + np.trace(bread @ meat @ bread @ (A.T @ A))
    s_sq = max(float(np.sum(residual**2)) / max(dof, 1e-9), floor**2)
    cov = s_sq * bread @ meat @ bread
    return 0.5 * (cov + cov.T)


class FrameAligner:
    """Candidate alignments T_oi_oj between an ego map and another robot's map.

    Stateless apart from its parameters; one instance can serve every robot pair.
    """

    def __init__(self, params: FrameAlignerParams | None = None) -> None:
        self.params = params or FrameAlignerParams()

    def measurements(self, ego: ObjectMap, other: ObjectMap, now: float
                     ) -> list[AlignmentMeasurement]:
        """Candidate alignments, best score first; empty when nothing qualifies.

        Args:
            ego: map of robot i in its odometry frame.
            other: map of robot j in its odometry frame.
            now: seconds, current time on the clock of the maps' `last_seen`.
        Raises:
            DataError: `now` is not finite.
        """
        prm = self.params
        ego_idx = ego.recent_indices(now, prm.kappa)
        other_idx = other.recent_indices(now, prm.kappa)
        if min(ego_idx.size, other_idx.size) < prm.min_associations:
            return []
        ego_r, other_r = ego.subset(ego_idx), other.subset(other_idx)
        assoc = putative_associations(ego_r, other_r, prm.size_ratio, prm.size_abs_diff)
        if assoc.shape[0] < prm.min_associations:
            return []
        p_all = ego_r.centroids[:, : prm.dim]
        q_all = other_r.centroids[:, : prm.dim]
        graph = consistency_graph(p_all, q_all, assoc, prm.clipper.epsilon, prm.clipper.sigma)
        solutions = mno_clipper(graph, prm.n_solutions, prm.clipper, prm.mno_downweight)
        if not solutions:
            return []
        best = max(s.score for s in solutions)
        ages_ego, ages_other = ego_r.ages(now), other_r.ages(now)
        out: list[AlignmentMeasurement] = []
        for sol in solutions:
            if len(sol) < prm.min_associations or sol.score < prm.min_score_ratio * best:
                continue
            a = sol.associations
            p, q = p_all[a[:, 0]], q_all[a[:, 1]]
            w = arun_weights(ages_ego[a[:, 0]], ages_other[a[:, 1]], prm.weight_offset)
            T = weighted_arun(p, q, w)
            if T is None:
                continue
            T2 = se3_to_se2(T) if prm.dim == 3 else T
            rmse = registration_rmse(T2, p[:, :2], q[:, :2])
            if prm.max_rmse is not None and rmse > prm.max_rmse:
                continue
            z = se2_to_params(T2)
            R = (prm.R_constant.copy() if prm.covariance == "constant"
                 else residual_covariance(T2, p[:, :2], q[:, :2], w, prm.residual_floor))
            associations = np.column_stack([ego_idx[a[:, 0]], other_idx[a[:, 1]]])
            out.append(AlignmentMeasurement(z, R, associations, sol.score, rmse))
        out.sort(key=lambda meas: -meas.score)
        return out
