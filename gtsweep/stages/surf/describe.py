"""SURF orientation and descriptor, vectorised over keypoints.

Follows Bay, Ess, Tuytelaars, Van Gool, "Speeded-Up Robust Features (SURF)", CVIU 110(3), 2008 (section 4.1:
orientation from Haar wavelet responses in a sliding 60-degree window; section 4.2: 4x4 sub-regions of
(sum dx, sum dy, sum |dx|, sum |dy|)) exactly as OpenCV implements it in
``opencv_contrib/modules/xfeatures2d/src/surf.cpp`` (``SURFInvoker``; Apache-2.0, original code by Liu Liu,
revised by Ian Mahon): the same sampling grid, rounding, float32 arithmetic and summation order, and the same
``cv2.phase``, ``cv2.getGaussianKernel`` and ``cv2.resize(INTER_AREA)`` calls. Only the loops over keypoints are
replaced by array operations (keypoints are grouped by window size; loops run over groups or batches). On real
textures this gives OpenCV's angles bit for bit and descriptors equal to within a few float32 ulps.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.stages.surf.hessian import box_response, scale_boxes
from gtsweep.stages.surf.windows import batch_pixels, rotated_windows

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


#: Coefficients of OpenCV's ``atan_f32`` polynomial, in degrees (float32 products as in mathfuncs_core).
ATAN_COEFFS = tuple(F32(c) * F32(180 / np.pi)
                    for c in (0.9997878412794807, -0.3258083974640975, 0.1555786518463281, -0.04432655554792128))


def sample_angles_degrees(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``cv2.phase`` in degrees: what surf.cpp uses for the angles of the orientation samples."""
    y, x = np.asarray(y, dtype=F32), np.asarray(x, dtype=F32)
    if x.size == 0:
        return np.zeros(x.shape, F32)
    return cv2.phase(x.reshape(-1, 1), y.reshape(-1, 1), angleInDegrees=True).reshape(x.shape)


def fast_atan2_degrees(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """OpenCV's scalar ``fastAtan2(y, x)`` (a 7th-order polynomial, ~0.3 degree accuracy) in float32, [0, 360)."""
    y, x = np.asarray(y, dtype=F32), np.asarray(x, dtype=F32)
    p1, p3, p5, p7 = ATAN_COEFFS
    ax, ay = np.abs(x), np.abs(y)
    x_major = ax >= ay
    eps = F32(np.finfo(np.float64).eps)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(x_major, ay, ax) / (np.where(x_major, ax, ay) + eps)
    c2 = c * c
    poly = (((p7 * c2 + p5) * c2 + p3) * c2 + p1) * c
    a = np.where(x_major, poly, F32(90) - poly)
    a = np.where(x < 0, F32(180) - a, a)
    return np.where(y < 0, F32(360) - a, a)


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
    with np.errstate(invalid="ignore"):  # wavelet side 0 (size < 1.9): 0 * inf; OpenCV's NaNs end as angle 0
        resp_x = box_response(integral, corners_x[:, None], weights_x[:, None], safe_y, safe_x) * weights
        resp_y = box_response(integral, corners_y[:, None], weights_y[:, None], safe_y, safe_x) * weights
    usable = inside & (wavelet > 0)[:, None]
    resp_x, resp_y = np.where(usable, resp_x, F32(0)), np.where(usable, resp_y, F32(0))
    rounded = np.rint(sample_angles_degrees(resp_y, resp_x)).astype(np.int64)
    sum_x, sum_y = (_window_sums(resp, rounded % 360, inside) for resp in (resp_x, resp_y))
    strength = sum_x * sum_x + sum_y * sum_y
    best = np.argmax(strength, axis=1)
    chosen = strength[np.arange(len(best)), best] > 0
    # The winning window's sums again, now in float32 and in sample order as OpenCV adds them.
    distance = np.abs(rounded - (best * ORI_SEARCH_STEP)[:, None])
    in_best = inside & ((distance < ORI_WINDOW // 2) | (distance > 360 - ORI_WINDOW // 2)) & chosen[:, None]
    best_x, best_y = (np.cumsum(np.where(in_best, resp, F32(0)), axis=1, dtype=F32)[:, -1]
                      for resp in (resp_x, resp_y))
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


def _upright_windows(gray: np.ndarray, x, y, win: int) -> np.ndarray:
    """OpenCV's upright windows ``(n, win, win)``: pixel ``(start_x + i, start_y - j)``, clamped (transposed)."""
    offset = F32(-(win - 1) / 2)
    steps = np.arange(win)
    cols = np.clip(np.rint(x + offset).astype(np.intp)[:, None, None] + steps[None, :, None], 0, gray.shape[1] - 1)
    rows = np.clip(np.rint(y - offset).astype(np.intp)[:, None, None] - steps[None, None, :], 0, gray.shape[0] - 1)
    return gray[rows, cols]


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
    pixels = gray.astype(F32).ravel()
    out = np.zeros((len(x), PATCH_SIZE + 1, PATCH_SIZE + 1), np.uint8)
    for win in np.unique(win_sizes):
        members = np.flatnonzero(win_sizes == win)
        batch = max(1, batch_pixels() // int(win * win))
        for start in range(0, len(members), batch):
            idx = members[start:start + batch]
            if upright:
                windows = _upright_windows(gray, x[idx], y[idx], int(win))
            else:
                windows = rotated_windows(gray, pixels, x[idx], y[idx], angle[idx], int(win))
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
