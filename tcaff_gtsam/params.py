"""Parameter objects. Defaults are the paper's values (and the released code's where the paper
is silent); every object validates itself and raises `ConfigError` naming the field."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .errors import ConfigError

__all__ = ["ClipperParams", "FrameAlignerParams", "constant_alignment_covariance"]


def _require(condition: bool, owner: str, name: str, value, rule: str) -> None:
    if not condition:
        raise ConfigError(f"{owner}.{name} = {value!r}: {rule}")


def constant_alignment_covariance() -> np.ndarray:
    """The original code's fixed measurement covariance diag(0.5 m, 0.5 m, 5 deg)^2, (3, 3)."""
    return np.diag([0.5**2, 0.5**2, math.radians(5.0) ** 2])


@dataclass(frozen=True)
class ClipperParams:
    """CLIPPER consistency graph and solver settings.

    Attributes:
        sigma: metres, width of the affinity kernel exp(-c^2 / (2 sigma^2)).
        epsilon: metres, two associations are consistent when their distance difference c < epsilon.
        rounding: "size" keeps the round(F) largest entries of u (CLIPPER's rule, F the final
            objective); "threshold" keeps entries above `threshold` * max(u).
        threshold: relative threshold for rounding = "threshold", in (0, 1).
        tol_u: stop an inner ascent when the objective changes by less than this. 1e-6 rather
            than CLIPPER's 1e-8: the same solutions on our benchmarks, 25 % less time.
        eps: entries of u (and penalties) below this count as zero.
        beta: backtracking factor of the line search, in (0, 1).
        max_outer, max_inner, max_line_search: iteration caps of homotopy, ascent and line search.
        power_iterations: power-method steps that shape the seeded random start vector (each
            costs a full pass over the graph; more than 5 changed no solution we measured).
        seed: seed of the start vector; same seed, same graph -> same solution.
    """

    sigma: float = 0.15
    epsilon: float = 0.25
    rounding: Literal["size", "threshold"] = "size"
    threshold: float = 0.5
    tol_u: float = 1e-6
    eps: float = 1e-9
    beta: float = 0.25
    max_outer: int = 1000
    max_inner: int = 200
    max_line_search: int = 99
    power_iterations: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        o = "ClipperParams"
        _require(self.sigma > 0 and math.isfinite(self.sigma), o, "sigma", self.sigma,
                 "must be a finite number > 0")
        _require(self.epsilon > 0 and math.isfinite(self.epsilon), o, "epsilon", self.epsilon,
                 "must be a finite number > 0")
        _require(self.rounding in ("size", "threshold"), o, "rounding", self.rounding,
                 "must be 'size' or 'threshold'")
        _require(0 < self.threshold < 1, o, "threshold", self.threshold, "must be in (0, 1)")
        _require(self.tol_u > 0, o, "tol_u", self.tol_u, "must be > 0")
        _require(self.eps > 0, o, "eps", self.eps, "must be > 0")
        _require(0 < self.beta < 1, o, "beta", self.beta, "must be in (0, 1)")
        for name in ("max_outer", "max_inner", "max_line_search"):
            value = getattr(self, name)
            _require(isinstance(value, int) and value >= 1, o, name, value, "must be an int >= 1")
        _require(isinstance(self.power_iterations, int) and self.power_iterations >= 0, o,
                 "power_iterations", self.power_iterations, "must be an int >= 0")


