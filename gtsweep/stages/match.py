"""Feature matching (survey section 2): brute force with Lowe's ratio test, optionally mutual.

For each test descriptor the two closest reference descriptors are found (Hamming distance for binary, Euclidean
for real-valued descriptors); the closest is proposed as a match when its distance is below ``ratio`` times the
second closest (Lowe, IJCV 2004; the survey uses 0.7). ``ratio >= 1`` switches the test off. ``mutual`` also
requires the test descriptor to be its reference's nearest neighbour (``cv2.BFMatcher``'s ``crossCheck``; with
the ratio test off, the mutual-nearest-neighbour matcher that learned features such as XFeat are built for).
``cv2.batchDistance`` returns the nearest neighbours of all descriptors as arrays, equal to
``cv2.BFMatcher.knnMatch`` without its per-match Python objects.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.core.errors import UnknownMethod

_NORMS = {"hamming": (cv2.NORM_HAMMING, cv2.CV_32S), "l2": (cv2.NORM_L2, cv2.CV_32F)}


def match_descriptors(test: np.ndarray, reference: np.ndarray, norm: str, ratio: float = 0.7,
                      mutual: bool = False) -> np.ndarray:
    """Matches from ``test`` to ``reference`` descriptors: ratio test (off when ``ratio >= 1``), optionally mutual.

    Returns an ``(M, 2)`` int array of (test index, reference index), in test order. The ratio test needs two
    reference descriptors: with fewer, it returns no match.
    """
    if norm not in _NORMS:
        raise UnknownMethod("norm", norm, _NORMS)
    use_ratio = ratio < 1.0
    if len(test) == 0 or len(reference) < (2 if use_ratio else 1):
        return np.zeros((0, 2), dtype=np.int64)
    norm_type, dtype = _NORMS[norm]
    distances, indices = cv2.batchDistance(test, reference, dtype, normType=norm_type, K=2 if use_ratio else 1)
    keep = np.ones(len(test), dtype=bool)
    if use_ratio:
        distances = distances.astype(np.float64)
        keep = distances[:, 0] < ratio * distances[:, 1]
    if mutual:
        _, backward = cv2.batchDistance(reference, test, dtype, normType=norm_type, K=1)
        keep &= backward[indices[:, 0], 0] == np.arange(len(test))
    test_idx = np.flatnonzero(keep)
    return np.column_stack([test_idx, indices[keep, 0]]).astype(np.int64)
