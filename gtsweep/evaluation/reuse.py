"""Describe each image once per task: every transform strength that shares a reference image, every reference
count of survey Table 7 (for the test image) and every matcher/estimator reuse the same descriptors.

A memo keyed by the image's and the keypoints' content: only identical calls are shared. The descriptors of a
subset of keypoints are not cut from those of a larger set, because some extractors describe a keypoint
differently in a different set (OpenCV's SIFT builds its pyramid from the lowest octave among the keypoints it is
given; AKAZE and KAZE read ``class_id``).
"""
from __future__ import annotations

import hashlib
import weakref

import numpy as np

from gtsweep.core.errors import GtsweepError
from gtsweep.stages.applicability import applicability, describe_timed
from gtsweep.stages.describe import DESCRIPTORS, describe_batch


def _digest(array: np.ndarray) -> bytes:
    array = np.ascontiguousarray(array)
    return hashlib.blake2b(array.view(np.uint8).reshape(-1), digest_size=16).digest() + str(array.shape).encode()


class _Seen:
    """An image the memo has described, held weakly (the memo keeps no image alive); its content digest is
    computed only when another call could share its result, while the image still exists (else None)."""

    def __init__(self, image: np.ndarray):
        self._image, self._digest = weakref.ref(image), None

    def same(self, image: np.ndarray) -> bool:
        """The very array this memo saw (no hashing needed)."""
        return self._image() is image

    def digest(self) -> bytes | None:
        if self._digest is None:
            image = self._image()
            self._digest = None if image is None else _digest(image)
        return self._digest


class DescribeOnce:
    """A task's memo of described images: ``describe(image, keypoints, count)`` returns what
    ``describe_timed(image, keypoints[:count], ...)`` returns (kept keypoints, descriptors, seconds), calling the
    descriptor once per distinct (image, keypoints); ``seconds`` is the time of the call that computed them.
    ``foreign_scale``: where foreign keypoints are described (``experiment.foreign_scale``; None: ``own``).

    Calls are looked up by the keypoints' digest first; an image's content is hashed only when an earlier call
    had the same keypoints on another array (then both images are compared by digest), so an image described once
    is never hashed.
    An earlier image that no longer exists (a task's views hold theirs) cannot be compared: described again.
    Images are read, never changed in place (an image changed after its description would be compared as it is now).
    """

    def __init__(self, descriptor: str, detector: str, params: dict, foreign_scale: str | None = None,
                 dense=None):
        self.descriptor, self.detector, self.params = descriptor, detector, params
        self.foreign_scale, self.dense = foreign_scale, dense  # dense: see describe_timed
        self._found: dict[bytes, list[tuple[_Seen, tuple]]] = {}
        self.computed = 0  # descriptor calls made (for tests and benchmarks)

    def describe(self, image: np.ndarray, keypoints: np.ndarray, count: int | None = None):
        chosen = np.asarray(keypoints) if count is None else np.asarray(keypoints)[:count]
        earlier = self._found.setdefault(_digest(chosen), [])
        image = np.asarray(image)
        seen = _Seen(image)
        for other, result in earlier:
            if other.same(image):
                return result
            digest = other.digest()
            if digest is not None and digest == seen.digest():
                return result
        result = describe_timed(image, chosen, self.descriptor, self.detector, self.foreign_scale, dense=self.dense,
                                **self.params)
        earlier.append((seen, result))
        self.computed += 1
        return result

    def hold(self, image: np.ndarray, keypoints_digest: bytes, result: tuple) -> None:
        """Keep ``result``, computed elsewhere (:func:`describe_together`), as this memo's description of the
        keypoints whose :func:`_digest` is ``keypoints_digest`` in ``image``."""
        self._found.setdefault(keypoints_digest, []).append((_Seen(np.asarray(image)), result))


def describe_together(requests: list[tuple[str, list[tuple[np.ndarray, np.ndarray]]]], descriptor: str,
                      params: dict, foreign_scale: str | None = None, dense=None) -> list[DescribeOnce]:
    """A memo per member of ``requests`` (``[(detector, [(image, keypoints), ...]), ...]``; one detector may be
    several members, e.g. under two selectors) holding the descriptions it asks for, made with as few descriptor
    calls per image as a descriptor that describes keypoint sets ``together`` allows
    (:func:`gtsweep.stages.describe.describe_batch`; DAISY: one pass over the image for every member's keypoint
    sets and every reference count of survey Table 7; SIFT: one per first octave). Descriptors equal those of
    separate calls; each set's seconds are its share of the call. Images are matched by identity (the views of
    one task). Any other descriptor, a pairing the survey calls NA, or a batch that fails leaves the memos empty:
    they describe as before (and raise as before)."""
    memos = [DescribeOnce(descriptor, detector, params, foreign_scale, dense) for detector, _ in requests]
    if not DESCRIPTORS.get(descriptor).together:
        return memos
    images: dict[int, tuple[np.ndarray, dict]] = {}
    for member, (detector, asked) in enumerate(requests):
        if applicability(detector, descriptor) is not None:
            continue
        for image, keypoints in asked:
            chosen = np.asarray(keypoints)
            _, sets = images.setdefault(id(image), (image, {}))
            sets.setdefault((member, _digest(chosen)), chosen)
    for image, sets in images.values():
        try:
            results = describe_batch(image, [(requests[m][0], chosen) for (m, _), chosen in sets.items()],
                                     descriptor, foreign_scale, **params)
        except GtsweepError:
            continue
        for (member, digest), result in zip(sets, results):
            if result is not None:
                memos[member].hold(image, digest, result)
    return memos
