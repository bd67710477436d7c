"""MSD, the Maximal Self-Dissimilarity detector (Tombari & Di Stefano, "Interest Points via Maximal
Self-Dissimilarities", ACCV 2014), as OpenCV's ``cv2.xfeatures2d.MSDDetector`` computes it, vectorised.

OpenCV's ``opencv_contrib/modules/xfeatures2d/src/msd.cpp`` (a port of github.com/fedassa/msdDetector by Federico
Tombari and Daniele De Gregorio; OpenCV is distributed under the Apache License 2.0) visits each pixel of each
pyramid level and each of the (2 r_b + 1)² - 1 offsets of its search area with scalar code: on a 1288×964 view
that is 3.4 s, most of the survey protocol's detection time. Here the saliency has two implementations with the
same bytes: :func:`saliency_numpy`, where each pair of opposite offsets is one pass over a strip of rows (the squared
difference of the image and its shifted copy, summed over the patch by a separable filter of ones, the k smallest
kept by a min/max insertion), ~20 passes through memory per pair of offsets, ~0.9 CPU-s per view
(``docs/performance.md`` lists what else was tried); and, where Numba is installed (``pip install gtsweep[fast]``),
the same integer arithmetic in one compiled loop over rows (:mod:`gtsweep.stages.msd_compiled`), ~0.3 CPU-s.
The numbers are OpenCV's, bit for bit: the patch sums are integers (exact in float32 below 2^24: at most
(2 r_s + 1)² · 255² · k), the mean of the k smallest is the same float32 division, the pyramid is OpenCV's own
``resize(INTER_AREA)``, and the non-maximum suppression and the sub-pixel step replay msd.cpp's float and double
arithmetic (``cv::solve``'s 2×2 Cramer rule in double); ``tests/test_msd.py`` compares keypoints with OpenCV's on
views, transforms and masks, with either saliency.

Settings the fast path does not cover (``m_compute_orientation``, a patch sum that could leave float32's
integers, ``m_nms_scale_radius`` > 0, where msd.cpp indexes level k with level r's width, out of bounds, and its
keypoints vary from call to call) are handed to OpenCV's implementation.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import functools
import math

import cv2
import numpy as np

from gtsweep.stages import keypoints as kp
from gtsweep.stages.msd_compiled import saliency_compiled

#: Rows of centres per strip: a strip's few working arrays stay in the core's cache.
STRIP_ROWS = 64
#: msd.cpp's start value of the k smallest sums (INT_MAX): with k above the offsets' count it enters the mean.
_UNSET = np.float32(2 ** 31 - 1)


@functools.cache
def _logf(value: float) -> float:
    """The C library's ``logf``, which msd.cpp's ``std::log(float)`` calls (NumPy's float32 log is its own SIMD
    code and differs in the last bit for some inputs)."""
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    libm.logf.restype, libm.logf.argtypes = ctypes.c_float, [ctypes.c_float]
    return float(libm.logf(value))


def _levels(image: np.ndarray, patch_radius: int, search_radius: int, scale_factor: np.float32,
            n_scales: int) -> list[np.ndarray]:
    """msd.cpp's pyramid: level r is the input resized by INTER_AREA to round(size / scale_factor^r) (float)."""
    rows, cols = image.shape
    if n_scales == -1:  # cvFloor(log(min / (2 (r_s + r_b) + 1.0)) / std::log(float))
        n_scales = math.floor(math.log(min(cols, rows) / ((patch_radius + search_radius) * 2.0 + 1))
                              / _logf(float(scale_factor)))
    if n_scales < 1:  # a view too small for one search area (msd.cpp would index an empty pyramid)
        return []
    levels = [image]
    for level in range(1, n_scales):
        scale = np.float32(1) / (scale_factor ** np.float32(level))  # a NumPy scalar's **: libm's powf
        size = (int(np.rint(np.float32(cols) * scale)), int(np.rint(np.float32(rows) * scale)))
        levels.append(cv2.resize(image, size, interpolation=cv2.INTER_AREA))
    return levels


def _insert(smallest: np.ndarray, value: np.ndarray, spare: tuple) -> None:
    """Insert ``value`` into the ascending ``smallest`` (k, rows, cols) in place; the largest drops out."""
    k = len(smallest)
    for q in range(k - 1):
        larger = spare[q % 2]
        np.maximum(smallest[q], value, out=larger)
        np.minimum(smallest[q], value, out=smallest[q])
        value = larger
    np.minimum(smallest[k - 1], value, out=smallest[k - 1])


def saliency(image: np.ndarray, patch_radius: int = 3, search_radius: int = 5, knn: int = 4) -> np.ndarray:
    """:func:`saliency_numpy`'s map, by the compiled loop of :mod:`gtsweep.stages.msd_compiled` where Numba is
    installed (the same bytes, ~5x faster: 0.19-0.23 against 1.06 CPU-s for a 1288x964 view's levels), else by
    :func:`saliency_numpy`."""
    compiled = saliency_compiled(image, patch_radius, search_radius, knn)
    return saliency_numpy(image, patch_radius, search_radius, knn) if compiled is None else compiled


