"""Keypoint selection (survey section 2.2, experiment 5.1): NMS, ANMS via SSC, and bucketing.

Every selector takes an ``(N, 7)`` keypoint array (:mod:`gtsweep.stages.keypoints`) and the ``(height, width)`` of the
image, and returns a subset sorted by response, largest first, ties in detection order. Outputs depend only on
the inputs (no randomness).
"""
from __future__ import annotations

import math

import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.core.registry import Method, Registry, function_defaults, partial_factory
from gtsweep.stages.keypoints import COLUMNS, RESPONSE, X, Y, empty, sort_by_response


def _check_keypoints(keypoints) -> np.ndarray:
    kps = np.asarray(keypoints, dtype=np.float64)
    if kps.ndim != 2 or kps.shape[1] != len(COLUMNS):
        raise BadInput(f"keypoints must be an (N, {len(COLUMNS)}) array, got shape {kps.shape}")
    if not np.all(np.isfinite(kps[:, [X, Y, RESPONSE]])):
        raise BadInput("keypoints hold non-finite x, y or response values")
    return kps


def _check_shape(image_shape) -> tuple[int, int]:
    if len(image_shape) < 2 or int(image_shape[0]) < 1 or int(image_shape[1]) < 1:
        raise BadInput(f"image_shape must be (height, width, ...) with positive sides, got {tuple(image_shape)}")
    return int(image_shape[0]), int(image_shape[1])


