"""Tests for gtsweep.stages.surf: the NumPy SURF (Bay et al., CVIU 2008) against hand-worked values and OpenCV's own
SURF.

``tests/data/surf_reference.npz`` holds OpenCV's results (a nonfree build) on two 320x240 texture crops; it is
made by ``tools/make_surf_reference.py``.
"""
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from gtsweep.core.errors import BadInput
from gtsweep.stages.surf import NumpySURF, SURF_create, opencv_surf_available
from gtsweep.stages.surf.describe import _area_resize, descriptor_weights, orientation_samples, orientations
from gtsweep.stages.surf.hessian import (DXX_BOXES, box_response, integral_image, layer_det_and_trace, scale_boxes,
                                         solve_offsets)

REFERENCE = Path(__file__).parent / "data" / "surf_reference.npz"
IMAGES = ("gravel", "brick")


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as data:
        return {key: data[key] for key in data.files}


# --- building blocks, by hand ------------------------------------------------------------------------------------

def test_haar_boxes_scale_like_opencv():
    # Size 15: ratio 15/9 = 1.667; Dxx corners (0,2,3,7) -> round(0, 3.33, 5, 11.67) = (0, 3, 5, 12), and so on.
    # Each box is 5 x 9 = 45 pixels, so the weights are +1/45, -2/45, +1/45.
    corners, weights = scale_boxes(DXX_BOXES, 9, 15)
    assert corners.tolist() == [[0, 3, 5, 12], [5, 3, 10, 12], [10, 3, 15, 12]]
    np.testing.assert_allclose(weights, [1 / 45, -2 / 45, 1 / 45], rtol=1e-6)


def test_box_filter_responses_on_a_small_integral_image():
    # I(y, x) = x^2 + x*y on 12x12 (max 242). At origin (0, 0), size 9:
    #   Dxx boxes x in {0,1,2} | {3,4,5} | {6,7,8}, y in {2..6} (5 rows, area 15):
    #     x^2 part: 5*(0+1+4)/15 - 2*5*(9+16+25)/15 + 5*(36+49+64)/15 = (25 - 500 + 745)/15 = 18
    #     x*y part: (3 - 2*12 + 21) * (2+3+4+5+6) / 15 = 0
    #   Dyy: the x^2 part is constant along y, the x*y part linear in y -> 0.
    #   Dxy boxes x,y in {1,2,3} / {5,6,7} (area 9): x^2 cancels; x*y: (6*6 - 18*6 - 6*18 + 18*18)/9 = 144/9 = 16
    #   det = 18*0 - 0.81*16^2 = -207.36, trace = 18. Shifting the origin adds linear terms: same everywhere.
    y, x = np.mgrid[0:12, 0:12]
    image = (x ** 2 + x * y).astype(np.uint8)
    integral = integral_image(image)
    assert integral[12, 12] == image.sum()
    dxx = box_response(integral, *scale_boxes(DXX_BOXES, 9, 9), 0, 0)
    assert dxx == pytest.approx(18, rel=1e-6)
    det, trace = layer_det_and_trace(integral, 9, 1)
    # 1 + (12 - 9) = 4 samples per axis, placed after a margin of 9 // 2 = 4; the rest stays 0.
    # (float32 weights such as 1/15 leave a few 1e-6 of relative error)
    np.testing.assert_allclose(det[4:8, 4:8], -207.36, rtol=1e-5)
    np.testing.assert_allclose(trace[4:8, 4:8], 18, rtol=1e-5)
    assert not det[:4].any() and not det[:, :4].any()


def test_subsample_interpolation_finds_the_peak_of_a_quadratic():
    # f(x, y, s) = -((x - 0.25)^2 + (y + 0.5)^2 + (s - 0.1)^2) sampled at -1, 0, 1: one Newton step is exact.
    s, y, x = np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")
    f = -((x - 0.25) ** 2 + (y + 0.5) ** 2 + (s - 0.1) ** 2)
    n9 = f.reshape(1, 3, 9).astype(np.float32)
    np.testing.assert_allclose(solve_offsets(n9)[0], [0.25, -0.5, 0.1], atol=1e-6)
    assert not solve_offsets(np.zeros((1, 3, 9), np.float32)).any()  # singular: offset 0, rejected


