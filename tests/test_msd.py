"""gtsweep.stages.msd: the vectorised MSD (Tombari & Di Stefano, ACCV 2014) gives OpenCV's keypoints bit for bit,
and its saliency is the definition's (hand-worked and brute force), with either saliency: Numba's compiled loop
(gtsweep.stages.msd_compiled) and the NumPy path."""
import cv2
import numpy as np
import pytest
import skimage.data
import surf_digests

from gtsweep.stages import keypoints as kp
from gtsweep.stages import msd
from gtsweep.stages.detect import detect
from gtsweep.stages.msd import MSD_create, saliency, saliency_numpy
from gtsweep.stages.msd_compiled import compiled_kernel, saliency_compiled


@pytest.fixture(params=["compiled", "numpy"])
def kernel(request, monkeypatch):
    """Each saliency: Numba's compiled loop (skipped without Numba) and NumPy's."""
    if request.param == "numpy":
        monkeypatch.setattr(msd, "saliency_compiled", lambda *args: None)
    elif compiled_kernel(3, 5, 4) is None:
        pytest.skip("Numba is not installed (pip install gtsweep[fast])")
    return request.param


def _texture(shape=(240, 320), seed=0, sigma=1.0) -> np.ndarray:
    noise = np.random.default_rng(seed).random(shape) * 255
    return cv2.GaussianBlur(noise, (0, 0), sigma).astype(np.uint8)


def _opencv(image, mask=None, **params) -> np.ndarray:
    return kp.to_array(cv2.xfeatures2d.MSDDetector_create(**params).detect(image, mask))


def _brute_saliency(image, r_s, r_b, k):
    """The definition, pixel by pixel: mean over the patch of the k smallest patch SSDs in the search area."""
    img = image.astype(np.int64)
    rows, cols = img.shape
    border, out = r_s + r_b, np.zeros(img.shape, np.float32)
    for y in range(border, rows - border):
        for x in range(border, cols - border):
            patch = img[y - r_s:y + r_s + 1, x - r_s:x + r_s + 1]
            ssd = sorted(int(((img[y + dy - r_s:y + dy + r_s + 1, x + dx - r_s:x + dx + r_s + 1] - patch) ** 2).sum())
                         for dy in range(-r_b, r_b + 1) for dx in range(-r_b, r_b + 1) if (dy, dx) != (0, 0))
            out[y, x] = np.float32(sum(ssd[:k])) / np.float32((2 * r_s + 1) ** 2 * k)
    return out


def test_saliency_hand_worked(kernel):
    # one bright pixel (10) on black, 1x1 patches, 3x3 search area, k = 1: at the pixel every neighbour differs by
    # 10, so the smallest SSD is 100; next to it seven neighbours are black like itself, so 0
    image = np.zeros((7, 7), np.uint8)
    image[3, 3] = 10
    s = saliency(image, patch_radius=0, search_radius=1, knn=1)
    assert s[3, 3] == 100.0
    assert s[3, 2] == 0.0 and s[2, 2] == 0.0
    assert (s[0] == 0).all() and (s[:, -1] == 0).all()  # the border r_s + r_b is never scored
    # k = 2 at the pixel: (100 + 100) / (1 * 2)
    assert saliency(image, 0, 1, 2)[3, 3] == 100.0
    # no centre r_s + r_b inside the border: all 0
    assert saliency(np.full((2, 40), 9, np.uint8), 0, 1, 1).tolist() == np.zeros((2, 40)).tolist()


@pytest.mark.parametrize("r_s, r_b, k", [(3, 5, 4), (1, 2, 1), (2, 4, 3)])
def test_saliency_is_the_definition(r_s, r_b, k, kernel):
    image = _texture((26, 30), seed=r_s)
    np.testing.assert_array_equal(saliency(image, r_s, r_b, k), _brute_saliency(image, r_s, r_b, k))


@pytest.mark.parametrize("params", [
    {},  # OpenCV's defaults
    {"m_nms_radius": 2, "m_th_saliency": 67.81491332492301},  # the tuned survey setting
    {"m_nms_radius": 7, "m_th_saliency": 30.0, "m_kNN": 2, "m_patch_radius": 2, "m_search_area_radius": 4},
    {"m_scale_factor": 1.6, "m_n_scales": 4},
])
def test_keypoints_equal_opencv(params, kernel):
    image = _texture((240, 320))
    expected = _opencv(image, **params)
    assert len(expected) > 20
    np.testing.assert_array_equal(MSD_create(**params).detect_array(image), expected)
    np.testing.assert_array_equal(kp.to_array(MSD_create(**params).detect(image)), expected)


def test_keypoints_equal_opencv_on_a_texture_with_a_mask(kernel):
    image = cv2.resize(skimage.data.gravel(), (400, 300), interpolation=cv2.INTER_AREA)
    mask = np.zeros(image.shape, np.uint8)
    mask[40:250, 70:330] = 255
    params = {"m_nms_radius": 2, "m_th_saliency": 67.81491332492301}
    expected = _opencv(image, mask, **params)
    ours = MSD_create(**params).detect_array(image, mask)
    np.testing.assert_array_equal(ours, expected)
    assert len(ours) < len(MSD_create(**params).detect_array(image))  # the mask removed keypoints


def test_settings_outside_the_fast_path_are_opencvs():
    image = _texture((120, 160), seed=3)
    params = {"m_compute_orientation": True}
    np.testing.assert_array_equal(MSD_create(**params).detect_array(image), _opencv(image, **params))
    # msd.cpp's scale NMS indexes level k with level r's width (out of bounds: its count varies from call to call,
    # 119 or 121 here), so there is nothing to reproduce: OpenCV runs it
    assert not MSD_create(**params).fast and not MSD_create(m_nms_scale_radius=1).fast
    assert MSD_create().fast


