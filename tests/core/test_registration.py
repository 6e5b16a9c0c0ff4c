"""Tests for tcaff_gtsam.registration: size-gated associations and weighted Arun registration."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from tcaff_gtsam.association import putative_associations
from tcaff_gtsam.errors import ConfigError, DataError
from tcaff_gtsam.object_map import ObjectMap
from tcaff_gtsam.registration import arun_weights, registration_rmse, weighted_arun

PROPS = settings(max_examples=40, deadline=None)

seeds = st.integers(0, 2**32 - 1)
n_points = st.integers(3, 30)
translation = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)

# Well-spread anchor points written over the first rows of every random point set, so that no
# drawn set is degenerate (2D: a triangle; 3D: a triangle, then a tetrahedron when n >= 4).
ANCHORS = {
    2: np.array([[-5.0, -5.0], [5.0, -5.0], [0.0, 5.0]]),
    3: np.array([[-5.0, -5.0, 0.0], [5.0, -5.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.0, 5.0]]),
}


def make_points(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    pts = rng.uniform(-10.0, 10.0, (n, dim))
    k = min(n, len(ANCHORS[dim]))
    pts[:k] = ANCHORS[dim][:k]
    return rng.permutation(pts, axis=0)


def rigid(R: np.ndarray, t) -> np.ndarray:
    d = R.shape[0]
    T = np.eye(d + 1)
    T[:d, :d] = R
    T[:d, d] = t
    return T


def rot2(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def apply(T: np.ndarray, q: np.ndarray) -> np.ndarray:
    d = q.shape[1]
    return q @ T[:d, :d].T + T[:d, d]


def assert_proper_rigid(T: np.ndarray, d: int) -> None:
    assert T.shape == (d + 1, d + 1)
    R = T[:d, :d]
    np.testing.assert_allclose(R @ R.T, np.eye(d), atol=1e-10)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-10)
    np.testing.assert_array_equal(T[d], np.r_[np.zeros(d), 1.0])


def random_map(rng: np.random.Generator, n: int) -> ObjectMap:
    # Mix of small objects (abs-diff rule matters) and larger ones (ratio rule matters);
    # quantised sizes make exact ties (boundary cases) common.
    small = rng.random(n) < 0.3
    widths = np.where(small, rng.uniform(0.0, 0.3, n), rng.uniform(0.2, 4.0, n))
    heights = np.where(small, rng.uniform(0.0, 0.3, n), rng.uniform(0.2, 4.0, n))
    if rng.random() < 0.5:
        widths, heights = np.round(widths, 1), np.round(heights, 1)
    return ObjectMap(rng.uniform(-20, 20, (n, 3)), widths, heights, rng.uniform(0, 10, n))


def brute_force_pairs(ego: ObjectMap, other: ObjectMap, ratio: float, abs_diff: float):
    def similar(a: float, b: float) -> bool:
        return max(a, b) <= ratio * min(a, b) or abs(a - b) <= abs_diff

    pairs = []
    for i in range(len(ego)):
        for j in range(len(other)):
            if (similar(float(ego.widths[i]), float(other.widths[j]))
                    and similar(float(ego.heights[i]), float(other.heights[j]))):
                pairs.append((i, j))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


# ---------------------------------------------------------------------------------------------
# weighted_arun: recovery


@PROPS
@given(seeds, n_points, angle, translation, translation)
def test_weighted_arun_recovers_2d_transform(seed, n, theta, tx, ty):
    rng = np.random.default_rng(seed)
    T_true = rigid(rot2(theta), [tx, ty])
    q = make_points(rng, n, 2)
    p = apply(T_true, q)
    w = rng.uniform(0.05, 20.0, n)
    T = weighted_arun(p, q, w)
    assert T is not None
    assert_proper_rigid(T, 2)
    assert np.abs(T - T_true).max() < 1e-9
    assert registration_rmse(T, p, q) < 1e-9


@PROPS
@given(seeds, st.integers(2, 30), st.sampled_from([0.01, 0.5, 5.0]))
def test_weighted_arun_in_the_plane_is_the_weighted_least_squares_optimum(seed, n, noise):
    """On noisy, weighted pairs the planar closed form equals the SVD solution (Kabsch with the
    reflection fixed), which minimises the weighted squared residual over proper rotations."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-20, 20, (n, 2))
    p = apply(rigid(rot2(rng.uniform(-np.pi, np.pi)), rng.uniform(-5, 5, 2)), q)
    p = p + rng.normal(0.0, noise, p.shape)
    w = rng.uniform(0.0, 3.0, n)
    T = weighted_arun(p, q, w)
    if np.count_nonzero(w > 0) < 2:
        assert T is None
        return
    p_mean, q_mean = w @ p / w.sum(), w @ q / w.sum()
    U, _, Vt = np.linalg.svd(((q - q_mean) * w[:, None]).T @ (p - p_mean))
    D = np.diag([1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    assert T is not None
    assert_proper_rigid(T, 2)
    np.testing.assert_allclose(T[:2, :2], R, atol=1e-9)
    np.testing.assert_allclose(T[:2, 2], p_mean - R @ q_mean, atol=1e-8)


@PROPS
@given(seeds, n_points, st.tuples(angle, angle, angle), translation, translation, translation)
def test_weighted_arun_recovers_3d_transform(seed, n, rotvec, tx, ty, tz):
    rng = np.random.default_rng(seed)
    R = Rotation.from_rotvec(np.array(rotvec)).as_matrix()
    T_true = rigid(R, [tx, ty, tz])
    q = make_points(rng, n, 3)
    p = apply(T_true, q)
    w = rng.uniform(0.05, 20.0, n)
    T = weighted_arun(p, q, w)
    assert T is not None
    assert_proper_rigid(T, 3)
    assert np.abs(T - T_true).max() < 1e-9


@PROPS
@given(seeds, st.sampled_from([2, 3]))
def test_weighted_arun_default_weights_are_ones(seed, dim):
    rng = np.random.default_rng(seed)
    q = make_points(rng, 8, dim)
    R = rot2(rng.uniform(-np.pi, np.pi)) if dim == 2 else Rotation.random(
        random_state=rng).as_matrix()
    T_true = rigid(R, rng.uniform(-5, 5, dim))
    p = apply(T_true, q) + rng.normal(0, 0.05, q.shape)  # noisy: weights change the answer
    T_none = weighted_arun(p, q)
    T_ones = weighted_arun(p, q, np.ones(len(q)))
    np.testing.assert_allclose(T_none, T_ones, atol=1e-12)
    T_scaled = weighted_arun(p, q, np.full(len(q), 7.5))
    np.testing.assert_allclose(T_scaled, T_ones, atol=1e-10)


def test_weighted_arun_two_points_suffice_in_2d():
    T_true = rigid(rot2(0.7), [1.0, -2.0])
    q = np.array([[0.0, 0.0], [3.0, 1.0]])
    T = weighted_arun(apply(T_true, q), q)
    assert T is not None
    np.testing.assert_allclose(T, T_true, atol=1e-12)


def test_weighted_arun_planar_points_in_3d():
    # Coplanar (but not collinear) points determine a 3D rigid transform.
    rng = np.random.default_rng(5)
    q = np.c_[rng.uniform(-5, 5, (6, 2)), np.zeros(6)]
    T_true = rigid(Rotation.from_euler("xyz", [0.3, -0.8, 2.0]).as_matrix(), [1.0, 2.0, 3.0])
    T = weighted_arun(apply(T_true, q), q)
    assert T is not None
    np.testing.assert_allclose(T, T_true, atol=1e-10)


@PROPS
@given(seeds, st.integers(4, 30), st.sampled_from([2, 3]))
def test_weighted_arun_is_reflection_safe(seed, n, dim):
    rng = np.random.default_rng(seed)
    p = make_points(rng, n, dim)
    q = p.copy()
    q[:, 0] *= -1.0  # mirror image: the best orthogonal map is a reflection
    w = rng.uniform(0.1, 10.0, n)
    # Check the case really is one where the unconstrained SVD solution has det -1.
    wn = w / w.sum()
    H = ((q - wn @ q) * w[:, None]).T @ (p - wn @ p)
    U, _, Vt = np.linalg.svd(H)
    assert np.linalg.det(Vt.T @ U.T) < 0
    T = weighted_arun(p, q, w)
    assert T is not None
    assert_proper_rigid(T, dim)


def test_weighted_arun_mirror_gives_optimal_proper_rotation_2d():
    rng = np.random.default_rng(11)
    p = make_points(rng, 12, 2)
    q = p * np.array([-1.0, 1.0])
    w = rng.uniform(0.5, 2.0, 12)
    T = weighted_arun(p, q, w)
    assert T is not None
    assert_proper_rigid(T, 2)

    def cost(R):
        t = w @ p / w.sum() - R @ (w @ q / w.sum())
        return float(w @ np.sum((p - (q @ R.T + t)) ** 2, axis=1))

    best_grid = min(cost(rot2(a)) for a in np.linspace(-np.pi, np.pi, 7200, endpoint=False))
    got = float(w @ np.sum((p - apply(T, q)) ** 2, axis=1))
    assert got <= best_grid + 1e-9


@pytest.mark.parametrize("dim", [2, 3])
def test_weights_matter_for_an_outlier(dim):
    rng = np.random.default_rng(42 + dim)
    n = 20
    q = make_points(rng, n, dim)
    R = rot2(1.1) if dim == 2 else Rotation.from_euler("zyx", [1.1, 0.2, -0.4]).as_matrix()
    T_true = rigid(R, np.arange(1.0, dim + 1.0))
    p = apply(T_true, q)
    p[7] += 100.0  # gross outlier
    w = np.ones(n)
    T_equal = weighted_arun(p, q, w)
    assert np.abs(T_equal - T_true).max() > 0.1  # equal weights: the outlier drags it away
    w[7] = 1e-9
    T = weighted_arun(p, q, w)
    assert T is not None
    assert np.abs(T - T_true).max() < 1e-3
    w[7] = 0.0  # zero weight: the outlier is ignored entirely
    T = weighted_arun(p, q, w)
    assert np.abs(T - T_true).max() < 1e-9


# ---------------------------------------------------------------------------------------------
# weighted_arun: degenerate input and validation


@pytest.mark.parametrize("dim", [2, 3])
def test_weighted_arun_single_point_is_degenerate(dim):
    x = np.ones((1, dim))
    assert weighted_arun(x, x + 1.0) is None


def test_weighted_arun_no_points_is_degenerate():
    assert weighted_arun(np.zeros((0, 2)), np.zeros((0, 2))) is None


@pytest.mark.parametrize("dim", [2, 3])
def test_weighted_arun_coincident_points_are_degenerate(dim):
    q = np.tile(np.arange(1.0, dim + 1.0), (6, 1))
    p = q + 3.0
    assert weighted_arun(p, q) is None
    assert weighted_arun(p, q, np.linspace(0.1, 1.0, 6)) is None


def test_weighted_arun_collinear_points_are_degenerate_in_3d():
    s = np.linspace(-5.0, 5.0, 8)[:, None]
    q = np.array([1.0, 2.0, 3.0]) + s * np.array([0.3, -0.5, 0.8])
    p = apply(rigid(Rotation.from_euler("z", 0.5).as_matrix(), [1, 1, 1]), q)
    assert weighted_arun(p, q) is None
    # Two points in 3D are always collinear.
    assert weighted_arun(p[:2], q[:2]) is None


def test_weighted_arun_collinear_points_are_fine_in_2d():
    s = np.linspace(-5.0, 5.0, 8)[:, None]
    q = np.array([1.0, 2.0]) + s * np.array([0.6, -0.8])
    T_true = rigid(rot2(-2.0), [4.0, 5.0])
    T = weighted_arun(apply(T_true, q), q)
    assert T is not None
    np.testing.assert_allclose(T, T_true, atol=1e-10)


@pytest.mark.parametrize("dim", [2, 3])
def test_weighted_arun_zero_weights_are_degenerate(dim):
    rng = np.random.default_rng(dim)
    q = np.vstack([ANCHORS[dim][:3], rng.uniform(-10, 10, (3, dim))])
    T_true = rigid(np.eye(dim), np.full(dim, 2.0))
    p = apply(T_true, q)
    assert weighted_arun(p, q, np.zeros(6)) is None
    w = np.zeros(6)
    w[1] = 1.0  # a single point with positive weight
    assert weighted_arun(p, q, w) is None
    w[:3] = 1.0  # the three anchors, a non-degenerate triangle: enough in either dimension
    T = weighted_arun(p, q, w)
    assert T is not None
    np.testing.assert_allclose(T, T_true, atol=1e-12)


@pytest.mark.parametrize(
    ("p", "q"),
    [
        (np.zeros((5, 2)), np.zeros((4, 2))),
        (np.zeros((5, 2)), np.zeros((5, 3))),
        (np.zeros((5, 4)), np.zeros((5, 4))),
        (np.zeros((5, 1)), np.zeros((5, 1))),
        (np.zeros(6), np.zeros(6)),
        (np.zeros((2, 3, 2)), np.zeros((2, 3, 2))),
    ],
    ids=["rows", "dims", "dim4", "dim1", "flat", "3d-array"],
)
def test_weighted_arun_rejects_bad_shapes(p, q):
    with pytest.raises(DataError):
        weighted_arun(p, q)


@pytest.mark.parametrize("where", ["p", "q", "w"])
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_weighted_arun_rejects_non_finite(where, value):
    rng = np.random.default_rng(0)
    arrays = {"p": make_points(rng, 5, 3), "q": make_points(rng, 5, 3), "w": np.ones(5)}
    arrays[where][(1, 1) if where != "w" else 1] = value
    with pytest.raises(DataError, match="finite"):
        weighted_arun(arrays["p"], arrays["q"], arrays["w"])


def test_weighted_arun_rejects_negative_weights():
    q = make_points(np.random.default_rng(1), 5, 2)
    with pytest.raises(DataError, match=">= 0"):
        weighted_arun(q, q, np.array([1.0, 1.0, -0.5, 1.0, 1.0]))


@pytest.mark.parametrize("w", [np.ones(4), np.ones(6), np.ones((5, 1)), np.float64(1.0)])
def test_weighted_arun_rejects_bad_weight_shapes(w):
    q = make_points(np.random.default_rng(1), 5, 2)
    with pytest.raises(DataError, match="weights"):
        weighted_arun(q, q, w)


# ---------------------------------------------------------------------------------------------
# putative_associations


def test_putative_associations_hand_made():
    ego = ObjectMap(
        np.zeros((4, 3)),
        widths=[1.0, 0.05, 3.0, 1.2],
        heights=[2.0, 0.05, 1.0, 2.2],
        last_seen=np.zeros(4),
    )
    other = ObjectMap(
        np.zeros((7, 3)),
        #       0    1    2     3    4    5    6
        widths=[1.3, 1.4, 0.12, 3.9, 1.0, 2.5, 0.12],
        heights=[2.6, 2.0, 0.14, 1.2, 3.0, 1.3, 0.5],
        last_seen=np.zeros(7),
    )
    # ego 0 ~ other 0 by ratio (1.3, 1.3); ego 0 vs other 1: height fine, width 1.4 fails;
    # ego 0 vs other 4: width fine, height 1.5 fails. ego 1 ~ other 2 only through the
    # absolute-difference rule (ratios 2.4 and 2.8, differences 0.07 and 0.09); ego 1 vs
    # other 6: width passes by abs-diff, height fails both rules. ego 2 ~ others 3 and 5;
    # ego 3 ~ others 0 and 1; ego 3 vs other 4: height ratio 1.36 just fails.
    expected = np.array([[0, 0], [1, 2], [2, 3], [2, 5], [3, 0], [3, 1]])
    pairs = putative_associations(ego, other, ratio=1.35, abs_diff=0.1)
    assert pairs.dtype == np.int64
    assert pairs.shape == (6, 2)
    np.testing.assert_array_equal(pairs, expected)
    # Swapping the maps swaps the pairs.
    swapped = putative_associations(other, ego, ratio=1.35, abs_diff=0.1)
    expected_swapped = expected[:, ::-1][np.lexsort((expected[:, 0], expected[:, 1]))]
    np.testing.assert_array_equal(swapped, expected_swapped)


def test_putative_associations_defaults_and_boundaries():
    ego = ObjectMap(np.zeros((1, 3)), [2.0], [0.5], [0.0])
    # other 0: width ratio exactly 1.5 (difference 1 is too big) is kept; other 1 just over.
    # other 2: height difference exactly 0.25 (ratio 2 is too big) is kept; other 3 just over.
    other = ObjectMap(np.zeros((4, 3)), [3.0, 3.0 + 1e-9, 2.0, 2.0],
                      [0.5, 0.5, 0.25, 0.25 - 1e-9], np.zeros(4))
    pairs = putative_associations(ego, other, ratio=1.5, abs_diff=0.25)
    np.testing.assert_array_equal(pairs, [[0, 0], [0, 2]])
    # The defaults are ratio 1.35 and abs_diff 0.1.
    np.testing.assert_array_equal(putative_associations(ego, other),
                                  putative_associations(ego, other, ratio=1.35, abs_diff=0.1))
    np.testing.assert_array_equal(putative_associations(ego, other), np.zeros((0, 2)))


def test_putative_associations_ratio_one_and_zero_diff_means_equal_sizes():
    ego = ObjectMap(np.zeros((2, 3)), [1.0, 2.0], [1.0, 2.0], [0.0, 0.0])
    other = ObjectMap(np.zeros((3, 3)), [2.0, 1.0, 1.0], [2.0, 1.0, 1.5], np.zeros(3))
    pairs = putative_associations(ego, other, ratio=1.0, abs_diff=0.0)
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 0]])


