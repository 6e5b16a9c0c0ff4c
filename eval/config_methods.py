"""Method-set configuration (`config`): which registered methods a study compares and their
settings — the FrameAligner, TCAFF and iSAM2 graph parameter dataclasses (minus what each run
sets), ICP, and the false-accept thresholds (with how overlaps and the perfect judge are
delimited).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pydantic import Field, field_validator, model_validator

from tcaff_gtsam.params import FrameAlignerParams, GraphParams, TCAFFParams

from .config_base import _Model, _params
from .registry import METHODS

#: the most ICP iterations per step: each pairs every object of one map with the other's
MAX_ICP_ITERATIONS = 10_000


class IcpConfig(_Model):
    """ICP on object centroids, started from the true alignment, then from its last estimate."""

    max_correspondence_distance: float = Field(1.0, gt=0, description="m")
    min_correspondences: int = Field(5, ge=3)
    max_iterations: int = Field(30, ge=1, le=MAX_ICP_ITERATIONS)


class ThresholdConfig(_Model):
    """An estimate further from the truth than either threshold is a false accept."""

    translation: float = Field(1.0, gt=0, description="m")
    heading_deg: float = Field(5.0, gt=0, le=180)


class ScoringConfig(ThresholdConfig):
    """The false-accept thresholds, and how overlaps and the perfect judge are delimited
    (`metrics.Thresholds`)."""

    overlap_gap_steps: int = Field(5, ge=1, description="fewer steps without overlap between "
                                   "two overlap steps do not end an overlap")
    judge_hold: float = Field(40.0, ge=0, description="s the perfect judge holds a candidate")


_PER_RUN = "is set per scenario/data set ({}), not per method set"
_Aligner = _params(FrameAlignerParams, kappa=_PER_RUN.format("mapping.kappa"))
_Tcaff = _params(TCAFFParams, window="the TCAFF window W " + _PER_RUN.format("window"))
_Graph = _params(GraphParams, Q="the alignment drift " + _PER_RUN.format("graph_drift"),
                 dim="the compared methods align planar frames: dim is 2")


class MethodsConfig(_Model):
    """Which methods a study compares, and their settings.

    `aligner` (the FrameAligner of the TCAFF methods), `tcaff` (the default TCAFF preset;
    `tcaff_reference` is always the released code's) and `graph` (the iSAM2 graph) take any
    fields of their parameter dataclass; the rest keep its defaults. What belongs to the run is
    set by the scenario or data set and refused here: kappa (`mapping.kappa`), the window W
    (`window`) and the graph's drift (`graph_drift`).
    """

    name: str = Field("methods", min_length=1)
    methods: list[str] = Field(default_factory=lambda: list(METHODS), min_length=1,
                               description="names in the registry (registry.METHODS)")
    clipper_k: list[int] = Field(default_factory=lambda: list(range(3, 13)), min_length=1)
    clipper_k_shown: int = Field(10, description="the single-shot threshold drawn over time")
    aligner: _Aligner = FrameAlignerParams()
    tcaff: _Tcaff = TCAFFParams()
    icp: IcpConfig = IcpConfig()
    graph: _Graph = GraphParams()
    thresholds: ScoringConfig = ScoringConfig()

    def aligner_params(self, kappa: float) -> FrameAlignerParams:
        """The FrameAligner of the TCAFF methods, objects seen within `kappa` s (the run's)."""
        return replace(self.aligner, kappa=kappa)

    def tcaff_params(self, reference: bool, window: int | None) -> TCAFFParams:
        """This set's TCAFF preset, or (`reference`) the released code's settings as they are,
        with the run's window W (None: the preset's)."""
        base = TCAFFParams.reference() if reference else self.tcaff
        return base if window is None else replace(base, window=window)

    def graph_params(self, drift: tuple[float, float] | None) -> GraphParams:
        """This set's iSAM2 graph, assuming `drift` (metres, degrees) of alignment drift per
        step (None: TCAFF's Q)."""
        if drift is None:
            return self.graph
        metres, degrees = drift
        Q = np.diag([metres**2, metres**2, np.radians(degrees) ** 2])
        return replace(self.graph, Q=Q)

    @field_validator("methods")
    @classmethod
    def _unique(cls, value: list[str]) -> list[str]:
        unknown = [m for m in value if m not in METHODS]
        if unknown:
            raise ValueError(f"unknown methods {unknown}; registered: {', '.join(METHODS)}")
        if len(set(value)) != len(value):
            raise ValueError(f"methods must not repeat, got {value}")
        return value

    @field_validator("clipper_k")
    @classmethod
    def _k(cls, value: list[int]) -> list[int]:
        if any(k < 2 for k in value) or len(set(value)) != len(value):
            raise ValueError(f"clipper_k must be distinct ints >= 2, got {value}")
        return sorted(value)

    @model_validator(mode="after")
    def _shown(self) -> MethodsConfig:
        if "clipper" in self.methods and self.clipper_k_shown not in self.clipper_k:
            raise ValueError(f"clipper_k_shown ({self.clipper_k_shown}) must be one of "
                             f"clipper_k {self.clipper_k}")
        return self
