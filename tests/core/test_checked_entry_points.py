"""The checks of the public entry points name the function, the argument and the value; the
unchecked versions the library calls on its own arrays give the same results on valid input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tcaff_gtsam import DataError, FrameAlignerParams, InterRobotGraph, ObjectMap
from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.frame_aligner import MapMemory, confirms, residual_covariance
from tcaff_gtsam.geometry import (
    _se2_from_params,
    _se2_to_params,
    _wrap_angle,
    se2_from_params,
    se2_to_params,
    se3_from_xyz_yaw,
    transform_points_batch,
    wrap_angle,
)
from tcaff_gtsam.inputs import output_path, shown, write_whole
from tcaff_gtsam.pairwise import admitted, evidence_of
from tcaff_gtsam.registration import mutual_inliers, registration_rmse, spread

params3 = hnp.arrays(np.float64, st.sampled_from([(3,), (5, 3), (2, 4, 3)]),
                     elements=st.floats(-1e6, 1e6))


@settings(max_examples=50, deadline=None)
@given(params3)
def test_checked_geometry_equals_the_unchecked(p):
    T = se2_from_params(p)
    assert np.array_equal(T, _se2_from_params(p))
    assert np.array_equal(se2_to_params(T), _se2_to_params(T))
    assert np.array_equal(wrap_angle(p), _wrap_angle(p))


def test_nan_is_a_missing_pose_and_infinity_is_refused():
    p = np.array([[1.0, 2.0, 0.5], [np.nan, np.nan, np.nan]])
    T = se2_from_params(p)
    assert np.isfinite(T[0]).all() and np.isnan(T[1, :2]).all()
    assert math.isnan(wrap_angle(math.nan))
    with pytest.raises(DataError, match=r"se2_from_params: params must not be infinite"):
        se2_from_params([0.0, 0.0, math.inf])
    with pytest.raises(DataError, match=r"wrap_angle: angle must be real numbers"):
        wrap_angle(1j)
    with pytest.raises(DataError, match=r"se3_from_xyz_yaw: yaw must be a finite number, "
                                        r"got 'x'"):
        se3_from_xyz_yaw(0.0, 0.0, 0.0, "x")
    # NaN transforms are frames not known then: their points are NaN, the others mapped
    T = np.stack([np.eye(3), np.full((3, 3), np.nan)])
    out = transform_points_batch(T, np.ones((2, 2)))
    assert np.array_equal(out[0], [1.0, 1.0]) and np.isnan(out[1]).all()
    with pytest.raises(DataError, match="do not broadcast"):
        transform_points_batch(np.stack([np.eye(3)] * 2), np.ones((3, 2)))


def test_registration_checks_name_the_argument():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert registration_rmse(np.eye(3), p, p) == 0.0
    with pytest.raises(DataError, match=r"registration_rmse: q must be \(k, 2\) points"):
        registration_rmse(np.eye(3), p, p[:, :1])
    with pytest.raises(DataError, match=r"registration_rmse: T_a_b must be a finite \(3, 3\)"):
        registration_rmse(np.eye(4), p, p)
    with pytest.raises(DataError, match=r"spread: points\[0, 1\] = nan is not finite"):
        spread(np.array([[0.0, np.nan], [1.0, 1.0]]))
    # beyond MAX_COORDINATE the squares overflow: the spread came out NaN
    with pytest.raises(DataError, match=r"spread: points\[1, 0\] = 1e\+160 is beyond 1e\+09 m"):
        spread(np.array([[0.0, 0.0], [1e160, 1.0]]))
    with pytest.raises(DataError, match=r"mutual_inliers: compatible must be a \(3, 3\) bool"):
        mutual_inliers(np.eye(3), p, p, np.ones((3, 3)), 0.5)
    with pytest.raises(DataError, match="mutual_inliers: radius must be a finite number"):
        mutual_inliers(np.eye(3), p, p, np.ones((3, 3), bool), -1.0)
    with pytest.raises(DataError, match="residual_covariance: weights must be >= 0"):
        residual_covariance(np.eye(3), p, p, -np.ones(3), 0.05)


def test_aligner_helpers_check_types():
    prm = FrameAlignerParams()
    assert confirms(np.zeros(3), np.zeros(3), prm)
    assert not confirms(np.zeros(3), None, prm)
    with pytest.raises(DataError, match=r"confirms: held must be three finite numbers"):
        confirms(np.zeros(3), [0.0, math.nan, 0.0], prm)
    with pytest.raises(ConfigError, match=r"confirms\.params"):
        confirms(np.zeros(3), None, None)
    with pytest.raises(DataError, match="admitted: found must be a list of Alignment"):
        admitted([np.zeros(3)], None, prm)
    with pytest.raises(DataError, match="evidence_of: ids must be None or"):
        evidence_of([], np.arange(3))
    with pytest.raises(ConfigError, match=r"MapMemory\.of\.params"):
        MapMemory.of(None)
    assert MapMemory(10**400, 1.0).span == math.inf  # longer than any run: keep everything


def test_a_path_that_cannot_be_written_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match=r"ObjectMap\.save: path must be a str or a path"):
        ObjectMap.empty().save(None)
    with pytest.raises(DataError, match="is a folder, not a file"):
        ObjectMap.empty().save(tmp_path)
    with pytest.raises(DataError, match=r"write_g2o: the folder .* does not exist"):
        InterRobotGraph(2).write_g2o(tmp_path / "missing" / "g.g2o")
    assert output_path("x", str(tmp_path / "m.npz")) == tmp_path / "m.npz"
    with pytest.raises(DataError, match="shown: limit must be an int >= 4"):
        shown(1, None)


@given(st.text(max_size=50), st.text(min_size=1, max_size=50))
@settings(max_examples=50, deadline=None)
def test_a_file_is_written_whole_or_left_as_it_was(tmp_path_factory, old, new):
    """`write_whole` replaces a file by all of the new text (UTF-8, whatever the locale) or,
    when writing fails part way (a character no encoding writes), leaves the old one."""
    path = tmp_path_factory.mktemp("whole") / "results.json"
    write_whole(path, old)
    write_whole(path, new)
    assert path.read_bytes().decode("utf-8") == new
    with pytest.raises(UnicodeEncodeError):
        write_whole(path, new + "\ud800")  # a lone surrogate: written up to it, then refused
    assert path.read_bytes().decode("utf-8") == new
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # nothing left aside


def test_the_reason_of_a_foreign_error_is_its_first_line_or_its_kind():
    """What errors of ours quote of gtsam's, Zenoh's or rcl's: gtsam's start with a newline
    and run on over lines."""
    from tcaff_gtsam.errors import reason

    assert reason(RuntimeError("\nIndeterminate linear system detected while working near "
                               "variable\n1 (Symbol: a1).\n\nThrown when...")) == (
        "Indeterminate linear system detected while working near variable")
    assert reason(RuntimeError("")) == "RuntimeError"
    assert reason(OSError("  \n ")) == "OSError"
