"""Capture conditions from camera physics: what a downward global-shutter camera on a moving robot records.

The survey's images (Micro-GPS, Zhang et al. ICRA 2019; survey section 5) come from a gray-scale Point Grey
camera, 1288x964 px, looking down at the floor under the robot's own lights, 30 px = 4.8 mm (6.25 px/mm). Per
frame (:func:`draw_frame`, :func:`capture`):

- **motion blur** along the direction of travel, ``length_px = exposure_s * speed_mm_s * px_per_mm`` (a line
  kernel centred on the pixel, so it smears but never moves content);
- **exposure and gain**: the exposure time is drawn per frame, auto-exposure sets the gain so that the mean
  brightness stays at its target, up to a per-frame brightness error (the control loop hunting);
- **the robot's own lighting**: natural lens vignetting (cos^4 of the field angle, from the focal length), the
  LED spot's falloff and a light gradient from the off-axis light, all fixed to the camera, so they move with the
  pose over the floor;
- **sensor noise**: photo-electrons ``e = reflectance * full_well * exposure / saturation_exposure`` (Poisson shot
  noise), Gaussian read noise in electrons, then ``gray = e * 255 / full_well * gain``, clipped to [0, 255];
- **tilt**: suspension pitch and roll rotate the camera by a degree or two; the view then is the nadir view
  warped by the rotation homography ``K R K^-1`` (exact for a planar floor), which the data set folds into the
  pose (:func:`tilt`), so ground truth stays exact.

Per day (:func:`draw_day`, :func:`day`), for captures "taken at different times" (absolute pairs): ambient light
leaking under the robot (a smooth illumination added to the robot's own), dust specks, wear (contrast loss of
the surface) and a tone change (the survey's gamma). Day effects act on the floor's reflectance before
:func:`capture`; a localization query "from another day" composes the two the same way.
"""
from __future__ import annotations

import math
from typing import Mapping

import cv2
import numpy as np

from gtsweep.core.errors import BadInput

#: Per-frame parameters and ranges [low, high] (see conf/dataset/survey.yaml for the camera facts behind them).
FRAME_DEFAULTS = {
    "speed_m_s": [0.5, 1.5],          # robot speed, uniform
    "exposure_ms": [0.1, 1.0],        # exposure time, log-uniform
    "saturation_exposure_ms": 1.0,    # exposure at which a white floor fills the well under the robot's lights
    "brightness_jitter": 0.05,        # std of the log brightness error of auto-exposure, per frame
    "full_well_e": 10000.0,           # electrons; null = no shot noise
    "read_noise_e": 12.0,             # electrons (std)
    "camera_height_mm": 250.0,        # lens centre above the floor: focal length in px = height * px_per_mm
    "lens_vignetting": True,          # natural vignetting cos^4 of the field angle
    "light_falloff": [0.0, 0.15],     # LED spot: extra loss at the corners, 1 - f * (r / r_corner)^2
    "light_gradient": [0.0, 0.15],    # off-axis light: 1 + g * (distance along light_direction / half diagonal)
    "light_direction_deg": 90.0,      # where the light sits in the image (fixed to the robot)
    "tilt_deg": 1.5,                  # pitch and roll, each uniform in [-tilt, tilt]
}
#: Per-day ranges [low, high], uniform (gamma log-uniform).
DAY_DEFAULTS = {
    "ambient": [0.0, 0.2],            # ambient light relative to the robot's own light
    "dust": [0.0, 0.01],              # share of the floor covered by dust specks
    "wear": [0.0, 0.2],               # contrast loss of the surface (smooth over ~50 mm)
    "gamma": [0.8, 1.25],             # tone change of the surface (moisture, polish), survey's gamma definition
}


def _range(options: Mapping, key: str) -> tuple[float, float]:
    value = options[key]
    low, high = (float(value), float(value)) if not isinstance(value, (list, tuple)) else map(float, value)
    if not 0 <= low <= high:
        raise BadInput(f"dataset capture option {key} must be a number or [low, high] with 0 <= low <= high, "
                       f"got {value}")
    return low, high


def check(options: Mapping | None, defaults: Mapping) -> dict | None:
    """``options`` completed with ``defaults`` (None stays None: effects off); unknown keys raise BadInput."""
    if options is None:
        return None
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise BadInput(f"unknown capture key(s) {', '.join(unknown)}; valid: {', '.join(defaults)}")
    merged = {**defaults, **options}
    for key, value in merged.items():
        if isinstance(value, (list, tuple)) or (isinstance(value, (int, float)) and not isinstance(value, bool)):
            _range(merged, key)
    if "exposure_ms" in merged and _range(merged, "exposure_ms")[0] <= 0:
        raise BadInput("dataset capture exposure_ms must be > 0")
    return merged


