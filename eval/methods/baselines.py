"""The methods TCAFF is compared with, and their runners: single-shot CLIPPER, ICP on object
centroids, and the ground truth.

- Single-shot CLIPPER (the paper's baseline): one standard CLIPPER solution per step, accepted
  as the alignment when it holds at least k associations, otherwise no alignment that step; its
  covariance is the aligner's R of that solution.
- ICP (Open3D, point to point) on the two maps' recent centroids, given the true alignment at
  the start and then started from its own previous estimate, as a local method must be. It
  reports nothing until its first registration with enough correspondences; after that, a step
  with too few keeps the previous estimate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tcaff_gtsam.frame_aligner import AlignmentMeasurement, FrameAligner
from tcaff_gtsam.geometry import se2_to_params, se2_to_se3, se3_to_se2
from tcaff_gtsam.object_map import ObjectMap

from ..config import MethodsConfig
from .stages import RunSetup, SharedStages

__all__ = ["CentroidICP", "ClipperRunner", "IcpRunner", "TruthRunner", "single_shot"]


def single_shot(solution: AlignmentMeasurement | None, k: int) -> np.ndarray:
    """(3,) the solution's (x, y, theta) if it has at least k associations, else NaN."""
    if solution is None or len(solution.associations) < k:
        return np.full(3, np.nan)
    return solution.z.copy()


class CentroidICP:
    """ICP between the other robot's recent centroids and the ego's, tracking T_oi_oj.

    Args:
        T_init: (3, 3) the alignment to start from (the truth at the first step).
        kappa: seconds; only objects seen within kappa take part.
        max_correspondence_distance: metres.
        min_correspondences: fewer correspondences leave the estimate unchanged.
        max_iterations: ICP iterations per step.
    """

    def __init__(self, T_init: np.ndarray, kappa: float, max_correspondence_distance: float,
                 min_correspondences: int, max_iterations: int) -> None:
        self.T = np.asarray(T_init, dtype=float).copy()
        self.registered = False
        self.kappa = kappa
        self.max_distance = max_correspondence_distance
        self.min_correspondences = min_correspondences
        # here, not at the top: the ground truth's and CLIPPER's runners share this module, and
        # a study without ICP spares its workers Open3D's import (1 s with the Dash it imports)
        import open3d as o3d

        self._o3d = o3d
        self.criteria = o3d.pipelines.registration.ICPConvergenceCriteria(
            max_iteration=max_iterations)
        self.estimation = o3d.pipelines.registration.TransformationEstimationPointToPoint()

    def update(self, t: float, ego: ObjectMap, other: ObjectMap) -> np.ndarray:
        """(3,) (x, y, theta) of the T_oi_oj estimate after one ICP step at time t; NaN before
        the first successful registration."""
        target = ego.recent(t, self.kappa).centroids
        source = other.recent(t, self.kappa).centroids
        if min(len(target), len(source)) >= self.min_correspondences:
            result = self._o3d.pipelines.registration.registration_icp(
                self._cloud(source), self._cloud(target), self.max_distance,
                se2_to_se3(self.T), self.estimation, self.criteria)
            if len(result.correspondence_set) >= self.min_correspondences:
                self.T = se3_to_se2(np.asarray(result.transformation))
                self.registered = True
        return se2_to_params(self.T) if self.registered else np.full(3, np.nan)

    def _cloud(self, points: np.ndarray):
        """An Open3D point cloud of (n, 3) points."""
        o3d = self._o3d
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.array(points, float)))


class ClipperRunner:
    """`clipper`: one single-shot CLIPPER solution per pair and step serves every threshold k
    of `clipper_k` (each stream is charged the whole time)."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        self.setup, self.ks = setup, methods.clipper_k
        # the TCAFF methods' aligner (size gate, CLIPPER, kappa), keeping one solution
        self.aligner = FrameAligner(replace(stages.aligner.params, n_solutions=1,
                                            min_associations=min(self.ks),
                                            sparse_associations=None, max_rmse=None))
        self.estimates = {f"clipper_k{k}": setup.empty() for k in self.ks}
        self.covariances = {f"clipper_k{k}": setup.empty_covariance() for k in self.ks}
        self.step_streams, self.finish_streams = list(self.estimates), []

    def step(self, s: int, t: float) -> None:
        for p in range(len(self.setup.pairs)):
            found = self.aligner.measurements(*self.setup.maps(p, s), t)
            best = found[0] if found else None
            for k in self.ks:
                stream = f"clipper_k{k}"
                self.estimates[stream][p, s] = single_shot(best, k)
                if best is not None and len(best.associations) >= k:
                    self.covariances[stream][p, s] = best.R

    def finish(self) -> None:
        pass


class IcpRunner:
    """`icp`: `CentroidICP` of every pair, started from the true alignment."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        icp, kappa = methods.icp, setup.run.settings.kappa
        self.setup = setup
        self.icps = [CentroidICP(setup.T_true[p][0], kappa, icp.max_correspondence_distance,
                                 icp.min_correspondences, icp.max_iterations)
                     for p in range(len(setup.pairs))]
        self.estimates = {"icp": setup.empty()}
        self.covariances: dict[str, np.ndarray] = {}  # ICP's fit reports none
        self.step_streams, self.finish_streams = ["icp"], []

    def step(self, s: int, t: float) -> None:
        for p, icp in enumerate(self.icps):
            self.estimates["icp"][p, s] = icp.update(t, *self.setup.maps(p, s))

    def finish(self) -> None:
        pass


class TruthRunner:
    """`ground_truth`: the true alignment, a check on the evaluation itself."""

    def __init__(self, setup: RunSetup, stages: SharedStages, methods: MethodsConfig) -> None:
        self.truth = setup.truth
        self.estimates = {"ground_truth": setup.empty()}
        self.covariances: dict[str, np.ndarray] = {}  # exact: no covariance to check
        self.step_streams, self.finish_streams = ["ground_truth"], []

    def step(self, s: int, t: float) -> None:
        self.estimates["ground_truth"][:, s] = self.truth[:, s]

    def finish(self) -> None:
        pass
