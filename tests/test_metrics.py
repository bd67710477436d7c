"""Tests of gtsweep.evaluation.metrics; every expected number is worked out by hand in a comment."""
import math

import numpy as np
import pytest

from gtsweep.core.errors import BadInput
from gtsweep.evaluation.metrics import (_max_centre_distance, circle_iou, correct_matches, correspondences,
                                        map_keypoints, matching_precision, pose_error, pose_success, repeatability,
                                        too_few_keypoints)


def grid(step=10, n=10, size=4.0):
    """Keypoints on a grid x, y in {5, 15, ..., 95} (for step 10, n 10), all of one size."""
    v = 5.0 + step * np.arange(n)
    x, y = np.meshgrid(v, v)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, size)])


def translation(tx, ty):
    return np.array([[1.0, 0, tx], [0, 1.0, ty], [0, 0, 1]])


def rotation_about(deg, cx, cy):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return translation(cx, cy) @ R @ translation(-cx, -cy)


# ------------------------------------------------------------------------------------------------ circle_iou
def test_iou_equal_circles_at_distance_one():
    # r = 1, d = 1: lens = 2·acos(1/2) − (1/2)·sqrt(3) = 2.0943951 − 0.8660254 = 1.2283697
    # union = 2π − 1.2283697 = 5.0548156, IoU = 1.2283697 / 5.0548156 = 0.2430098
    assert circle_iou([[0, 0, 2]], [[1, 0, 2]])[0] == pytest.approx(0.2430098, abs=1e-7)


def test_iou_containment_disjoint_identical():
    # containment: r = 2 around r = 1 (d = 0.5 <= 2 − 1): I = π, U = 4π, IoU = 1/4
    # disjoint (d = 3 > 1 + 1) and tangent (d = 2): IoU = 0; identical circles: IoU = 1
    a = np.array([[0, 0, 4], [0, 0, 2], [0, 0, 2], [7, 3, 5]], dtype=float)
    b = np.array([[0.5, 0, 2], [3, 0, 2], [0, 2, 2], [7, 3, 5]], dtype=float)
    np.testing.assert_allclose(circle_iou(a, b), [0.25, 0.0, 0.0, 1.0], atol=1e-12)


def test_iou_radius_two_near_threshold():
    # r = 2, d = 1: I = 2·4·acos(1/4) − ½·1·sqrt(16 − 1) = 10.544928 − 1.936492 = 8.608436,
    #   U = 8π − I = 16.524305, IoU = 0.520956
    # r = 2, d = 1.2: I = 8·acos(0.3) − 0.6·sqrt(16 − 1.44) = 10.128832 − 2.289454 = 7.839378,
    #   U = 17.293363, IoU = 0.453317
    got = circle_iou([[10, 10, 4], [10, 10, 4]], [[11, 10, 4], [11.2, 10, 4]])
    np.testing.assert_allclose(got, [0.520956, 0.453317], atol=1e-6)


def test_iou_is_symmetric():
    rng = np.random.default_rng(1)
    a = np.column_stack([rng.uniform(0, 5, (50, 2)), rng.uniform(1, 6, 50)])
    b = np.column_stack([rng.uniform(0, 5, (50, 2)), rng.uniform(1, 6, 50)])
    np.testing.assert_array_equal(circle_iou(a, b), circle_iou(b, a))


def test_centre_distance_bound_holds_for_all_radius_ratios():
    # Equal unit circles reach IoU 0.5 at d ≈ 0.5299 (2·acos(d/2) − (d/2)·sqrt(4 − d²) = 2π/3); +1 % → 0.5352.
    c = _max_centre_distance(0.5)
    assert c == pytest.approx(0.5352, abs=1e-4)
    # Claim used by the KD-tree search: at distance c·r_max no radius ratio gets IoU above 0.5 (nor t = 0.2, 0.8).
    for t in (0.2, 0.5, 0.8):
        rho = np.linspace(0.01, 1.0, 2000)
        big = np.column_stack([np.zeros_like(rho), np.zeros_like(rho), np.full_like(rho, 2.0)])
        small = np.column_stack([np.full_like(rho, _max_centre_distance(t)), np.zeros_like(rho), 2.0 * rho])
        assert circle_iou(big, small).max() <= t


