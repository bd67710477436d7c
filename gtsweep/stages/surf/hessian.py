"""SURF detection: integral image, box-filter Hessian, 3x3x3 maxima and sub-pixel interpolation.

Follows Bay, Ess, Tuytelaars, Van Gool, "Speeded-Up Robust Features (SURF)", CVIU 110(3), 2008 (section 3: the
fast-Hessian detector) exactly as OpenCV implements it in ``opencv_contrib/modules/xfeatures2d/src/surf.cpp``
(``calcLayerDetAndTrace``, ``SURFFindInvoker::findMaximaInLayer``, ``interpolateKeypoint``,
``fastHessianDetector``; Apache-2.0, original code by Liu Liu, revised by Ian Mahon). Arithmetic is done in the
same precision and order as OpenCV's (float32 products, float64 accumulation of box terms, float32 Cramer solve),
so responses and positions agree with OpenCV's to the last bit or so.

Keypoints leave this module as an ``(N, 7)`` float64 array with the columns of :mod:`gtsweep.stages.keypoints`
(x, y, size, angle, response, octave, class_id), angle -1, sorted as OpenCV sorts them.
"""
from __future__ import annotations

import cv2
import numpy as np

from gtsweep.stages.keypoints import COLUMNS

F32 = np.float32

#: Filter side of the first layer of the first octave (surf.cpp ``SURF_HAAR_SIZE0``) and its growth per layer.
HAAR_SIZE0 = 9
HAAR_SIZE_INC = 6
#: 9x9 base box patterns ``(x1, y1, x2, y2, weight)`` of the second-derivative filters (Bay et al. fig. 1).
DXX_BOXES = ((0, 2, 3, 7, 1), (3, 2, 6, 7, -2), (6, 2, 9, 7, 1))
DYY_BOXES = ((2, 0, 7, 3, 1), (2, 3, 7, 6, -2), (2, 6, 7, 9, 1))
DXY_BOXES = ((1, 1, 4, 4, 1), (5, 1, 8, 4, -1), (1, 5, 4, 8, -1), (5, 5, 8, 8, 1))
#: The mean filter used to test the detection mask over a filter's footprint.
MASK_BOX = ((0, 0, 9, 9, 1),)
#: Relative weight of Dxy in det(H) = Dxx Dyy - (0.9 Dxy)^2 (Bay et al. eq. 4).
DXY_WEIGHT = F32(0.81)


def integral_image(gray: np.ndarray) -> np.ndarray:
    """The ``(H+1, W+1)`` int32 integral image of an 8-bit image (``cv2.integral`` with ``CV_32S``)."""
    return cv2.integral(gray, sdepth=cv2.CV_32S)


