"""SURF's rotated descriptor windows: the bilinear resampling of surf.cpp's ``SURFInvoker``, bit for bit.

The cost of SURF's description is this resampling: a keypoint of size L reads a window of ``int(21 * 1.2 L / 9)``
pixels square (1000 keypoints of a 1288x964 survey view: ~31 million samples). Two implementations give the same
bytes:

- :func:`sample_numpy`, array operations over batches of windows (the pure path, always available);
- :func:`sample_compiled`, one loop compiled by Numba (an optional dependency, ``pip install gtsweep[fast]``),
  over 4x faster: no NumPy formulation gets below ~20 passes over every sample (coordinates, floors, fractions,
  index, gathers, eight products, three sums, rounding), which alone cost more than SIFT's whole description.
  It uses only float32/float64 operations in the same order, without fast-math or contraction into FMAs, so
  its numbers do not depend on the machine.

``GTSWEEP_SURF_KERNEL=numpy`` forces the pure path (the tests compare both).
"""
from __future__ import annotations

import functools

import numpy as np

from gtsweep.stages.numba_types import compile_or_none

F32 = np.float32

#: The environment variable that forces the NumPy sampler ("numpy") instead of the compiled one.
KERNEL_ENV = "GTSWEEP_SURF_KERNEL"
#: Window pixels per batch: the NumPy path's temporaries stay in cache; the compiled one has none.
NUMPY_BATCH_PIXELS = 1 << 15
COMPILED_BATCH_PIXELS = 1 << 20


def window_starts(x, y, angle, win: int):
    """First sample of every window and its steps, float32 ``(n,)`` each: ``(start_x, start_y, cos_dir, sin_dir)``.

    Row ``i``, column ``j`` samples ``start + i (sin, cos) + j (cos, -sin)`` with ``sin = -sin(angle)``, as
    surf.cpp computes them: row starts advance in float32 steps, columns in float64.
    """
    theta = (angle.astype(F32) * F32(np.pi / 180)).astype(np.float64)
    sin_dir, cos_dir = (-np.sin(theta)).astype(F32), np.cos(theta).astype(F32)
    offset = F32(-(win - 1) / 2)
    start_x = x + offset * cos_dir + offset * sin_dir
    start_y = y - offset * sin_dir + offset * cos_dir
    return start_x, start_y, cos_dir, sin_dir


def window_rows(start_x, start_y, cos_dir, sin_dir, win: int):
    """Start of every window row, float32 ``(n, win)`` each: the float32 running sums of the row steps."""
    row_x = np.cumsum(np.concatenate([start_x[:, None], np.repeat(sin_dir[:, None], win - 1, 1)], 1), 1, F32)
    row_y = np.cumsum(np.concatenate([start_y[:, None], np.repeat(cos_dir[:, None], win - 1, 1)], 1), 1, F32)
    return row_x, row_y


