"""Feature matching (survey section 2): brute force with Lowe's ratio test.

For each test descriptor the two closest reference descriptors are found (Hamming distance for binary, Euclidean
for real-valued descriptors); the closest is proposed as a match when its distance is below ``ratio`` times the
second closest (Lowe, IJCV 2004; the survey uses 0.7). ``cv2.batchDistance`` returns the two nearest neighbours of
all test descriptors as arrays, equal to ``cv2.BFMatcher.knnMatch`` without its per-match Python objects.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.errors import UnknownMethod

_NORMS = {"hamming": (cv2.NORM_HAMMING, cv2.CV_32S), "l2": (cv2.NORM_L2, cv2.CV_32F)}


def match_descriptors(test: np.ndarray, reference: np.ndarray, norm: str, ratio: float = 0.7) -> np.ndarray:
    """Ratio-test matches from ``test`` to ``reference`` descriptors.

    Returns an ``(M, 2)`` int array of (test index, reference index), in test order. With fewer than two
    reference descriptors the ratio test is undefined and no match is returned.
    """
    if norm not in _NORMS:
        raise UnknownMethod("norm", norm, _NORMS)
    if len(test) == 0 or len(reference) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    norm_type, dtype = _NORMS[norm]
    distances, indices = cv2.batchDistance(test, reference, dtype, normType=norm_type, K=2)
    distances = distances.astype(np.float64)
    keep = distances[:, 0] < ratio * distances[:, 1]
    test_idx = np.flatnonzero(keep)
    return np.column_stack([test_idx, indices[keep, 0]]).astype(np.int64)
