"""Photometric differences between captures on different days (absolute pairs) and sensor noise.

The survey's absolute pairs were "taken at different times" (Micro-GPS database vs. later test sequences), so
illumination, exposure, focus and lens shading differ; gamma follows the survey's definition
g_out = g_max * (g_in / g_max) ** gamma with g_max = 255.
"""
from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

#: The parameters, each drawn from a range [low, high] (uniform; gamma log-uniform); the synthetic data set's
#: ranges are its ``photometric`` option (conf/dataset/synthetic.yaml).
PARAMETERS = ("gamma", "gain", "noise", "blur", "vignetting")


def draw(rng: np.random.Generator, ranges: Mapping[str, list]) -> dict[str, float]:
    """One set of photometric parameters from ``ranges`` (keys: :data:`PARAMETERS`)."""
    params = {}
    for key in PARAMETERS:
        low, high = (float(v) for v in ranges[key])
        if key == "gamma":
            params[key] = float(np.exp(rng.uniform(np.log(low), np.log(high))))
        else:
            params[key] = float(rng.uniform(low, high))
    return params


def vignetting(shape, strength: float) -> np.ndarray:
    """Radial falloff 1 - strength * (r / r_corner)^2 (float32, 1 at the centre)."""
    h, w = shape
    y, x = np.ogrid[0:h, 0:w]
    r2 = ((x - (w - 1) / 2) ** 2 + (y - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
    return (1.0 - strength * r2).astype(np.float32)


def capture(radiance: np.ndarray, rng: np.random.Generator, sensor_noise: float,
            params: Mapping[str, float] | None = None) -> np.ndarray:
    """A uint8 camera image of ``radiance`` (float32, 0-255): lens shading, exposure gain, gamma and blur from
    ``params`` (none if None), then Gaussian sensor noise of std ``sensor_noise`` (plus ``params['noise']``)."""
    image = radiance.astype(np.float32)
    noise = float(sensor_noise)
    if params:
        image = image * vignetting(image.shape, params["vignetting"]) * params["gain"]
        image = 255.0 * (np.clip(image, 0, 255) / 255.0) ** params["gamma"]
        if params["blur"] > 0.05:
            image = cv2.GaussianBlur(image, (0, 0), params["blur"])
        noise = float(np.hypot(noise, params["noise"]))
    if noise > 0:
        image = image + rng.normal(0.0, noise, image.shape).astype(np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