def focal_px(options: Mapping, px_per_mm: float) -> float:
    """Focal length in pixels: a floor ``camera_height_mm`` below the lens is imaged at ``px_per_mm``."""
    return float(options["camera_height_mm"]) * float(px_per_mm)


def draw_frame(rng: np.random.Generator, options: Mapping) -> dict[str, float]:
    """One frame's capture parameters from the ranges in ``options`` (keys of :data:`FRAME_DEFAULTS`)."""
    low, high = _range(options, "exposure_ms")
    params = {"exposure_ms": float(math.exp(rng.uniform(math.log(low), math.log(high))))}
    for key in ("speed_m_s", "light_falloff", "light_gradient"):
        params[key] = float(rng.uniform(*_range(options, key)))
    params["brightness"] = float(math.exp(rng.normal(0.0, float(options["brightness_jitter"]))))
    tilt_max = float(options["tilt_deg"])
    params["pitch_deg"], params["roll_deg"] = (float(v) for v in rng.uniform(-tilt_max, tilt_max, 2))
    return params


def blur_length_px(params: Mapping, px_per_mm: float) -> float:
    """Motion blur in pixels: exposure time x speed, in pixels (1 ms at 1 m/s is 1 mm, 6.25 px at Micro-GPS)."""
    return params["exposure_ms"] * 1e-3 * params["speed_m_s"] * 1e3 * float(px_per_mm)


