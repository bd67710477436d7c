"""Procedural ground-texture "floors": large gray mosaics that camera views are cut from.

One generator per texture type of the survey (Micro-GPS database, Zhang et al. ICRA 2019): fine and coarse
asphalt (aggregate stones in dark binder, differing in grain size and contrast), carpet (fine repetitive weave
with tuft noise), concrete (smooth low-contrast mottling with pores), tiles (grout lines, subtle speckle), wood
(anisotropic grain, weak texture). Sizes are in millimetres and converted with ``px_per_mm`` (Micro-GPS: 30 px
= 4.8 mm, i.e. 6.25 px/mm at 1288x964). scikit-image's texture photographs (gravel, brick, grass) are upsampled
to give extra floors. Every floor is a 2-D float32 array in [0, 255], band-limited so that views resampled with
sub-pixel offsets stay faithful; generation is deterministic for a given generator.
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

#: Micro-GPS resolution: 1288 px wide images, 30 px = 4.8 mm.
MICROGPS_PX_PER_MM = 30 / 4.8


def smooth_noise(rng: np.random.Generator, shape, cell_px: float) -> np.ndarray:
    """Zero-mean, unit-std noise with features about ``cell_px`` pixels wide (white noise upsampled bicubically)."""
    h, w = shape
    if cell_px <= 1.0:
        return rng.standard_normal((h, w), dtype=np.float32)
    small = rng.standard_normal((int(h / cell_px) + 4, int(w / cell_px) + 4), dtype=np.float32)
    big = cv2.resize(small, (int(small.shape[1] * cell_px), int(small.shape[0] * cell_px)),
                     interpolation=cv2.INTER_CUBIC)[:h, :w]
    return (big - big.mean()) / (big.std() + 1e-6)


def anisotropic_noise(rng: np.random.Generator, shape, cell_x: float, cell_y: float) -> np.ndarray:
    """Like :func:`smooth_noise` but with different feature lengths along x and y."""
    h, w = shape
    small = rng.standard_normal((int(h / cell_y) + 4, int(w / cell_x) + 4), dtype=np.float32)
    big = cv2.resize(small, (int(small.shape[1] * cell_x), int(small.shape[0] * cell_y)),
                     interpolation=cv2.INTER_CUBIC)[:h, :w]
    return (big - big.mean()) / (big.std() + 1e-6)


def fractal(rng: np.random.Generator, shape, cells_px, weights) -> np.ndarray:
    """Weighted sum of :func:`smooth_noise` octaves."""
    return sum(w * smooth_noise(rng, shape, c) for c, w in zip(cells_px, weights)).astype(np.float32)


def blobs(rng: np.random.Generator, shape, spacing_px: float, radius_px: tuple[float, float], warp_px: float):
    """Irregular round blobs (stones, pores) scattered with mean ``spacing_px``.

    Returns (mask, value, depth): ``mask`` marks blob pixels, ``value`` is a per-blob random number in [0, 1),
    ``depth`` is 1 at a blob's centre falling to 0 at its rim (for shading). Nearest seeds come from OpenCV's
    labelled distance transform; a smooth noise warps the distances so outlines are irregular.
    """
    h, w = shape
    n = max(1, int(h * w / spacing_px ** 2))
    seeds = np.unique(rng.integers(0, h * w, size=n))  # raster order = label order of OpenCV
    image = np.full((h, w), 255, np.uint8)
    image.flat[seeds] = 0
    dist, labels = cv2.distanceTransformWithLabels(image, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    radius = rng.uniform(*radius_px, size=len(seeds)).astype(np.float32)
    value = rng.random(len(seeds)).astype(np.float32)
    index = labels - 1
    warped = dist + warp_px * smooth_noise(rng, shape, max(radius_px[1] * 0.7, 1.5))
    r = radius[index]
    depth = np.clip(1.0 - warped / r, 0.0, 1.0)
    return depth > 0, value[index], depth


def grid(shape) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates as broadcastable float32 (h, 1) and (1, w) arrays (cheaper than a full mesh)."""
    h, w = shape
    return np.arange(h, dtype=np.float32)[:, None], np.arange(w, dtype=np.float32)[None, :]