@pytest.mark.parametrize(("n_ego", "n_other"), [(0, 5), (5, 0), (0, 0)])
def test_putative_associations_empty_maps(n_ego, n_other):
    rng = np.random.default_rng(0)
    ego = random_map(rng, n_ego) if n_ego else ObjectMap.empty()
    other = random_map(rng, n_other) if n_other else ObjectMap.empty()
    pairs = putative_associations(ego, other)
    assert pairs.shape == (0, 2)
    assert pairs.dtype == np.int64


def test_putative_associations_nothing_passes():
    ego = ObjectMap(np.zeros((2, 3)), [1.0, 1.0], [1.0, 1.0], [0.0, 0.0])
    other = ObjectMap(np.zeros((2, 3)), [5.0, 10.0], [5.0, 10.0], [0.0, 0.0])
    pairs = putative_associations(ego, other)
    assert pairs.shape == (0, 2)
    assert pairs.dtype == np.int64


@pytest.mark.parametrize(("ratio", "abs_diff", "name"), [
    (0.9, 0.1, "ratio"), (1.35, -0.01, "abs_diff"), ("1.35", 0.1, "ratio"),
    (None, 0.1, "ratio"), (float("nan"), 0.1, "ratio"), (1.35, [0.1], "abs_diff"),
    (True, 0.1, "ratio"),
])
def test_putative_associations_rejects_bad_gate_as_a_config_error(ratio, abs_diff, name):
    m = random_map(np.random.default_rng(0), 3)
    with pytest.raises(ConfigError, match=f"putative_associations.{name} = "):
        putative_associations(m, m, ratio=ratio, abs_diff=abs_diff)