def scale_boxes(boxes, base_size, new_size):
    """Scale box patterns from ``base_size`` to ``new_size`` like surf.cpp's ``resizeHaarPattern``.

    ``new_size`` may be a scalar or an array (one filter size per keypoint). Returns integer corners of shape
    ``(*shape(new_size), n_boxes, 4)`` as (x1, y1, x2, y2) and float32 weights ``(*shape, n_boxes)``: each box's
    weight divided by its area. Corners are ``cvRound(ratio * c)`` with ``ratio = float(new) / old`` in float32
    (cvRound rounds half to even, as ``np.rint`` does).
    """
    base = np.asarray(boxes, dtype=np.int64)
    ratio = (np.asarray(new_size, dtype=F32) / F32(base_size))[..., None, None]
    corners = np.rint(ratio * base[:, :4].astype(F32)).astype(np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        area = ((corners[..., 2] - corners[..., 0]) * (corners[..., 3] - corners[..., 1])).astype(F32)
        weights = base[:, 4].astype(F32) / area
    return corners, weights


def _weighted_total(box_sums, weights) -> np.ndarray:
    """OpenCV's ``calcHaarPattern`` arithmetic: each int box sum times its float32 weight, added in float64."""
    total = None
    for k, box_sum in enumerate(box_sums):
        term = box_sum.astype(F32) * weights[..., k]
        total = term.astype(np.float64) if total is None else total + term
    return total.astype(F32)


def box_response(integral: np.ndarray, corners: np.ndarray, weights: np.ndarray, ys, xs) -> np.ndarray:
    """Weighted sum of box sums with the pattern's top-left corner at ``(ys, xs)`` (surf.cpp ``calcHaarPattern``).

    ``ys`` and ``xs`` broadcast against each other. ``corners``/``weights`` come from :func:`scale_boxes`, either
    one pattern for all positions or one pattern per position (leading axes broadcasting with ``ys``). Each box
    sum is an int, multiplied by its float32 weight; the terms are added in float64 and the total rounded to
    float32, as OpenCV does.
    """
    flat = integral.ravel()
    width = integral.shape[1]
    origin = np.asarray(ys, dtype=np.int64) * width + np.asarray(xs, dtype=np.int64)

    def box_sums():
        for k in range(corners.shape[-2]):
            x1, y1, x2, y2 = (corners[..., k, c] for c in range(4))
            yield (flat[origin + (y1 * width + x1)] + flat[origin + (y2 * width + x2)]
                   - flat[origin + (y2 * width + x1)] - flat[origin + (y1 * width + x2)])
    return _weighted_total(box_sums(), weights)


def grid_box_response(integral: np.ndarray, corners: np.ndarray, weights: np.ndarray, n_rows: int, n_cols: int,
                      step: int) -> np.ndarray:
    """:func:`box_response` of one pattern on the grid of corners ``(step * i, step * j)``, by strided slices."""
    def corner(x, y):
        return integral[y:y + step * n_rows:step, x:x + step * n_cols:step]

    def box_sums():
        for x1, y1, x2, y2 in corners.tolist():
            yield corner(x1, y1) + corner(x2, y2) - corner(x1, y2) - corner(x2, y1)
    return _weighted_total(box_sums(), weights)


def layer_sizes(n_octaves: int, n_octave_layers: int):
    """Filter side and sampling step of every layer, octave by octave: ``(9 + 6 l) << o`` and ``1 << o``.

    There are ``n_octave_layers + 2`` layers per octave (one below and one above each middle layer).
    """
    sizes = [(HAAR_SIZE0 + HAAR_SIZE_INC * layer) << octave
             for octave in range(n_octaves) for layer in range(n_octave_layers + 2)]
    steps = [1 << octave for octave in range(n_octaves) for _ in range(n_octave_layers + 2)]
    return sizes, steps


def layer_det_and_trace(integral: np.ndarray, size: int, step: int):
    """Determinant and trace of the box-filter Hessian of one layer (surf.cpp ``calcLayerDetAndTrace``).

    Arrays have shape ``(H // step, W // step)``; sample ``(i, j)`` has its filter's top-left corner at pixel
    ``(step * (i - margin), step * (j - margin))`` with ``margin = (size // 2) // step``. Samples whose filter
    would leave the image stay 0 (OpenCV leaves them unset and never reads them).
    """
    height, width = integral.shape[0] - 1, integral.shape[1] - 1
    det = np.zeros((height // step, width // step), dtype=F32)
    trace = np.zeros_like(det)
    if size > height or size > width:
        return det, trace
    n_rows, n_cols = 1 + (height - size) // step, 1 + (width - size) // step
    margin = (size // 2) // step
    dxx, dyy, dxy = (grid_box_response(integral, *scale_boxes(boxes, HAAR_SIZE0, size), n_rows, n_cols, step)
                     for boxes in (DXX_BOXES, DYY_BOXES, DXY_BOXES))
    det[margin:margin + n_rows, margin:margin + n_cols] = dxx * dyy - DXY_WEIGHT * dxy * dxy
    trace[margin:margin + n_rows, margin:margin + n_cols] = dxx + dyy
    return det, trace


def solve_offsets(n9: np.ndarray) -> np.ndarray:
    """Sub-sample offsets (x, y, scale) of maxima by one Newton step (Brown & Lowe; surf.cpp ``interpolateKeypoint``).

    ``n9`` is ``(N, 3, 9)`` float32: the 3x3 neighbourhoods in the layer below, at and above the maximum
    (row-major, the maximum at ``n9[:, 1, 4]``). The 3x3 system is solved by Cramer's rule in float32, as OpenCV's
    ``Matx33f::solve`` does; a singular system gives offset 0 (which the caller rejects).
    """
    half, quarter, two = F32(2), F32(4), F32(2)
    lo, mid, hi = n9[:, 0], n9[:, 1], n9[:, 2]
    b0 = -(mid[:, 5] - mid[:, 3]) / half
    b1 = -(mid[:, 7] - mid[:, 1]) / half
    b2 = -(hi[:, 4] - lo[:, 4]) / half
    a00 = mid[:, 3] - two * mid[:, 4] + mid[:, 5]
    a01 = (mid[:, 8] - mid[:, 6] - mid[:, 2] + mid[:, 0]) / quarter
    a02 = (hi[:, 5] - hi[:, 3] - lo[:, 5] + lo[:, 3]) / quarter
    a11 = mid[:, 1] - two * mid[:, 4] + mid[:, 7]
    a12 = (hi[:, 7] - hi[:, 1] - lo[:, 7] + lo[:, 1]) / quarter
    a22 = lo[:, 4] - two * mid[:, 4] + hi[:, 4]
    a10, a20, a21 = a01, a02, a12
    det = a00 * (a11 * a22 - a21 * a12) - a01 * (a10 * a22 - a20 * a12) + a02 * (a10 * a21 - a20 * a11)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = F32(1) / det
        x0 = inv * (b0 * (a11 * a22 - a12 * a21) - a01 * (b1 * a22 - a12 * b2) + a02 * (b1 * a21 - a11 * b2))
        x1 = inv * (a00 * (b1 * a22 - a12 * b2) - b0 * (a10 * a22 - a12 * a20) + a02 * (a10 * b2 - b1 * a20))
        x2 = inv * (a00 * (a11 * b2 - b1 * a21) - a01 * (a10 * b2 - b1 * a20) + b0 * (a10 * a21 - a11 * a20))
    offsets = np.stack([x0, x1, x2], axis=1)
    offsets[det == 0] = 0
    return offsets


def _neighbourhoods(dets, layer: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The ``(N, 3, 9)`` det samples around ``(rows, cols)`` in layers ``layer-1 .. layer+1``."""
    dr, dc = np.divmod(np.arange(9), 3)
    r = rows[:, None] + dr - 1
    c = cols[:, None] + dc - 1
    return np.stack([dets[layer + k][r, c] for k in (-1, 0, 1)], axis=1)


def _strong_planar_maxima(det, row0, row1, col0, col1, threshold):
    """Samples in ``det[row0:row1, col0:col1]`` above ``threshold`` and strictly above their 8 in-layer neighbours.

    A cheap first cut before the 3x3x3 test: it keeps exactly the samples that can pass it.
    """
    if row1 <= row0 or col1 <= col0:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    centre = det[row0:row1, col0:col1]
    keep = centre > F32(threshold)
    for dr, dc in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
        keep &= centre > det[row0 + dr:row1 + dr, col0 + dc:col1 + dc]
    rows, cols = np.nonzero(keep)
    return rows + row0, cols + col0


def find_layer_maxima(integral, mask_integral, dets, traces, sizes, layer, octave, step, threshold):
    """Interpolated maxima of one middle layer (surf.cpp ``findMaximaInLayer``), as an ``(N, 7)`` array.

    A sample is a keypoint when its det exceeds ``threshold``, at least half the mask under its filter is set
    (when a mask is given), it is strictly greater than its 26 neighbours, and the interpolated offset is nonzero
    with every component within 1 sample.
    """
    size = sizes[layer]
    det = dets[layer]
    layer_rows, layer_cols = (integral.shape[0] - 1) // step, (integral.shape[1] - 1) // step
    margin = (sizes[layer + 1] // 2) // step + 1
    rows, cols = _strong_planar_maxima(det, margin, layer_rows - margin, margin, layer_cols - margin, threshold)
    sum_i = step * (rows - (size // 2) // step)
    sum_j = step * (cols - (size // 2) // step)
    if mask_integral is not None:
        covered = box_response(mask_integral, *scale_boxes(MASK_BOX, HAAR_SIZE0, size), sum_i, sum_j)
        keep = covered >= 0.5
        rows, cols, sum_i, sum_j = rows[keep], cols[keep], sum_i[keep], sum_j[keep]
    n9 = _neighbourhoods(dets, layer, rows, cols)
    centre = n9[:, 1, 4]
    others = np.concatenate([n9[:, 0], n9[:, 1, :4], n9[:, 1, 5:], n9[:, 2]], axis=1)
    is_max = np.all(centre[:, None] > others, axis=1)
    n9, rows, cols, sum_i, sum_j = n9[is_max], rows[is_max], cols[is_max], sum_i[is_max], sum_j[is_max]
    offsets = solve_offsets(n9)
    ok = np.any(offsets != 0, axis=1) & np.all(np.abs(offsets) <= 1, axis=1)
    half_size = F32((size - 1) * 0.5)
    step32, ds32 = F32(step), F32(size - sizes[layer - 1])
    kps = np.zeros((int(ok.sum()), len(COLUMNS)), dtype=np.float64)
    kps[:, 0] = (sum_j[ok].astype(F32) + half_size) + offsets[ok, 0] * step32
    kps[:, 1] = (sum_i[ok].astype(F32) + half_size) + offsets[ok, 1] * step32
    kps[:, 2] = np.rint(F32(size) + offsets[ok, 2] * ds32)
    kps[:, 3] = -1
    kps[:, 4] = n9[ok, 1, 4]
    kps[:, 5] = octave
    kps[:, 6] = np.sign(traces[layer][rows[ok], cols[ok]])
    return kps


def sort_like_opencv(kps: np.ndarray) -> np.ndarray:
    """Order keypoints as surf.cpp's ``KeypointGreater``: response, size, octave, y descending, then x ascending."""
    order = np.lexsort((kps[:, 0], -kps[:, 1], -kps[:, 5], -kps[:, 2], -kps[:, 4]))
    return kps[order]


def detect_keypoints(gray: np.ndarray, integral: np.ndarray, mask: np.ndarray | None,
                     hessian_threshold: float, n_octaves: int, n_octave_layers: int) -> np.ndarray:
    """Fast-Hessian keypoints of an 8-bit image (surf.cpp ``fastHessianDetector`` plus the final mask test).

    Returns an ``(N, 7)`` array (angle -1) in OpenCV's order. With a mask, a maximum needs half its filter's
    footprint inside the mask, and its rounded position must fall on a set mask pixel.
    """
    mask_integral = None
    if mask is not None:
        mask_integral = integral_image(np.minimum(mask, 1).astype(np.uint8))
    sizes, steps = layer_sizes(n_octaves, n_octave_layers)
    dets, traces = zip(*(layer_det_and_trace(integral, size, step) for size, step in zip(sizes, steps)))
    per_octave = n_octave_layers + 2
    found = [find_layer_maxima(integral, mask_integral, dets, traces, sizes, octave * per_octave + layer,
                               octave, steps[octave * per_octave], hessian_threshold)
             for octave in range(n_octaves) for layer in range(1, n_octave_layers + 1)]
    kps = sort_like_opencv(np.concatenate(found, axis=0))
    if mask is not None and len(kps):
        xs = np.rint(kps[:, 0].astype(F32)).astype(np.int64)
        ys = np.rint(kps[:, 1].astype(F32)).astype(np.int64)
        kps = kps[mask[ys, xs] != 0]
    return kps