def tilt(pitch_deg: float, roll_deg: float, shape, focal: float) -> np.ndarray:
    """Homography tilted-view pixel -> nadir-view pixel for a camera rotated by pitch (about x) and roll (about y).

    A rotation about the optical centre maps image points by ``K R K^-1`` for any scene, so this is exact; the
    principal point is the image centre. The result is then shifted so that the image centre keeps its floor point
    (the robot stood ``f * tan(tilt)``, a few mm, elsewhere): the layout's overlaps stay as drawn. Normalised so
    that ``[2, 2] == 1``.
    """
    h, w = shape[:2]
    K = np.array([[focal, 0.0, (w - 1) / 2.0], [0.0, focal, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    rotation, _ = cv2.Rodrigues(np.radians([pitch_deg, roll_deg, 0.0]))
    H = K @ rotation @ np.linalg.inv(K)
    moved = H @ K[:, 2]
    shift = np.eye(3)
    shift[:2, 2] = K[:2, 2] - moved[:2] / moved[2]
    H = shift @ H
    return H / H[2, 2]


def tilt_reach_px(tilt_deg: float, view_size, focal: float) -> float:
    """An upper bound on how far a tilt of up to ``tilt_deg`` in pitch and roll moves a view's corner."""
    w, h = view_size
    angle = math.radians(tilt_deg) * math.sqrt(2.0)
    field = math.atan(math.hypot(w, h) / 2.0 / focal)
    return focal * (math.tan(field + angle) - math.tan(field)) + 1.0


def motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """A normalised line kernel of ``length_px`` along ``angle_deg`` (image x towards y), symmetric about its
    centre pixel (so it does not shift the image); ``length_px < 0.5`` gives the identity."""
    half = int(math.ceil(length_px / 2.0)) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float64)
    if length_px < 0.5:
        kernel[half, half] = 1.0
        return kernel.astype(np.float32)
    t = np.linspace(-length_px / 2.0, length_px / 2.0, max(int(length_px * 8), 2) | 1)
    x = half + t * math.cos(math.radians(angle_deg))
    y = half + t * math.sin(math.radians(angle_deg))
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    for dx, dy, weight in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                           (1, 1, fx * fy)):
        np.add.at(kernel, (y0 + dy, x0 + dx), weight)
    return (kernel / kernel.sum()).astype(np.float32)


def _radius2(shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centred coordinates (dx, dy as (1, w) and (h, 1)) and squared radius normalised to 1 at the corners."""
    h, w = shape[:2]
    dx = (np.arange(w, dtype=np.float32) - (w - 1) / 2.0)[None, :]
    dy = (np.arange(h, dtype=np.float32) - (h - 1) / 2.0)[:, None]
    return dx, dy, (dx ** 2 + dy ** 2) / (((w - 1) / 2.0) ** 2 + ((h - 1) / 2.0) ** 2)


def shading(shape, params: Mapping, options: Mapping, focal: float) -> np.ndarray:
    """Illumination x lens shading relative to the centre (float32): cos^4 vignetting, LED falloff and gradient."""
    dx, dy, r2 = _radius2(shape)
    field = 1.0 - params["light_falloff"] * r2
    if options["lens_vignetting"]:
        field = field * (focal ** 2 / (focal ** 2 + dx ** 2 + dy ** 2)) ** 2
    angle = math.radians(float(options["light_direction_deg"]))
    half_diagonal = math.hypot((shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0)
    gradient = 1.0 + params["light_gradient"] * (dx * math.cos(angle) + dy * math.sin(angle)) / half_diagonal
    return (field * gradient).astype(np.float32)


def sensor(irradiance: np.ndarray, rng: np.random.Generator, params: Mapping, options: Mapping) -> np.ndarray:
    """uint8 gray levels from ``irradiance`` (0-255 = white floor under full light): shot and read noise in
    electrons, auto-exposure gain ``brightness * saturation_exposure / exposure``, rounding and clipping."""
    fill = params["exposure_ms"] / float(options["saturation_exposure_ms"])  # well fill of white at this exposure
    full_well = options["full_well_e"]
    gain = params["brightness"] / fill
    if full_well is None:
        gray = irradiance.astype(np.float32) * gain * fill
    else:
        electrons = np.clip(irradiance, 0, None).astype(np.float64) / 255.0 * float(full_well) * fill
        electrons = rng.poisson(electrons).astype(np.float32)
        read = float(options["read_noise_e"])
        if read > 0:
            electrons += rng.normal(0.0, read, electrons.shape).astype(np.float32)
        gray = electrons * np.float32(255.0 / float(full_well) * gain)
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


def capture(radiance: np.ndarray, rng: np.random.Generator, params: Mapping, options: Mapping, px_per_mm: float,
            travel_deg: float) -> np.ndarray:
    """The uint8 frame of ``radiance`` (float32 0-255, the floor as seen at the frame's pose): motion blur along
    ``travel_deg`` (image coordinates), the robot's lighting, then the sensor (:func:`sensor`)."""
    kernel = motion_kernel(blur_length_px(params, px_per_mm), travel_deg)
    image = radiance.astype(np.float32, copy=False)
    if kernel.shape[0] > 3 or kernel[1, 1] < 1.0:
        image = cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)
    image = image * shading(image.shape, params, options, focal_px(options, px_per_mm))
    return sensor(image, rng, params, options)


def random_frame(radiance: np.ndarray, rng: np.random.Generator, options: Mapping, px_per_mm: float) -> np.ndarray:
    """:func:`capture` with a frame drawn from ``options`` (:func:`draw_frame`) and a random direction of travel.

    Tilt is not applied here: it changes where pixels lie, so it belongs in the pose (:func:`tilt`), as the data
    set does; everything else (blur, exposure, lighting, noise) moves no pixel."""
    params = draw_frame(rng, options)
    return capture(radiance, rng, params, options, px_per_mm, float(rng.uniform(0.0, 360.0)))


def draw_day(rng: np.random.Generator, ranges: Mapping) -> dict[str, float]:
    """One day's parameters from ``ranges`` (keys of :data:`DAY_DEFAULTS`), plus the ambient light's direction."""
    params = {key: float(rng.uniform(*_range(ranges, key))) for key in ("ambient", "dust", "wear")}
    low, high = _range(ranges, "gamma")
    params["gamma"] = float(math.exp(rng.uniform(math.log(max(low, 1e-3)), math.log(max(high, 1e-3)))))
    params["ambient_direction_deg"] = float(rng.uniform(0.0, 360.0))
    return params


def _smooth(rng: np.random.Generator, shape, cell_px: float) -> np.ndarray:
    """Smooth noise in [0, 1] with features about ``cell_px`` wide (coarse uniform grid, bicubic upsampling)."""
    h, w = shape[:2]
    coarse = rng.random((max(int(h / cell_px), 1) + 2, max(int(w / cell_px), 1) + 2)).astype(np.float32)
    return np.clip(cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC), 0.0, 1.0)


def day(reflectance: np.ndarray, rng: np.random.Generator, params: Mapping, px_per_mm: float) -> np.ndarray:
    """The floor as it looks on another day (float32 0-255; apply before :func:`capture`): worn contrast, dust
    specks, the tone change ``255 (r / 255) ** gamma``, and ambient light added to the robot's own."""
    image = reflectance.astype(np.float32)
    shape = image.shape
    if params["wear"] > 0:
        mean = float(image.mean())
        image = mean + (image - mean) * (1.0 - params["wear"] * _smooth(rng, shape, 50 * px_per_mm))
    if params["dust"] > 0:
        specks = (rng.random(shape, dtype=np.float32) < params["dust"] / 4.0).astype(np.float32)
        specks = cv2.dilate(specks, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))
        image = image * (1 - specks) + specks * 230.0  # light gray dust, ~0.5 mm grains
    if params["gamma"] != 1.0:
        image = 255.0 * (np.clip(image, 0, 255) / 255.0) ** params["gamma"]
    if params["ambient"] > 0:  # ambient light: a ramp from 0 to ``ambient`` across the view, any direction
        dx, dy, _ = _radius2(shape)
        angle = math.radians(params["ambient_direction_deg"])
        half_diagonal = math.hypot((shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0)
        ramp = 0.5 + 0.5 * (dx * math.cos(angle) + dy * math.sin(angle)) / half_diagonal
        image = image * (1.0 + params["ambient"] * ramp)
    return image.astype(np.float32)
