"""RANSAC pose estimation from point correspondences (survey section 5: 2000 iterations, threshold 3 px).

A 2-D similarity (rotation, translation, one uniform scale) is the complex-affine map ``z_ref = a · z_test + b``
with ``z = x + i y`` and ``a = s·e^{iθ}``; a Euclidean transform has ``|a| = 1``. Two correspondences determine
a hypothesis; the final model is refit on the inliers by least squares (Umeyama 1991, with or without scale).
The matrix maps TEST pixels to REFERENCE pixels: ``[[Re a, -Im a, Re b], [Im a, Re a, Im b], [0, 0, 1]]``.

:data:`ESTIMATORS` holds the robust estimators a sweep can compare (the survey's outlook: "different ... pose
estimation methods"): ``ransac`` (:func:`estimate_pose`, the survey's), OpenCV's ``estimateAffinePartial2D``
with RANSAC (``cv_ransac``) or least median of squares (``cv_lmeds``, Rousseeuw 1984), and ``magsac``: MAGSAC++
(Barath et al., CVPR 2020). OpenCV 5.0's ``estimateAffinePartial2D`` accepts only RANSAC and LMEDS (USAC flags:
"Unknown or unsupported robust estimation method", opencv/opencv#19166); its USAC framework estimates 2-D
transforms only in ``estimateAffine2D``, so ``magsac`` runs ``estimateAffine2D(method=USAC_MAGSAC)`` (6-DoF
affine hypotheses, MAGSAC++ scoring) and fits the similarity by least squares on the inliers it returns.
"""
from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.ranges import Choice, Range, check_all
from gtsweep.core.registry import Method, Registry

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
    match term, so all hypotheses are scored by one matrix product on centred coordinates. Entries whose expanded
    value lies within its rounding bound of ``threshold²`` (which holds in any order of summation) have their row
    recomputed directly, so counts are those of ``|a zt + b - zr| < threshold`` evaluated one by one.

    The product is NumPy's own ``einsum`` loop, not BLAS: with inner dimension 9 a multi-threaded BLAS gains nothing,
    and its threads keep spinning after each call, on the cores OpenCV's next ``detect``/``compute`` needs (serial
    sweep, bench grid under load: OpenCV's calls 33 -> 25 s, the floor's own 25 s).
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
        squared = np.einsum("ki,ij->kj", hyp[start:start + step], pts)  # not BLAS: see the docstring
        rows = slice(start, start + step)
        counts[rows] = np.count_nonzero(squared < limit - bound[rows], axis=1)
        near = squared <= limit + bound[rows]  # holds wherever the count above does: equal totals, equal rows
        if np.count_nonzero(near) == counts[rows].sum():
            continue
        unsure = np.flatnonzero(np.count_nonzero(near, axis=1) != counts[rows]) + start
        if unsure.size:  # a value within rounding of the threshold: score these hypotheses directly
            counts[unsure] = np.count_nonzero(
                np.abs(a[unsure, None] * zt[None, :] + b[unsure, None] - zr[None, :]) < threshold, axis=1)
    return counts


def _distinct_counts(first, second, valid, a, b, zt, zr, threshold: float) -> np.ndarray:
    """:func:`_inlier_counts` of every valid hypothesis (-1 for the others), each distinct one scored once.

    A hypothesis depends only on its unordered sample pair: swapping the two matches negates both differences,
    which leaves their quotient ``a`` and the midpoints behind ``b`` unchanged bit for bit. With few matches most
    of the 2000 samples repeat a pair; each distinct pair is scored once and its count copied to its repeats
    (checked: the copies' ``a`` and ``b`` equal their representative's exactly, else every one is scored). With
    many more pairs than samples (few repeats) finding them costs more than it saves: all are scored."""
    counts = np.full(len(a), -1, dtype=np.int64)
    chosen = np.flatnonzero(valid)
    m = len(zt)
    if m * (m - 1) // 2 > 2 * len(a):
        counts[chosen] = _inlier_counts(a[chosen], b[chosen], zt, zr, threshold)
        return counts
    pair = np.minimum(first, second)[chosen] * m + np.maximum(first, second)[chosen]
    _, where, back = np.unique(pair, return_index=True, return_inverse=True)
    scored = chosen[where]
    if np.array_equal(a[scored][back], a[chosen]) and np.array_equal(b[scored][back], b[chosen]):
        counts[chosen] = _inlier_counts(a[scored], b[scored], zt, zr, threshold)[back]
    else:
        counts[chosen] = _inlier_counts(a[chosen], b[chosen], zt, zr, threshold)
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
    counts = _distinct_counts(first, second, valid, a, b, zt, zr, threshold)
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


