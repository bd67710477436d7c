"""Keypoints as plain arrays.

``cv2.KeyPoint`` does not pickle, so keypoints travel between processes (and into the cache) as an ``(N, 7)``
float64 array with the columns of :data:`COLUMNS`. ``angle`` is -1 where the detector gives no orientation
(OpenCV's convention). Every metric only needs the first three columns (x, y, size).
"""
from __future__ import annotations

import itertools
import operator
from typing import Sequence

import cv2
import numpy as np

COLUMNS = ("x", "y", "size", "angle", "response", "octave", "class_id")
X, Y, SIZE, ANGLE, RESPONSE, OCTAVE, CLASS_ID = range(len(COLUMNS))


def empty() -> np.ndarray:
    """An empty keypoint array."""
    return np.zeros((0, len(COLUMNS)), dtype=np.float64)


_ATTRIBUTES = operator.attrgetter("size", "angle", "response", "octave", "class_id")


def to_array(keypoints: Sequence[cv2.KeyPoint]) -> np.ndarray:
    """Convert OpenCV keypoints to an ``(N, 7)`` array (see :data:`COLUMNS`); positions come from OpenCV's own
    vectorised ``KeyPoint_convert``, the other attributes stream through one C-level ``map`` into ``fromiter``."""
    n = len(keypoints)
    if n == 0:
        return empty()
    array = np.empty((n, len(COLUMNS)), dtype=np.float64)
    array[:, [X, Y]] = cv2.KeyPoint_convert(keypoints)
    attributes = itertools.chain.from_iterable(map(_ATTRIBUTES, keypoints))
    array[:, SIZE:] = np.fromiter(attributes, dtype=np.float64, count=n * (len(COLUMNS) - SIZE)).reshape(n, -1)
    return array


def to_keypoints(array: np.ndarray) -> list[cv2.KeyPoint]:
    """Convert an ``(N, 7)`` array back to OpenCV keypoints (octave and class_id rounded to int)."""
    a = np.asarray(array, dtype=np.float64).reshape(-1, len(COLUMNS))
    if len(a) == 0:
        return []
    floats = a[:, :OCTAVE].T.tolist()
    ints = np.rint(a[:, OCTAVE:]).astype(np.int64).T.tolist()
    return list(map(cv2.KeyPoint, *floats, *ints))


def float32_exact(array: np.ndarray) -> np.ndarray:
    """The ``(N, 7)`` array as a round trip through ``cv2.KeyPoint`` leaves it: the float columns rounded to
    float32, octave and class_id to integers (what an extractor taking arrays must see to agree with OpenCV's)."""
    a = np.asarray(array, dtype=np.float64).reshape(-1, len(COLUMNS))
    return np.column_stack([a[:, :OCTAVE].astype(np.float32).astype(np.float64), np.rint(a[:, OCTAVE:])])


def sort_by_response(array: np.ndarray) -> np.ndarray:
    """Keypoints sorted by response, largest first; ties keep their detection order (stable)."""
    order = np.argsort(-array[:, RESPONSE], kind="stable")
    return array[order]


class UnorientedFloatFeature:
    """What every network feature (XFeat, ALIKED, DISK) shares as an OpenCV-style ``Feature2D``: keypoints of one
    fixed ``keypoint_size`` without orientation (angle -1, response = score) and float32 descriptors of
    :attr:`descriptor_size` compared with the L2 norm."""

    descriptor_size = 0

    def _keypoints(self, xy: np.ndarray, scores: np.ndarray) -> list[cv2.KeyPoint]:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        array = np.zeros((len(xy), len(COLUMNS)))
        array[:, [X, Y]], array[:, SIZE], array[:, ANGLE] = xy, self.keypoint_size, -1.0
        array[:, RESPONSE], array[:, CLASS_ID] = np.asarray(scores, dtype=np.float64).reshape(-1), -1
        return to_keypoints(array)

    def descriptorSize(self) -> int:  # noqa: N802 (OpenCV names)
        return self.descriptor_size

    def descriptorType(self) -> int:  # noqa: N802
        return cv2.CV_32F

    def defaultNorm(self) -> int:  # noqa: N802
        return cv2.NORM_L2
