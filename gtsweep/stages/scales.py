"""Where in a descriptor's own scale space a keypoint of another detector family is described.

OpenCV's keypoints carry an ``octave`` field whose meaning is the detector's: SIFT packs its octave (signed byte,
-1 for the upsampled first octave), layer and sub-layer offset into it; ORB writes its pyramid level; MSD, AKAZE,
HarrisLaplace and others their own level indices. Two descriptors read the field to choose the image they sample
from, and build a pyramid down to the largest value they are given:

- **SIFT** (``sift.dispatch.cpp``): ``octave & 255`` (signed) and ``layer = (octave >> 8) & 255`` select the
  Gaussian pyramid image; its own keypoints have ``size = 2 sigma 2^(octave + (layer + xi) / nOctaveLayers)`` with
  ``layer`` in 1..nOctaveLayers and ``|xi| <= 0.5``.
- **ORB** (``orb.cpp``): ``octave`` is the pyramid level, ``size = patchSize * scaleFactor^(level - firstLevel)``;
  it samples its fixed 31-pixel pattern in that level's image.

Every other descriptor of gtsweep ignores the field (tests/test_foreign_scale.py checks it): BRIEF, LATCH (fixed
patches at full resolution), BRISK, FREAK, BEBLID, TEBLID, SURF (sampling scaled by ``size`` in the
full-resolution image or its integral), DAISY (a dense full-resolution descriptor), XFeat (a dense feature map);
AKAZE and KAZE describe only their own keypoints.

A foreign keypoint's octave field is set by one of the :data:`FOREIGN_SCALES` (``experiment.foreign_scale``):

- ``own`` (default): the level whose scale the keypoint's ``size`` has under the descriptor's own convention, i.e.
  where the descriptor's own detector would have put a keypoint of that size. A SIFT or ORB keypoint stripped of
  its octave is described exactly as its own family describes it.
- ``octave0``: octave 0 for every foreign keypoint (gtsweep before this option): SIFT samples the full-resolution
  image with a window scaled by ``size`` (up to 25x the cost of its own keypoints), ORB its level 0 whatever the
  size.
- ``passthrough``: the detector's raw octave, as OpenCV 3.x did in the survey (SIFT reads ORB's level k as octave k).
  A raw value outside the descriptor's pyramid (MSD's levels 0-16 as SIFT octaves; SIFT's packed values as ORB
  levels, an NA pairing anyway) is an error of the pairing, not a 68 GB allocation.

Keypoints of the descriptor's own family keep their octave under every option.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gtsweep.core.errors import BadInput, GtsweepError

OWN, OCTAVE0, PASSTHROUGH = "own", "octave0", "passthrough"
FOREIGN_SCALES = (OWN, OCTAVE0, PASSTHROUGH)


def check_foreign_scale(value) -> str:
    """``value`` (None: the default, ``own``) if it names one of :data:`FOREIGN_SCALES`, else a one-line error."""
    if value is None:
        return OWN
    if value not in FOREIGN_SCALES:
        raise BadInput(f"experiment.foreign_scale must be one of {', '.join(FOREIGN_SCALES)}, got {value!r}")
    return value


# --- SIFT ----------------------------------------------------------------------------------------------------------

def sift_octave_range(shape: tuple[int, int]) -> tuple[int, int]:
    """The octaves SIFT's detector builds for an image of ``shape`` (rows, cols): from -1 (upsampled) on,
    ``nOctaves = cvRound(log2(2 min(rows, cols)) - 2) + 1`` of them (``SIFT_Impl::detectAndCompute``)."""
    return -1, int(np.rint(math.log2(2 * min(shape)) - 2)) - 1


def pack_sift_octave(octave: np.ndarray, layer: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """SIFT's packed octave field: ``(octave & 255) | layer << 8 | round((xi + 0.5) 255) << 16``."""
    return ((octave.astype(np.int64) & 255) | (layer.astype(np.int64) << 8)
            | (np.rint((offset + 0.5) * 255).astype(np.int64) << 16))