def sample_numpy(gray: np.ndarray, pixels: np.ndarray, start_x, start_y, cos_dir, sin_dir, win: int):
    """The windows ``(n, win, win)`` uint8 by array operations; ``pixels`` is ``gray`` as flat float32.

    Sample ``(i, j)`` lies at ``(row_x[i] + j cos, row_y[i] - j sin)`` (float64). Its value is
    ``cvRound(p00 (1-a)(1-b) + p01 a (1-b) + p10 (1-a) b + p11 a b)`` in float32; a sample whose 2x2
    neighbourhood leaves the image takes the nearest (clamped) pixel. Blocks of rows of at most
    :data:`NUMPY_BATCH_PIXELS` samples keep the temporaries in cache (a large keypoint's window alone has 10^5).
    """
    row_x, row_y = window_rows(start_x, start_y, cos_dir, sin_dir, win)
    out = np.empty((len(row_x), win, win), np.uint8)
    block = max(1, NUMPY_BATCH_PIXELS // (len(row_x) * win))
    for top in range(0, win, block):
        rows = slice(top, top + block)
        out[:, rows] = _bilinear_rows(gray, pixels, row_x[:, rows], row_y[:, rows], cos_dir, sin_dir, win)
    return out


def _bilinear_rows(gray: np.ndarray, pixels: np.ndarray, row_x, row_y, cos_dir, sin_dir, win: int):
    """:func:`sample_numpy` for the window rows that start at ``(row_x, row_y)`` ``(n, rows)``."""
    steps = np.arange(win, dtype=np.float64)
    px = row_x.astype(np.float64)[:, :, None] + (steps * cos_dir.astype(np.float64)[:, None])[:, None, :]
    py = row_y.astype(np.float64)[:, :, None] - (steps * sin_dir.astype(np.float64)[:, None])[:, None, :]
    ix, iy = np.floor(px), np.floor(py)
    a = np.subtract(px, ix, out=np.empty(px.shape, F32), casting="same_kind")
    b = np.subtract(py, iy, out=np.empty(py.shape, F32), casting="same_kind")
    rows, cols = gray.shape
    # Positions are monotonic along rows and columns, so the block's corners bound them all.
    row_ends, ends = [0, row_x.shape[1] - 1], [0, win - 1]
    corners_x, corners_y = ix[:, row_ends][:, :, ends], iy[:, row_ends][:, :, ends]
    all_inside = (corners_x.min() >= 0 and corners_x.max() < cols - 1
                  and corners_y.min() >= 0 and corners_y.max() < rows - 1)
    if not all_inside:
        inside = (ix >= 0) & (ix < cols - 1) & (iy >= 0) & (iy < rows - 1)
        ix[~inside] = 0
        iy[~inside] = 0
    iy *= cols  # in place, to keep memory traffic down: iy becomes the flat index of the top-left pixel
    iy += ix
    index = iy.astype(np.intp)
    one = F32(1)
    not_a, not_b = one - a, one - b
    value = pixels[index]
    value *= not_a
    value *= not_b
    term = pixels[1:][index]  # right neighbour: the same index into shifted views
    term *= a
    term *= not_b
    value += term
    np.take(pixels[cols:], index, out=term)  # below
    term *= not_a
    term *= b
    value += term
    np.take(pixels[cols + 1:], index, out=term)  # below right
    term *= a
    term *= b
    value += term
    window = np.rint(value, out=value).astype(np.uint8)
    if not all_inside:
        nearest = gray[np.clip(np.rint(py), 0, rows - 1).astype(np.intp),
                       np.clip(np.rint(px), 0, cols - 1).astype(np.intp)]
        window = np.where(inside, window, nearest)
    return window


def _sample_loop(gray, start_x, start_y, cos_dir, sin_dir, out):
    """:func:`sample_numpy`'s arithmetic, compiled by Numba (plain Python is far too slow), a window row at a time:
    one pass finds every sample's pixel and weights (LLVM vectorises it), a second reads the pixels and
    interpolates. A sample whose 2x2 neighbourhood leaves the image is stored as ``-1 - index`` of its nearest
    pixel."""
    rows, cols = gray.shape
    flat = gray.ravel()
    win = out.shape[1]
    one = np.float32(1)
    at = np.empty(win, np.int64)
    a, b = np.empty(win, np.float32), np.empty(win, np.float32)
    for k in range(out.shape[0]):
        cos_k, sin_k = np.float64(cos_dir[k]), np.float64(sin_dir[k])
        row_x, row_y = start_x[k], start_y[k]  # float32, advanced in float32 as window_rows does
        for i in range(win):
            x0, y0 = np.float64(row_x), np.float64(row_y)
            for j in range(win):
                px, py = x0 + j * cos_k, y0 - j * sin_k
                fx, fy = np.floor(px), np.floor(py)
                inside = (fx >= 0) & (fx < cols - 1) & (fy >= 0) & (fy < rows - 1)
                a[j], b[j] = np.float32(px - fx), np.float32(py - fy)
                near_x, near_y = min(max(np.rint(px), 0.0), cols - 1.0), min(max(np.rint(py), 0.0), rows - 1.0)
                at[j] = (np.int64(fy) * cols + np.int64(fx) if inside
                         else -1 - (np.int64(near_y) * cols + np.int64(near_x)))
            row = out[k, i]
            for j in range(win):
                p = at[j]
                if p < 0:
                    row[j] = flat[-1 - p]
                    continue
                not_a, not_b = one - a[j], one - b[j]
                value = (np.float32(flat[p]) * not_a * not_b + np.float32(flat[p + 1]) * a[j] * not_b
                         + np.float32(flat[p + cols]) * not_a * b[j] + np.float32(flat[p + cols + 1]) * a[j] * b[j])
                row[j] = np.uint8(np.rint(value))
            row_x += sin_dir[k]
            row_y += cos_dir[k]


@functools.lru_cache(maxsize=1)
def compiled_loop():
    """The Numba-compiled :func:`_sample_loop` (compiled here, once per process, or read from Numba's cache), or
    None when Numba is not installed, cannot compile it (a warning), or the NumPy path is forced."""
    return compile_or_none(_sample_loop, KERNEL_ENV, "SURF's window sampler",
                           lambda t: (t.float32[::1],) * 4 + (t.uint8[:, :, ::1],))


def batch_pixels() -> int:
    """How many window pixels to sample per call."""
    return NUMPY_BATCH_PIXELS if compiled_loop() is None else COMPILED_BATCH_PIXELS


def sample_compiled(gray: np.ndarray, start_x, start_y, cos_dir, sin_dir, win: int) -> np.ndarray:
    """The windows of :func:`sample_numpy`, by the compiled loop (which must exist: see :func:`compiled_loop`)."""
    out = np.empty((len(start_x), win, win), np.uint8)
    compiled_loop()(np.ascontiguousarray(gray), *(np.ascontiguousarray(v, F32) for v in
                                                  (start_x, start_y, cos_dir, sin_dir)), out)
    return out


def rotated_windows(gray: np.ndarray, pixels: np.ndarray, x, y, angle, win: int) -> np.ndarray:
    """OpenCV's rotated descriptor windows ``(n, win, win)`` uint8 around ``(x, y)`` at ``angle`` (degrees);
    ``pixels`` is ``gray`` as flat float32 (used by the NumPy path)."""
    starts = window_starts(x, y, angle, win)
    if compiled_loop() is not None:
        return sample_compiled(gray, *starts, win)
    return sample_numpy(gray, pixels, *starts, win)
