"""A NumPy SURF with the interface of OpenCV's ``cv2.xfeatures2d.SURF``.

SURF is Bay, Ess, Tuytelaars, Van Gool, "Speeded-Up Robust Features (SURF)", CVIU 110(3), 2008. This class
reproduces OpenCV's ``SURF_Impl::detectAndCompute`` (``opencv_contrib/modules/xfeatures2d/src/surf.cpp``,
Apache-2.0): detection (:mod:`gtsweep.stages.surf.hessian`), then orientation and descriptor
(:mod:`gtsweep.stages.surf.describe`), dropping keypoints OpenCV drops and keeping the rest in OpenCV's order.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.stages.keypoints import ANGLE, COLUMNS, SIZE, X, Y, to_array, to_keypoints
from gtsweep.stages.surf.describe import (UPRIGHT_ANGLE, descriptors_from_patches, keypoint_scale, orientations,
                                          patches, window_sizes)
from gtsweep.stages.surf.hessian import detect_keypoints, integral_image

F32 = np.float32


def _gray_image(image) -> np.ndarray:
    """The 8-bit single-channel image SURF works on (BGR or BGRA converted as OpenCV does)."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise BadInput(f"SURF needs an 8-bit image with 1, 3 or 4 channels, got {image.dtype} {image.shape}")
    if image.ndim == 3 and image.shape[2] > 1:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return np.ascontiguousarray(image.reshape(image.shape[:2]))


def _check_mask(mask, shape):
    """The mask as a uint8 array of the image's shape, or None."""
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.size == 0:
        return None
    if mask.dtype != np.uint8 or mask.shape != shape:
        raise BadInput(f"SURF mask must be uint8 of shape {shape}, got {mask.dtype} {mask.shape}")
    return mask


