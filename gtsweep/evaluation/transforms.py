"""Synthetic transformations of one ground-texture image (survey section 3 and 4).

Each transform turns a reference image (2-D uint8) into a :class:`ViewPair`: the reference and test images with
their detection masks (uint8, 0 or 255, OpenCV's convention) and the homography ``H`` that maps test-image pixel
coordinates to reference-image pixel coordinates. Parameter ranges follow the survey (section 4):
rotation 0-180 degrees, translation IoU 0.2-1.0, Gaussian noise sigma 0-40, gamma 0.1-3.0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.core.ranges import Range
from gtsweep.core.registry import Method, Registry, function_defaults, partial_factory


@dataclass(frozen=True)
class ViewPair:
    """A reference/test image pair with detection masks and ``H`` (test pixel -> reference pixel, 3x3)."""

    reference: np.ndarray
    reference_mask: np.ndarray
    test: np.ndarray
    test_mask: np.ndarray
    H: np.ndarray
    name: str
    strength: float


def _check_image(image) -> np.ndarray:
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 2 or 0 in image.shape:
        described = f"{image.dtype} array of shape {image.shape}" if isinstance(image, np.ndarray) else type(image)
        raise BadInput(f"image must be a non-empty 2-D uint8 gray image, got {described}")
    return image


#: Allowed strengths of each synthetic transform (checked per strength before a sweep starts, and by the functions).
STRENGTH_RANGES = {
    "rotation": Range(-360.0, 360.0),             # angle in degrees
    "translation": Range(0.0, 1.0, low_open=True),  # IoU of reference and test masks
    "noise": Range(0.0, 255.0),                    # sigma in gray levels
    "gamma": Range(0.0, 10.0, low_open=True),
}
_MASK_FRACTION = Range(0.0, 1.0, low_open=True)


def _check_range(name: str, value, allowed: Range) -> float:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = float(value)
    return allowed.check(name, value)


def _full_mask(image: np.ndarray) -> np.ndarray:
    return np.full(image.shape, 255, dtype=np.uint8)


def _photometric_pair(image: np.ndarray, test: np.ndarray, name: str, strength: float) -> ViewPair:
    return ViewPair(image, _full_mask(image), test, _full_mask(image), np.eye(3), name, strength)


def rotation_matrix(angle_deg: float, shape: tuple[int, int]) -> np.ndarray:
    """3x3 rotation by ``angle_deg`` about the image centre ((w-1)/2, (h-1)/2), reference -> test pixels.

    Same convention as ``cv2.getRotationMatrix2D`` (positive = counter-clockwise on screen); cosine and sine
    are exact at multiples of 90 degrees so that such rotations permute pixels exactly.
    """
    height, width = shape[:2]
    quarter_turns = angle_deg / 90.0
    if quarter_turns.is_integer():
        cos, sin = [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][int(quarter_turns) % 4]
    else:
        cos, sin = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    return np.array(
        [[cos, sin, (1 - cos) * cx - sin * cy], [-sin, cos, sin * cx + (1 - cos) * cy], [0.0, 0.0, 1.0]]
    )


def rotate(image, angle_deg: float, border: int = 3) -> ViewPair:
    """Rotate about the image centre with bicubic interpolation, same size (survey section 3).

    The test mask is the region holding image content after rotation, eroded by ``border`` pixels so that
    detectors do not fire on the edges of the black corners; the reference mask is full.
    """
    image = _check_image(image)
    angle = _check_range("rotation angle (degrees)", angle_deg, STRENGTH_RANGES["rotation"])
    if isinstance(border, bool) or not isinstance(border, (int, np.integer)) or border < 0:
        raise BadInput(f"border must be a non-negative integer, got {border!r}")
    height, width = image.shape
    forward = rotation_matrix(angle, image.shape)
    test = cv2.warpAffine(image, forward[:2], (width, height), flags=cv2.INTER_CUBIC, borderValue=0)
    H = np.linalg.inv(forward)
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    ref_x = H[0, 0] * xs + H[0, 1] * ys + H[0, 2]
    ref_y = H[1, 0] * xs + H[1, 1] * ys + H[1, 2]
    eps = 1e-9  # exact 90-degree maps land on integer borders up to rounding
    inside = (ref_x >= -eps) & (ref_x <= width - 1 + eps) & (ref_y >= -eps) & (ref_y <= height - 1 + eps)
    test_mask = inside.astype(np.uint8) * 255
    if border > 0:  # pixels outside the image count as content, so only the black corners' edges erode
        kernel = np.ones((2 * border + 1, 2 * border + 1), np.uint8)
        test_mask = cv2.erode(test_mask, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=255)
    return ViewPair(image, _full_mask(image), test, test_mask, H, "rotation", angle)


IOU_PRECISION = 0.01  # largest accepted gap between the asked and the pixel-rounded translation IoU


def _overlap_fraction(iou: float) -> float:
    """Overlap o = (1 - s)^2 of two equal rectangles with IoU = o / (2 - o), solved for o."""
    return 2.0 * iou / (1.0 + iou)


def _rectangles_iou(size: tuple[int, int], shift: tuple[int, int]) -> float:
    (w, h), (dx, dy) = size, shift
    intersection = max(w - dx, 0) * max(h - dy, 0)
    return intersection / (2 * w * h - intersection)


def translation_masks(shape: tuple[int, int], iou: float, mask_fraction: float = 0.7):
    """Reference and test masks for :func:`translate`, and the realised IoU after rounding to pixels.

    The rectangles have ``mask_fraction`` of the image's sides; the test one is shifted by s·(w_m, h_m) towards
    the lower right, with (1 - s)^2 = 2·IoU / (1 + IoU). Of the floor/ceil pixel shifts the one with the IoU
    nearest to the asked one is used (BadInput if still off by more than
    :data:`IOU_PRECISION`); the pair is centred in the image.
    """
    height, width = shape[:2]
    mask_w, mask_h = round(mask_fraction * width), round(mask_fraction * height)
    if mask_w < 1 or mask_h < 1:
        raise BadInput(f"translation mask of {mask_fraction:g} x {width}x{height} pixels is empty")
    s = 1.0 - math.sqrt(_overlap_fraction(iou))
    shifts = [(dx, dy) for dx in {math.floor(s * mask_w), math.ceil(s * mask_w)}
              for dy in {math.floor(s * mask_h), math.ceil(s * mask_h)}]
    shifts.sort()  # set order is arbitrary; sort for determinism before picking the best
    dx, dy = min(shifts, key=lambda d: abs(_rectangles_iou((mask_w, mask_h), d) - iou))
    if mask_w + dx > width or mask_h + dy > height:
        raise BadInput(f"translation to IoU {iou:g} with mask_fraction {mask_fraction:g} does not fit the image")
    realised = _rectangles_iou((mask_w, mask_h), (dx, dy))
    if abs(realised - iou) > IOU_PRECISION:
        raise BadInput(f"a {width}x{height} image is too small to realise translation IoU {iou:g} within "
                       f"{IOU_PRECISION:g} (got {realised:.4f})")
    x0, y0 = (width - mask_w - dx) // 2, (height - mask_h - dy) // 2
    reference_mask = np.zeros((height, width), np.uint8)
    test_mask = np.zeros((height, width), np.uint8)
    reference_mask[y0:y0 + mask_h, x0:x0 + mask_w] = 255
    test_mask[y0 + dy:y0 + dy + mask_h, x0 + dx:x0 + dx + mask_w] = 255
    return reference_mask, test_mask, realised


def translate(image, iou: float, mask_fraction: float = 0.7) -> ViewPair:
    """Translation as the survey simulates it: the image stays, the detection mask moves (survey section 3).

    The test mask is the reference mask pushed along the diagonal towards the lower-right corner so that the
    masks' IoU is ``iou``; ``H`` is the identity. Raises BadInput if the pair does not fit the image.
    """
    image = _check_image(image)
    iou = _check_range("translation IoU", iou, STRENGTH_RANGES["translation"])
    mask_fraction = _check_range("mask_fraction", mask_fraction, _MASK_FRACTION)
    reference_mask, test_mask, _ = translation_masks(image.shape, iou, mask_fraction)
    return ViewPair(image, reference_mask, image.copy(), test_mask, np.eye(3), "translation", iou)


def add_noise(image, sigma: float, seed: int = 0) -> ViewPair:
    """Zero-mean i.i.d. Gaussian noise: test = clip(round(image + N(0, sigma)), 0, 255) (survey section 3)."""
    image = _check_image(image)
    sigma = _check_range("noise sigma", sigma, STRENGTH_RANGES["noise"])
    noise = np.random.default_rng(seed).normal(0.0, sigma, image.shape)
    test = np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)
    return _photometric_pair(image, test, "noise", sigma)


def gamma_table(gamma: float) -> np.ndarray:
    """256-entry LUT g_out = round(255 · (g_in / 255)^gamma), halves rounded up (survey section 3)."""
    levels = np.arange(256, dtype=np.float64) / 255.0
    return np.floor(255.0 * levels**gamma + 0.5).astype(np.uint8)


def adjust_gamma(image, gamma: float) -> ViewPair:
    """Illumination change by gamma correction (survey section 3); ``H`` is the identity, masks full."""
    image = _check_image(image)
    gamma = _check_range("gamma", gamma, STRENGTH_RANGES["gamma"])
    return _photometric_pair(image, gamma_table(gamma)[image], "gamma", gamma)


@dataclass(frozen=True, kw_only=True)
class TransformSpec(Method):
    """A synthetic transform ``function(image, strength, **params)``; a ``seeded`` one also takes ``seed``."""

    seeded: bool = False
    strength: Range = Range()

    def check_strength(self, where: str, value) -> float:
        """``value`` if it is an allowed strength, else a one-line BadInput naming ``where``."""
        return self.strength.check(where, value)


def _transform(name: str, label: str, function, params=None, capabilities=None) -> TransformSpec:
    """A transform ``function(image, strength, [seed,] **params)`` as a registry entry (``params`` over its own
    defaults); one declared in YAML takes any strength."""
    defaults = function_defaults(function, 2)
    seeded = "seed" in defaults
    defaults.pop("seed", None)  # the seed comes from synthesize(), per image and strength, not from a config
    return TransformSpec("transform", name, label, partial_factory(function), {**defaults, **(params or {})},
                         seeded=seeded, strength=STRENGTH_RANGES.get(name, Range()))


TRANSFORMS: Registry[TransformSpec] = Registry("transform", [
    _transform("rotation", "Rotation", rotate),
    _transform("translation", "Translation", translate),
    _transform("noise", "Noise", add_noise),
    _transform("gamma", "Gamma", adjust_gamma),
], make=_transform)

STRENGTHS: dict[str, list[float]] = {
    "rotation": [0, 15, 30, 45, 60, 90, 120, 150, 180],
    "translation": [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2],
    "noise": [0, 5, 10, 15, 20, 25, 30, 35, 40],
    "gamma": [0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0],
}
#: What a transform's strength is, as the label of a plot's axis (the report's plots, MLflow's figures).
STRENGTH_AXIS = {"rotation": "rotation angle (deg)", "translation": "IoU of reference and test masks",
                 "noise": "noise sigma (gray levels)", "gamma": "gamma"}


def synthesize(name: str, image, strength: float, seed: int = 0, **params) -> ViewPair:
    """Apply the transform registered as ``name`` with the given strength; ``seed`` only matters for noise."""
    spec = TRANSFORMS.get(name)
    transform = spec.build(params)
    return transform(image, strength, seed=seed) if spec.seeded else transform(image, strength)