# --- Estimators as a registry family: every one maps (test_xy, ref_xy, seed) to a PoseEstimate. -------------------

_RULES = {"model": Choice(MODELS), "iterations": Range(1, None, integer=True),
          "threshold": Range(0, None, low_open=True),
          "confidence": Range(0, 1, low_open=True, high_open=True), "refine_iters": Range(0, None, integer=True)}


@dataclasses.dataclass(frozen=True)
class SeededRansac:
    """:func:`estimate_pose` with fixed settings (the survey's RANSAC: similarity, 2000 iterations, 3 px)."""

    model: str = "similarity"
    iterations: int = 2000
    threshold: float = 3.0

    def __post_init__(self):
        check_all(dataclasses.asdict(self), _RULES, "estimator 'ransac' parameter ")

    def estimate(self, test_xy, ref_xy, seed: int = 0) -> PoseEstimate:
        return estimate_pose(test_xy, ref_xy, model=self.model, iterations=self.iterations,
                             threshold=self.threshold, seed=seed)


def _points(xy, name: str) -> np.ndarray:
    """``xy`` as a contiguous float64 ``(M, 2)`` array (OpenCV's point set), checked like :func:`estimate_pose`."""
    a = np.asarray(xy, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 2))
    if a.ndim != 2 or a.shape[1] != 2:
        raise BadInput(f"{name} must be an (M, 2) array of x, y; got shape {a.shape}")
    if not np.isfinite(a).all():
        raise BadInput(f"{name} contain NaN or infinite values")
    return np.ascontiguousarray(a)


