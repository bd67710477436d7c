"""The NumPy SURF gives the same numbers bit for bit as the version whose output rows were committed.

The digests below were made by ``tests/surf_digests.py`` with the NumPy SURF as it was before its description was
restructured for speed. A change that moves any of them must bump ``IMPLEMENTATION_VERSION`` in
:mod:`gtsweep.stages.surf` (it enters the keypoint-cache and reuse keys) and re-pin them.
"""
import numpy as np
import pytest

import surf_digests
from gtsweep.orchestration.cache import library_versions
from gtsweep.stages.surf import IMPLEMENTATION_VERSION, NumpySURF, opencv_surf_available, windows

PINNED_VERSION = 1
CROPS = {
    "gravel/plain": "4cc04cf5f4262b0c",
    "gravel/extended": "46eaaf14a98b0899",
    "gravel/plain_upright": "862f38fcd90707de",
    "gravel/extended_upright": "f8d5841faf120c22",
    "gravel/foreign": "bb69210086226690",
    "brick/plain": "e2f0c3a9caa8c216",
    "brick/extended": "ad11d15f8e3da1bb",
    "brick/plain_upright": "c2ead869ced72b60",
    "brick/extended_upright": "759c7d873c40919b",
    "brick/foreign": "2cab45a6fe2b9f84",
}
SURVEY_VIEW = {
    "image": "ff843528a20d81c7",
    "view/plain": "69df496a1bd96b8d",
    "view/extended": "459e5b517d653650",
    "view/nms1000_surf": "676fd96efd845dd2",
    "view/nms1000_surf/rows": 1000,
    "view/nms1000_surf/first": [-0.0024495956022292376, 0.0013396787689998746, 0.0038789720274508,
                                0.0015629390254616737],
    "view/nms1000_sift": "3581bd4f7afdbdc1",
    "view/nms1000_sift/rows": 1000,
    "view/nms1000_sift/first": [0.012348996475338936, -0.00494666863232851, 0.014520030468702316,
                                0.005880917422473431],
}


def test_the_pinned_digests_belong_to_this_implementation_version():
    assert IMPLEMENTATION_VERSION == PINNED_VERSION


def test_the_first_version_leaves_todays_cache_keys_as_they_were():
    # Keys of committed rows hash library_versions(): version 1 must not change them; a later one must.
    if not opencv_surf_available():
        assert library_versions()["surf"] == "gtsweep-numpy"


@pytest.fixture(params=["compiled", "numpy"])
def sampler(request, monkeypatch):
    """Each way of sampling the descriptor windows: Numba's compiled loop (skipped without Numba) and NumPy's."""
    if request.param == "numpy":
        monkeypatch.setattr(windows, "compiled_loop", lambda: None)
    elif windows.compiled_loop() is None:
        pytest.skip("Numba is not installed (pip install gtsweep[fast])")
    return request.param


def test_reference_crops_give_the_pinned_output(sampler):
    with np.load(surf_digests.REFERENCE) as data:
        reference = {key: data[key] for key in data.files}
    assert surf_digests.crop_outputs(reference) == CROPS


@pytest.mark.slow
def test_a_survey_view_gives_the_pinned_output(sampler):
    # Renders one 1288x964 view of the survey data set (~15 s, then cached) and describes ~7300 keypoints.
    view = surf_digests.survey_view()
    assert view.shape == (964, 1288)
    assert surf_digests.view_outputs(view) == SURVEY_VIEW


def test_both_samplers_agree_on_windows_that_leave_the_image():
    # Windows around points near and beyond every border, at every angle: clamped samples included.
    if windows.compiled_loop() is None:
        pytest.skip("Numba is not installed (pip install gtsweep[fast])")
    rng = np.random.default_rng(5)
    gray = rng.integers(0, 256, (60, 80), dtype=np.uint8)
    n = 64
    x = rng.uniform(-20, 100, n).astype(np.float32)
    y = rng.uniform(-20, 80, n).astype(np.float32)
    angle = rng.uniform(0, 360, n).astype(np.float32)
    for win in (1, 7, 33):
        starts = windows.window_starts(x, y, angle, win)
        expected = windows.sample_numpy(gray, gray.astype(np.float32).ravel(), *starts, win)
        np.testing.assert_array_equal(windows.sample_compiled(gray, *starts, win), expected)


def test_a_read_only_image_is_described_as_a_writable_one(sampler):
    # Ray's object store hands images to its workers read-only; the compiled loop must take them too.
    with np.load(surf_digests.REFERENCE) as data:
        image = data["gravel_image"]
    frozen = image.copy()
    frozen.flags.writeable = False
    surf = NumpySURF()
    keypoints = surf.detect(image, None)
    assert len(keypoints) > 10
    _, expected = surf.compute(image, keypoints)
    _, found = surf.compute(frozen, keypoints)
    np.testing.assert_array_equal(found, expected)
