"""Describing once (gtsweep.evaluation.reuse): the same bytes as describing each keypoint set alone, one call each."""
import numpy as np
import pytest

from gtsweep.core.errors import NotApplicable
from gtsweep.evaluation.reuse import DescribeOnce
from gtsweep.stages.applicability import describe_timed
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.detect import detect_timed
from gtsweep.stages.select import select


def _texture() -> np.ndarray:
    rng = np.random.default_rng(4)
    noise = rng.normal(0, 1, (60, 80)).astype(np.float32)
    import cv2

    image = cv2.resize(noise, (320, 240), interpolation=cv2.INTER_CUBIC) + 0.3 * rng.normal(0, 1, (240, 320))
    return np.clip(128 + 40 * image, 0, 255).astype(np.uint8)


# every descriptor with a detector whose keypoints it describes (the survey's NA rules)
PAIRINGS = [("sift", "sift"), ("surf", "surf"), ("orb", "orb"), ("akaze", "akaze"), ("kaze", "kaze"),
            ("brisk", "brisk"), ("sift", "brief"), ("sift", "freak"), ("sift", "latch"), ("sift", "daisy"),
            ("sift", "beblid"), ("sift", "teblid"), ("xfeat", "xfeat"),
            *[pytest.param(name, name, marks=pytest.mark.slow) for name in ("aliked_n16", "aliked_n16rot", "disk")]]


@pytest.mark.parametrize("detector, descriptor", PAIRINGS)
def test_subsets_of_one_description_equal_describing_each_subset(detector, descriptor):
    assert {p.values[1] if hasattr(p, 'values') else p[1] for p in PAIRINGS} == set(DESCRIPTORS.names())
    image = _texture()
    found, _ = detect_timed(image, detector, None)
    keypoints = select(found, "nms", image.shape, n=300)
    params = descriptor_params({"params": {}}, detector)
    memo = DescribeOnce(descriptor, detector, params)
    try:
        for count in (None, 150, 40, 10):
            kept, descriptors, _ = memo.describe(image, keypoints, count)
            chosen = keypoints if count is None else keypoints[:count]
            alone_kept, alone_descriptors, _ = describe_timed(image, chosen, descriptor, detector, **params)
            assert np.array_equal(kept, alone_kept) and np.array_equal(descriptors, alone_descriptors)
            assert descriptors.dtype == alone_descriptors.dtype
    except NotApplicable as e:
        pytest.fail(f"{detector}-{descriptor} should apply: {e}")
    # one descriptor call per distinct keypoint set; equal content (another array) is found again
    assert memo.computed == 4
    memo.describe(image.copy(), keypoints.copy())
    memo.describe(image.copy(), keypoints.copy(), 40)
    assert memo.computed == 4


def test_the_same_keypoints_in_another_image_are_described_again_and_one_image_is_never_hashed(monkeypatch):
    import gtsweep.evaluation.reuse as reuse

    image = _texture()
    found, _ = detect_timed(image, "sift", None)
    keypoints = select(found, "nms", image.shape, n=100)
    memo = DescribeOnce("brief", "sift", descriptor_params({"params": {}}, "sift"))
    hashed = []
    real = reuse._digest
    monkeypatch.setattr(reuse, "_digest", lambda array: (hashed.append(array.shape), real(array))[1])
    memo.describe(image, keypoints)
    assert image.shape not in hashed  # described once: only the keypoints were hashed
    other = np.ascontiguousarray(image[:, ::-1])  # other pixels, the same keypoints
    _, descriptors, _ = memo.describe(other, keypoints)
    assert memo.computed == 2
    assert np.array_equal(descriptors, describe_timed(other, keypoints, "brief", "sift")[1])
    memo.describe(other.copy(), keypoints)  # equal pixels: found again
    assert memo.computed == 2