# ------------------------------------------------------------------------------------------------ mapping
def test_map_keypoints_rotation_and_scale():
    # H = 90° rotation × 2 plus (10, 5): (1, 0) → (0·1 − 2·0 + 10, 2·1 + 0·0 + 5) = (10, 7);
    # det [[0, −2], [2, 0]] = 4 → size 3 · sqrt(4) = 6. Extra columns are ignored.
    H = np.array([[0, -2, 10], [2, 0, 5], [0, 0, 1.0]])
    np.testing.assert_allclose(map_keypoints([[1, 0, 3, 45, 0.1, 0, 0]], H), [[10, 7, 6]])


@pytest.mark.parametrize("threshold", [0.3, 0.5])
def test_correspondences_match_brute_force_with_varying_sizes(threshold):
    rng = np.random.default_rng(7)
    sizes = np.exp(rng.uniform(np.log(2), np.log(200), 400))
    ref = np.column_stack([rng.uniform(0, 300, (400, 2)), sizes])
    H = rotation_about(10, 150, 150) @ np.diag([1.1, 1.1, 1.0])
    # test keypoints: ref keypoints moved back by inv(H), jittered in place and size
    back = np.linalg.inv(H) @ np.column_stack([ref[:, :2], np.ones(400)]).T
    test = np.column_stack([back[:2].T + rng.normal(0, 2, (400, 2)), sizes / 1.1 * rng.uniform(0.7, 1.3, 400)])
    mapped = map_keypoints(test, H)
    iou = circle_iou(np.repeat(mapped, 400, axis=0), np.tile(ref, (400, 1))).reshape(400, 400)
    expected = np.argwhere(iou > threshold)  # row-major: sorted by test, then ref index
    got = correspondences(test, ref, H, iou_threshold=threshold)
    assert len(expected) > 300
    np.testing.assert_array_equal(got, expected)


# ------------------------------------------------------------------------------------------------ repeatability
def test_identical_sets_repeat_fully():
    # 100 keypoints on themselves: each has exactly one partner (neighbours are 10 px apart, IoU 0).
    kps = grid()
    r = repeatability(kps, kps, np.eye(3), ref_shape=(100, 100), test_shape=(100, 100))
    assert (r.repeatability, r.ambiguity, r.n_test, r.n_ref, r.n_repeated, r.n_correspondences) == (
        1.0, 1.0, 100, 100, 100, 100)
    assert r.as_dict()["n_test"] == 100


def test_tripled_reference_gives_ambiguity_three():
    # each test keypoint has 3 identical partners: 300 pairs / 100 repeated = 3
    kps = grid()
    r = repeatability(kps, np.concatenate([kps, kps, kps]), np.eye(3))
    assert (r.repeatability, r.ambiguity, r.n_ref, r.n_correspondences) == (1.0, 3.0, 300, 300)


def test_only_keypoints_in_both_masks_count():
    # test mask: columns 0..49 → test grid points x ∈ {5..45}: 5 columns × 10 rows = 50 counted, and only those
    # reference keypoints whose (identity-mapped) centre is in the test mask count: 50.
    # Removing the reference column x = 5 leaves 40 of the 50 test keypoints repeated → 0.8.
    kps = grid()
    test_mask = np.zeros((100, 100), np.uint8)
    test_mask[:, :50] = 1
    ref = kps[kps[:, 0] != 5]
    r = repeatability(kps, ref, np.eye(3), test_mask=test_mask, ref_mask=np.ones((100, 100), np.uint8))
    assert (r.n_test, r.n_ref, r.n_repeated, r.repeatability) == (50, 40, 40, 0.8)


def test_translation_maps_test_onto_reference():
    # H = shift (+30, 0). Test x ∈ {5..65} land on reference grid points x + 30 ∈ {35..95} inside the 100-wide
    # reference image (x + 30 ≤ 99.5): 7 columns × 10 = 70 counted, all repeated. Reference keypoints count when
    # x − 30 ≥ −0.5: x ∈ {35..95}, 70. With no H (identity) the grids would still overlap; shift +25 puts every
    # mapped test point 5 px from any reference point (IoU 0 for size 4) → repeatability 0.
    kps = grid()
    kw = dict(ref_shape=(100, 100), test_shape=(100, 100))
    r = repeatability(kps, kps, translation(30, 0), **kw)
    assert (r.n_test, r.n_ref, r.repeatability, r.ambiguity) == (70, 70, 1.0, 1.0)
    r = repeatability(kps, kps, translation(25, 0), **kw)
    assert (r.repeatability, r.n_repeated) == (0.0, 0)
    assert math.isnan(r.ambiguity)


