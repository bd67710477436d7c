"""LATCH (Levi & Hassner, WACV 2016; survey section 2.3) as OpenCV's xfeatures2d computes it, without its read
past the image.

OpenCV's LATCH drops keypoints closer than ``PATCH_SIZE / 2 + half_ssd_size`` (24 + K) pixels to the border,
judging each by its position rounded to the nearest integer, ties to even (``Rect::contains`` on a ``Point2f``),
but samples its mini-patches around the position rounded half up (``(int)(x + 0.5)``), up to 24 + K pixels away.
A keypoint whose coordinate is ``n + 0.5`` with ``n`` even, on the last kept column or row, so reads one column or
row past the image: memory that is not the image's, and its descriptor varies from call to call (one LATCH row of
Table 4 on survey views, HarrisLaplace keypoint at y = 936.5 in a 964-row view).

:class:`BorderSafeLATCH` gives OpenCV the image with one more column and row, reflected as OpenCV's own blur
continues the image (``BORDER_REFLECT_101``, so the blurred pixels of the image are unchanged), and the keypoints
OpenCV's border rule keeps on the image's own size. The same keypoints are described, every descriptor that read
only the image is OpenCV's bit for bit, and the few that read past it read the reflected column or row.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.stages import keypoints as kp

#: OpenCV's ``LATCHDescriptorExtractorImpl::PATCH_SIZE``: mini-patch centres lie within +-24 of the keypoint.
PATCH_SIZE = 48


def kept_by_border(keypoints: np.ndarray, shape, border: int) -> np.ndarray:
    """OpenCV's ``KeyPointsFilter::runByImageBorder``: which keypoints of an ``(N, 7)`` array (float32 values)
    lie at least ``border`` pixels inside an image of ``shape``, by their position rounded half to even."""
    height, width = shape[:2]
    if height <= 2 * border or width <= 2 * border:
        return np.zeros(len(keypoints), dtype=bool)
    x, y = np.rint(keypoints[:, kp.X]), np.rint(keypoints[:, kp.Y])
    return (x >= border) & (x < width - border) & (y >= border) & (y < height - border)


class BorderSafeLATCH:
    """OpenCV's LATCH (same parameters) described from the image and one reflected column and row beyond it:
    arrays in and out (``compute_array``), as gtsweep's own extractors."""

    def __init__(self, bytes: int = 32, rotationInvariance: bool = True, half_ssd_size: int = 3,  # noqa: A002
                 sigma: float = 2.0):
        self.latch = cv2.xfeatures2d.LATCH_create(bytes, rotationInvariance, half_ssd_size, sigma)
        self.border = PATCH_SIZE // 2 + half_ssd_size

    def compute_array(self, image: np.ndarray, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(kept keypoints, descriptors)`` of ``keypoints`` (float32 values, :func:`kp.float32_exact`)."""
        kept = keypoints[kept_by_border(keypoints, image.shape, self.border)]
        if len(kept) == 0:
            return kp.empty(), None
        padded = cv2.copyMakeBorder(image, 0, 1, 0, 1, cv2.BORDER_REFLECT_101)
        found, descriptors = self.latch.compute(padded, kp.to_keypoints(kept))
        return kp.to_array(found), descriptors

    def compute(self, image: np.ndarray, keypoints, descriptors=None):
        """OpenCV's ``compute``: ``cv2.KeyPoint`` objects in, ``(kept keypoints, descriptors)`` out."""
        kept, found = self.compute_array(image, kp.to_array(keypoints))
        return kp.to_keypoints(kept), found

    def descriptorSize(self) -> int:  # noqa: N802 (OpenCV's names)
        return self.latch.descriptorSize()

    def descriptorType(self) -> int:  # noqa: N802
        return self.latch.descriptorType()

    def defaultNorm(self) -> int:  # noqa: N802
        return self.latch.defaultNorm()


#: ``cv2.xfeatures2d.LATCH_create``'s name and signature (the registry's factory), as for MSD's port.
LATCH_create = BorderSafeLATCH