def test_gaussian_weights():
    # Orientation: lattice points with x^2 + y^2 <= 36: 13 + 2*(11 + 11 + 11 + 9 + 7 + 1) = 113.
    # Taps of getGaussianKernel(13, 2.5): exp(-k^2 / 12.5) / S with S = 1 + 2*(e^-.08 + e^-.32 + e^-.72 + e^-1.28
    # + e^-2 + e^-2.88) = 6.211048, so the centre weight is (1/S)^2 = 0.0259218.
    offsets, weights = orientation_samples()
    assert len(offsets) == 113 and offsets[0].tolist() == [-6, 0]
    centre = weights[np.flatnonzero((offsets == 0).all(axis=1))[0]]
    assert centre == pytest.approx(1 / 6.211048 ** 2, rel=1e-5)
    # Descriptor: getGaussianKernel(20, 3.3) is centred at 9.5 but OpenCV's bit-exact kernel sets its two central
    # taps to exp(0) = 1 instead of exp(-0.5^2 / 21.78); so G[0] / G[9] = exp(-9.5^2 / 21.78) = 0.0158639 (not
    # the 0.016047 of a true Gaussian), and the weights are as OpenCV's because they come from the same call.
    dw = descriptor_weights()
    assert dw.shape == (20, 20) and dw.sum() == pytest.approx(1, rel=1e-5)
    assert dw[0, 9] / dw[9, 9] == pytest.approx(0.0158639, rel=1e-4)
    np.testing.assert_array_equal(dw, dw.T)


@pytest.mark.parametrize("direction", [0.0, 30.0, 90.0, 135.0, 250.0])
def test_orientation_of_a_synthetic_gradient(direction):
    # A ramp brightening along (cos d, sin d) in image coordinates (y down) gives angle d: the Haar x response is
    # positive, the y response (top minus bottom) is sin-negative, and the angle is fastAtan2(-sum_y, sum_x).
    y, x = np.mgrid[0:101, 0:101].astype(float)
    t = np.deg2rad(direction)
    image = np.clip(128 + 1.2 * ((x - 50) * np.cos(t) + (y - 50) * np.sin(t)), 0, 255).astype(np.uint8)
    angle, valid = orientations(integral_image(image), np.array([50.0]), np.array([50.0]), np.array([20.0]))
    assert valid[0]
    assert abs((angle[0] - direction + 180) % 360 - 180) < 0.5  # fastAtan2 is good to ~0.3 degrees


def test_area_resize_of_stacked_windows_equals_one_at_a_time():
    rng = np.random.default_rng(3)
    for side in (5, 19, 21, 25, 43, 64):
        windows = rng.integers(0, 256, (9, side, side), dtype=np.uint8)
        one_by_one = np.stack([cv2.resize(w, (21, 21), interpolation=cv2.INTER_AREA) for w in windows])
        np.testing.assert_array_equal(_area_resize(windows), one_by_one)


# --- invariances and interface ------------------------------------------------------------------------------------

def test_rotated_image_gives_rotated_keypoints_with_shifted_angles(reference):
    # cv2.ROTATE_90_CLOCKWISE maps pixel (x, y) to (H - 1 - y, x); SURF's filters and sampling grid are symmetric
    # under it, so every keypoint reappears at the mapped position, same size, angle + 90 degrees.
    image = reference["gravel_image"]
    surf = NumpySURF()
    before = surf.detect_array(image)
    after = surf.detect_array(cv2.rotate(image, cv2.ROTATE_90_CLOCKWISE))
    mapped = np.column_stack([image.shape[0] - 1 - before[:, 1], before[:, 0]])
    dist, nearest = cKDTree(after[:, :2]).query(mapped)
    assert len(after) == len(before) > 500
    assert np.all(dist < 0.01)
    np.testing.assert_array_equal(after[nearest, 2], before[:, 2])
    shift = (after[nearest, 3] - before[:, 3] - 90 + 180) % 360 - 180
    assert np.abs(shift).max() < 1.0


def test_factory_and_opencv_interface():
    ours = SURF_create(200, 3, 2, True, False, prefer_opencv=False)
    assert ours.implementation == "gtsweep-numpy"
    assert (ours.getHessianThreshold(), ours.getNOctaves(), ours.getNOctaveLayers()) == (200, 3, 2)
    assert ours.getExtended() and not ours.getUpright()
    assert (ours.descriptorSize(), ours.descriptorType(), ours.defaultNorm()) == (128, cv2.CV_32F, cv2.NORM_L2)
    ours.setExtended(False)
    ours.setUpright(True)
    assert ours.descriptorSize() == 64 and ours.getUpright()
    default = SURF_create()
    assert default.implementation == ("opencv" if opencv_surf_available() else "gtsweep-numpy")
    with pytest.raises(BadInput):
        NumpySURF(nOctaves=0)