def _mask_off_double_rounded_lines(shape, factor):
    """A mask zeroing the rows and columns where cvRound(j * pow(f, r)) in double and in float32 disagree."""
    mask = np.full(shape, 255, np.uint8)
    f = float(np.float32(factor))
    for r in range(1, 6):
        for j in range(max(shape)):
            exact, single = int(np.rint(j * f ** r)), int(np.rint(np.float32(j) * np.float32(f ** r)))
            if exact != single:
                mask[min(exact, shape[0] - 1), :] = 0
                mask[:, min(exact, shape[1] - 1)] = 0
    return mask


# Cases a review found where float32 NumPy arithmetic and OpenCV's (libm powf/logf, a double pow) part ways.
@pytest.mark.parametrize("shape, params, with_mask", [
    ((200, 947), {"m_scale_factor": 1.29, "m_th_saliency": 30.0}, False),  # level sizes: powf
    ((49, 60), {"m_scale_factor": 1.4, "m_search_area_radius": 9, "m_th_saliency": 30.0}, False),  # logf
    ((240, 320), {"m_scale_factor": 1.015, "m_n_scales": 16, "m_th_saliency": 30.0}, False),  # positions: powf
    ((240, 320), {"m_scale_factor": 1.1, "m_th_saliency": 30.0, "m_nms_radius": 1}, True),  # mask: double pow
    ((120, 160), {"m_patch_radius": 1, "m_search_area_radius": 1, "m_kNN": 10}, False),  # k > offsets: INT_MAX
    ((120, 160), {"m_search_area_radius": 0}, False),  # no offsets at all
    ((120, 160), {"m_nms_radius": -1, "m_th_saliency": 100.0}, False),  # no suppression
])
def test_keypoints_equal_opencv_where_the_arithmetic_is_subtle(shape, params, with_mask, kernel):
    image = _texture(shape, seed=1)
    mask = _mask_off_double_rounded_lines(shape, params["m_scale_factor"]) if with_mask else None
    expected = _opencv(image, mask, **params)
    assert len(expected) > 0
    np.testing.assert_array_equal(MSD_create(**params).detect_array(image, mask), expected)


def test_masks_msd_cpp_reads_otherwise_are_opencvs():
    image = _texture((120, 160), seed=2)
    wide = np.zeros(image.shape, np.int32)
    wide[20:100, 30:130] = 1  # msd.cpp reads a mask's raw bytes: an int32 mask is not what its values say
    np.testing.assert_array_equal(MSD_create().detect_array(image, wide), _opencv(image, wide))
    full = np.full(image.shape, 255, np.uint8)
    small = {"m_patch_radius": 1, "m_search_area_radius": 1}  # a refined point may leave the view: delegated
    assert not MSD_create(**small)._covered(image, full) and MSD_create(**small)._covered(image, None)


def test_a_view_smaller_than_the_search_area_has_no_keypoints():
    assert MSD_create().detect_array(_texture((12, 40))).shape == (0, len(kp.COLUMNS))
    assert MSD_create().detect(_texture((12, 40))) == []


def test_the_registry_detects_with_it():
    image = _texture((240, 320), seed=5)
    expected = _opencv(image, m_th_saliency=100.0)
    expected[:, kp.ANGLE] = -1.0  # MSD has no orientation
    np.testing.assert_array_equal(detect(image, "msd", m_th_saliency=100.0), expected)


# settings the other tests compile too (each setting is a compiled kernel, ~3 s the first time)
@pytest.mark.parametrize("r_s, r_b, k", [(3, 5, 4), (1, 1, 10), (3, 0, 4), (0, 1, 2)])
def test_compiled_saliency_is_the_numpy_saliency_at_survey_size(gravel_1288x964, r_s, r_b, k):
    # the whole 1288x964 level, every setting's code path: defaults (k = 4: the sorting network), k above the 8
    # offsets (INT_MAX), no offsets, one-pixel patches and another k (insertions)
    if compiled_kernel(r_s, r_b, k) is None:
        pytest.skip("Numba is not installed (pip install gtsweep[fast])")
    view = gravel_1288x964 if (r_s, r_b) == (3, 5) else gravel_1288x964[:300, :420]
    np.testing.assert_array_equal(saliency_compiled(view, r_s, r_b, k), saliency_numpy(view, r_s, r_b, k))


def test_saliency_of_other_images_is_numpys():
    image = _texture((30, 40)).astype(np.float32)  # the compiled loop takes uint8 only
    assert saliency_compiled(image, 3, 5, 4) is None
    np.testing.assert_array_equal(saliency(image), saliency_numpy(image))


@pytest.mark.slow
def test_a_survey_view_gives_opencvs_keypoints(monkeypatch):
    # One 1288x964 view of the survey data set (rendered in ~15 s, then cached), MSD's defaults and the tuned
    # setting, each saliency: ~4 s of OpenCV per setting
    view = surf_digests.survey_view()
    for params in ({}, {"m_nms_radius": 2, "m_th_saliency": 67.81491332492301}):
        expected = _opencv(view, **params)
        assert len(expected) > 1000
        np.testing.assert_array_equal(MSD_create(**params).detect_array(view), expected)
        with monkeypatch.context() as numpy_only:
            numpy_only.setattr(msd, "saliency_compiled", lambda *args: None)
            np.testing.assert_array_equal(MSD_create(**params).detect_array(view), expected)


def test_a_read_only_image_gives_the_same_keypoints(kernel):
    # Ray's object store hands images to its workers read-only; the compiled loop must take them too.
    image = _texture()
    frozen = image.copy()
    frozen.flags.writeable = False
    np.testing.assert_array_equal(detect(frozen, "msd"), detect(image, "msd"))
