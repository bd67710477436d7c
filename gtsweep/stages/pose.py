"""RANSAC pose estimation from point correspondences (survey section 5: 2000 iterations, threshold 3 px).

A 2-D similarity (rotation, translation, one uniform scale) is the complex-affine map ``z_ref = a · z_test + b``
with ``z = x + i y`` and ``a = s·e^{iθ}``; a Euclidean transform has ``|a| = 1``. Two correspondences determine
a hypothesis; the final model is refit on the inliers by least squares (Umeyama 1991, with or without scale).
The matrix maps TEST pixels to REFERENCE pixels: ``[[Re a, -Im a, Re b], [Im a, Re a, Im b], [0, 0, 1]]``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from gtsweep.core.errors import BadInput, UnknownMethod

MODELS = ("similarity", "euclidean")
# Hypotheses × matches scored per matrix product (bounds memory to ~32 MiB of squared errors).
_CHUNK_ELEMENTS = 1 << 22
# Sample pairs whose test points are closer than this (px) are degenerate.
_MIN_SPAN = 1e-9


@dataclasses.dataclass(frozen=True)
class PoseEstimate:
    """Result of :func:`estimate_pose`: ``matrix`` (3x3 test→ref, or None), inlier mask and count."""

    matrix: np.ndarray | None
    inliers: np.ndarray
    n_inliers: int


def _complex(xy, name: str) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64)
    if a.size == 0:
        return np.zeros(0, dtype=np.complex128)
    if a.ndim != 2 or a.shape[1] != 2:
        raise BadInput(f"{name} must be an (M, 2) array of x, y; got shape {a.shape}")
    if not np.isfinite(a).all():
        raise BadInput(f"{name} contain NaN or infinite values")
    return a[:, 0] + 1j * a[:, 1]


def _unit(a: np.ndarray) -> np.ndarray:
    """Rotation part e^{iθ} of complex factors (scale removed)."""
    return np.exp(1j * np.angle(a))


def _fit(zt: np.ndarray, zr: np.ndarray, with_scale: bool):
    """Least-squares (a, b) of ``zr ≈ a zt + b`` (Umeyama); None when the test points coincide."""
    mt, mr = zt.mean(), zr.mean()
    ct, cr = zt - mt, zr - mr
    spread = float(np.sum(ct.real ** 2 + ct.imag ** 2))
    cross = np.sum(np.conj(ct) * cr)
    if spread < _MIN_SPAN ** 2 or (cross == 0):
        return None
    a = cross / spread if with_scale else _unit(cross)
    return a, mr - a * mt


def _inlier_counts(a: np.ndarray, b: np.ndarray, zt: np.ndarray, zr: np.ndarray, threshold: float) -> np.ndarray:
    """Number of matches with reprojection error < threshold, for every hypothesis (a[k], b[k]).

    The squared error ``|a zt + b - zr|²`` expands into a sum of nine products of one hypothesis term and one
    match term, so all hypotheses are scored by one matrix product (BLAS) on centred coordinates. Entries whose
    expanded value lies within its rounding bound of ``threshold²`` have their row recomputed directly, so counts are
    those of ``|a zt + b - zr| < threshold`` evaluated one by one.
    """
    mt, mr = zt.mean(), zr.mean()
    ct, cr, cb = zt - mt, zr - mr, b + a * mt - mr
    c, q = a * np.conj(cb), ct * np.conj(cr)
    hyp = np.stack([np.abs(a) ** 2, np.abs(cb) ** 2, np.ones(len(a)), 2 * c.real, -2 * c.imag, -2 * a.real,
                    2 * a.imag, -2 * cb.real, -2 * cb.imag], axis=1)
    pts = np.stack([np.abs(ct) ** 2, np.ones(len(ct)), np.abs(cr) ** 2, ct.real, ct.imag, q.real, q.imag, cr.real,
                    cr.imag])
    # |error of a 9-term dot product| <= 9 eps sum|terms| <= 81 eps max|hyp row| max|pts| (x4 margin), per row.
    bound = 4 * 81 * np.finfo(np.float64).eps * np.abs(hyp).max(axis=1, keepdims=True) * float(np.abs(pts).max())
    limit = threshold * threshold
    counts = np.empty(len(a), dtype=np.int64)
    step = max(1, _CHUNK_ELEMENTS // len(zt))
    for start in range(0, len(a), step):
        squared = hyp[start:start + step] @ pts
        rows = slice(start, start + step)
        counts[rows] = np.count_nonzero(squared < limit - bound[rows], axis=1)
        unsure = np.flatnonzero(np.count_nonzero(squared <= limit + bound[rows], axis=1) != counts[rows]) + start
        if unsure.size:  # a value within rounding of the threshold: score these hypotheses directly
            counts[unsure] = np.count_nonzero(
                np.abs(a[unsure, None] * zt[None, :] + b[unsure, None] - zr[None, :]) < threshold, axis=1)
    return counts


def _matrix(a: complex, b: complex) -> np.ndarray:
    return np.array([[a.real, -a.imag, b.real], [a.imag, a.real, b.imag], [0.0, 0.0, 1.0]])


def estimate_pose(test_xy, ref_xy, model: str = "similarity", iterations: int = 2000, threshold: float = 3.0,
                  seed: int = 0) -> PoseEstimate:
    """RANSAC estimate of the test→reference transform from matched points ``test_xy[i] ↔ ref_xy[i]``.

    ``model``: ``"similarity"`` (4 DoF) or ``"euclidean"`` (3 DoF). Each of ``iterations`` hypotheses comes from a
    random pair of distinct matches (``numpy.random.default_rng(seed)``); all are scored at once (inlier =
    reprojection error < ``threshold`` px); the one with most inliers (first on ties) is refit by least squares
    on its inliers and its inliers recounted. Fewer than 2 matches or only degenerate samples → ``matrix=None``.
    """
    if model not in MODELS:
        raise UnknownMethod("pose model", model, MODELS)
    if int(iterations) < 1 or not threshold > 0:
        raise BadInput(f"RANSAC needs iterations >= 1 and threshold > 0; got {iterations} and {threshold}")
    zt, zr = _complex(test_xy, "test points"), _complex(ref_xy, "reference points")
    if zt.shape != zr.shape:
        raise BadInput(f"test and reference points differ in number: {zt.size} vs {zr.size}")
    m = zt.size
    none = PoseEstimate(matrix=None, inliers=np.zeros(m, dtype=bool), n_inliers=0)
    if m < 2:
        return none
    rng = np.random.default_rng(seed)
    first = rng.integers(m, size=int(iterations))
    second = rng.integers(m - 1, size=int(iterations))
    second += second >= first  # a distinct second index, uniformly
    dt, dr = zt[second] - zt[first], zr[second] - zr[first]
    valid = (np.abs(dt) > _MIN_SPAN) & (np.abs(dr) > 0)
    if not valid.any():
        return none
    a = np.where(valid, dr / np.where(valid, dt, 1.0), 1.0)
    if model == "euclidean":
        a = _unit(a)
    b = 0.5 * (zr[first] + zr[second]) - a * 0.5 * (zt[first] + zt[second])
    counts = np.where(valid, _inlier_counts(a, b, zt, zr, threshold), -1)
    best = int(np.argmax(counts))
    inliers = np.abs(a[best] * zt + b[best] - zr) < threshold
    fit = _fit(zt[inliers], zr[inliers], with_scale=(model == "similarity"))
    if fit is not None:
        inliers = np.abs(fit[0] * zt + fit[1] - zr) < threshold
        a_best, b_best = fit
    else:
        a_best, b_best = a[best], b[best]
    return PoseEstimate(matrix=_matrix(complex(a_best), complex(b_best)), inliers=inliers,
                        n_inliers=int(inliers.sum()))
