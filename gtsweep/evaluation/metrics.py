"""Evaluation metrics of the survey (Schmid, Simon, Mester, BMVC 2019, section 4).

Conventions (shared by every function here):

* ``H`` is a 3x3 matrix mapping TEST image pixel coordinates to REFERENCE image pixel coordinates:
  ``p_ref ~ H @ [x, y, 1]`` (homogeneous, divided by the last coordinate).
* Keypoints are an ``(N, >=3)`` float array whose first three columns are x, y, size; size is the diameter
  (OpenCV's ``KeyPoint.size``). Further columns are ignored.
* A keypoint is a circle. A test and a reference keypoint *correspond* when the IoU of their circles, compared
  in the reference frame (test centre mapped by ``H``, test diameter scaled by ``sqrt(|det H[:2, :2]|)``), is
  greater than a threshold (0.5 in the survey, section 4.1).
* Masks are 2-D uint8 arrays (nonzero = inside) or ``None`` (= the whole image). Image shapes are NumPy shapes
  ``(height, width)``. A point lies in an image/mask when its centre rounded to the nearest pixel
  (``floor(v + 0.5)``) is a valid pixel index there (and the mask is nonzero at that pixel).
"""
from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
from scipy.spatial import cKDTree

from gtsweep.core.errors import BadInput

# Keypoints are put in bins of radius whose edges grow by this factor; each bin pair is searched with one radius.
_BIN_FACTOR = math.sqrt(2.0)


# --------------------------------------------------------------------------------------------------- validation
def _keypoint_circles(keypoints, name: str) -> np.ndarray:
    """First three columns (x, y, size) of a keypoint array as float64, checked."""
    a = np.asarray(keypoints, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 3))
    if a.ndim != 2 or a.shape[1] < 3:
        raise BadInput(f"{name} must be an (N, >=3) array of x, y, size; got shape {a.shape}")
    a = a[:, :3]
    if not np.isfinite(a).all():
        raise BadInput(f"{name} contain NaN or infinite values")
    if (a[:, 2] <= 0).any():
        raise BadInput(f"{name} must have positive sizes")
    return a


def _homography(H) -> np.ndarray:
    h = np.asarray(H, dtype=np.float64)
    if h.shape != (3, 3) or not np.isfinite(h).all():
        raise BadInput(f"H must be a finite 3x3 matrix; got shape {h.shape}")
    if abs(np.linalg.det(h)) < 1e-12:
        raise BadInput("H is singular")
    return h


def _threshold(iou_threshold: float) -> float:
    if not 0.0 <= iou_threshold < 1.0:
        raise BadInput(f"iou_threshold must lie in [0, 1); got {iou_threshold}")
    return float(iou_threshold)


# --------------------------------------------------------------------------------------------------- geometry
def circle_iou(a, b) -> np.ndarray:
    """Elementwise intersection over union of circles ``a[i]`` and ``b[i]``, each row (x, y, diameter).

    Exact lens area of two circles with radii r1, r2 at centre distance d
    (https://mathworld.wolfram.com/Circle-CircleIntersection.html)::

        I = r1² acos((d² + r1² - r2²) / (2 d r1)) + r2² acos((d² + r2² - r1²) / (2 d r2))
            - ½ sqrt((-d + r1 + r2)(d + r1 - r2)(d - r1 + r2)(d + r1 + r2))

    with I = 0 when d >= r1 + r2 (disjoint) and I = π min(r1, r2)² when d <= |r1 - r2| (containment);
    IoU = I / (π r1² + π r2² - I).
    """
    a = np.atleast_2d(np.asarray(a, dtype=np.float64))
    b = np.atleast_2d(np.asarray(b, dtype=np.float64))
    if a.shape != b.shape or a.shape[-1] < 3:
        raise BadInput(f"circle_iou needs two (N, 3) arrays of equal shape; got {a.shape} and {b.shape}")
    r1, r2 = a[:, 2] / 2.0, b[:, 2] / 2.0
    d = np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])
    inter = np.where(d <= np.abs(r1 - r2), np.pi * np.minimum(r1, r2) ** 2, 0.0)
    lens = (d < r1 + r2) & (d > np.abs(r1 - r2))
    if lens.any():
        # smaller radius first, so that circle_iou(a, b) == circle_iou(b, a) bit for bit
        p, q, s = np.minimum(r1, r2)[lens], np.maximum(r1, r2)[lens], d[lens]
        cos1 = np.clip((s * s + p * p - q * q) / (2.0 * s * p), -1.0, 1.0)
        cos2 = np.clip((s * s + q * q - p * p) / (2.0 * s * q), -1.0, 1.0)
        kite = np.sqrt(np.clip((-s + p + q) * (s + p - q) * (s - p + q) * (s + p + q), 0.0, None))
        inter[lens] = p * p * np.arccos(cos1) + q * q * np.arccos(cos2) - 0.5 * kite
    union = np.pi * (r1 * r1 + r2 * r2) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def jacobian(H: np.ndarray, point) -> np.ndarray:
    """The 2x2 Jacobian of the homography ``H`` at ``point`` (x, y): its linear part for an affine ``H``."""
    H = np.asarray(H, dtype=np.float64)
    point = np.asarray(point, dtype=np.float64)
    w = H[2, 0] * point[0] + H[2, 1] * point[1] + H[2, 2]
    mapped = (H[:2, :2] @ point + H[:2, 2]) / w
    return (H[:2, :2] - np.outer(mapped, H[2, :2])) / w


