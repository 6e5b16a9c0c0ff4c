"""PairwiseAligner: object maps over time in, T_oi_oj out."""

from __future__ import annotations

import numpy as np
import pytest
from tcaff_gtsam.eval.sim.maps import overlapping_maps

from tcaff_gtsam import PairwiseAligner, TCAFFParams
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.geometry import se2_error, se2_from_params


def test_maps_over_time_give_the_true_alignment_after_the_window():
    T_true = se2_from_params([4.0, -7.0, 2.5])
    rng = np.random.default_rng(0)
    pair_aligner = PairwiseAligner()
    estimates = []
    for t in range(15):
        overlap = 0.5 if t % 5 else 0.0  # every fifth exchange shares no objects
        pair = overlapping_maps(rng, 30, overlap, 0.1, clutter=5, T_oi_oj=T_true, now=100.0 + t)
        estimates.append(pair_aligner.update(pair.now, pair.ego, pair.other))
    assert all(e is None for e in estimates[:8])
    assert estimates[-1] is not None
    dt, dtheta = se2_error(T_true, estimates[-1].T)
    assert dt < 0.3 and np.degrees(dtheta) < 2.0
    assert pair_aligner.measurements  # the latest step's candidates are kept


def test_time_must_increase_and_be_finite():
    pair = overlapping_maps(np.random.default_rng(1), 20, 0.5)
    aligner = PairwiseAligner()
    aligner.update(10.0, pair.ego, pair.other)
    with pytest.raises(DataError, match="not after"):
        aligner.update(10.0, pair.ego, pair.other)
    with pytest.raises(DataError, match="not finite"):
        aligner.update(float("nan"), pair.ego, pair.other)


def test_needs_an_se2_state():
    params = TCAFFParams(Q=np.eye(2) * 0.01, P0=np.eye(2), angle_indices=())
    with pytest.raises(ConfigError, match="d = 2"):
        PairwiseAligner(tcaff_params=params)


def test_reference_uses_both_released_presets():
    ref = PairwiseAligner.reference()
    assert ref.filter.params.cost_model == "reference"
    assert ref.aligner.params.max_rmse is None