def _check_positive_int(name: str, value) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < 1:
        raise BadInput(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def select_none(keypoints, image_shape) -> np.ndarray:
    """All keypoints, sorted by response (the survey's "w/o selection" column)."""
    _check_shape(image_shape)
    return sort_by_response(_check_keypoints(keypoints))


def select_nms(keypoints, image_shape, n: int = 1000) -> np.ndarray:
    """Non-maximum suppression as the survey uses the term: keep the ``n`` keypoints with largest response."""
    _check_shape(image_shape)
    n = _check_positive_int("n", n)
    return sort_by_response(_check_keypoints(keypoints))[:n]


def _cpp_round(value: float) -> int:
    """C++ ``round``: halves away from zero (Python's ``round`` rounds half to even)."""
    return int(math.copysign(math.floor(abs(value) + 0.5), value))


def _ssc_search_range(num_points: int, k: int, width: int, height: int) -> tuple[int, int]:
    """Initial binary-search range of the square width, as in Bailo et al.'s code (``ssc`` in ``anms.h``).

    ``high`` is the positive root of the quadratic in the paper; it divides by ``k - 1``, so for ``k == 1`` the
    largest image side (one square covers the whole image) is used instead. ``high`` is raised to ``low`` when
    the root lies below it, so that at least one coverage pass runs (upstream would return nothing).
    """
    low = max(1, math.floor(math.sqrt(num_points / k)))
    if k == 1:
        return low, max(low, width, height)
    exp1 = height + width + 2 * k
    exp2 = (4 * width + 4 * k + 4 * height * k + height * height + width * width
            - 2 * height * width + 4 * height * width * k)
    exp3 = math.sqrt(exp2)
    sol1 = -_cpp_round((exp1 + exp3) / (k - 1))
    sol2 = -_cpp_round((exp1 - exp3) / (k - 1))
    return low, max(low, sol1, sol2)


def _first_in_each_cell(cell_x: np.ndarray, cell_y: np.ndarray, n_cols: int, n_rows: int) -> np.ndarray:
    """Ascending indices of the first keypoint in each occupied cell (``minimum.at`` is order-independent)."""
    count = len(cell_x)
    first = np.full((n_rows + 1) * (n_cols + 1), count, dtype=np.int64)
    np.minimum.at(first, cell_y * (n_cols + 1) + cell_x, np.arange(count, dtype=np.int64))
    return np.sort(first[first < count])


def _ssc_cover(cell_x: np.ndarray, cell_y: np.ndarray, candidates: np.ndarray, n_cols: int, n_rows: int) -> list:
    """One SSC coverage pass over a grid of ``(n_rows + 1) x (n_cols + 1)`` cells of side ``width / 2``.

    A candidate whose cell is still uncovered is selected and covers the 5 x 5 cells centred on its own (about
    +-width pixels around it). ``candidates`` are indices (ascending, i.e. in response order) of the first keypoint
    in each occupied cell: a later keypoint in a cell can never be selected, since its cell is covered by then.
    """
    stride = n_cols + 1
    covered = bytearray(stride * (n_rows + 1))
    full = b"\x01" * 5
    selected = []
    for i, cx, cy in zip(candidates.tolist(), cell_x[candidates].tolist(), cell_y[candidates].tolist()):
        if covered[cy * stride + cx]:
            continue
        selected.append(i)
        c0, c1 = max(cx - 2, 0), min(cx + 2, n_cols)
        span = full[: c1 - c0 + 1]
        for row in range(max(cy - 2, 0), min(cy + 2, n_rows) + 1):
            start = row * stride + c0
            covered[start:start + len(span)] = span
    return selected


def select_anms(keypoints, image_shape, n: int = 1000, tolerance: float = 0.2) -> np.ndarray:
    """Adaptive NMS by Suppression via Square Covering (SSC).

    Bailo et al., "Efficient adaptive non-maximal suppression algorithms for homogeneous spatial keypoint
    distribution", Pattern Recognition Letters 106, 2018; follows ``ssc`` of the public code BAILOOL/ANMS-Codes
    (C++ ``anms.h``): a binary search over the integer square width until the number of selected keypoints lies
    in ``[round(n - n*tol), round(n + n*tol)]``, else the last pass's result. With ``N <= n`` all are returned.
    Coordinates are clipped into the image so that sub-pixel positions just outside it stay on the grid.
    """
    height, width = _check_shape(image_shape)
    n = _check_positive_int("n", n)
    if not isinstance(tolerance, (int, float, np.floating)) or not 0.0 <= tolerance < 1.0:
        raise BadInput(f"tolerance must lie in [0, 1), got {tolerance!r}")
    kps = sort_by_response(_check_keypoints(keypoints))
    if len(kps) <= n:
        return kps
    x = np.clip(kps[:, X], 0.0, float(width))
    y = np.clip(kps[:, Y], 0.0, float(height))
    k_min = _cpp_round(n - n * tolerance)
    k_max = _cpp_round(n + n * tolerance)
    low, high = _ssc_search_range(len(kps), n, width, height)
    previous_width, result = -1, []
    while True:
        square = low + (high - low) // 2
        if square == previous_width or low > high:
            break  # upstream: keep the previous pass's result
        cell = square / 2.0
        n_cols, n_rows = math.floor(width / cell), math.floor(height / cell)
        cell_x = np.floor(x / cell).astype(np.int64)
        cell_y = np.floor(y / cell).astype(np.int64)
        result = _ssc_cover(cell_x, cell_y, _first_in_each_cell(cell_x, cell_y, n_cols, n_rows), n_cols, n_rows)
        if k_min <= len(result) <= k_max:
            break
        if len(result) < k_min:
            high = square - 1
        else:
            low = square + 1
        previous_width = square
    return kps[np.asarray(result, dtype=np.int64)]


def select_bucketing(keypoints, image_shape, rows: int = 8, cols: int = 6, per_cell: int = 21) -> np.ndarray:
    """Bucketing (Kitt et al., IV 2010): a regular ``rows x cols`` grid, NMS (top ``per_cell``) in each cell.

    The survey uses 8 rows x 6 columns and 21 keypoints per cell (at most 1008). Keypoints outside the image are
    counted in the nearest border cell.
    """
    height, width = _check_shape(image_shape)
    rows, cols = _check_positive_int("rows", rows), _check_positive_int("cols", cols)
    per_cell = _check_positive_int("per_cell", per_cell)
    kps = sort_by_response(_check_keypoints(keypoints))
    row = np.clip(np.floor(kps[:, Y] * rows / height), 0, rows - 1).astype(np.int64)
    col = np.clip(np.floor(kps[:, X] * cols / width), 0, cols - 1).astype(np.int64)
    cell = row * cols + col
    by_cell = np.argsort(cell, kind="stable")  # grouped by cell, response order inside each cell
    grouped = cell[by_cell]
    group_start = np.searchsorted(grouped, grouped, side="left")
    rank = np.arange(len(grouped)) - group_start
    keep = np.sort(by_cell[rank < per_cell])
    return kps[keep]


def _selector(name: str, label: str, function, params=None, capabilities=None) -> Method:
    """A selector ``function(keypoints, image_shape, **params)`` as a registry entry (``params`` over its own
    defaults); its pre-flight selects from no keypoints (checks the values)."""
    return Method("selector", name, label, partial_factory(function), {**function_defaults(function, 2),
                                                                        **(params or {})},
                  probe=lambda selector: selector(empty(), (1, 1)))


SELECTORS: Registry[Method] = Registry("selector", [
    _selector("none", "w/o selection", select_none),
    _selector("nms", "NMS", select_nms),
    _selector("anms", "ANMS", select_anms),
    _selector("bucketing", "Bucketing", select_bucketing),
], make=_selector)


def select(keypoints, name: str, image_shape, **params) -> np.ndarray:
    """Apply the selector registered as ``name`` (see :data:`SELECTORS`) with its keyword parameters."""
    return SELECTORS.get(name).build(params)(keypoints, image_shape)