@PROPS
@given(seeds, st.integers(0, 25), st.integers(0, 25),
       st.floats(1.0, 3.0, allow_nan=False), st.floats(0.0, 0.5, allow_nan=False))
def test_putative_associations_matches_brute_force(seed, n_ego, n_other, ratio, abs_diff):
    rng = np.random.default_rng(seed)
    ego, other = random_map(rng, n_ego), random_map(rng, n_other)
    pairs = putative_associations(ego, other, ratio=ratio, abs_diff=abs_diff)
    assert pairs.dtype == np.int64
    assert pairs.ndim == 2 and pairs.shape[1] == 2
    np.testing.assert_array_equal(pairs, brute_force_pairs(ego, other, ratio, abs_diff))
    if len(pairs):
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        np.testing.assert_array_equal(order, np.arange(len(pairs)))
        assert len(np.unique(pairs, axis=0)) == len(pairs)


@PROPS
@given(seeds, st.integers(1, 20))
def test_putative_associations_default_gate_matches_brute_force(seed, n):
    rng = np.random.default_rng(seed)
    ego, other = random_map(rng, n), random_map(rng, n + 3)
    np.testing.assert_array_equal(putative_associations(ego, other),
                                  brute_force_pairs(ego, other, 1.35, 0.1))


# ---------------------------------------------------------------------------------------------
# arun_weights / registration_rmse