def unpack_sift_octave(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(octave, layer)`` as ``unpackOctave`` reads them (the octave a signed byte)."""
    packed = packed.astype(np.int64)
    octave = packed & 255
    return np.where(octave < 128, octave, octave - 256), (packed >> 8) & 255


def sift_own_octaves(size: np.ndarray, extractor, shape) -> np.ndarray:
    """The packed octave of the SIFT layer whose scale matches each ``size``: ``t = log2(size / 2 sigma)`` in
    units of layers, rounded to the nearest layer ``u``; octave ``floor((u - 1) / n)``, layer 1..n, offset
    ``xi = t n - u``; clamped to the octaves SIFT builds for ``shape`` (the smallest and largest layer there)."""
    layers, sigma = int(extractor.getNOctaveLayers()), float(extractor.getSigma())
    position = np.log2(np.maximum(size, 1e-6) / (2 * sigma)) * layers
    nearest = np.rint(position)
    octave = np.floor_divide(nearest - 1, layers)
    layer = nearest - octave * layers
    offset = position - nearest
    lowest, highest = sift_octave_range(shape)
    below, above = octave < lowest, octave > highest
    octave, layer = np.clip(octave, lowest, highest), np.where(below, 1, np.where(above, layers, layer))
    offset = np.where(below, -0.5, np.where(above, 0.5, offset))
    return pack_sift_octave(octave, layer, np.clip(offset, -0.5, 0.5))


def sift_passthrough_problem(octaves: np.ndarray, extractor, shape) -> str | None:
    """Why SIFT cannot use these raw octave fields, or None: an octave outside those it builds for ``shape``, or
    a layer beyond ``nOctaveLayers + 2`` (OpenCV asserts, or halves the image to nothing)."""
    octave, layer = unpack_sift_octave(octaves)
    lowest, highest = sift_octave_range(shape)
    if octave.min() < lowest or octave.max() > highest:
        return (f"octaves {int(octave.min())}..{int(octave.max())} read as SIFT octaves; a "
                f"{shape[1]}x{shape[0]} image has octaves {lowest}..{highest}")
    if layer.max() > int(extractor.getNOctaveLayers()) + 2:
        return f"layer {int(layer.max())} read as a SIFT layer; SIFT has {int(extractor.getNOctaveLayers()) + 3}"
    return None


# --- ORB -----------------------------------------------------------------------------------------------------------

def orb_own_levels(size: np.ndarray, extractor, shape) -> np.ndarray:
    """The ORB pyramid level whose patch matches each ``size``: ``firstLevel + round(log(size / patchSize) /
    log(scaleFactor))``, clamped to the descriptor's levels ``0..nlevels - 1``."""
    factor, patch = float(extractor.getScaleFactor()), float(extractor.getPatchSize())
    first, levels = int(extractor.getFirstLevel()), int(extractor.getNLevels())
    level = first + np.rint(np.log(np.maximum(size, 1e-6) / patch) / math.log(factor))
    return np.clip(level, 0, levels - 1).astype(np.int64)


def orb_passthrough_problem(octaves: np.ndarray, extractor, shape) -> str | None:
    """Why ORB cannot use these raw octave fields, or None: a negative level (OpenCV asserts) or one whose image
    would be smaller than a pixel (OpenCV builds every level up to the largest it is given)."""
    factor = float(extractor.getScaleFactor())
    highest = int(math.floor(math.log(min(shape)) / math.log(factor))) + int(extractor.getFirstLevel())
    if octaves.min() < 0 or octaves.max() > highest:
        return (f"octaves {int(octaves.min())}..{int(octaves.max())} read as ORB pyramid levels; a "
                f"{shape[1]}x{shape[0]} image has levels 0..{highest}")
    return None


@dataclass(frozen=True)
class ScaleSpace:
    """How a descriptor reads the octave field: the octave of a keypoint of a given size (``own``), and why raw
    octave values cannot be used (``passthrough``), both as functions of ``(values, extractor, image shape)``."""

    own: Callable[[np.ndarray, object, tuple[int, int]], np.ndarray]
    passthrough_problem: Callable[[np.ndarray, object, tuple[int, int]], str | None]


#: The descriptors' scale spaces by name (a descriptor's ``scale_space``; None: it ignores the octave field).
SCALE_SPACES = {"sift": ScaleSpace(sift_own_octaves, sift_passthrough_problem),
                "orb": ScaleSpace(orb_own_levels, orb_passthrough_problem)}


def foreign_octaves(size: np.ndarray, octave: np.ndarray, scale_space: str | None, option: str, extractor, shape,
                    where: str) -> np.ndarray:
    """The octave field to give foreign keypoints of ``size`` and raw ``octave`` under ``option`` (see the
    module's docstring), for a descriptor with ``scale_space`` built as ``extractor``, in an image of ``shape``."""
    raw = np.rint(octave).astype(np.int64)
    if scale_space is None or option == OCTAVE0:
        return np.zeros(len(raw), dtype=np.int64)
    space = SCALE_SPACES[scale_space]
    if option == OWN:
        return space.own(np.asarray(size, dtype=np.float64), extractor, shape)
    problem = space.passthrough_problem(raw, extractor, shape) if len(raw) else None
    if problem is not None:
        raise GtsweepError(f"{where}: experiment.foreign_scale=passthrough: {problem}")
    return raw
