"""Describe each image once per task: every transform strength that shares a reference image, every reference
count of survey Table 7 (for the test image) and every matcher/estimator reuse the same descriptors.

A memo keyed by the image's and the keypoints' content: only identical calls are shared. The descriptors of a
subset of keypoints are not cut from those of a larger set, because some extractors describe a keypoint
differently in a different set (OpenCV's SIFT builds its pyramid from the lowest octave among the keypoints it is
given; AKAZE and KAZE read ``class_id``).
"""
from __future__ import annotations

import hashlib

import numpy as np

from gtsweep.stages.applicability import describe_timed


def _digest(array: np.ndarray) -> bytes:
    array = np.ascontiguousarray(array)
    return hashlib.blake2b(array.view(np.uint8).reshape(-1), digest_size=16).digest() + str(array.shape).encode()


class _Seen:
    """An image the memo has described, its content digest computed only when another call could share it."""

    def __init__(self, image: np.ndarray):
        self.image, self._digest = image, None

    def digest(self) -> bytes:
        if self._digest is None:
            self._digest = _digest(self.image)
        return self._digest


class DescribeOnce:
    """A task's memo of described images: ``describe(image, keypoints, count)`` returns what
    ``describe_timed(image, keypoints[:count], ...)`` returns (kept keypoints, descriptors, seconds), calling the
    descriptor once per distinct (image, keypoints); ``seconds`` is the time of the call that computed them.
    ``foreign_scale``: where foreign keypoints are described (``experiment.foreign_scale``; None: ``own``).

    Calls are looked up by the keypoints' digest first; an image's content is hashed only when an earlier call
    had the same keypoints (then both images are compared by digest), so an image described once is never hashed.
    """

    def __init__(self, descriptor: str, detector: str, params: dict, foreign_scale: str | None = None):
        self.descriptor, self.detector, self.params = descriptor, detector, params
        self.foreign_scale = foreign_scale
        self._found: dict[bytes, list[tuple[_Seen, tuple]]] = {}
        self.computed = 0  # descriptor calls made (for tests and benchmarks)

    def describe(self, image: np.ndarray, keypoints: np.ndarray, count: int | None = None):
        chosen = np.asarray(keypoints) if count is None else np.asarray(keypoints)[:count]
        earlier = self._found.setdefault(_digest(chosen), [])
        seen = _Seen(image)
        for other, result in earlier:
            if other.digest() == seen.digest():
                return result
        result = describe_timed(image, chosen, self.descriptor, self.detector, self.foreign_scale, **self.params)
        earlier.append((seen, result))
        self.computed += 1
        return result
