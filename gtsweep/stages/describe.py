"""Feature description (survey section 2.3): a registry of descriptors, their norms and their requirements.

A pairing the survey could not evaluate (its NA cells, section 5.2) is reported by :func:`applicability` with the
reason, and :func:`describe` raises :class:`~gtsweep.core.errors.NotApplicable` for it — never a crash, never a silent
zero:

- the AKAZE descriptor needs AKAZE keypoints (it reads their nonlinear scale level from ``class_id``);
- DAISY needs keypoints with an orientation;
- the ORB descriptor needs keypoints on its own pyramid scales, which excludes SIFT (the survey's LIFT too; our
  learned stand-in XFeat gives fixed-size keypoints at octave 0, which ORB describes).

Foreign keypoints are normalised before description: their ``octave`` is reset to 0 (SIFT packs a large integer
there and MSD uses 0–14; OpenCV's ORB/SIFT would read it as a pyramid level and try to allocate ~68 GB), and
keypoints without an orientation are described upright (angle 0).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np

from gtsweep.core.errors import NotApplicable, UnknownMethod
from gtsweep.stages import keypoints as kp
from gtsweep.stages.detect import (
    build_method,
    create_surf,
    create_xfeat,
    first_line,
    get_detector,
)

_x = cv2.xfeatures2d
HAMMING, L2 = "hamming", "l2"


@dataclass(frozen=True)
class DescriptorSpec:
    """What a descriptor is, how its vectors are compared, and what keypoints it can describe."""

    name: str
    label: str  # as printed in the survey's tables
    create: Callable[..., object]
    norm: str  # HAMMING for binary, L2 for real-valued descriptors
    requires_orientation: bool = False
    only_detectors: tuple[str, ...] | None = None  # None: any detector
    excluded_detectors: dict[str, str] = field(default_factory=dict)  # detector -> reason
    learned: bool = False


_ORB_SCALES = "the ORB descriptor needs keypoints on its own pyramid scales (survey 5.2)"

DESCRIPTORS: dict[str, DescriptorSpec] = {
    s.name: s
    for s in [
        DescriptorSpec("orb", "ORB", cv2.ORB_create, HAMMING,
                       excluded_detectors={"sift": _ORB_SCALES}),
        DescriptorSpec("brief", "BRIEF", _x.BriefDescriptorExtractor_create, HAMMING),
        DescriptorSpec("latch", "LATCH", _x.LATCH_create, HAMMING),
        DescriptorSpec("surf", "SURF", create_surf, L2),
        DescriptorSpec("sift", "SIFT", cv2.SIFT_create, L2),
        DescriptorSpec("akaze", "AKAZE", _x.AKAZE_create, HAMMING, only_detectors=("akaze",)),
        DescriptorSpec("brisk", "BRISK", _x.BRISK_create, HAMMING),
        DescriptorSpec("freak", "FREAK", _x.FREAK_create, HAMMING),
        DescriptorSpec("daisy", "DAISY", _x.DAISY_create, L2, requires_orientation=True),
        # Beyond the survey: learned binary descriptors shipped with OpenCV, KAZE, and the learned XFeat.
        DescriptorSpec("beblid", "BEBLID", _x.BEBLID_create, HAMMING),
        DescriptorSpec("teblid", "TEBLID", _x.TEBLID_create, HAMMING),
        DescriptorSpec("kaze", "KAZE", _x.KAZE_create, L2, only_detectors=("kaze",)),
        DescriptorSpec("xfeat", "XFeat", create_xfeat, L2, learned=True),
    ]
}

#: Detectors whose keypoints carry an ``octave`` that the same-named descriptor understands.
_OWN_OCTAVE = {"orb", "sift", "akaze", "kaze", "brisk", "surf"}


def get_descriptor(name: str) -> DescriptorSpec:
    """The registry entry for ``name``; :class:`UnknownMethod` lists the valid names otherwise."""
    try:
        return DESCRIPTORS[name]
    except KeyError:
        raise UnknownMethod("descriptor", name, DESCRIPTORS) from None


def applicability(detector: str, descriptor: str) -> str | None:
    """``None`` when ``descriptor`` can describe ``detector``'s keypoints, else the reason it cannot."""
    det, desc = get_detector(detector), get_descriptor(descriptor)
    if desc.only_detectors is not None and detector not in desc.only_detectors:
        allowed = ", ".join(get_detector(d).label for d in desc.only_detectors)
        return f"the {desc.label} descriptor only describes {allowed} keypoints"
    if detector in desc.excluded_detectors:
        return f"{desc.excluded_detectors[detector]}; {det.label} keypoints are not"
    if desc.requires_orientation and not det.orientation:
        return f"the {desc.label} descriptor needs oriented keypoints; {det.label} gives no orientation"
    return None


def descriptor_params(descriptor_cfg: dict, detector: str) -> dict:
    """The parameters of a descriptor config for keypoints of ``detector``.

    A config holds ``params`` and optionally ``per_detector: {<detector>: {<param>: value}}`` overrides (e.g. the
    sampling scale of BEBLID/TEBLID, which depends on the detector's keypoint size convention).
    """
    params = dict(descriptor_cfg.get("params") or {})
    params.update((descriptor_cfg.get("per_detector") or {}).get(detector) or {})
    return params


def describe(image: np.ndarray, keypoints: np.ndarray, name: str, detector: str, **params):
    """Describe ``keypoints`` (an ``(N, 7)`` array from ``detector``) in ``image`` with descriptor ``name``.

    Returns ``(kept_keypoints, descriptors)``: descriptors may drop keypoints (e.g. near the border), so the
    returned keypoints are the ones aligned with the descriptor rows. Binary descriptors are uint8, real-valued
    ones float32. Raises :class:`NotApplicable` for the survey's NA pairings.
    """
    kept, descriptors, _ = describe_timed(image, keypoints, name, detector, **params)
    return kept, descriptors


def describe_timed(image: np.ndarray, keypoints: np.ndarray, name: str, detector: str, **params):
    """:func:`describe` plus the wall time in seconds of the descriptor call itself."""
    spec = get_descriptor(name)
    reason = applicability(detector, name)
    if reason is not None:
        raise NotApplicable(reason)
    extractor = build_method("descriptor", spec.name, spec.create, params)
    prepared = _prepare(keypoints, detector, name)
    if len(prepared) == 0:
        return kp.empty(), _empty_descriptors(spec, extractor), 0.0
    start = time.perf_counter()
    try:
        found, descriptors = extractor.compute(image, kp.to_keypoints(prepared))
    except cv2.error as e:
        raise NotApplicable(f"the {spec.label} descriptor failed on {get_detector(detector).label} keypoints: "
                            f"{first_line(e)}") from None
    seconds = time.perf_counter() - start
    if descriptors is None or len(found) == 0:
        return kp.empty(), _empty_descriptors(spec, extractor), seconds
    return kp.to_array(found), np.ascontiguousarray(descriptors), seconds


def _prepare(keypoints: np.ndarray, detector: str, descriptor: str) -> np.ndarray:
    prepared = np.array(keypoints, dtype=np.float64, copy=True).reshape(-1, len(kp.COLUMNS))
    if detector != descriptor or detector not in _OWN_OCTAVE:
        prepared[:, kp.OCTAVE] = 0
    prepared[prepared[:, kp.ANGLE] < 0, kp.ANGLE] = 0.0
    return prepared


def _empty_descriptors(spec: DescriptorSpec, extractor) -> np.ndarray:
    dtype = np.uint8 if spec.norm == HAMMING else np.float32
    return np.zeros((0, int(extractor.descriptorSize())), dtype=dtype)
