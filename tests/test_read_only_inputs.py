"""Every detector and descriptor takes a read-only image and gives what it gives for a writable one.

Ray's object store hands images to its workers read-only. A compiled loop declared for writable arrays only (SURF's
window sampler, MSD's saliency under Numba) then failed every cell of a Ray sweep while serial runs passed.
"""
import numpy as np
import pytest

from gtsweep.core.registry import availability
from gtsweep.stages.describe import DESCRIPTORS, describe
from gtsweep.stages.detect import DETECTORS, detect

RUNNABLE_DETECTORS = availability(DETECTORS)[0]
RUNNABLE_DESCRIPTORS = availability(DESCRIPTORS)[0]


def _image(shape=(192, 256), seed=3) -> np.ndarray:
    """A textured test image (smoothed noise with structure at several scales)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.normal(128, 60, shape).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 1.5) * 1.8 - 100, 0, 255).astype(np.uint8)


def _frozen(image: np.ndarray) -> np.ndarray:
    frozen = image.copy()
    frozen.flags.writeable = False
    return frozen


@pytest.mark.parametrize("name", RUNNABLE_DETECTORS)
def test_a_detector_takes_a_read_only_image(name):
    image = _image()
    np.testing.assert_array_equal(detect(_frozen(image), name)[:, :6], detect(image, name)[:, :6])


@pytest.mark.parametrize("name", RUNNABLE_DESCRIPTORS)
def test_a_descriptor_takes_a_read_only_image(name):
    image = _image()
    detector = name if name in RUNNABLE_DETECTORS else "sift"  # AKAZE and KAZE describe only their own keypoints
    keypoints = detect(image, detector)[:200]
    kept, descriptors = describe(image, keypoints, name, detector)
    kept_ro, descriptors_ro = describe(_frozen(image), keypoints, name, detector)
    np.testing.assert_array_equal(kept_ro, kept)
    np.testing.assert_array_equal(descriptors_ro, descriptors)
