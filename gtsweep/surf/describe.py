"""SURF orientation and descriptor, vectorised over keypoints.

Follows Bay, Ess, Tuytelaars, Van Gool, "Speeded-Up Robust Features (SURF)", CVIU 110(3), 2008 (section 4.1:
orientation from Haar wavelet responses in a sliding 60-degree window; section 4.2: 4x4 sub-regions of
(sum dx, sum dy, sum |dx|, sum |dy|)) exactly as OpenCV implements it in
``opencv_contrib/modules/xfeatures2d/src/surf.cpp`` (``SURFInvoker``; Apache-2.0, original code by Liu Liu,
revised by Ian Mahon): the same sampling grid, rounding, float32 arithmetic and summation order, and the same
``cv2.phase``, ``cv2.getGaussianKernel`` and ``cv2.resize(INTER_AREA)`` calls. Only the loops over keypoints are
replaced by array operations (keypoints are grouped by window size; loops run over groups, rows or windows).
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.surf.hessian import box_response, scale_boxes

F32 = np.float32

#: Orientation samples lie on the integer grid within this radius (in units of the scale s) (``ORI_RADIUS``).
ORI_RADIUS = 6
#: Gaussian sigma of the orientation sample weights, in units of s (``SURF_ORI_SIGMA``).
ORI_SIGMA = 2.5
#: Width of the sliding orientation window and its step, in degrees (``ORI_WIN``, ``SURF_ORI_SEARCH_INC``).
ORI_WINDOW = 60
ORI_SEARCH_STEP = 5
#: The descriptor patch is ``PATCH_SIZE + 1`` pixels square before the 2x2 differences (``PATCH_SZ``).
PATCH_SIZE = 20
#: Gaussian sigma of the descriptor weights, in patch pixels (``SURF_DESC_SIGMA``).
DESC_SIGMA = 3.3
#: 4x4 base patterns (x1, y1, x2, y2, weight) of the Haar wavelets used for the orientation.
HAAR_X_BOXES = ((0, 0, 2, 4, -1), (2, 0, 4, 4, 1))
HAAR_Y_BOXES = ((0, 0, 4, 2, 1), (0, 2, 4, 4, -1))
#: Angle given to every keypoint in upright mode (OpenCV's ``360 - 90``).
UPRIGHT_ANGLE = 270.0
#: Keypoints per batch in the orientation step (bounds the (batch, 360) histograms).
ORIENTATION_BATCH = 4096
#: Channels per cv2.resize call when enlarging windows (OpenCV's Python binding takes up to 128 here).
UPSCALE_CHANNELS = 128
#: cv2.remap needs output sides below 32767 (SHRT_MAX).
REMAP_MAX_ROWS = 32000
#: Window pixels per batch when sampling descriptor windows.
WINDOW_BATCH_PIXELS = 1 << 21


def keypoint_scale(size: np.ndarray) -> np.ndarray:
    """SURF scale s = 1.2 L / 9 of keypoints of side L, in float32 as OpenCV computes it."""
    return np.asarray(size, dtype=F32) * F32(1.2) / F32(9.0)


def window_sizes(size: np.ndarray) -> np.ndarray:
    """Side ``int(21 s)`` of the image window each keypoint's descriptor is computed from."""
    return (F32(PATCH_SIZE + 1) * keypoint_scale(size)).astype(np.int64)


def orientation_samples():
    """Grid offsets ``(113, 2)`` as (x, y) within radius 6 and their Gaussian weights (float32, sigma 2.5).

    The order is OpenCV's: x outer from -6 to 6, y inner. The weight is the product of two taps of
    ``getGaussianKernel(13, 2.5)``.
    """
    grid = np.arange(-ORI_RADIUS, ORI_RADIUS + 1)
    gx, gy = np.meshgrid(grid, grid, indexing="ij")
    inside = gx ** 2 + gy ** 2 <= ORI_RADIUS ** 2
    taps = cv2.getGaussianKernel(2 * ORI_RADIUS + 1, ORI_SIGMA, ktype=cv2.CV_32F).ravel()
    weights = taps[gx + ORI_RADIUS] * taps[gy + ORI_RADIUS]
    return np.stack([gx[inside], gy[inside]], axis=1), weights[inside].astype(F32)