def finish(field: np.ndarray, mean: float, std: float, blur_px: float = 0.7) -> np.ndarray:
    """Band-limit (Gaussian ``blur_px``), then set mean and std (gray levels) and clip to [0, 255]."""
    field = cv2.GaussianBlur(field.astype(np.float32), (0, 0), blur_px) if blur_px > 0 else field
    field = (field - field.mean()) / (field.std() + 1e-6) * std + mean
    return np.clip(field, 0, 255).astype(np.float32)


def asphalt(rng, shape, ppm: float, stone_mm: float, contrast: float, voids: float) -> np.ndarray:
    """Aggregate stones (diameter ~``stone_mm``) of varied brightness in a dark grainy binder with voids."""
    spacing = stone_mm * 0.8 * ppm
    mask, value, depth = blobs(rng, shape, spacing, (0.35 * stone_mm * ppm, 0.6 * stone_mm * ppm),
                               0.18 * stone_mm * ppm)
    grain = smooth_noise(rng, shape, 0.35 * ppm)
    stone = 0.35 + 0.5 * value + 0.25 * np.sqrt(depth) + 0.08 * grain
    binder = 0.12 + 0.05 * grain
    field = np.where(mask, stone, binder)
    pits, _, pit_depth = blobs(rng, shape, spacing * 2.5 / max(voids, 1e-3), (0.2 * ppm, 0.5 * stone_mm * ppm),
                               0.1 * stone_mm * ppm)
    field = field - 0.25 * pits * (pit_depth > 0.1)
    field += 0.12 * smooth_noise(rng, shape, 25 * ppm)  # uneven wear and dirt
    return finish(field, 120, 45 * contrast, blur_px=0.6)


def fine_asphalt(rng, shape, ppm):
    """Fine asphalt: small (≈2.5 mm), dense aggregate."""
    return asphalt(rng, shape, ppm, stone_mm=2.5, contrast=1.0, voids=0.5)


def coarse_asphalt(rng, shape, ppm):
    """Coarse asphalt: large (≈8 mm) aggregate, more voids, higher contrast."""
    return asphalt(rng, shape, ppm, stone_mm=8.0, contrast=1.2, voids=1.0)


def carpet(rng, shape, ppm):
    """Loop-pile carpet: a fine, slightly irregular weave (period ≈1.6 mm), tuft noise and soft mottling."""
    h, w = shape
    period = 1.6 * ppm
    y, x = grid(shape)
    jitter = 0.6 * period
    phase_x = (x + jitter * smooth_noise(rng, shape, 6 * ppm)) * (2 * np.pi / period)
    phase_y = (y + jitter * smooth_noise(rng, shape, 6 * ppm)) * (2 * np.pi / period)
    weave = np.sin(phase_x) * np.sin(phase_y)
    tufts = smooth_noise(rng, shape, 0.9 * ppm)
    rows = np.sin(phase_y * 0.5) * 0.3  # the backing's rows, every second loop
    field = 0.8 * weave + 0.7 * tufts + rows + 0.35 * smooth_noise(rng, shape, 8 * ppm)
    return finish(field, 110, 38, blur_px=0.6)


def concrete(rng, shape, ppm):
    """Concrete: smooth low-contrast mottling, fine sand grain and sparse dark pores."""
    field = fractal(rng, shape, (2 * ppm, 6 * ppm, 20 * ppm, 60 * ppm), (0.25, 0.35, 0.45, 0.5))
    field += 0.3 * smooth_noise(rng, shape, 0.5 * ppm)
    pores, _, depth = blobs(rng, shape, 2.2 * ppm, (0.2 * ppm, 0.7 * ppm), 0.15 * ppm)
    field -= 2.5 * pores * np.sqrt(depth)
    return finish(field, 135, 20, blur_px=0.6)