def saliency_numpy(image: np.ndarray, patch_radius: int = 3, search_radius: int = 5, knn: int = 4) -> np.ndarray:
    """The contextual self-dissimilarity of every pixel of a uint8 ``image``: the mean of the ``knn`` smallest
    sums of squared differences between the (2 r_s + 1)² patch at the pixel and the patches at the other pixels of
    its (2 r_b + 1)² search area, over the patch's pixel count (msd.cpp ``contextualSelfDissimilarity``); 0 within
    r_s + r_b of the border. float32, equal to OpenCV's.

    The sum for offset d at p is the sum for -d at p + d: each map of a half of the offsets, computed on a strip
    grown by the offset, serves both."""
    rows, cols = image.shape
    r, border, side = patch_radius, patch_radius + search_radius, 2 * patch_radius + 1
    out = np.zeros((rows, cols), np.float32)
    width = cols - 2 * border
    if width <= 0 or rows - 2 * border <= 0:
        return out
    pixels = image.astype(np.float32)
    ones = np.ones(side, np.float32)
    half = [(dy, dx) for dy in range(0, search_radius + 1) for dx in range(-search_radius, search_radius + 1)
            if dy > 0 or dx > 0]
    for top in range(border, rows - border, STRIP_ROWS):
        bottom = min(top + STRIP_ROWS, rows - border)
        height = bottom - top
        smallest = np.full((knn, height, width), _UNSET, np.float32)
        spare = (np.empty((height, width), np.float32), np.empty((height, width), np.float32))
        for dy, dx in half:
            left, right = max(dx, 0), max(-dx, 0)  # the map's extra columns
            y0, y1, x0, x1 = top - dy - r, bottom + r, border - left - r, cols - border + right + r
            diff = pixels[y0 + dy:y1 + dy, x0 + dx:x1 + dx] - pixels[y0:y1, x0:x1]
            np.multiply(diff, diff, out=diff)
            # a separable filter of ones: float32 sums of integers below 2^24, exact in any order
            summed = cv2.sepFilter2D(diff, -1, ones, ones, borderType=cv2.BORDER_CONSTANT)
            summed = summed[r:summed.shape[0] - r, r:summed.shape[1] - r]
            _insert(smallest, summed[dy:dy + height, left:left + width], spare)  # offset d at p
            _insert(smallest, summed[:height, right:right + width], spare)  # offset -d at p: the map at p - d
        total = smallest[0]
        for q in range(1, knn):  # msd.cpp adds the k smallest in ascending order (exact: integers below 2^24)
            total = total + smallest[q]
        out[top:bottom, border:cols - border] = total / np.float32(side * side * knn)
    return out


def _local_maxima(level_saliency: np.ndarray, border: int, radius: int, threshold: np.float32):
    """Rows and columns (row-major order) where the saliency exceeds ``threshold`` and no pixel of the
    (2 radius + 1)² window, clipped to the region ``border`` inside the level, is larger (msd.cpp's NMS)."""
    inner = level_saliency[border:level_saliency.shape[0] - border, border:level_saliency.shape[1] - border]
    if inner.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    radius = max(radius, 0)  # msd.cpp's window loop is empty for a negative radius: no suppression
    window = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius + 1, 2 * radius + 1))
    largest = cv2.dilate(inner, window)  # the default border never wins: the window is clipped
    rows, cols = np.nonzero((inner > threshold) & (inner >= largest))
    return rows + border, cols + border


def _refine(sal: np.ndarray, i: np.ndarray, j: np.ndarray):
    """msd.cpp ``rescalePoint``'s sub-pixel offsets (xc, xr) at columns ``i``, rows ``j`` of a level's saliency, in
    its float32 arithmetic, and the 2×2 solve of ``cv::solve(DECOMP_LU)`` (Cramer's rule in double; a singular
    Hessian leaves the offsets 0)."""
    c, left, right, up, down = sal[j, i], sal[j, i - 1], sal[j, i + 1], sal[j - 1, i], sal[j + 1, i]
    half, quarter = np.float32(0.5), np.float32(0.25)
    gx, gy = (right - left) * half, (down - up) * half
    cc = c * np.float32(2)
    dxx, dyy = (right + left) - cc, (down + up) - cc
    dxy = (((sal[j + 1, i + 1] - sal[j + 1, i - 1]) - sal[j - 1, i + 1]) + sal[j - 1, i - 1]) * quarter
    det = dxx.astype(np.float64) * dyy - dxy.astype(np.float64) * dxy
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inverse = 1.0 / det
        x0 = ((gx.astype(np.float64) * dyy - gy.astype(np.float64) * dxy) * inverse).astype(np.float32)
        x1 = ((gy.astype(np.float64) * dxx - gx.astype(np.float64) * dxy) * inverse).astype(np.float32)
    singular = det == 0
    x0[singular], x1[singular] = 0, 0
    return -x0, -x1