def descriptor_weights() -> np.ndarray:
    """The ``(20, 20)`` float32 Gaussian (sigma 3.3) weighting the patch gradients."""
    taps = cv2.getGaussianKernel(PATCH_SIZE, DESC_SIGMA, ktype=cv2.CV_32F).ravel()
    return taps[:, None] * taps[None, :]


def fast_atan2_degrees(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """OpenCV's ``fastAtan2`` (a 7th-order polynomial, ~0.3 degree accuracy) in float32, in [0, 360)."""
    y, x = np.asarray(y, dtype=F32), np.asarray(x, dtype=F32)
    return cv2.phase(x.reshape(-1, 1), y.reshape(-1, 1), angleInDegrees=True).reshape(x.shape)


def _window_sums(values: np.ndarray, angle: np.ndarray, included: np.ndarray) -> np.ndarray:
    """Sums of ``values`` (N, S) in every sliding orientation window (N, 72), from a per-degree histogram.

    ``angle`` holds each sample's rounded angle in [0, 360); the window starting at ``a`` covers angles within
    29 degrees of ``a`` cyclically (surf.cpp's ``|round(angle) - a| < 30 or > 330``). Sums are float64 here and
    float32 added in sample order in OpenCV; the difference only matters for near-exact ties between windows.
    """
    n = len(values)
    half = ORI_WINDOW // 2
    bins = (np.arange(n)[:, None] * 360 + angle)[included]
    hist = np.bincount(bins, weights=values[included], minlength=n * 360).reshape(n, 360)
    wrapped = np.concatenate([np.zeros((n, 1)), hist[:, -half:], hist, hist[:, :half]], axis=1)
    prefix = np.cumsum(wrapped, axis=1)
    starts = np.arange(0, 360, ORI_SEARCH_STEP)
    return prefix[:, starts + 2 * half] - prefix[:, starts + 1]


def _orientation_batch(integral, x, y, s, offsets, weights):
    """Orientation (degrees) and validity of a batch of keypoints; see :func:`orientations`."""
    wavelet = 2 * np.rint(F32(2) * s).astype(np.int64)
    corners_x, weights_x = scale_boxes(HAAR_X_BOXES, 4, wavelet)
    corners_y, weights_y = scale_boxes(HAAR_Y_BOXES, 4, wavelet)
    half = ((wavelet - 1).astype(F32) / F32(2))[:, None]
    px = np.rint(x[:, None] + offsets[None, :, 0].astype(F32) * s[:, None] - half).astype(np.int64)
    py = np.rint(y[:, None] + offsets[None, :, 1].astype(F32) * s[:, None] - half).astype(np.int64)
    rows, cols = integral.shape
    inside = (py >= 0) & (py < rows - wavelet[:, None]) & (px >= 0) & (px < cols - wavelet[:, None])
    safe_x, safe_y = np.where(inside, px, 0), np.where(inside, py, 0)
    resp_x = box_response(integral, corners_x[:, None], weights_x[:, None], safe_y, safe_x) * weights
    resp_y = box_response(integral, corners_y[:, None], weights_y[:, None], safe_y, safe_x) * weights
    resp_x, resp_y = np.where(inside, resp_x, F32(0)), np.where(inside, resp_y, F32(0))
    sample_angle = np.rint(fast_atan2_degrees(resp_y, resp_x)).astype(np.int64) % 360
    sum_x, sum_y = (_window_sums(resp, sample_angle, inside) for resp in (resp_x, resp_y))
    strength = sum_x * sum_x + sum_y * sum_y
    best = np.argmax(strength, axis=1)
    pick = (np.arange(len(best)), best)
    chosen = strength[pick] > 0
    best_x = np.where(chosen, sum_x[pick], 0).astype(F32)
    best_y = np.where(chosen, sum_y[pick], 0).astype(F32)
    return fast_atan2_degrees(-best_y, best_x), inside.any(axis=1)


def orientations(integral: np.ndarray, x: np.ndarray, y: np.ndarray, size: np.ndarray):
    """Dominant orientations (degrees, float32) of keypoints and whether each could be oriented.

    Haar responses of side ``2 round(2s)`` are sampled at the 113 grid points within radius 6s, weighted by a
    Gaussian (sigma 2.5s), and summed inside a 60-degree window slid in 5-degree steps (a sample belongs to the
    window starting at ``a`` when its rounded angle is within 30 degrees of ``a``, cyclically); the angle is
    ``fastAtan2(-sum_y, sum_x)`` of the strongest window. A keypoint with no sample inside the image cannot be
    oriented (OpenCV then drops it).
    """
    x, y, s = np.asarray(x, F32), np.asarray(y, F32), keypoint_scale(size)
    offsets, weights = orientation_samples()
    angles, valid = np.zeros(len(x), F32), np.zeros(len(x), bool)
    for start in range(0, len(x), ORIENTATION_BATCH):
        part = slice(start, start + ORIENTATION_BATCH)
        angles[part], valid[part] = _orientation_batch(integral, x[part], y[part], s[part], offsets, weights)
    return angles, valid


def _rotated_sample_maps(x, y, angle, win):
    """Sample positions ``(n, win, win)`` of OpenCV's rotated descriptor windows, as float32 maps.

    Row ``i``, column ``j`` of a window samples ``start + i (sin, cos) + j (cos, -sin)`` with
    ``sin = -sin(angle)``; row starts advance in float32 steps as in surf.cpp.
    """
    theta = (angle.astype(F32) * F32(np.pi / 180)).astype(np.float64)
    sin_dir, cos_dir = (-np.sin(theta)).astype(F32), np.cos(theta).astype(F32)
    offset = F32(-(win - 1) / 2)
    start_x = x + offset * cos_dir + offset * sin_dir
    start_y = y - offset * sin_dir + offset * cos_dir
    row_x = np.cumsum(np.concatenate([start_x[:, None], np.repeat(sin_dir[:, None], win - 1, 1)], 1), 1, F32)
    row_y = np.cumsum(np.concatenate([start_y[:, None], np.repeat(cos_dir[:, None], win - 1, 1)], 1), 1, F32)
    steps = np.arange(win, dtype=F32)
    map_x = row_x[:, :, None] + steps * cos_dir[:, None, None]
    map_y = row_y[:, :, None] - steps * sin_dir[:, None, None]
    return map_x, map_y


def _upright_sample_maps(x, y, win):
    """Integer sample positions ``(n, win, win)`` of OpenCV's upright windows (transposed, y decreasing)."""
    offset = F32(-(win - 1) / 2)
    steps = np.arange(win, dtype=F32)
    start_x = np.rint(x + offset)
    start_y = np.rint(y - offset)
    map_x = np.broadcast_to(start_x[:, None, None] + steps[None, :, None], (len(x), win, win))
    map_y = np.broadcast_to(start_y[:, None, None] - steps[None, None, :], (len(x), win, win))
    return map_x, map_y


def _sample(gray: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``gray`` at float positions ``(n, win, win)`` -> uint8 windows.

    As in surf.cpp, a position whose 2x2 neighbourhood leaves the image takes the nearest pixel (clamped).
    Interpolation is ``cv2.remap``'s (positions quantised to 1/32 pixel) instead of surf.cpp's float weights:
    sample values may differ by a grey level or so, which the INTER_AREA averaging that follows shrinks further.
    """
    n, win, _ = map_x.shape
    rows, cols = gray.shape
    inside = (map_x >= 0) & (map_x < cols - 1) & (map_y >= 0) & (map_y < rows - 1)
    if not inside.all():
        map_x = np.where(inside, map_x, np.clip(np.rint(map_x), 0, cols - 1)).astype(F32)
        map_y = np.where(inside, map_y, np.clip(np.rint(map_y), 0, rows - 1)).astype(F32)
    out = np.empty((n, win, win), np.uint8)
    per_call = max(1, REMAP_MAX_ROWS // win)
    for start in range(0, n, per_call):
        part = slice(start, start + per_call)
        out[part] = cv2.remap(gray, np.ascontiguousarray(map_x[part]).reshape(-1, win),
                              np.ascontiguousarray(map_y[part]).reshape(-1, win), cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE).reshape(-1, win, win)
    return out


def _area_resize(windows: np.ndarray) -> np.ndarray:
    """Resize ``(n, win, win)`` windows to ``(n, 21, 21)`` with ``INTER_AREA``, as one window at a time would.

    Shrinking windows are stacked vertically and resized in one call: each maps to exactly 21 output rows and
    INTER_AREA never mixes rows across such a boundary (checked for every side 21-800). Enlarging windows
    (side < 21, only from foreign keypoints) are resized as the channels of one image, up to
    :data:`UPSCALE_CHANNELS` at a time, which is exact by construction.
    """
    n, win, _ = windows.shape
    side = PATCH_SIZE + 1
    if win >= side:
        stacked = cv2.resize(windows.reshape(n * win, win), (side, n * side), interpolation=cv2.INTER_AREA)
        return stacked.reshape(n, side, side)
    out = np.empty((n, side, side), np.uint8)
    for start in range(0, n, UPSCALE_CHANNELS):
        part = np.ascontiguousarray(windows[start:start + UPSCALE_CHANNELS].transpose(1, 2, 0))
        resized = cv2.resize(part, (side, side), interpolation=cv2.INTER_AREA)
        out[start:start + UPSCALE_CHANNELS] = resized.reshape(side, side, -1).transpose(2, 0, 1)
    return out


def patches(gray, x, y, angle, size, upright):
    """The ``(n, 21, 21)`` uint8 patches that SURF differentiates, for keypoints of one window size each batch.

    The window of side ``int(21 s)`` around each keypoint (rotated by its angle unless upright) is resized to
    21x21 with INTER_AREA, so that each patch pixel spans s.
    """
    win_sizes = window_sizes(size)
    out = np.zeros((len(x), PATCH_SIZE + 1, PATCH_SIZE + 1), np.uint8)
    for win in np.unique(win_sizes):
        members = np.flatnonzero(win_sizes == win)
        batch = max(1, WINDOW_BATCH_PIXELS // int(win * win))
        for start in range(0, len(members), batch):
            idx = members[start:start + batch]
            if upright:
                maps = _upright_sample_maps(x[idx], y[idx], int(win))
            else:
                maps = _rotated_sample_maps(x[idx], y[idx], angle[idx], int(win))
            windows = _sample(gray, *maps)
            out[idx] = _area_resize(windows)
    return out


def _block_sums(values: np.ndarray) -> np.ndarray:
    """Float32 sums over the 4x4 grid of 5x5 blocks of ``(n, 20, 20)`` values, added row by row as OpenCV does."""
    n = values.shape[0]
    blocks = values.reshape(n, 4, 5, 4, 5).transpose(0, 1, 3, 2, 4).reshape(n, 4, 4, 25)
    return np.cumsum(blocks, axis=3, dtype=F32)[..., -1]


def descriptors_from_patches(patch: np.ndarray, extended: bool) -> np.ndarray:
    """SURF descriptors ``(n, 64)`` or ``(n, 128)`` float32 from ``(n, 21, 21)`` patches.

    Gradients are 2x2 pixel differences weighted by a sigma-3.3 Gaussian. Per 5x5 sub-region: (sum dx, sum dy,
    sum |dx|, sum |dy|); extended: (sum dx, sum |dx|) split by the sign of dy, then (sum dy, sum |dy|) split by
    the sign of dx. The vector is scaled to unit length (+FLT_EPSILON).
    """
    p = patch.astype(np.int32)
    weight = descriptor_weights()
    dx = (p[:, :-1, 1:] - p[:, :-1, :-1] + p[:, 1:, 1:] - p[:, 1:, :-1]).astype(F32) * weight
    dy = (p[:, 1:, :-1] - p[:, :-1, :-1] + p[:, 1:, 1:] - p[:, :-1, 1:]).astype(F32) * weight
    zero = F32(0)
    if extended:
        up, right = dy >= 0, dx >= 0
        parts = [np.where(up, dx, zero), np.where(up, np.abs(dx), zero),
                 np.where(up, zero, dx), np.where(up, zero, np.abs(dx)),
                 np.where(right, dy, zero), np.where(right, np.abs(dy), zero),
                 np.where(right, zero, dy), np.where(right, zero, np.abs(dy))]
    else:
        parts = [dx, dy, np.abs(dx), np.abs(dy)]
    vec = np.stack([_block_sums(part) for part in parts], axis=3).reshape(len(patch), -1)
    square_mag = np.cumsum((vec * vec).astype(np.float64), axis=1)[:, -1] if len(vec) else np.zeros(0)
    scale = (1.0 / (np.sqrt(square_mag) + np.finfo(F32).eps)).astype(F32)
    return vec * scale[:, None]
