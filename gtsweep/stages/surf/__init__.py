"""SURF (Bay, Ess, Tuytelaars, Van Gool, "Speeded-Up Robust Features (SURF)", CVIU 110(3), 2008) for gtsweep.

``SURF_create(...)`` takes OpenCV's arguments and returns OpenCV's own SURF when the installed OpenCV is a nonfree
build (``cv2.xfeatures2d.SURF_create()`` works), otherwise :class:`~gtsweep.stages.surf.feature.NumpySURF`, a NumPy
reimplementation that reproduces OpenCV's keypoints and descriptors. The NumPy code follows OpenCV's
``opencv_contrib/modules/xfeatures2d/src/surf.cpp`` (Copyright (c) 2008 Liu Liu, modifications by Ian Mahon and
the OpenCV team; OpenCV is distributed under the Apache License 2.0) constant for constant. The choice is logged
on the ``gtsweep.stages.surf`` logger and shown by the returned object's ``implementation`` ("opencv" or
"gtsweep-numpy").
"""
from __future__ import annotations

import functools
import logging

import cv2

from gtsweep.stages.surf.feature import NumpySURF

__all__ = ["SURF_create", "NumpySURF", "OpenCVSURF", "opencv_surf_available", "implementation_name",
           "IMPLEMENTATION_VERSION"]

log = logging.getLogger(__name__)

#: Version of the NumPy SURF's numbers: bump it when a change moves any keypoint or descriptor bit (the digests
#: pinned by tests/test_surf_identity.py), so that no cached or committed row made by older code is reused.
IMPLEMENTATION_VERSION = 1


@functools.lru_cache(maxsize=1)
def opencv_surf_available() -> bool:
    """Whether this OpenCV is a nonfree build with a working ``cv2.xfeatures2d.SURF_create`` (tried once)."""
    try:
        cv2.xfeatures2d.SURF_create()
    except (cv2.error, AttributeError):
        return False
    return True


def implementation_name() -> str:
    """Which SURF runs, as the keypoint-cache and reuse keys record it: "opencv" (a nonfree build) or
    "gtsweep-numpy", with "/<version>" from :data:`IMPLEMENTATION_VERSION` 2 on (version 1's keys stay as
    they were)."""
    if opencv_surf_available():
        return "opencv"
    return "gtsweep-numpy" + (f"/{IMPLEMENTATION_VERSION}" if IMPLEMENTATION_VERSION > 1 else "")


class OpenCVSURF:
    """OpenCV's SURF object with an ``implementation`` attribute; every other attribute is OpenCV's."""

    implementation = "opencv"

    def __init__(self, surf):
        self._surf = surf

    def __getattr__(self, name):
        return getattr(self._surf, name)

    def __repr__(self):
        return f"OpenCVSURF({self._surf!r})"


def SURF_create(hessianThreshold=100, nOctaves=4, nOctaveLayers=3, extended=False, upright=False, *,
                prefer_opencv=True):
    """A SURF feature detector/extractor with OpenCV's arguments and interface.

    OpenCV's own when available and ``prefer_opencv`` (the default), else the NumPy one. Both have ``detect``,
    ``compute``, ``detectAndCompute``, ``descriptorSize`` and the getters/setters of ``cv2.xfeatures2d.SURF``.
    """
    if prefer_opencv and opencv_surf_available():
        surf = OpenCVSURF(cv2.xfeatures2d.SURF_create(hessianThreshold, nOctaves, nOctaveLayers, extended, upright))
    else:
        surf = NumpySURF(hessianThreshold, nOctaves, nOctaveLayers, extended, upright)
    log.info("SURF implementation: %s (%s)", surf.implementation,
             "OpenCV nonfree build" if surf.implementation == "opencv" else "NumPy port of OpenCV's surf.cpp")
    return surf