class FastMSD:
    """OpenCV's ``MSDDetector`` interface (``detect``) with the vectorised computation of this module."""

    implementation = "gtsweep-numpy"

    def __init__(self, m_patch_radius=3, m_search_area_radius=5, m_nms_radius=5, m_nms_scale_radius=0,
                 m_th_saliency=250.0, m_kNN=4, m_scale_factor=1.25, m_n_scales=-1, m_compute_orientation=False):
        self.params = dict(m_patch_radius=m_patch_radius, m_search_area_radius=m_search_area_radius,
                           m_nms_radius=m_nms_radius, m_nms_scale_radius=m_nms_scale_radius,
                           m_th_saliency=m_th_saliency, m_kNN=m_kNN, m_scale_factor=m_scale_factor,
                           m_n_scales=m_n_scales, m_compute_orientation=m_compute_orientation)
        side = 2 * int(m_patch_radius) + 1
        self.fast = (not m_compute_orientation and int(m_nms_scale_radius) == 0
                     and side * side * 255 ** 2 * int(m_kNN) < 2 ** 24)

    def _covered(self, image: np.ndarray, mask: np.ndarray | None) -> bool:
        """Inputs whose keypoints this module reproduces: a gray uint8 view; a mask of bytes (msd.cpp reads its
        raw bytes), and only where a refined point cannot leave the view (r_s + r_b >= 5: msd.cpp's second mask
        read is unchecked)."""
        p = self.params
        masked = mask is not None and mask.size > 0
        return (self.fast and image.ndim == 2 and image.dtype == np.uint8
                and (not masked or (mask.ndim == 2 and mask.dtype.itemsize == 1
                                    and int(p["m_patch_radius"]) + int(p["m_search_area_radius"]) >= 5)))

    def _opencv(self):
        return cv2.xfeatures2d.MSDDetector_create(*self.params.values())

    def detect(self, image: np.ndarray, mask: np.ndarray | None = None) -> list[cv2.KeyPoint]:
        if not self._covered(image, mask):
            return list(self._opencv().detect(image, mask))
        return kp.to_keypoints(self.detect_array(image, mask))

    def detect_array(self, image: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """The keypoints as an ``(N, 7)`` array (:mod:`gtsweep.stages.keypoints`) in OpenCV's order: what
        :func:`~gtsweep.stages.keypoints.to_array` makes of OpenCV's, without the ``cv2.KeyPoint`` objects."""
        if not self._covered(image, mask):
            return kp.to_array(self._opencv().detect(image, mask))
        p = self.params
        rs, rb, radius = int(p["m_patch_radius"]), int(p["m_search_area_radius"]), int(p["m_nms_radius"])
        factor, threshold = np.float32(p["m_scale_factor"]), np.float32(p["m_th_saliency"])
        border, rows0, cols0 = rs + rb, *image.shape
        mask = None if mask is None or mask.size == 0 else mask
        found = []
        for r, level in enumerate(_levels(image, rs, rb, factor, int(p["m_n_scales"]))):
            sal = saliency(level, rs, rb, int(p["m_kNN"]))
            j, i = _local_maxima(sal, border, radius, threshold)
            power = factor ** np.float32(r)  # positions and size: powf, as msd.cpp's results show
            if mask is not None:  # the first mask read: cvRound(j * pow(scale, r)) in double
                full = float(factor) ** r
                at = (np.minimum(np.rint(j * full).astype(np.int64), rows0 - 1),
                      np.minimum(np.rint(i * full).astype(np.int64), cols0 - 1))
                keep = mask[at] != 0
                j, i = j[keep], i[keep]
            xc, xr = _refine(sal, i, j)
            keep = (np.abs(xr) <= 5) & (np.abs(xc) <= 5)
            j, i, xc, xr = j[keep], i[keep], xc[keep], xr[keep]
            x = i.astype(np.float32) + xc + np.float32(0.5)
            y = j.astype(np.float32) + xr + np.float32(0.5)
            if r > 0:
                x, y = x * power - np.float32(0.5), y * power - np.float32(0.5)
                keep = (x >= 0) & (x < cols0) & (y >= 0) & (y < rows0)
                j, i, x, y = j[keep], i[keep], x[keep], y[keep]
            if mask is not None:
                keep = mask[y.astype(np.int64), x.astype(np.int64)] != 0
                j, i, x, y = j[keep], i[keep], x[keep], y[keep]
            array = np.zeros((len(x), len(kp.COLUMNS)))
            array[:, kp.X], array[:, kp.Y] = x, y
            array[:, kp.SIZE] = np.float32(rs * 2.0 + 1) * power
            array[:, kp.ANGLE], array[:, kp.RESPONSE] = -1.0, sal[j, i]
            array[:, kp.OCTAVE], array[:, kp.CLASS_ID] = r, -1
            found.append(array)
        return np.concatenate(found) if found else kp.empty()


#: An MSD detector with ``cv2.xfeatures2d.MSDDetector_create``'s arguments and OpenCV's keypoints.
MSD_create = FastMSD
