"""Tests for gtsweep.evaluation.transforms (survey section 3: rotation, translation, Gaussian noise, gamma)."""
import numpy as np
import pytest
from skimage import data

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.evaluation.transforms import (STRENGTHS, TRANSFORMS, add_noise, adjust_gamma, gamma_table, rotate,
                                           synthesize, translate)


@pytest.fixture(scope="module")
def gravel():
    return data.gravel()[:240, :320].copy()  # 240 x 320 uint8 crop


def smooth_image(height=200, width=260) -> np.ndarray:
    """A slowly varying pattern (periods >= 40 px), so bicubic resampling is nearly exact."""
    ys, xs = np.mgrid[0:height, 0:width].astype(float)
    pattern = 128 + 60 * np.sin(xs / 9.0) * np.cos(ys / 11.0) + 40 * np.sin((xs + ys) / 15.0)
    return np.clip(np.rint(pattern), 0, 255).astype(np.uint8)


def masks_iou(a, b) -> float:
    a, b = a > 0, b > 0
    return np.sum(a & b) / np.sum(a | b)


def test_gamma_formula_on_known_values():
    table = gamma_table(2.0)
    # 255 * (128/255)^2 = 128^2 / 255 = 16384 / 255 = 64.25 -> 64
    assert table[128] == 64
    # 255 * (200/255)^2 = 40000 / 255 = 156.86 -> 157; 255 * (10/255)^2 = 0.39 -> 0
    assert table[200] == 157 and table[10] == 0
    # gamma 0.5: 255 * sqrt(64/255) = sqrt(64 * 255) = sqrt(16320) = 127.75 -> 128
    assert gamma_table(0.5)[64] == 128
    assert table[0] == 0 and table[255] == 255


def test_gamma_one_is_identity_and_masks_full(gravel):
    pair = adjust_gamma(gravel, 1.0)
    assert np.array_equal(pair.test, gravel)
    assert pair.reference_mask.min() == 255 and pair.test_mask.min() == 255
    assert np.array_equal(pair.H, np.eye(3))
    assert pair.test.dtype == np.uint8


def test_noise_is_deterministic_per_seed_and_has_asked_sigma():
    gray = np.full((200, 200), 128, np.uint8)
    first, again, other = add_noise(gray, 10.0, seed=1), add_noise(gray, 10.0, seed=1), add_noise(gray, 10.0, seed=2)
    assert first.test.tobytes() == again.test.tobytes()
    assert not np.array_equal(first.test, other.test)
    difference = first.test.astype(float) - 128
    # 40000 samples: the sample sd is within ~0.4 % of sigma; rounding adds 1/12 variance (sd 10.004)
    assert abs(difference.std() - 10.0) < 0.3
    assert abs(difference.mean()) < 0.2
    assert first.test_mask.min() == 255 and first.reference_mask.min() == 255


def test_noise_zero_sigma_is_identity(gravel):
    assert np.array_equal(add_noise(gravel, 0.0).test, gravel)


def test_noise_clips_to_valid_range():
    black = np.zeros((50, 50), np.uint8)
    test = add_noise(black, 30.0).test
    assert test.min() == 0 and test.dtype == np.uint8 and test.max() > 30


def test_rotation_by_zero_is_identity(gravel):
    pair = rotate(gravel, 0)
    assert np.array_equal(pair.test, gravel)
    assert np.array_equal(pair.H, np.eye(3))
    assert pair.test_mask.min() == 255


@pytest.mark.parametrize("angle", [30.0, 90.0, 137.0])
def test_rotation_H_maps_test_pixels_onto_matching_reference_intensities(angle):
    image = smooth_image()
    pair = rotate(image, angle)
    ys, xs = np.nonzero(pair.test_mask)
    ref = pair.H @ np.vstack([xs, ys, np.ones_like(xs)]).astype(float)
    # bilinear sample of the reference at the mapped (sub-pixel) positions
    rx, ry = ref[0], ref[1]
    x0, y0 = np.floor(rx).astype(int), np.floor(ry).astype(int)
    x1, y1 = np.minimum(x0 + 1, image.shape[1] - 1), np.minimum(y0 + 1, image.shape[0] - 1)
    fx, fy = rx - x0, ry - y0
    img = image.astype(float)
    sampled = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x1] * fx * (1 - fy)
               + img[y1, x0] * (1 - fx) * fy + img[y1, x1] * fx * fy)
    error = np.abs(sampled - pair.test[ys, xs].astype(float))
    assert error.mean() < 1.0 and error.max() < 6.0
    # a wrong direction (H inverted) would give errors of tens of gray levels on this pattern


