"""MSD's saliency (:func:`gtsweep.stages.msd.saliency`) compiled by Numba: the same float32 map, bit for bit.

The NumPy path makes ~20 passes over a strip per pair of opposite offsets (difference, square, a separable sum,
14 min/max passes that keep the k smallest), each through memory: ~0.9 CPU-s per 1288x964 view. This loop does
the same integer arithmetic row by row, with every row's working set in the core's cache:

- per offset d, a running column sum of the squared differences over the patch's 2 r_s + 1 rows (one row enters,
  one leaves), then the patch sums of one row of centres as 2 r_s + 1 shifted additions;
- that row is offset d's sum at the centres of row y and offset -d's at the centres of row y + d_y, shifted by d_x
  (the sum for -d at p + d is the sum for d at p); both are inserted into the k smallest of their row (a ring of
  r_b + 1 rows of ``int32``, by min/max exchanges);
- a row whose offsets are all in is done: the mean of its k smallest in msd.cpp's float32 order.

Sums are integers (exact in ``int32``), ``INT_MAX`` stands for msd.cpp's unset sums as in the NumPy path, and the
float32 additions and the division are the same operations in the same order without fast-math, so the map does
not depend on the machine. ``r_s``, ``r_b`` and ``k`` are compile-time constants (one compiled kernel per
setting; Numba caches it on disk), so the inner loops unroll and vectorise.

``GTSWEEP_MSD_KERNEL=numpy`` forces the NumPy path (the tests compare both).
"""
from __future__ import annotations

import functools
import logging
import os

import numpy as np

log = logging.getLogger(__name__)

#: The environment variable that forces the NumPy saliency ("numpy") instead of the compiled one.
KERNEL_ENV = "GTSWEEP_MSD_KERNEL"
#: msd.cpp's start value of the k smallest sums.
INT_MAX = np.int32(2 ** 31 - 1)


def _saliency_loop(patch_radius: int, search_radius: int, knn: int):
    """The saliency loop, ``loop(image, out)``, with its setting as constants in its closure (compiled by Numba;
    plain Python is far too slow). ``out`` must be zero within r_s + r_b of the border."""
    r, side, border, ring_rows = patch_radius, 2 * patch_radius + 1, patch_radius + search_radius, search_radius + 1
    k, denominator, unset = knn, np.float32((2 * patch_radius + 1) ** 2 * knn), INT_MAX
    dy, dx = np.mgrid[0:search_radius + 1, -search_radius:search_radius + 1].reshape(2, -1).astype(np.int64)
    offset_dy, offset_dx = dy[(dy > 0) | (dx > 0)], dx[(dy > 0) | (dx > 0)]  # half of the offsets, row-major

    def loop(image, out):
        rows, cols = image.shape
        pixels = image.astype(np.int32)
        column_sums = np.zeros((len(offset_dy), cols), np.int32)
        patch_sums = np.empty(cols, np.int32)
        width = cols - 2 * border
        smallest = np.full((ring_rows, k, width), unset, np.int32)
        for y in range(r, rows - border):  # rows of centres: offset d's sums serve row y and, as -d's, row y + dy
            for o in range(len(offset_dy)):
                # loops run from 0 over views: Numba then drops its negative-index checks and LLVM vectorises
                dy, dx = offset_dy[o], offset_dx[o]
                lo = border - max(dx, 0) - r
                n = width + abs(dx) + 2 * r
                sums = column_sums[o, lo:lo + n]
                for t in range(side if y == r else 0):  # the first row: the patch's rows summed
                    here, there = pixels[t, lo:lo + n], pixels[t + dy, lo + dx:lo + dx + n]
                    for x in range(n):
                        d = there[x] - here[x]
                        sums[x] += d * d
                if y > r:  # the patch's rows move down by one
                    enter, enter_d = pixels[y + r, lo:lo + n], pixels[y + r + dy, lo + dx:lo + dx + n]
                    leave, leave_d = pixels[y - r - 1, lo:lo + n], pixels[y - r - 1 + dy, lo + dx:lo + dx + n]
                    for x in range(n):
                        a, b = enter_d[x] - enter[x], leave_d[x] - leave[x]
                        sums[x] += a * a - b * b
                for x in range(n - 2 * r):  # patch_sums[i]: the centre at column lo + r + i
                    total = sums[x]
                    for u in range(1, side):
                        total += sums[x + u]
                    patch_sums[x] = total
                for target, first in ((y, max(dx, 0)), (y + dy, max(-dx, 0))):  # d at row y, -d at row y + dy
                    if border <= target < rows - border:
                        best, values = smallest[target % ring_rows], patch_sums[first:first + width]
                        for x in range(width):  # insert into the ascending k smallest
                            v = values[x]
                            for q in range(k - 1):
                                a = best[q, x]
                                best[q, x] = min(a, v)
                                v = max(a, v)
                            best[k - 1, x] = min(best[k - 1, x], v)
            if y >= border:  # all of row y's offsets are in
                best, row = smallest[y % ring_rows], out[y, border:cols - border]
                for x in range(width):
                    total = np.float32(best[0, x])
                    for q in range(1, k):  # msd.cpp adds the k smallest in ascending order
                        total = total + np.float32(best[q, x])
                    row[x] = total / denominator
                best[:] = unset

    return loop


@functools.cache
def compiled_kernel(patch_radius: int, search_radius: int, knn: int):
    """The Numba-compiled saliency loop for one setting (compiled here, once per process, or read from Numba's
    cache), or None when Numba is not installed, cannot compile it (a warning), or the NumPy path is forced."""
    if os.environ.get(KERNEL_ENV, "").lower() == "numpy":
        return None
    try:
        import numba
    except ImportError:
        return None
    try:
        return numba.njit("void(uint8[:, ::1], float32[:, ::1])", cache=True, nogil=True, fastmath=False,
                          error_model="numpy")(_saliency_loop(patch_radius, search_radius, knn))
    except Exception as e:  # noqa: BLE001 - any Numba/LLVM failure: the NumPy path gives the same numbers
        log.warning("MSD: Numba could not compile the saliency loop (%s); using the NumPy path",
                    str(e).splitlines()[0] if str(e) else type(e).__name__)
        return None


def saliency_compiled(image: np.ndarray, patch_radius: int, search_radius: int, knn: int) -> np.ndarray | None:
    """:func:`gtsweep.stages.msd.saliency` of a 2-D uint8 ``image`` by the compiled loop, or None where there is
    none (or for another image type)."""
    if image.ndim != 2 or image.dtype != np.uint8 or knn < 1:
        return None
    loop = compiled_kernel(int(patch_radius), int(search_radius), int(knn))
    if loop is None:
        return None
    out = np.zeros(image.shape, np.float32)
    border = patch_radius + search_radius
    if image.shape[0] > 2 * border and image.shape[1] > 2 * border:
        loop(np.ascontiguousarray(image), out)
    return out
