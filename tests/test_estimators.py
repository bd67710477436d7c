"""The pose estimator registry (gtsweep.stages.pose.ESTIMATORS): every estimator recovers a known similarity from
exact correspondences with 40 % outliers, is reproducible per seed, and checks its parameters strictly."""
import math

import cv2
import numpy as np
import pytest

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.stages.pose import ESTIMATORS, estimate_pose, similarity_lstsq

CORNERS = np.array([[0, 0], [1287, 0], [0, 963], [1287, 963.0]])


def similarity(deg, scale, tx, ty):
    c, s = scale * math.cos(math.radians(deg)), scale * math.sin(math.radians(deg))
    return np.array([[c, -s, tx], [s, c, ty], [0, 0, 1.0]])


def exact_matches(T, n=200, outliers=0.4, seed=3):
    """n exact matches test→ref under T; a random 40 % of them replaced by uniform points (outliers)."""
    rng = np.random.default_rng(seed)
    test = rng.uniform(0, [1288, 964], (n, 2))
    ref = test @ T[:2, :2].T + T[:2, 2]
    wrong = np.zeros(n, bool)
    wrong[rng.choice(n, int(outliers * n), replace=False)] = True
    ref[wrong] = rng.uniform(0, [1288, 964], (wrong.sum(), 2))
    return test, ref, wrong


def apply(M, xy):
    return xy @ M[:2, :2].T + M[:2, 2]


@pytest.mark.parametrize("name", ["ransac", "cv_ransac", "cv_lmeds", "magsac"])
def test_every_estimator_recovers_a_known_similarity(name):
    T = similarity(23, 1.03, 40, -17)
    test, ref, wrong = exact_matches(T)
    estimate = ESTIMATORS.get(name).build().estimate(test, ref, seed=7)
    assert np.abs(apply(estimate.matrix, CORNERS) - apply(T, CORNERS)).max() < 0.01  # px, over the whole image
    assert math.degrees(math.atan2(estimate.matrix[1, 0], estimate.matrix[0, 0])) == pytest.approx(23, abs=0.01)
    assert estimate.matrix[2].tolist() == [0, 0, 1]
    assert (estimate.inliers == ~wrong).all() and estimate.n_inliers == (~wrong).sum()


@pytest.mark.parametrize("name", ["ransac", "cv_ransac", "cv_lmeds", "magsac"])
def test_same_seed_same_answer_and_too_few_points(name):
    test, ref, _ = exact_matches(similarity(-70, 0.9, 3, 5), outliers=0.45, seed=4)
    estimator = ESTIMATORS.get(name).build()
    first, again = estimator.estimate(test, ref, seed=1), estimator.estimate(test, ref, seed=1)
    assert np.array_equal(first.matrix, again.matrix) and np.array_equal(first.inliers, again.inliers)
    big = estimator.estimate(test, ref, seed=2**63 + 5)  # a view's seed (core.seeds.stable_seed) is 64-bit
    assert big.matrix is not None and big.n_inliers > 0
    none = estimator.estimate(test[:1], ref[:1], seed=0)
    assert none.matrix is None and none.n_inliers == 0 and none.inliers.shape == (1,)


def test_ransac_is_estimate_pose():
    test, ref, _ = exact_matches(similarity(10, 1.0, 1, 2), seed=5)
    built = ESTIMATORS.get("ransac").build({"model": "euclidean", "iterations": 50})
    expected = estimate_pose(test, ref, model="euclidean", iterations=50, threshold=3.0, seed=11)
    assert np.array_equal(built.estimate(test, ref, seed=11).matrix, expected.matrix)


def test_ransac_agrees_with_opencvs_ransac():
    # Cross-check on exact correspondences with 40 % outliers: the same inlier set, the same similarity.
    T = similarity(-35, 1.1, -60, 25)
    test, ref, wrong = exact_matches(T, seed=9)
    ours = ESTIMATORS.get("ransac").build().estimate(test, ref, seed=0)
    cv2.setRNGSeed(0)
    matrix, mask = cv2.estimateAffinePartial2D(test, ref, method=cv2.RANSAC, ransacReprojThreshold=3.0,
                                               maxIters=2000, confidence=0.99, refineIters=10)
    assert np.array_equal(ours.inliers, mask.ravel().astype(bool))
    # OpenCV's Levenberg-Marquardt stops at ~1e-5 px; ours is the exact least-squares fit
    assert np.abs(apply(ours.matrix, CORNERS) - apply(np.vstack([matrix, [0, 0, 1]]), CORNERS)).max() < 1e-3


def test_similarity_lstsq_by_hand():
    # a unit square turned by 90° and shifted by (2, 3): (0,0)->(2,3), (1,0)->(2,4), (0,1)->(1,3)
    test = np.array([[0, 0], [1, 0], [0, 1.0]])
    ref = np.array([[2, 3], [2, 4], [1, 3.0]])
    assert np.allclose(similarity_lstsq(test, ref), [[0, -1, 2], [1, 0, 3], [0, 0, 1]], atol=1e-12)
    assert similarity_lstsq(test[:1], ref[:1]) is None
    assert similarity_lstsq(np.zeros((3, 2)), ref) is None


def test_registry_params_are_strict_and_checked():
    assert ESTIMATORS.get("ransac").params() == {"model": "similarity", "iterations": 2000, "threshold": 3.0}
    assert ESTIMATORS.get("magsac").params()["confidence"] == 0.99
    with pytest.raises(BadInput, match="'cv_lmeds' has no parameter 'threshold'"):
        ESTIMATORS.get("cv_lmeds").params({"threshold": 2.0})
    with pytest.raises(BadInput, match="should be int"):
        ESTIMATORS.get("cv_ransac").params({"iterations": 2.5})
    with pytest.raises(BadInput, match="iterations must be an integer in \\[1, inf\\), got 0"):
        ESTIMATORS.get("ransac").check({"iterations": 0})
    with pytest.raises(BadInput, match="estimator 'cv_ransac' parameter confidence must be a number in \\(0, 1\\)"):
        ESTIMATORS.get("cv_ransac").check({"confidence": 1.0})
    with pytest.raises(BadInput, match="model must be one of similarity, euclidean, got 'affine'"):
        ESTIMATORS.get("ransac").check({"model": "affine"})
    with pytest.raises(UnknownMethod, match="valid choices: cv_lmeds, cv_ransac, magsac, ransac"):
        ESTIMATORS.get("lo_ransac")


@pytest.mark.parametrize("name", ["ransac", "cv_ransac", "cv_lmeds", "magsac"])
def test_degenerate_correspondences_give_no_estimate(name):
    # every test point at one place: no similarity maps it onto ten different reference points (OpenCV answers
    # such samples with a singular matrix, which the estimators report as no estimate)
    ref = np.random.default_rng(0).uniform(0, 100, (10, 2))
    estimator = ESTIMATORS.get(name).build()
    for test, reference in ((np.full((10, 2), 5.0), ref), (ref, np.full((10, 2), 5.0))):
        estimate = estimator.estimate(test, reference, seed=1)
        assert estimate.matrix is None and estimate.n_inliers == 0
