"""MSD's saliency (:func:`gtsweep.stages.msd.saliency`) compiled by Numba: the same float32 map, bit for bit.

The NumPy path makes ~20 passes over a strip per pair of opposite offsets (difference, square, a separable sum,
14 min/max passes that keep the k smallest), each through memory: ~0.9 CPU-s per 1288x964 view. This loop does
the same integer arithmetic row by row, with every row's working set in the core's cache:

- per offset d, a running column sum of the squared differences over the patch's 2 r_s + 1 rows (one row enters,
  one leaves), then the patch sums of one row of centres as 2 r_s + 1 shifted additions;
- that row is offset d's sum at the centres of row y and offset -d's at the centres of row y + d_y, shifted by d_x
  (the sum for -d at p + d is the sum for d at p); both go into the k smallest of their row (a ring of r_b + 1
  rows of ``int32``), four offsets of one d_y at a time: with k = 4 (msd.cpp's default, the survey's setting) the
  four are sorted and merged with the row's four smallest by a min/max network (22 min/max operations and 4 stores
  instead of four insertions' 28 and 16), else each is inserted by min/max exchanges;
- a row whose offsets are all in is done: the mean of its k smallest in msd.cpp's float32 order.

Sums are integers (exact in ``int32``), ``INT_MAX`` stands for msd.cpp's unset sums as in the NumPy path (and fills
a group's unused places: the k smallest keep their values), and the float32 additions and the division are the
same operations in the same order without fast-math, so the map does not depend on the machine. ``r_s``, ``r_b``
and ``k`` are compile-time constants (one compiled kernel per setting; Numba caches it on disk), so the inner loops
unroll and vectorise.

``GTSWEEP_MSD_KERNEL=numpy`` forces the NumPy path (the tests compare both).
"""
from __future__ import annotations

import functools

import numpy as np

from gtsweep.stages.numba_types import compile_or_none

try:  # Numba is optional (gtsweep[fast]): without it the helpers stay Python and compiled_kernel gives None
    from numba import njit as _njit

    _inline = _njit(inline="always", nogil=True)
except ImportError:
    _njit = None

    def _inline(function):
        return function


#: The environment variable that forces the NumPy saliency ("numpy") instead of the compiled one.
KERNEL_ENV = "GTSWEEP_MSD_KERNEL"
#: msd.cpp's start value of the k smallest sums.
INT_MAX = np.int32(2 ** 31 - 1)
#: Offsets whose sums are computed and merged together (of one d_y, so that their -d share a row).
GROUP = 4


def offset_groups(search_radius: int):
    """Half of the search area's offsets (d_y > 0, or d_y = 0 and d_x > 0; row-major) in groups of at most
    :data:`GROUP` of one d_y: ``group_dy (g,)``, ``group_dx (g, GROUP)`` (0 in unused places), ``group_size (g,)``."""
    dxs = {dy: [dx for dx in range(-search_radius, search_radius + 1) if dy > 0 or dx > 0]
           for dy in range(search_radius + 1)}
    groups = [(dy, row[i:i + GROUP]) for dy, row in dxs.items() for i in range(0, len(row), GROUP)]
    group_dx = np.zeros((len(groups), GROUP), np.int64)
    for g, (_, members) in enumerate(groups):
        group_dx[g, :len(members)] = members
    return (np.array([dy for dy, _ in groups], np.int64), group_dx,
            np.array([len(members) for _, members in groups], np.int64))


@_inline
def _patch_sums(pixels, column_sums, out, y, dy, dx, r, border, width):
    """Offset (dy, dx)'s patch sums at row y's centres from column border - max(dx, 0) on, into ``out``; the
    offset's ``column_sums`` move down to row y (or are summed, at the first row, r). Loops run from 0 over views:
    Numba then drops its negative-index checks, and LLVM vectorises them."""
    lo, n = border - max(dx, 0) - r, width + abs(dx) + 2 * r
    sums = column_sums[lo:lo + n]
    for t in range(2 * r + 1 if y == r else 0):  # the first row: the patch's rows summed
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
    for x in range(n - 2 * r):
        total = sums[x]
        for u in range(1, 2 * r + 1):
            total += sums[x + u]
        out[x] = total


