"""Tests of gtsweep.stages.pose (RANSAC similarity / Euclidean estimation)."""
import math

import numpy as np
import pytest

from gtsweep.core.errors import UnknownMethod
from gtsweep.stages import pose
from gtsweep.stages.pose import estimate_pose


def similarity(deg, scale, tx, ty):
    c, s = scale * math.cos(math.radians(deg)), scale * math.sin(math.radians(deg))
    return np.array([[c, -s, tx], [s, c, ty], [0, 0, 1.0]])


def noisy_matches(T, n=200, outliers=0.4, sigma=0.5, seed=3):
    """n matches test→ref under T with Gaussian noise; the first `outliers` share replaced by random points."""
    rng = np.random.default_rng(seed)
    test = rng.uniform(0, [1288, 964], (n, 2))
    ref = test @ T[:2, :2].T + T[:2, 2] + rng.normal(0, sigma, (n, 2))
    n_out = int(outliers * n)
    ref[:n_out] = rng.uniform(0, [1288, 964], (n_out, 2))
    return test, ref, n_out


def test_recovers_known_similarity():
    # 23°, scale 1.03, shift (40, −17); 120 inliers with σ = 0.5 px → fit error ≈ 0.5/sqrt(120) px ≈ 0.05 px.
    T = similarity(23, 1.03, 40, -17)
    test, ref, n_out = noisy_matches(T)
    est = estimate_pose(test, ref)
    corners = np.array([[0, 0, 1], [1287, 0, 1], [0, 963, 1], [1287, 963, 1.0]]).T
    assert np.abs((est.matrix @ corners - T @ corners)[:2]).max() < 0.1
    assert math.degrees(math.atan2(est.matrix[1, 0], est.matrix[0, 0])) == pytest.approx(23, abs=0.05)
    # every true match is within 3 px (≈ 6σ) and the random outliers almost never are
    assert est.inliers[n_out:].all() and est.inliers[:n_out].sum() <= 2
    assert est.n_inliers == est.inliers.sum()


def test_euclidean_model_has_unit_scale():
    T = similarity(-40, 1.0, 5, 9)
    test, ref, _ = noisy_matches(T, seed=4)
    M = estimate_pose(test, ref, model="euclidean").matrix
    # rotation part is (cos θ, sin θ): scale 1 up to one rounding error
    assert math.hypot(M[0, 0], M[1, 0]) == pytest.approx(1.0, abs=1e-15)
    assert (M[0, 0], M[1, 0]) == (M[1, 1], -M[0, 1])
    assert math.degrees(math.atan2(M[1, 0], M[0, 0])) == pytest.approx(-40, abs=0.05)


def test_same_seed_same_bytes():
    test, ref, _ = noisy_matches(similarity(10, 0.98, 1, 2), outliers=0.6, seed=5)
    a, b = estimate_pose(test, ref, seed=11), estimate_pose(test, ref, seed=11)
    assert a.matrix.tobytes() == b.matrix.tobytes()
    np.testing.assert_array_equal(a.inliers, b.inliers)


def test_too_few_or_degenerate_matches_give_none():
    one = estimate_pose(np.array([[1.0, 2.0]]), np.array([[3.0, 4.0]]))
    assert one.matrix is None and one.n_inliers == 0 and one.inliers.shape == (1,)
    same = estimate_pose(np.ones((5, 2)), np.arange(10.0).reshape(5, 2))  # all test points coincide
    assert same.matrix is None
    assert estimate_pose(np.zeros((0, 2)), np.zeros((0, 2))).matrix is None


def test_unknown_model():
    with pytest.raises(UnknownMethod, match="pose model"):
        estimate_pose(np.zeros((3, 2)), np.zeros((3, 2)), model="affine")


def _direct_counts(a, b, zt, zr, threshold):
    """The definition: one reprojection error per hypothesis and match."""
    return np.count_nonzero(np.abs(a[:, None] * zt[None, :] + b[:, None] - zr[None, :]) < threshold, axis=1)


def test_matrix_product_scoring_equals_direct_errors_even_on_the_threshold():
    rng = np.random.default_rng(3)
    zt = rng.uniform(0, 1288, 300) + 1j * rng.uniform(0, 964, 300)
    a = np.exp(1j * rng.uniform(-np.pi, np.pi, 500)) * rng.uniform(0.9, 1.1, 500)
    b = rng.uniform(-500, 500, 500) + 1j * rng.uniform(-500, 500, 500)
    zr = a[0] * zt + b[0] + rng.normal(0, 2, 300) + 1j * rng.normal(0, 2, 300)
    # points exactly 3 px from hypothesis 1's prediction (not counted: error < 3 is strict), and a huge factor
    zr[:100] = a[1] * zt[:100] + b[1] + 3.0 * np.exp(1j * rng.uniform(0, 2 * np.pi, 100))
    a[2], b[2] = 1e9, 0.0
    counts = pose._inlier_counts(a, b, zt, zr, 3.0)
    np.testing.assert_array_equal(counts, _direct_counts(a, b, zt, zr, 3.0))
    assert counts[0] > 100 and 0 < counts[1] <= 100


@pytest.mark.parametrize("n", [3, 12, 40])
def test_repeated_sample_pairs_get_the_count_of_scoring_each_hypothesis(n):
    # few matches: 2000 samples repeat the n(n-1)/2 pairs, each scored once; the counts are those of all 2000
    test, ref, _ = noisy_matches(similarity(5, 1.0, 3, -2), n=n, outliers=0.3)
    zt, zr = test[:, 0] + 1j * test[:, 1], ref[:, 0] + 1j * ref[:, 1]
    rng = np.random.default_rng(8)
    first, second = rng.integers(n, size=2000), rng.integers(n - 1, size=2000)
    second += second >= first
    a = (zr[second] - zr[first]) / (zt[second] - zt[first])
    b = 0.5 * (zr[first] + zr[second]) - a * 0.5 * (zt[first] + zt[second])
    valid = np.ones(2000, dtype=bool)
    valid[::7] = False
    counts = pose._distinct_counts(first, second, valid, a, b, zt, zr, 3.0)
    assert np.array_equal(counts[valid], pose._inlier_counts(a[valid], b[valid], zt, zr, 3.0))
    assert (counts[~valid] == -1).all()
