"""Single-shot CLIPPER and ICP on centroids."""

from __future__ import annotations

import numpy as np
from tcaff_gtsam.eval.methods.baselines import CentroidICP, single_shot
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam.frame_aligner import FrameAligner
from tcaff_gtsam.geometry import se2_error, se2_from_params
from tcaff_gtsam.object_map import ObjectMap


def test_icp_reports_nothing_before_its_first_registration_then_tracks():
    pair = overlapping_maps(np.random.default_rng(0), 30, 0.8, 0.05)
    T_start = pair.T_oi_oj @ se2_from_params([0.3, -0.2, 0.03])  # a nearby start
    icp = CentroidICP(T_start, kappa=20.0, max_correspondence_distance=1.0,
                      min_correspondences=5, max_iterations=50)
    assert np.all(np.isnan(icp.update(pair.now, ObjectMap.empty(), pair.other)))
    x = icp.update(pair.now, pair.ego, pair.other)
    translation, heading = se2_error(pair.T_oi_oj, se2_from_params(x))
    assert translation < 0.1 and heading < np.radians(1.0)
    # too few objects later: the estimate is kept, not dropped
    np.testing.assert_allclose(icp.update(pair.now, ObjectMap.empty(), pair.other), x)


def test_single_shot_accepts_only_solutions_of_at_least_k_associations():
    pair = overlapping_maps(np.random.default_rng(1), 30, 0.6, 0.05)
    best = FrameAligner().measurements(pair.ego, pair.other, pair.now)[0]
    n = len(best.associations)
    np.testing.assert_allclose(single_shot(best, n), best.z)
    assert np.all(np.isnan(single_shot(best, n + 1)))
    assert np.all(np.isnan(single_shot(None, 3)))