def test_detect_compute_shapes_and_edge_cases(reference):
    image = reference["brick_image"]
    surf = NumpySURF()
    keypoints = surf.detect(image)
    assert isinstance(keypoints, tuple) and isinstance(keypoints[0], cv2.KeyPoint)
    kept, desc = surf.compute(image, keypoints[:50])
    assert len(kept) == 50 and desc.shape == (50, 64) and desc.dtype == np.float32
    rows, same = surf.compute_array(image, surf.detect_array(image)[:50])
    np.testing.assert_array_equal(same, desc)
    assert rows[:, 0].tolist() == [k.pt[0] for k in kept]
    np.testing.assert_allclose(np.linalg.norm(desc, axis=1), 1, rtol=1e-5)
    both, desc2 = surf.detectAndCompute(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), None)
    assert len(both) == len(keypoints)
    np.testing.assert_array_equal(desc2[:50], desc)  # deterministic, and BGR is converted like OpenCV
    assert surf.detectAndCompute(np.full((60, 80), 90, np.uint8), None) == ((), None)  # flat: no keypoint
    assert surf.compute(image, []) == ((), None)
    with pytest.raises(BadInput):
        surf.detect(image.astype(np.float32))


# --- agreement with OpenCV's own SURF -----------------------------------------------------------------------------

def match_by_position(ours: np.ndarray, theirs: np.ndarray):
    """Index of our keypoint nearest to each of OpenCV's, and the distance."""
    dist, index = cKDTree(ours[:, :2]).query(theirs[:, :2].astype(np.float64))
    return index, dist


def assert_same_keypoints(ours: np.ndarray, theirs: np.ndarray, angles=True):
    """The issue's tolerances: position 0.01 px, same size and class_id, response 1e-4 relative, angle 1 degree."""
    assert len(ours) == len(theirs)
    index, dist = match_by_position(ours, theirs)
    matched = ours[index]
    assert dist.max() < 0.01
    np.testing.assert_array_equal(matched[:, 2], theirs[:, 2])  # size
    np.testing.assert_array_equal(matched[:, 5:7], theirs[:, 5:7])  # octave, class_id
    np.testing.assert_allclose(matched[:, 4], theirs[:, 4], rtol=1e-4)  # response
    if angles:
        assert np.abs((matched[:, 3] - theirs[:, 3] + 180) % 360 - 180).max() <= 1.0
    return index


def cosines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cosine similarity; two all-zero rows (a featureless patch) count as identical."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    norms = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    both_zero = ~a.any(axis=1) & ~b.any(axis=1)
    return np.where(both_zero, 1.0, np.sum(a * b, axis=1) / np.where(norms > 0, norms, 1.0))


@pytest.mark.parametrize("name", IMAGES)
@pytest.mark.parametrize("upright", [False, True])
def test_keypoints_and_descriptors_match_opencv(reference, name, upright):
    tag = "_upright" if upright else ""
    image, theirs = reference[f"{name}_image"], reference[f"{name}_kp{tag}"]
    for extended in (False, True):
        surf = NumpySURF(extended=extended, upright=upright)
        ours, desc = surf.detect_and_compute_array(image)
        index = assert_same_keypoints(ours, theirs)
        expected = reference[f"{name}_desc{128 if extended else 64}{tag}"]
        assert cosines(desc[index[:len(expected)]], expected).min() >= 0.999


@pytest.mark.parametrize("name", IMAGES)
def test_mask_and_other_parameters_match_opencv(reference, name):
    image = reference[f"{name}_image"]
    mask = np.zeros(image.shape, np.uint8)
    cv2.circle(mask, (image.shape[1] // 2, image.shape[0] // 2), int(0.4 * min(image.shape)), 255, -1)
    assert_same_keypoints(NumpySURF().detect_array(image, mask), reference[f"{name}_kp_mask"])
    assert_same_keypoints(NumpySURF(400, 3, 2).detect_array(image), reference[f"{name}_kp_other"])


@pytest.mark.parametrize("name", IMAGES)
def test_compute_on_foreign_keypoints_matches_opencv(reference, name):
    # Random positions (some outside the image), sizes 0.5-120, any angle and octave: OpenCV recomputes the angle
    # and drops keypoints it cannot orient; the kept ones come back in order, aligned with the descriptor rows.
    image, given = reference[f"{name}_image"], reference[f"{name}_foreign_in"]
    keypoints = [cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o), int(c))
                 for x, y, s, a, r, o, c in given]
    kept, desc = NumpySURF().compute(image, keypoints)
    theirs = reference[f"{name}_foreign_kp"]
    ours = np.array([(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave, k.class_id) for k in kept])
    assert 0 < len(theirs) < len(given)
    np.testing.assert_array_equal(ours[:, [0, 1, 2, 5, 6]], theirs[:, [0, 1, 2, 5, 6]])
    assert np.abs((ours[:, 3] - theirs[:, 3] + 180) % 360 - 180).max() <= 1.0
    assert cosines(desc, reference[f"{name}_foreign_desc64"]).min() >= 0.999