class NumpySURF:
    """SURF following OpenCV's implementation, usable where ``cv2.xfeatures2d.SURF`` is.

    Arguments are OpenCV's: ``hessianThreshold`` (det(H) threshold), ``nOctaves``, ``nOctaveLayers`` (middle
    layers per octave), ``extended`` (128-d descriptors), ``upright`` (no orientation; angle 270).
    Methods return tuples of ``cv2.KeyPoint`` and ``(N, 64|128)`` float32 descriptors (None when empty).
    Inputs OpenCV would assert on raise :class:`gtsweep.core.errors.BadInput`.
    """

    implementation = "gtsweep-numpy"

    def __init__(self, hessianThreshold=100, nOctaves=4, nOctaveLayers=3, extended=False, upright=False):
        self.setHessianThreshold(hessianThreshold)
        self.setNOctaves(nOctaves)
        self.setNOctaveLayers(nOctaveLayers)
        self.setExtended(extended)
        self.setUpright(upright)

    def __repr__(self):
        return (f"NumpySURF(hessianThreshold={self._threshold}, nOctaves={self._octaves}, "
                f"nOctaveLayers={self._layers}, extended={self._extended}, upright={self._upright})")

    # Parameters, with OpenCV's getter/setter names.
    def getHessianThreshold(self) -> float:
        return self._threshold

    def setHessianThreshold(self, value) -> None:
        if not value >= 0:
            raise BadInput(f"SURF hessianThreshold must be >= 0, got {value}")
        self._threshold = float(value)

    def getNOctaves(self) -> int:
        return self._octaves

    def setNOctaves(self, value) -> None:
        if int(value) <= 0:
            raise BadInput(f"SURF nOctaves must be > 0, got {value}")
        self._octaves = int(value)

    def getNOctaveLayers(self) -> int:
        return self._layers

    def setNOctaveLayers(self, value) -> None:
        if int(value) <= 0:
            raise BadInput(f"SURF nOctaveLayers must be > 0, got {value}")
        self._layers = int(value)

    def getExtended(self) -> bool:
        return self._extended

    def setExtended(self, value) -> None:
        self._extended = bool(value)

    def getUpright(self) -> bool:
        return self._upright

    def setUpright(self, value) -> None:
        self._upright = bool(value)

    def descriptorSize(self) -> int:
        return 128 if self._extended else 64

    def descriptorType(self) -> int:
        return cv2.CV_32F

    def defaultNorm(self) -> int:
        return cv2.NORM_L2

    def getDefaultName(self) -> str:
        return "Feature2D.SURF"

    def empty(self) -> bool:
        return True  # what OpenCV's Feature2D reports for SURF

    # Feature2D interface.
    def detect(self, image, mask=None):
        """Keypoints of ``image`` (detection mask optional), oriented unless upright."""
        keypoints, _ = self._run(image, mask, None, describe=False)
        return keypoints

    def compute(self, image, keypoints, descriptors=None):
        """Descriptors of given keypoints: ``(kept_keypoints, descriptors)``, rows aligned with the keypoints.

        Like OpenCV's, the orientation is recomputed (270 when upright) and keypoints that cannot be described
        (size <= 0, too large for the image, or no orientation sample inside the image) are dropped.
        """
        return self._run(image, None, to_array(keypoints), describe=True)

    def detectAndCompute(self, image, mask, descriptors=None, useProvidedKeypoints=False, *, keypoints=None):
        """``(keypoints, descriptors)``; with ``useProvidedKeypoints`` the ``keypoints`` given are described.

        (OpenCV's Python binding cannot pass keypoints in, so there ``useProvidedKeypoints=True`` describes none;
        the keyword ``keypoints`` is this class's extension.)
        """
        provided = to_array(keypoints if keypoints is not None else ()) if useProvidedKeypoints else None
        return self._run(image, mask, provided, describe=True)

    # The same on plain arrays: keypoints as (N, 7) float64 rows with the columns of gtsweep.stages.keypoints.
    def detect_array(self, image, mask=None) -> np.ndarray:
        """Like :meth:`detect`, keypoints as an ``(N, 7)`` array."""
        return self._arrays(image, mask, None, describe=False)[0]

    def compute_array(self, image, keypoints: np.ndarray):
        """Like :meth:`compute`, for an ``(N, 7)`` keypoint array: ``(kept_rows, descriptors or None)``."""
        return self._arrays(image, None, np.asarray(keypoints, np.float64).reshape(-1, len(COLUMNS)), True)

    def detect_and_compute_array(self, image, mask=None):
        """Like :meth:`detectAndCompute`: ``(keypoint rows, descriptors or None)``."""
        return self._arrays(image, mask, None, describe=True)

    def _run(self, image, mask, provided, describe):
        kps, desc = self._arrays(image, mask, provided, describe)
        return tuple(to_keypoints(kps)), desc

    def _arrays(self, image, mask, provided, describe):
        """Keypoint array and descriptors (None when not asked or empty), as ``SURF_Impl::detectAndCompute``."""
        image = np.asarray(image)
        if image.size == 0:
            return np.zeros((0, len(COLUMNS))), None
        gray = _gray_image(image)
        integral = integral_image(gray)
        if provided is None:
            kps = detect_keypoints(gray, integral, _check_mask(mask, gray.shape), self._threshold,
                                   self._octaves, self._layers)
        else:
            kps = provided.copy()
        if len(kps) == 0:
            return kps, None
        kps, keep = self._orient(integral, kps)
        if describe:  # a window of side int(21 s) = 0 is an assertion failure in OpenCV: drop such keypoints
            keep &= window_sizes(kps[:, SIZE]) >= 1
        kps = kps[keep]
        if not describe or len(kps) == 0:
            return kps, None
        x, y, size = kps[:, X].astype(F32), kps[:, Y].astype(F32), kps[:, SIZE].astype(F32)
        patch = patches(gray, x, y, kps[:, ANGLE].astype(F32), size, self._upright)
        return kps, descriptors_from_patches(patch, self._extended)

    def _orient(self, integral, kps):
        """Keypoints with their SURF angle set, and which of them OpenCV keeps."""
        size = kps[:, SIZE].astype(F32)
        wavelet = 2 * np.rint(F32(2) * keypoint_scale(size)).astype(np.int64)
        keep = (size > 0) & (wavelet <= min(integral.shape))
        kps = kps.copy()
        if self._upright:
            kps[:, ANGLE] = UPRIGHT_ANGLE
            return kps, keep
        angle, oriented = orientations(integral, kps[keep, X], kps[keep, Y], size[keep])
        kps[keep, ANGLE] = angle
        keep[keep] = oriented
        return kps, keep