def test_no_counted_test_keypoint_gives_zero():
    r = repeatability(np.zeros((0, 7)), grid(), np.eye(3))
    assert (r.repeatability, r.n_test, r.n_ref) == (0.0, 0, 100)
    assert math.isnan(r.ambiguity)


def test_bad_inputs_raise_one_line():
    with pytest.raises(BadInput, match="x, y, size"):
        repeatability(np.zeros((3, 2)), grid(), np.eye(3))
    with pytest.raises(BadInput, match="singular"):
        repeatability(grid(), grid(), np.zeros((3, 3)))
    with pytest.raises(BadInput, match="iou_threshold"):
        correspondences(grid(), grid(), np.eye(3), iou_threshold=1.0)
    with pytest.raises(BadInput, match="differs"):
        repeatability(grid(), grid(), np.eye(3), test_mask=np.ones((10, 10), np.uint8), test_shape=(20, 20))


def test_too_few_keypoints():
    # "< 100 KPs": 99 is too few, 100 is not
    assert too_few_keypoints(99) and not too_few_keypoints(100) and too_few_keypoints(4, n=5)


# ------------------------------------------------------------------------------------------------ matching
def test_correct_matches_and_precision():
    # H = identity, size 4 (r = 2). Match (0,0): identical → IoU 1, correct. (1,2): 10·√2 px apart → 0, wrong.
    # (2,3): d = 1 → IoU 0.520956 > 0.5, correct. (2,4): d = 1.2 → IoU 0.453317, wrong. Precision 2/4 = 0.5.
    test = np.array([[10, 10, 4], [20, 20, 4], [30, 30, 4.0]])
    ref = np.array([[10, 10, 4], [20, 20, 4], [30, 30, 4], [31, 30, 4], [31.2, 30, 4.0]])
    matches = np.array([[0, 0], [1, 2], [2, 3], [2, 4]])
    np.testing.assert_array_equal(correct_matches(test, ref, matches, np.eye(3)), [True, False, True, False])
    m = matching_precision(test, ref, matches, np.eye(3))
    assert (m.n_matches, m.n_correct, m.precision) == (4, 2, 0.5)
    # H = shift (−1, 0): (0,0) is now d = 1 → 0.520956, correct; (1,2) still far; (2,3): (29,30) vs (31,30),
    # d = 2, r = 2 → the d = 1, r = 1 case scaled by 2 → IoU 0.2430098, wrong; (2,4): d = 2.2, wrong → 1/4.
    assert matching_precision(test, ref, matches, translation(-1, 0)).precision == 0.25


def test_precision_without_matches_is_nan():
    m = matching_precision(grid(), grid(), np.zeros((0, 2), np.int64), np.eye(3))
    assert m.n_matches == 0 and math.isnan(m.precision)


def test_match_indices_are_checked():
    with pytest.raises(BadInput, match="out of range"):
        correct_matches(grid(), grid(), np.array([[0, 100]]), np.eye(3))


# ------------------------------------------------------------------------------------------------ pose
def test_pose_error_rotation_about_centre():
    # test_shape (101, 201): centre c = (100, 50). A 90° turn about c leaves c fixed → position 0, orientation 90.
    pos, ang = pose_error(rotation_about(90, 100, 50), np.eye(3), (101, 201))
    assert pos == pytest.approx(0.0, abs=1e-9) and ang == pytest.approx(90.0, abs=1e-9)


def test_pose_error_translation_and_wrap():
    # shift (3, 4) vs identity: |(3, 4)| = 5 px, 0°. Rotations +179° vs −179° (same centre) differ by 2°, not 358°.
    assert pose_error(translation(3, 4), np.eye(3), (10, 10)) == pytest.approx((5.0, 0.0))
    pos, ang = pose_error(rotation_about(179, 4.5, 4.5), rotation_about(-179, 4.5, 4.5), (10, 10))
    assert pos == pytest.approx(0.0, abs=1e-9) and ang == pytest.approx(2.0, abs=1e-9)
    assert pose_error(None, np.eye(3), (10, 10)) == (math.inf, math.inf)


def test_pose_success_edges():
    # strict bounds: 30 px and 1.5° themselves fail, just below passes; inf (no estimate) fails
    assert pose_success(29.999, 1.499)
    assert not pose_success(30.0, 0.0) and not pose_success(0.0, 1.5) and not pose_success(math.inf, math.inf)
    np.testing.assert_array_equal(pose_success(np.array([0.0, 31.0]), np.array([0.0, 0.0])), [True, False])