def test_rotation_mask_excludes_black_corners_by_border():
    image = np.full((100, 140), 200, np.uint8)
    pair = rotate(image, 45.0, border=3)
    # inside the mask every pixel keeps the flat value (no black bleeding through the bicubic kernel)
    assert pair.test[pair.test_mask > 0].min() >= 199
    # the unmasked content shrinks with the border: border 0 keeps more pixels
    assert np.sum(rotate(image, 45.0, border=0).test_mask > 0) > np.sum(pair.test_mask > 0)
    assert pair.reference_mask.min() == 255


def test_rotation_by_90_on_square_image_is_exact_permutation():
    image = np.arange(64, dtype=np.uint8).reshape(8, 8)
    pair = rotate(image, 90.0, border=0)
    # counter-clockwise (OpenCV convention) = numpy rot90
    assert np.array_equal(pair.test, np.rot90(image))
    assert pair.test_mask.min() == 255


@pytest.mark.parametrize("iou", [0.2, 0.5, 0.8, 1.0])
def test_translation_masks_have_asked_iou(iou):
    image = np.zeros((964, 1288), np.uint8)
    pair = translate(image, iou)
    assert abs(masks_iou(pair.reference_mask, pair.test_mask) - iou) <= 0.01
    assert np.array_equal(pair.H, np.eye(3)) and np.array_equal(pair.test, image)
    # the test mask is the reference mask pushed to the lower right: its top-left corner is not above/left
    ref_top_left = np.argwhere(pair.reference_mask).min(axis=0)
    test_top_left = np.argwhere(pair.test_mask).min(axis=0)
    assert np.all(test_top_left >= ref_top_left)
    # each mask is 0.7 of each side: 0.7 * 964 = 674.8 -> 675 rows, 0.7 * 1288 = 901.6 -> 902 columns
    assert np.sum(pair.reference_mask > 0) == 675 * 902 == np.sum(pair.test_mask > 0)


def test_translation_pair_is_centred():
    pair = translate(np.zeros((100, 100), np.uint8), 0.5)
    union = np.argwhere((pair.reference_mask > 0) | (pair.test_mask > 0))
    low, high = union.min(axis=0), 99 - union.max(axis=0)
    assert np.all(np.abs(low - high) <= 1)


def test_translation_that_does_not_fit_raises():
    # IoU 0.1 with 0.7 masks needs 0.7 * (1 + 1 - sqrt(0.2 / 1.1)) = 1.10 of the image
    with pytest.raises(BadInput, match="does not fit"):
        translate(np.zeros((100, 100), np.uint8), 0.1)


def test_synthesize_dispatches_and_passes_seed(gravel):
    pair = synthesize("noise", gravel, 5.0, seed=3)
    assert pair.name == "noise" and pair.strength == 5.0
    assert np.array_equal(pair.test, add_noise(gravel, 5.0, seed=3).test)
    assert synthesize("rotation", gravel, 15.0, border=1).name == "rotation"


def test_strengths_cover_the_survey_ranges():
    assert set(STRENGTHS) == set(TRANSFORMS)
    assert (min(STRENGTHS["rotation"]), max(STRENGTHS["rotation"])) == (0, 180)
    assert (min(STRENGTHS["translation"]), max(STRENGTHS["translation"])) == (0.2, 1.0)
    assert (min(STRENGTHS["noise"]), max(STRENGTHS["noise"])) == (0, 40)
    assert (min(STRENGTHS["gamma"]), max(STRENGTHS["gamma"])) == (0.1, 3.0)
    assert all(6 <= len(values) <= 10 for values in STRENGTHS.values())


def test_unknown_transform_raises(gravel):
    with pytest.raises(UnknownMethod, match="unknown transform 'blur'"):
        synthesize("blur", gravel, 1.0)


@pytest.mark.parametrize(
    "call",
    [
        lambda g: adjust_gamma(g.astype(np.float32), 2.0),
        lambda g: adjust_gamma(np.dstack([g, g, g]), 2.0),
        lambda g: adjust_gamma(g, 0.0),
        lambda g: add_noise(g, -1.0),
        lambda g: translate(g, 1.5),
        lambda g: rotate(g, float("nan")),
        lambda g: synthesize("gamma", g, 2.0, border=3),
    ],
)
def test_bad_input_raises_one_line(gravel, call):
    with pytest.raises(BadInput) as info:
        call(gravel)
    assert "\n" not in str(info.value)
