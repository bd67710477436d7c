"""Keypoint detection (survey section 2.1): a registry of detectors and one function to run them.

Each detector declares what it gives: an orientation, a response (else the detection order substitutes for it,
as the survey does for MSER, section 5.1), whether it honours a detection mask, and which of its parameters asks
it for a number of keypoints (the survey set that number to 1000 where a detector has one).
Adding a detector is one :class:`DetectorSpec` entry here and one YAML file in ``conf/detector/``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod
from gtsweep.stages import keypoints as kp

_x = cv2.xfeatures2d


def create_surf(**params):
    """SURF, imported on first use: OpenCV's when a nonfree build is installed, else gtsweep's NumPy port."""
    from gtsweep.stages.surf import SURF_create

    return SURF_create(**params)


def create_xfeat(**params):
    """XFeat, imported on first use: the learned feature, run by cv2.dnn."""
    from gtsweep.stages.xfeat import XFeat_create

    return XFeat_create(**params)


@dataclass(frozen=True)
class DetectorSpec:
    """What a detector is and what it gives."""

    name: str
    label: str  # as printed in the survey's tables
    create: Callable[..., object]
    orientation: bool
    response: bool = True
    mask: bool = True
    count_param: str | None = None  # parameter that asks the detector itself for N keypoints
    learned: bool = False


DETECTORS: dict[str, DetectorSpec] = {
    s.name: s
    for s in [
        DetectorSpec("harris", "Harris", lambda **p: cv2.GFTTDetector_create(useHarrisDetector=True, **p),
                     orientation=False, count_param="maxCorners"),
        DetectorSpec("gftt", "GFTT", cv2.GFTTDetector_create, orientation=False, count_param="maxCorners"),
        DetectorSpec("fast", "FAST", cv2.FastFeatureDetector_create, orientation=False),
        DetectorSpec("agast", "AGAST", _x.AgastFeatureDetector_create, orientation=False),
        # HarrisLaplace reports angle 0 for every keypoint: it has no orientation.
        DetectorSpec("harris_laplace", "HarrisLaplace", _x.HarrisLaplaceFeatureDetector_create, orientation=False,
                     count_param="maxCorners"),
        DetectorSpec("sift", "SIFT", cv2.SIFT_create, orientation=True, count_param="nfeatures"),
        DetectorSpec("surf", "SURF", create_surf, orientation=True),
        DetectorSpec("censure", "CenSurE", _x.StarDetector_create, orientation=False),
        DetectorSpec("brisk", "BRISK", _x.BRISK_create, orientation=True),
        DetectorSpec("orb", "ORB", cv2.ORB_create, orientation=True, count_param="nfeatures"),
        DetectorSpec("akaze", "AKAZE", _x.AKAZE_create, orientation=True),
        # KAZE computes orientations only when describing: its detect() reports angle 0.
        DetectorSpec("kaze", "KAZE", _x.KAZE_create, orientation=False),
        # MSER has no response: the detection order substitutes for it (first found = largest), as in the survey.
        DetectorSpec("mser", "MSER", cv2.MSER_create, orientation=False, response=False),
        DetectorSpec("msd", "MSD", _x.MSDDetector_create, orientation=False),
        DetectorSpec("xfeat", "XFeat", create_xfeat, orientation=False, learned=True, count_param="top_k"),
    ]
}


def get_detector(name: str) -> DetectorSpec:
    """The registry entry for ``name``; :class:`UnknownMethod` lists the valid names otherwise."""
    try:
        return DETECTORS[name]
    except KeyError:
        raise UnknownMethod("detector", name, DETECTORS) from None


def build_method(family: str, name: str, factory: Callable[..., object], params: dict):
    """``factory(**params)``; a method that is not installed or rejects its parameters is a one-line error."""
    try:
        return factory(**params)
    except ImportError as e:
        raise GtsweepError(f"{family} '{name}' is not available: {e}") from None
    except (TypeError, cv2.error) as e:
        raise BadInput(f"{family} '{name}' rejects its parameters {params}: {first_line(e)}") from None


def create_detector(name: str, **params):
    """An OpenCV-style detector object for ``name`` built with ``params`` (OpenCV's argument names)."""
    return build_method("detector", name, get_detector(name).create, params)


def detect(image: np.ndarray, name: str, mask: np.ndarray | None = None, **params) -> np.ndarray:
    """Detect keypoints in a uint8 gray ``image`` (optionally inside ``mask``) with detector ``name``.

    Returns an ``(N, 7)`` keypoint array (:mod:`gtsweep.stages.keypoints`) in detection order. Detectors without a
    response get ``response = N - i`` for the i-th keypoint found.
    """
    return detect_timed(image, name, mask, **params)[0]


def detect_timed(image: np.ndarray, name: str, mask: np.ndarray | None = None, **params) -> tuple[np.ndarray, float]:
    """:func:`detect` plus the wall time in seconds of the detector call itself."""
    spec = get_detector(name)
    _check_image(image)
    detector = create_detector(name, **params)
    if mask is not None and not spec.mask:
        raise GtsweepError(f"detector '{name}' does not accept a detection mask")
    start = time.perf_counter()
    try:
        found = detector.detect(image, mask)
    except cv2.error as e:
        raise GtsweepError(f"detector '{name}' failed: {first_line(e)}") from None
    seconds = time.perf_counter() - start
    array = kp.to_array(found)
    if not spec.response and len(array):
        array[:, kp.RESPONSE] = np.arange(len(array), 0, -1, dtype=np.float64)
    if not spec.orientation:
        array[:, kp.ANGLE] = -1.0
    return array, seconds


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise BadInput("images must be 2-D uint8 gray arrays")


def first_line(error: Exception) -> str:
    """The last non-empty line of an error message (OpenCV puts the reason there)."""
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(error).__name__