def _map_points(xy: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Points (N, 2) mapped by H; points sent to or beyond the line at infinity become NaN."""
    hom = xy @ H[:, :2].T + H[:, 2]
    w = hom[:, 2:3]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w > 1e-12, hom[:, :2] / w, np.nan)


def map_keypoints(keypoints, H) -> np.ndarray:
    """Keypoints as an (N, 3) array x, y, size mapped by ``H`` into the reference frame.

    The centre is mapped exactly; the size is scaled by ``sqrt(|det H[:2, :2]|)`` (the area scale of the linear
    part, exact for similarity transforms). Centres mapped to or beyond the line at infinity are NaN.
    """
    kps, h = _keypoint_circles(keypoints, "keypoints"), _homography(H)
    scale = math.sqrt(abs(np.linalg.det(h[:2, :2])))
    return np.column_stack([_map_points(kps[:, :2], h), kps[:, 2] * scale])


@functools.lru_cache(maxsize=64)
def _max_centre_distance(iou_threshold: float) -> float:
    """Factor c such that IoU > t implies centre distance < c · (larger radius) (a pure function of t, memoised:
    every repeatability call of a sweep asks for the same t).

    For fixed larger radius and distance the IoU grows with the smaller radius (checked numerically over the
    whole admissible radius ratio range, see tests/test_metrics.py), so c is the distance at which two EQUAL
    unit circles reach IoU = t; found by bisection (IoU falls monotonically with distance), plus 1 % margin.
    """
    lo, hi = 0.0, 2.0
    unit = np.array([[0.0, 0.0, 2.0]])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if circle_iou(unit, np.array([[mid, 0.0, 2.0]]))[0] > iou_threshold:
            lo = mid
        else:
            hi = mid
    return min(2.0, hi * 1.01)


def _radius_bins(radii: np.ndarray) -> np.ndarray:
    return np.floor(np.log(radii) / math.log(_BIN_FACTOR)).astype(np.int64)


def _circle_pairs(test: np.ndarray, ref: np.ndarray, iou_threshold: float) -> np.ndarray:
    """(P, 2) index pairs of circles (both given in the same frame) with IoU > threshold, sorted.

    Candidates come from KD-tree range searches per pair of radius bins: IoU > t needs the radius ratio to exceed
    sqrt(t) (I <= π r_min² and I > t·U >= t·π r_max²) and the centre distance to stay below
    ``_max_centre_distance(t)`` times the larger radius, so each bin pair gets one tight search radius.
    """
    t = _threshold(iou_threshold)
    if len(test) == 0 or len(ref) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    min_ratio, reach = math.sqrt(t), _max_centre_distance(t)
    rt, rr = test[:, 2] / 2.0, ref[:, 2] / 2.0
    bins_t, bins_r = _radius_bins(rt), _radius_bins(rr)
    groups_r = {b: np.flatnonzero(bins_r == b) for b in np.unique(bins_r)}
    trees_r = {b: cKDTree(ref[idx, :2]) for b, idx in groups_r.items()}
    found = []
    for bt in np.unique(bins_t):
        idx_t = np.flatnonzero(bins_t == bt)
        tree_t = cKDTree(test[idx_t, :2])
        lo_t, hi_t = rt[idx_t].min(), rt[idx_t].max()
        for br, idx_r in groups_r.items():
            lo_r, hi_r = rr[idx_r].min(), rr[idx_r].max()
            if hi_r <= lo_t * min_ratio or hi_t <= lo_r * min_ratio:
                continue
            near = tree_t.sparse_distance_matrix(trees_r[br], reach * max(hi_t, hi_r), output_type="ndarray")
            found.append(np.column_stack([idx_t[near["i"]], idx_r[near["j"]]]))
    cand = np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
    cand = cand[circle_iou(test[cand[:, 0]], ref[cand[:, 1]]) > t]
    return cand[np.lexsort((cand[:, 1], cand[:, 0]))]


def correspondences(test_kps, ref_kps, H, iou_threshold: float = 0.5) -> np.ndarray:
    """(P, 2) int array of (test index, ref index) pairs whose circles have IoU > ``iou_threshold``.

    The test keypoints are first mapped into the reference frame (:func:`map_keypoints`). Pairs are sorted by
    test index, then reference index. Runs in O((N + M) log) with KD-trees, also for widely varying sizes.
    """
    ref = _keypoint_circles(ref_kps, "reference keypoints")
    test = map_keypoints(test_kps, H)
    finite = np.flatnonzero(np.isfinite(test[:, 0]))
    pairs = _circle_pairs(test[finite], ref, iou_threshold)
    pairs[:, 0] = finite[pairs[:, 0]]
    return pairs


# --------------------------------------------------------------------------------------------------- repeatability
def _image_shape(mask, shape, name: str):
    if mask is not None:
        m = np.asarray(mask)
        if m.ndim != 2:
            raise BadInput(f"{name} mask must be a 2-D array; got shape {m.shape}")
        if shape is not None and tuple(shape[:2]) != m.shape:
            raise BadInput(f"{name} mask shape {m.shape} differs from the {name} image shape {tuple(shape[:2])}")
        return m.shape
    return None if shape is None else (int(shape[0]), int(shape[1]))


def _inside(xy: np.ndarray, mask, shape) -> np.ndarray:
    """True where the rounded point is a pixel of the image (when its shape is known) and nonzero in the mask."""
    if shape is None:
        return np.isfinite(xy).all(axis=1)
    with np.errstate(invalid="ignore"):
        col, row = np.floor(xy[:, 0] + 0.5), np.floor(xy[:, 1] + 0.5)
        ok = (col >= 0) & (col < shape[1]) & (row >= 0) & (row < shape[0])
    if mask is not None:
        ok[ok] = np.asarray(mask)[row[ok].astype(np.int64), col[ok].astype(np.int64)] != 0
    return ok


@dataclasses.dataclass(frozen=True)
class RepeatabilityResult:
    """Keypoint repeatability and ambiguity (survey 4.1) over the keypoints in both masks."""

    repeatability: float  # share of counted test keypoints with >= 1 corresponding counted reference keypoint
    ambiguity: float  # mean number of correspondences of the repeated test keypoints (NaN when none)
    n_test: int  # counted test keypoints
    n_ref: int  # counted reference keypoints
    n_repeated: int  # counted test keypoints with >= 1 correspondence
    n_correspondences: int  # corresponding (test, reference) pairs among the counted keypoints

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def repeatability(test_kps, ref_kps, H, test_mask=None, ref_mask=None, ref_shape=None, test_shape=None,
                  iou_threshold: float = 0.5) -> RepeatabilityResult:
    """Repeatability (Mikolajczyk et al. 2005) and ambiguity (survey 4.1) of test keypoints w.r.t. reference ones.

    Only keypoints in the intersection of both masks count: a test keypoint counts when it lies in the test mask
    and its centre mapped by ``H`` lies in the reference image and mask; a reference keypoint counts when it lies
    in the reference mask and its centre mapped by ``inv(H)`` lies in the test image and mask. Image bounds are
    taken from the masks or ``*_shape`` ((height, width)); without either that image is unbounded.

    repeatability = n_repeated / n_test (0.0 when n_test = 0), ambiguity = n_correspondences / n_repeated.
    """
    h = _homography(H)
    test, ref = _keypoint_circles(test_kps, "test keypoints"), _keypoint_circles(ref_kps, "reference keypoints")
    t_shape, r_shape = _image_shape(test_mask, test_shape, "test"), _image_shape(ref_mask, ref_shape, "reference")
    mapped = map_keypoints(test, h)
    keep_t = np.flatnonzero(_inside(test[:, :2], test_mask, t_shape) & _inside(mapped[:, :2], ref_mask, r_shape))
    back = _map_points(ref[:, :2], np.linalg.inv(h))
    keep_r = np.flatnonzero(_inside(ref[:, :2], ref_mask, r_shape) & _inside(back, test_mask, t_shape))
    pairs = _circle_pairs(mapped[keep_t], ref[keep_r], iou_threshold)
    n_repeated = int(np.unique(pairs[:, 0]).size)
    n_test = int(keep_t.size)
    return RepeatabilityResult(
        repeatability=n_repeated / n_test if n_test else 0.0,
        ambiguity=len(pairs) / n_repeated if n_repeated else math.nan,
        n_test=n_test, n_ref=int(keep_r.size), n_repeated=n_repeated, n_correspondences=int(len(pairs)),
    )


def too_few_keypoints(n_keypoints: int, n: int = 100) -> bool:
    """The survey's "< N KPs" event (section 4.1): fewer than ``n`` keypoints were found."""
    return bool(n_keypoints < n)


# --------------------------------------------------------------------------------------------------- matching
def correct_matches(test_kps, ref_kps, matches, H, iou_threshold: float = 0.5) -> np.ndarray:
    """Boolean (M,) array: is match ``(test index, ref index)`` correct?

    Rule: a match is correct when its two keypoints correspond, i.e. the IoU of their circles in the reference
    frame (test keypoint mapped by ``H``, see :func:`map_keypoints`) is greater than ``iou_threshold`` — the same
    rule as for repeatability (survey 4.1/4.2).
    """
    test = map_keypoints(test_kps, H)
    ref = _keypoint_circles(ref_kps, "reference keypoints")
    m = np.asarray(matches)
    if m.size == 0:
        return np.zeros(0, dtype=bool)
    if m.ndim != 2 or m.shape[1] != 2 or not np.issubdtype(m.dtype, np.integer):
        raise BadInput(f"matches must be an (M, 2) integer array of (test index, ref index); got {m.dtype} {m.shape}")
    if (m < 0).any() or (m[:, 0] >= len(test)).any() or (m[:, 1] >= len(ref)).any():
        raise BadInput("matches hold keypoint indices out of range")
    iou = circle_iou(test[m[:, 0]], ref[m[:, 1]])
    return np.nan_to_num(iou, nan=0.0) > _threshold(iou_threshold)


@dataclasses.dataclass(frozen=True)
class MatchingResult:
    """Number of correct matches and precision = correct / (correct + incorrect) (survey 4.2)."""

    n_matches: int
    n_correct: int
    precision: float  # NaN when there is no match

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def matching_precision(test_kps, ref_kps, matches, H, iou_threshold: float = 0.5) -> MatchingResult:
    """Matching precision (survey 4.2); correctness as in :func:`correct_matches`."""
    ok = correct_matches(test_kps, ref_kps, matches, H, iou_threshold)
    n = int(ok.size)
    return MatchingResult(n_matches=n, n_correct=int(ok.sum()), precision=float(ok.sum()) / n if n else math.nan)


# --------------------------------------------------------------------------------------------------- pose
def pose_error(T_est, T_true, test_shape) -> tuple[float, float]:
    """(position error in px, orientation error in degrees) of an estimated test→reference transform.

    Position error: distance between ``T_est(c)`` and ``T_true(c)`` for the test image centre
    ``c = ((w - 1) / 2, (h - 1) / 2)``, ``test_shape = (h, w)``. Orientation error:
    ``|wrap(angle(T_est) - angle(T_true))|`` in [0, 180] with ``angle(T) = atan2(J[1, 0], J[0, 0])``, ``J`` the
    Jacobian of ``T`` at ``c`` (``T``'s linear part when affine; a tilted camera's ground truth is projective).
    ``T_est is None`` (no estimate) gives ``(inf, inf)``.
    """
    if T_est is None:
        return math.inf, math.inf
    est, true = _homography(T_est), _homography(T_true)
    h, w = test_shape[:2]
    centre = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    position = float(np.linalg.norm(_map_points(centre, est) - _map_points(centre, true)))
    est_linear, true_linear = jacobian(est, centre[0]), jacobian(true, centre[0])
    turn = math.atan2(est_linear[1, 0], est_linear[0, 0]) - math.atan2(true_linear[1, 0], true_linear[0, 0])
    orientation = abs(math.degrees(math.atan2(math.sin(turn), math.cos(turn))))
    return position, orientation


def pose_success(position_error, orientation_error, max_position: float = 30.0, max_orientation: float = 1.5):
    """Survey 4.3 (thresholds of Zhang et al. 2019): position error < 30 px and orientation error < 1.5°.

    Both bounds are strict; NaN or inf errors fail. Elementwise for arrays, a plain bool for scalars.
    """
    ok = (np.asarray(position_error) < max_position) & (np.asarray(orientation_error) < max_orientation)
    return bool(ok) if ok.ndim == 0 else ok