def tiles(rng, shape, ppm):
    """Floor tiles (50 mm) with darker grout lines (2.5 mm), per-tile shade and a subtle speckle."""
    h, w = shape
    size, grout = 50 * ppm, 2.5 * ppm
    y, x = grid(shape)
    offset = rng.uniform(0, size, 2)
    col, row = np.floor((x + offset[0]) / size), np.floor((y + offset[1]) / size)
    fx, fy = (x + offset[0]) % size, (y + offset[1]) % size
    edge = np.minimum(np.minimum(fx, size - fx), np.minimum(fy, size - fy))
    line = np.clip(1.0 - (edge - grout / 2) / 1.0, 0.0, 1.0)
    shade = rng.normal(0, 1, (int(row.max() - row.min()) + 2, int(col.max() - col.min()) + 2)).astype(np.float32)
    tile_shade = shade[(row - row.min()).astype(int), (col - col.min()).astype(int)]
    speckle, _, chip = blobs(rng, shape, 1.6 * ppm, (0.2 * ppm, 0.7 * ppm), 0.15 * ppm)
    surface = 0.25 * tile_shade + 0.35 * smooth_noise(rng, shape, 0.6 * ppm) + 0.6 * speckle * (chip > 0.2)
    surface += 0.3 * smooth_noise(rng, shape, 15 * ppm)
    grout_texture = -2.8 + 0.5 * smooth_noise(rng, shape, 0.5 * ppm)
    field = (1 - line) * surface + line * grout_texture
    return finish(field, 150, 30, blur_px=0.7)


def wood(rng, shape, ppm):
    """Wooden floor: planks (90 mm) of long anisotropic grain with soft growth rings; weak texture."""
    h, w = shape
    y, x = grid(shape)
    plank_w = 90 * ppm
    plank = np.floor(y / plank_w)
    warp = 4 * ppm * smooth_noise(rng, shape, 60 * ppm)
    rings = np.sin((y + warp + 37 * plank * ppm) * (2 * np.pi / (6 * ppm)))
    grain = anisotropic_noise(rng, shape, 25 * ppm, 0.45 * ppm)
    pores = anisotropic_noise(rng, shape, 1.5 * ppm, 0.4 * ppm)
    n_planks = int(plank.max()) + 1
    plank_shade = rng.normal(0, 1, n_planks).astype(np.float32)[plank.astype(int)]
    narrow = (h, w // 5 + 1)  # pores: dark flecks drawn 5x narrower, then stretched along the grain
    flecks, _, fleck_depth = blobs(rng, narrow, 1.4 * ppm, (0.15 * ppm, 0.45 * ppm), 0.1 * ppm)
    flecks = cv2.resize((flecks * fleck_depth).astype(np.float32), (narrow[1] * 5, h),
                        interpolation=cv2.INTER_LINEAR)[:, :w]
    field = 0.5 * rings + 0.6 * grain + 0.35 * pores + 0.5 * plank_shade - 3.0 * flecks
    field += 0.3 * smooth_noise(rng, shape, 40 * ppm)
    seam = np.abs(y - (plank + 0.5) * plank_w) > plank_w / 2 - 0.6 * ppm
    joints = rng.uniform(0, w, n_planks)[plank.astype(int)]
    seam = seam | (np.abs(((x - joints) % (900 * ppm)) - 450 * ppm) > 450 * ppm - 0.6 * ppm)
    body = field[~seam]
    return finish(np.where(seam, body.mean() - 4 * body.std(), field), 125, 18, blur_px=0.6)


#: The survey's six texture types (Micro-GPS).
PROCEDURAL: dict[str, Callable] = {
    "fine_asphalt": fine_asphalt,
    "coarse_asphalt": coarse_asphalt,
    "carpet": carpet,
    "concrete": concrete,
    "tiles": tiles,
    "wood": wood,
}
#: Texture photographs shipped with scikit-image (512x512), used as extra floors.
PHOTOS = ("gravel", "brick", "grass")
FLOOR_TYPES = tuple(PROCEDURAL) + PHOTOS


def photo_floor(name: str, side: int) -> np.ndarray:
    """scikit-image's ``name`` photograph upsampled (Lanczos) to ``side`` x ``side`` pixels."""
    import skimage.data

    photo = getattr(skimage.data, name)().astype(np.float32)
    return np.clip(cv2.resize(photo, (side, side), interpolation=cv2.INTER_LANCZOS4), 0, 255)


def make_floor(kind: str, rng: np.random.Generator, shape, px_per_mm: float) -> np.ndarray:
    """The floor of texture ``kind`` (one of :data:`FLOOR_TYPES`), float32 in [0, 255] of ``shape`` (h, w).

    Photo floors ignore ``rng`` and ``px_per_mm``: they are square with side ``max(shape)``.
    """
    if kind in PHOTOS:
        return photo_floor(kind, max(shape))
    return PROCEDURAL[kind](rng, tuple(shape), px_per_mm)