@PROPS
@given(seeds, st.integers(0, 30))
def test_arun_weights_formula(seed, n):
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(0.0, 50.0, n), rng.uniform(0.0, 50.0, n)
    w = arun_weights(a, b)
    assert w.shape == (n,)
    np.testing.assert_allclose(w, 1.0 / (0.01 + a * b), rtol=1e-15)
    np.testing.assert_allclose(arun_weights(a, b, offset=0.5), 1.0 / (0.5 + a * b),
                               rtol=1e-15)
    assert np.all(w > 0)


def test_arun_weights_of_ages_whose_product_overflows_are_zero_without_a_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w = arun_weights(np.array([1e200, 2.0]), np.array([1e200, 3.0]))
    np.testing.assert_array_equal(w, [0.0, 1.0 / 6.01])


def test_arun_weights_known_values():
    w = arun_weights([0.0, 1.0, 2.0, 0.0], [5.0, 1.0, 3.0, 0.0])
    np.testing.assert_allclose(w, [100.0, 1.0 / 1.01, 1.0 / 6.01, 100.0])
    assert arun_weights([1.0], [1.0])[0] > arun_weights([2.0], [2.0])[0]  # older -> lighter
    np.testing.assert_allclose(arun_weights([[1.0, 2.0]], [[3.0, 4.0]]),
                               [[1 / 3.01, 1 / 8.01]])


