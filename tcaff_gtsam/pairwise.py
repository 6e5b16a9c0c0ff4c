"""PairwiseAligner: FrameAligner + TCAFF for one directed robot pair."""

from __future__ import annotations

import math

import numpy as np

from .errors import ConfigError, DataError
from .frame_aligner import AlignmentMeasurement, FrameAligner
from .object_map import ObjectMap
from .params import FrameAlignerParams, TCAFFParams
from .tcaff import TCAFF, AlignmentEstimate

__all__ = ["PairwiseAligner"]


class PairwiseAligner:
    """Estimates T_oi_oj (robot j's odometry frame in robot i's) from the two robots' object
    maps, exchanged once per step (the paper uses 1 Hz).

    Attributes:
        aligner: the FrameAligner making candidate alignments.
        filter: the TCAFF filter choosing among them over time.
        measurements: the candidates of the latest step.
    """

    def __init__(self, aligner_params: FrameAlignerParams | None = None,
                 tcaff_params: TCAFFParams | None = None) -> None:
        tcaff_params = tcaff_params or TCAFFParams()
        if tcaff_params.dim != 3 or tcaff_params.angle_indices != (2,):
            raise ConfigError(f"PairwiseAligner needs TCAFFParams for (x, y, theta) states "
                              f"(d = 3, angle_indices = (2,)), got d = {tcaff_params.dim}, "
                              f"angle_indices = {tcaff_params.angle_indices}")
        self.aligner = FrameAligner(aligner_params)
        self.filter = TCAFF(tcaff_params)
        self.measurements: list[AlignmentMeasurement] = []
        self._last_time: float | None = None

    @classmethod
    def reference(cls) -> PairwiseAligner:
        """Both stages with the authors' released settings."""
        return cls(FrameAlignerParams.reference(), TCAFFParams.reference())

    def update(self, t: float, ego_map: ObjectMap, other_map: ObjectMap
               ) -> AlignmentEstimate | None:
        """One step: align the maps, filter the candidates.

        Args:
            t: seconds, the current time on the maps' `last_seen` clock; increasing.
            ego_map: robot i's map in its odometry frame; other_map: robot j's in its own.
        Returns:
            The TCAFF estimate of T_oi_oj, or None while no hypothesis has been accepted.
        Raises:
            DataError: t is not finite or not later than the previous step's.
        """
        if not math.isfinite(t):
            raise DataError(f"PairwiseAligner.update: t = {t} is not finite")
        if self._last_time is not None and t <= self._last_time:
            raise DataError(f"PairwiseAligner.update: t = {t} is not after the previous step's "
                            f"t = {self._last_time}")
        self._last_time = t
        self.measurements = self.aligner.measurements(ego_map, other_map, t)
        zs = np.array([m.z for m in self.measurements]).reshape(-1, 3)
        Rs = np.array([m.R for m in self.measurements]).reshape(-1, 3, 3)
        return self.filter.update(zs, Rs)