@dataclass(frozen=True)
class FrameAlignerParams:
    """Settings of `FrameAligner` (two object maps -> candidate alignments of T_oi_oj).

    Attributes:
        kappa: seconds, only objects seen less than kappa ago take part (paper: 20 s).
        size_ratio, size_abs_diff: the size gate; a pair of objects may be associated when, for
            width and for height alike, the larger over the smaller is <= size_ratio or the
            absolute difference is <= size_abs_diff metres.
        dim: 2 matches (x, y) centroids (the original's choice), 3 matches full 3D centroids
            (the alignment is then projected onto the gravity-aligned plane).
        clipper: consistency graph and solver settings.
        n_solutions: N of MNO-CLIPPER (Algorithm 1).
        mno_downweight: factor applied to affinities among an earlier solution's associations;
            0 removes those associations, as in the paper.
        min_associations: solutions with fewer associations are discarded.
        min_score_ratio: solutions scoring below this fraction of the best are discarded.
        weight_offset: Arun weights are 1 / (weight_offset + age_i * age_j), ages in seconds.
        max_rmse: metres; solutions whose registration residual RMS exceeds it are discarded
            (mirror-image cliques pass the distance test but are not rigid). None disables it.
        covariance: "constant" gives every measurement `R_constant` (the original's choice);
            "residual" derives R from the registration residual and the associations' geometry.
        R_constant: (3, 3) covariance of (x [m], y [m], theta [rad]) for covariance="constant".
        residual_floor: metres, lower bound of the per-point noise used by covariance="residual".
    """

    kappa: float = 20.0
    size_ratio: float = 1.35
    size_abs_diff: float = 0.1
    dim: Literal[2, 3] = 2
    clipper: ClipperParams = field(default_factory=ClipperParams)
    n_solutions: int = 4
    mno_downweight: float = 0.0
    min_associations: int = 5
    min_score_ratio: float = 0.75
    weight_offset: float = 0.01
    max_rmse: float | None = 0.5
    covariance: Literal["constant", "residual"] = "constant"
    R_constant: np.ndarray = field(default_factory=constant_alignment_covariance)
    residual_floor: float = 0.05

    def __post_init__(self) -> None:
        o = "FrameAlignerParams"
        _require(self.kappa > 0, o, "kappa", self.kappa, "must be > 0 seconds")
        _require(self.size_ratio >= 1, o, "size_ratio", self.size_ratio, "must be >= 1")
        _require(self.size_abs_diff >= 0, o, "size_abs_diff", self.size_abs_diff,
                 "must be >= 0 metres")
        _require(self.dim in (2, 3), o, "dim", self.dim, "must be 2 or 3")
        _require(isinstance(self.clipper, ClipperParams), o, "clipper", self.clipper,
                 "must be a ClipperParams")
        _require(isinstance(self.n_solutions, int) and self.n_solutions >= 1, o, "n_solutions",
                 self.n_solutions, "must be an int >= 1")
        _require(0 <= self.mno_downweight < 1, o, "mno_downweight", self.mno_downweight,
                 "must be in [0, 1)")
        _require(isinstance(self.min_associations, int) and self.min_associations >= 2, o,
                 "min_associations", self.min_associations, "must be an int >= 2")
        _require(0 <= self.min_score_ratio <= 1, o, "min_score_ratio", self.min_score_ratio,
                 "must be in [0, 1]")
        _require(self.weight_offset > 0, o, "weight_offset", self.weight_offset, "must be > 0")
        _require(self.max_rmse is None or self.max_rmse > 0, o, "max_rmse", self.max_rmse,
                 "must be > 0 metres or None")
        _require(self.covariance in ("constant", "residual"), o, "covariance", self.covariance,
                 "must be 'constant' or 'residual'")
        R = np.asarray(self.R_constant, dtype=float)
        _require(R.shape == (3, 3) and bool(np.all(np.isfinite(R))) and np.allclose(R, R.T)
                 and bool(np.all(np.linalg.eigvalsh(R) > 0)), o, "R_constant", self.R_constant,
                 "must be a symmetric positive definite (3, 3) matrix")
        object.__setattr__(self, "R_constant", R)
        _require(self.residual_floor > 0, o, "residual_floor", self.residual_floor,
                 "must be > 0 metres")

    @classmethod
    def reference(cls) -> FrameAlignerParams:
        """The authors' released settings, without this project's residual check."""
        return cls(max_rmse=None)