@PROPS
@given(seeds, st.sampled_from([2, 3]), st.integers(1, 20))
def test_registration_rmse_of_exact_transform_is_zero(seed, dim, n):
    rng = np.random.default_rng(seed)
    R = rot2(rng.uniform(-np.pi, np.pi)) if dim == 2 else Rotation.random(
        random_state=rng).as_matrix()
    T = rigid(R, rng.uniform(-50, 50, dim))
    q = rng.uniform(-10, 10, (n, dim))
    p = apply(T, q)
    assert registration_rmse(T, p, q) < 1e-9
    # Shifting every p by a vector of length 0.5 gives an RMSE of exactly that.
    shift = rng.normal(size=dim)
    shift *= 0.5 / np.linalg.norm(shift)
    assert registration_rmse(T, p + shift, q) == pytest.approx(0.5, abs=1e-9)


def test_registration_rmse_known_value():
    q = np.zeros((2, 2))
    p = np.array([[3.0, 4.0], [0.0, 0.0]])
    assert registration_rmse(np.eye(3), p, q) == pytest.approx(np.sqrt(25.0 / 2))
    T = rigid(rot2(np.pi / 2), [0.0, 0.0])
    assert registration_rmse(T, np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]])) < 1e-15


# ---------------------------------------------------------------------------------------------
# bad input: clear errors, not garbage