@_inline
def _merge_group(best, patch_sums, first, width, k):
    """``best`` (k, width): the k smallest, ascending, of itself and the group's ``patch_sums[j, first[j]:]``."""
    if k == GROUP:  # sort the four (5 exchanges); the four smallest of two sorted fours: 4 minima, 4 exchanges
        v0, v1 = patch_sums[0, first[0]:first[0] + width], patch_sums[1, first[1]:first[1] + width]
        v2, v3 = patch_sums[2, first[2]:first[2] + width], patch_sums[3, first[3]:first[3] + width]
        b0, b1, b2, b3 = best[0], best[1], best[2], best[3]
        for x in range(width):
            a0, a1, a2, a3 = min(v0[x], v1[x]), max(v0[x], v1[x]), min(v2[x], v3[x]), max(v2[x], v3[x])
            a0, a2, a1, a3 = min(a0, a2), max(a0, a2), min(a1, a3), max(a1, a3)
            a1, a2 = min(a1, a2), max(a1, a2)
            c0, c1, c2, c3 = min(b0[x], a3), min(b1[x], a2), min(b2[x], a1), min(b3[x], a0)
            c0, c2, c1, c3 = min(c0, c2), max(c0, c2), min(c1, c3), max(c1, c3)
            b0[x], b1[x], b2[x], b3[x] = min(c0, c1), max(c0, c1), min(c2, c3), max(c2, c3)
        return
    for j in range(GROUP):  # any other k: insert each
        values = patch_sums[j, first[j]:first[j] + width]
        for x in range(width):
            v = values[x]
            for q in range(k - 1):
                a = best[q, x]
                best[q, x] = min(a, v)
                v = max(a, v)
            best[k - 1, x] = min(best[k - 1, x], v)


@_inline
def _finish(best, out, denominator, unset, k):
    """A row's saliency into ``out``: the mean of its k smallest sums in msd.cpp's float32 order; ``best`` is reset
    to ``unset``."""
    for x in range(out.shape[0]):
        total = np.float32(best[0, x])
        for q in range(1, k):  # msd.cpp adds the k smallest in ascending order
            total = total + np.float32(best[q, x])
        out[x] = total / denominator
    best[:] = unset


def _saliency_loop(patch_radius: int, search_radius: int, knn: int):
    """The saliency loop, ``loop(image, out)``, with its setting as constants in its closure (compiled by Numba;
    plain Python is far too slow). ``out`` must be zero within r_s + r_b of the border."""
    r, border, ring_rows = patch_radius, patch_radius + search_radius, search_radius + 1
    k, denominator, unset = knn, np.float32((2 * patch_radius + 1) ** 2 * knn), INT_MAX
    group_dy, group_dx, group_size = offset_groups(search_radius)

    def loop(image, out):
        rows, cols = image.shape
        pixels, width = image.astype(np.int32), cols - 2 * border
        column_sums = np.zeros((len(group_dy), GROUP, cols), np.int32)
        patch_sums = np.empty((GROUP, cols), np.int32)
        smallest = np.full((ring_rows, k, width), unset, np.int32)
        first = np.zeros(GROUP, np.int64)
        for y in range(r, rows - border):  # rows of centres: offset d's sums serve row y and, as -d's, row y + dy
            for g in range(len(group_dy)):
                dy = group_dy[g]
                for j in range(GROUP):
                    if j < group_size[g]:
                        _patch_sums(pixels, column_sums[g, j], patch_sums[j], y, dy, group_dx[g, j], r, border, width)
                    else:
                        patch_sums[j] = unset
                for target, sign in ((y, 1), (y + dy, -1)):  # d at row y, -d at row y + dy
                    if border <= target < rows - border:
                        for j in range(GROUP):
                            first[j] = max(sign * group_dx[g, j], 0)
                        _merge_group(smallest[target % ring_rows], patch_sums, first, width, k)
            if y >= border:  # all of row y's offsets are in
                _finish(smallest[y % ring_rows], out[y, border:cols - border], denominator, unset, k)

    return loop


@functools.cache
def compiled_kernel(patch_radius: int, search_radius: int, knn: int):
    """The Numba-compiled saliency loop for one setting (compiled here, once per process, or read from Numba's
    cache), or None when Numba is not installed, cannot compile it (a warning), or the NumPy path is forced."""
    if _njit is None:
        return None
    return compile_or_none(_saliency_loop(patch_radius, search_radius, knn), KERNEL_ENV, "MSD's saliency loop",
                           lambda t: (t.float32[:, ::1],))


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