def similarity_lstsq(test_xy: np.ndarray, ref_xy: np.ndarray) -> np.ndarray | None:
    """Least-squares similarity (3x3, test→ref) of matched points: the linear system in (a, b, tx, ty) of
    ``x' = a x - b y + tx, y' = b x + a y + ty`` (``numpy.linalg.lstsq``); None for fewer than 2 distinct points."""
    if len(test_xy) < 2 or np.ptp(test_xy, axis=0).max() <= _MIN_SPAN:
        return None
    x, y = test_xy[:, 0], test_xy[:, 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    rows = np.concatenate([np.column_stack([x, -y, one, zero]), np.column_stack([y, x, zero, one])])
    (a, b, tx, ty), *_ = np.linalg.lstsq(rows, np.concatenate([ref_xy[:, 0], ref_xy[:, 1]]), rcond=None)
    return np.array([[a, -b, tx], [b, a, ty], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class OpenCVEstimator:
    """OpenCV's robust 2-D estimators. ``method``: ``ransac`` or ``lmeds`` run ``cv2.estimateAffinePartial2D``
    (a similarity, refined by Levenberg-Marquardt on the inliers for ``refine_iters`` steps); ``magsac`` runs
    ``cv2.estimateAffine2D(method=cv2.USAC_MAGSAC)`` and refits a similarity on its inliers
    (:func:`similarity_lstsq`). ``cv2.setRNGSeed`` (the seed's low 31 bits) precedes every call: a seed, one answer.
    LMEDS has no threshold: OpenCV derives its inlier bound from the median residual. A singular model (scale 0,
    which OpenCV may return for degenerate samples) is no estimate (``matrix`` None), as for :func:`estimate_pose`."""

    method: str = "ransac"
    threshold: float = 3.0
    iterations: int = 2000
    confidence: float = 0.99
    refine_iters: int = 10

    def __post_init__(self):
        check_all(dataclasses.asdict(self), {**_RULES, "method": Choice(tuple(_CV_METHODS))},
                  f"estimator '{_CV_NAMES.get(self.method, self.method)}' parameter ")

    def estimate(self, test_xy, ref_xy, seed: int = 0) -> PoseEstimate:
        src, dst = _points(test_xy, "test points"), _points(ref_xy, "reference points")
        if src.shape != dst.shape:
            raise BadInput(f"test and reference points differ in number: {len(src)} vs {len(dst)}")
        none = PoseEstimate(matrix=None, inliers=np.zeros(len(src), dtype=bool), n_inliers=0)
        if len(src) < (3 if self.method == "magsac" else 2):
            return none
        function, flag = _CV_METHODS[self.method]
        cv2.setRNGSeed(int(seed) & _CV_SEED_MASK)  # OpenCV takes a C int; a view's seed is 64-bit
        matrix, mask = function(src, dst, method=flag, ransacReprojThreshold=float(self.threshold),
                                maxIters=int(self.iterations), confidence=float(self.confidence),
                                refineIters=int(self.refine_iters))
        if matrix is None or mask is None:
            return none
        inliers = mask.ravel().astype(bool)
        if self.method == "magsac":
            full = similarity_lstsq(src[inliers], dst[inliers])
            if full is None:
                return none
        else:
            full = np.vstack([matrix, [0.0, 0.0, 1.0]])
        if not abs(np.linalg.det(full[:2, :2])) > _SINGULAR:  # OpenCV's answer to degenerate samples: no estimate
            return none
        return PoseEstimate(matrix=full, inliers=inliers, n_inliers=int(inliers.sum()))


_CV_METHODS = {"ransac": (cv2.estimateAffinePartial2D, cv2.RANSAC),
               "lmeds": (cv2.estimateAffinePartial2D, cv2.LMEDS),
               "magsac": (cv2.estimateAffine2D, cv2.USAC_MAGSAC)}
_CV_SEED_MASK = 0x7FFFFFFF
_SINGULAR = 1e-12  # |det| of the 2x2 part at or below which a model maps the image to a line or a point
_CV_NAMES = {"ransac": "cv_ransac", "lmeds": "cv_lmeds", "magsac": "magsac"}


def _probe(estimator) -> None:
    """Estimate once on a few exact correspondences (OpenCV checks its arguments only when it runs)."""
    test = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 3.0]])
    estimator.estimate(test, test + 1.0, seed=0)


@dataclasses.dataclass(frozen=True, kw_only=True)
class EstimatorSpec(Method):
    """A pose estimator: ``build(params)`` gives an object with ``estimate(test_xy, ref_xy, seed) ->
    PoseEstimate`` (3x3 test→ref matrix or None, inlier mask, inlier count)."""

    probe: object = _probe


_estimator = functools.partial(EstimatorSpec, "estimator")
#: The survey's pose estimator (section 5: RANSAC, a similarity, 2000 iterations, 3 px).
SURVEY_ESTIMATOR = "ransac"
_CV = {"threshold": 3.0, "iterations": 2000, "confidence": 0.99, "refine_iters": 10}

ESTIMATORS: Registry[EstimatorSpec] = Registry("estimator", [
    _estimator(SURVEY_ESTIMATOR, "RANSAC", SeededRansac, {"model": "similarity", "iterations": 2000, "threshold": 3.0}),
    _estimator("cv_ransac", "cv RANSAC", functools.partial(OpenCVEstimator, "ransac"), _CV),
    _estimator("cv_lmeds", "cv LMEDS", functools.partial(OpenCVEstimator, "lmeds"),
               {k: v for k, v in _CV.items() if k != "threshold"}),
    _estimator("magsac", "MAGSAC++", functools.partial(OpenCVEstimator, "magsac"), _CV),
], spec=EstimatorSpec)