@pytest.mark.parametrize(("name", "value"), [
    ("ratio", float("nan")), ("ratio", np.float64("nan")), ("ratio", float("inf")),
    ("ratio", 1 + 0j), ("abs_diff", float("nan")), ("abs_diff", float("inf")),
    ("abs_diff", np.float32("nan")),
])
def test_putative_gate_must_be_finite(name, value):
    m = random_map(np.random.default_rng(0), 3)
    with pytest.raises(ConfigError, match=rf"^putative_associations\.{name} = .*: must be a "
                                          r"finite number >= "):
        putative_associations(m, m, **{name: value})


@pytest.mark.parametrize("which", ["ego", "other"])
@pytest.mark.parametrize("value", [None, "map", np.zeros((3, 3)), {"centroids": []}])
def test_putative_associations_need_object_maps(which, value):
    m = random_map(np.random.default_rng(0), 3)
    maps = {"ego": m, "other": m, which: value}
    with pytest.raises(DataError, match=rf"^putative_associations: {which} must be an "
                                        rf"ObjectMap, got {type(value).__name__}"):
        putative_associations(maps["ego"], maps["other"])


@pytest.mark.parametrize("scale", [1e10, 1e200, 1e300])
def test_weighted_arun_refuses_absurd_coordinates(scale):
    """1e200 m coordinates used to overflow into NaN (or an SVD that does not converge)."""
    rng = np.random.default_rng(0)
    q = make_points(rng, 6, 2) * scale
    with pytest.raises(DataError, match=r"^weighted_arun: coordinates must lie within 1e\+09 "
                                        r"metres of the origin, got one of magnitude"):
        weighted_arun(q + 1.0, q)


