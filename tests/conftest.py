"""Shared fixtures: real texture photographs that scikit-image ships (no download)."""
import cv2
import numpy as np
import pytest
import skimage.data


@pytest.fixture(scope="session")
def gravel_1288x964() -> np.ndarray:
    """scikit-image's gravel photograph upsampled to the survey's image size (1288 x 964)."""
    return cv2.resize(skimage.data.gravel(), (1288, 964), interpolation=cv2.INTER_CUBIC)


@pytest.fixture(scope="session")
def gravel_small() -> np.ndarray:
    """A 320 x 240 crop of the gravel photograph."""
    return np.ascontiguousarray(skimage.data.gravel()[100:340, 50:370])