def test_weighted_arun_refuses_weights_that_overflow():
    q = make_points(np.random.default_rng(0), 6, 2)
    with pytest.raises(DataError, match=r"^weighted_arun: weights must be <= 1e\+100, got 1e\+3"):
        weighted_arun(q, q, np.full(6, 1e300))


@PROPS
@given(seeds, st.sampled_from([2, 3]),
       st.floats(-1e9, 1e9, allow_nan=False), st.floats(1e-3, 1e100, allow_nan=False))
def test_weighted_arun_is_finite_up_to_the_limits(seed, dim, offset, weight):
    """Within MAX_COORDINATE and MAX_WEIGHT every result is finite (or None)."""
    rng = np.random.default_rng(seed)
    q = np.clip(make_points(rng, 8, dim) + offset, -1e9, 1e9)
    p = np.clip(q[::-1] * 0.5 + offset, -1e9, 1e9)
    T = weighted_arun(p, q, rng.uniform(0.0, 1.0, 8) * weight)
    assert T is None or np.all(np.isfinite(T))


@pytest.mark.parametrize(("p", "message"), [
    (np.ones((4, 2)) * (1 + 1j), "p must be real numbers"),
    ([["a", "b"]] * 4, "p must be real numbers"),
    (None, "p must be real numbers"),
])
def test_weighted_arun_refuses_what_is_not_real_numbers(p, message):
    with pytest.raises(DataError, match=f"^weighted_arun: {message}"):
        weighted_arun(p, np.zeros((4, 2)))


@pytest.mark.parametrize(("a", "b", "message"), [
    ([1.0, np.nan], [1.0, 1.0], "ages_ego must be finite numbers >= 0 seconds, got nan"),
    ([1.0, 1.0], [1.0, -2.0], "ages_other must be finite numbers >= 0 seconds, got -2.0"),
    ([np.inf, 1.0], [0.0, 1.0], "ages_ego must be finite numbers >= 0 seconds, got inf"),
    ([1.0, 2.0], [1.0], "ages_ego and ages_other must have the same shape"),
    ([1 + 1j], [1.0], "ages_ego must be real numbers"),
    ("soon", [1.0], "ages_ego must be real numbers"),
])
def test_arun_weights_refuse_bad_ages(a, b, message):
    with pytest.raises(DataError, match=f"^arun_weights: {message}"):
        arun_weights(a, b)


@pytest.mark.parametrize("offset", [0.0, -1.0, float("nan"), float("inf"), "0.01", None])
def test_arun_weight_offset_is_a_config_error(offset):
    with pytest.raises(ConfigError, match=r"^arun_weights\.offset = "):
        arun_weights([1.0], [1.0], offset)
