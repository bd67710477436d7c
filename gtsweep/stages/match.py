"""Feature matching (survey section 2): a registry of matchers; brute force with Lowe's ratio test by default.

For each test descriptor the two closest reference descriptors are found (Hamming distance for binary, Euclidean
for real-valued descriptors); the closest is proposed as a match when its distance is below ``ratio`` times the
second closest (Lowe, IJCV 2004; the survey uses 0.7). ``ratio >= 1`` switches the test off. ``mutual`` also
requires the test descriptor to be its reference's nearest neighbour (``cv2.BFMatcher``'s ``crossCheck``; with
the ratio test off, the mutual-nearest-neighbour matcher that learned features such as XFeat are built for).
``cv2.batchDistance`` returns the nearest neighbours of all descriptors as arrays, equal to
``cv2.BFMatcher.knnMatch`` without its per-match Python objects.

:data:`MATCHERS` holds the matchers a sweep can compare (the survey's outlook: "different matching ... methods"):
``bf_ratio`` (the survey's: brute force, ratio 0.7), ``mutual_nn`` (mutual nearest neighbours, no ratio test) and
``flann`` (approximate nearest neighbours with OpenCV's FLANN, as Micro-GPS matches against a whole map: randomised
KD-trees for real-valued descriptors, Muja & Lowe 2009; multi-probe LSH for binary ones, Lv et al. 2007) and
``lightglue`` (learned matching for the descriptors it was trained on: :mod:`gtsweep.stages.lightglue`). A built
matcher indexes the reference descriptors once (:meth:`index`) and matches any number of test sets against them.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Protocol

import cv2
import numpy as np

from gtsweep.core.errors import NotApplicable, UnknownMethod
from gtsweep.core.ranges import Choice, Range, check_all
from gtsweep.core.registry import Method, Registry, lazy_factory
from gtsweep.stages.lightglue import Side

_NORMS = {"hamming": (cv2.NORM_HAMMING, cv2.CV_32S), "l2": (cv2.NORM_L2, cv2.CV_32F)}


def match_descriptors(test: np.ndarray, reference: np.ndarray, norm: str, ratio: float = 0.7,
                      mutual: bool = False) -> np.ndarray:
    """Matches from ``test`` to ``reference`` descriptors: ratio test (off when ``ratio >= 1``), optionally mutual.

    Returns an ``(M, 2)`` int array of (test index, reference index), in test order. The ratio test needs two
    reference descriptors: with fewer, it returns no match.
    """
    if norm not in _NORMS:
        raise UnknownMethod("norm", norm, _NORMS)
    use_ratio = ratio < 1.0
    if len(test) == 0 or len(reference) < (2 if use_ratio else 1):
        return np.zeros((0, 2), dtype=np.int64)
    norm_type, dtype = _NORMS[norm]
    distances, indices = cv2.batchDistance(test, reference, dtype, normType=norm_type, K=2 if use_ratio else 1)
    keep = np.ones(len(test), dtype=bool)
    if use_ratio:
        distances = distances.astype(np.float64)
        keep = distances[:, 0] < ratio * distances[:, 1]
    if mutual:
        _, backward = cv2.batchDistance(reference, test, dtype, normType=norm_type, K=1)
        keep &= backward[indices[:, 0], 0] == np.arange(len(test))
    test_idx = np.flatnonzero(keep)
    return np.column_stack([test_idx, indices[keep, 0]]).astype(np.int64)


def _no_matches() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int64)


class MatchIndex(Protocol):
    """Reference descriptors prepared for matching: ``match(test)`` gives ``(M, 2)`` int64 (test, reference)
    index pairs in test order."""

    def match(self, test: np.ndarray) -> np.ndarray: ...


_BF_RULES = {"ratio": Range(0, None, low_open=True), "mutual": Choice((True, False))}


@dataclass(frozen=True)
class BruteForce:
    """Exhaustive matching (:func:`match_descriptors`): ratio test (off when ``ratio >= 1``), optionally mutual."""

    ratio: float = 0.7
    mutual: bool = False

    def __post_init__(self):
        check_all({"ratio": self.ratio, "mutual": self.mutual}, _BF_RULES, "matcher 'bf_ratio' parameter ")

    def index(self, reference: np.ndarray, norm: str) -> BruteForceIndex:
        if norm not in _NORMS:
            raise UnknownMethod("norm", norm, _NORMS)
        return BruteForceIndex(self, np.ascontiguousarray(reference), norm)


@dataclass(frozen=True)
class BruteForceIndex:
    matcher: BruteForce
    reference: np.ndarray
    norm: str

    def match(self, test: np.ndarray) -> np.ndarray:
        return match_descriptors(test, self.reference, self.norm, self.matcher.ratio, self.matcher.mutual)


#: FLANN's index algorithms (flann::flann_algorithm_t) and the descriptor norm each one needs.
_KDTREE, _LSH = 1, 6
FLANN_ALGORITHMS = {"kdtree": "l2", "lsh": "hamming"}
_FLANN_RULES = {
    "ratio": Range(0, None, low_open=True),
    "algorithm": Choice(("auto", *FLANN_ALGORITHMS)),
    "trees": Range(1, None, integer=True),
    "checks": Range(1, None, integer=True),
    "table_number": Range(1, None, integer=True),
    "key_size": Range(1, 31, integer=True),
    "multi_probe_level": Range(0, None, integer=True),
    "seed": Range(0, None, integer=True),
}


@dataclass(frozen=True)
class Flann:
    """Approximate nearest neighbours (``cv2.flann_Index``) plus the ratio test (off when ``ratio >= 1``).

    ``algorithm``: ``auto`` (KD-trees for real-valued, LSH for binary descriptors), ``kdtree`` or ``lsh``; a forced
    algorithm on descriptors of the other norm is not applicable (:meth:`applicability`). ``trees``: randomised
    KD-trees; ``checks``: leaves visited per query (more: closer to exact, slower); ``table_number``, ``key_size``
    (bits per hash key), ``multi_probe_level``: LSH's tables. FLANN builds its trees and hash functions with
    OpenCV's RNG, seeded with ``seed`` before each build, so a build is reproducible.
    """

    ratio: float = 0.7
    algorithm: str = "auto"
    trees: int = 4
    checks: int = 32
    table_number: int = 6
    key_size: int = 12
    multi_probe_level: int = 1
    seed: int = 0

    def __post_init__(self):
        check_all(dict(vars(self)), _FLANN_RULES, "matcher 'flann' parameter ")

    def applicability(self, norm: str, descriptor: str | None = None, against_map: bool = False) -> str | None:
        """Why this matcher cannot match descriptors of ``norm`` (None: it can); any descriptor, also a map's."""
        needs = FLANN_ALGORITHMS.get(self.algorithm)
        if needs is None or needs == norm:
            return None
        kind = "binary (Hamming)" if norm == "hamming" else "real-valued (L2)"
        return f"FLANN's {self.algorithm} index needs {needs.upper()} descriptors, these are {kind}"

    def index(self, reference: np.ndarray, norm: str) -> FlannIndex:
        if norm not in _NORMS:
            raise UnknownMethod("norm", norm, _NORMS)
        reason = self.applicability(norm)
        if reason:
            raise NotApplicable(reason)
        binary = norm == "hamming"
        k = 2 if self.ratio < 1.0 else 1
        if len(reference) < k:
            return FlannIndex(self, None, binary, len(reference))
        if binary:
            data = np.ascontiguousarray(reference, dtype=np.uint8)
            params = {"algorithm": _LSH, "table_number": self.table_number, "key_size": self.key_size,
                      "multi_probe_level": self.multi_probe_level}
        else:
            data = np.ascontiguousarray(reference, dtype=np.float32)
            params = {"algorithm": _KDTREE, "trees": self.trees}
        cv2.setRNGSeed(self.seed)
        return FlannIndex(self, cv2.flann_Index(data, params), binary, len(reference))


@dataclass(frozen=True)
class FlannIndex:
    matcher: Flann
    flann: object | None  # cv2.flann_Index; None when there are too few reference descriptors
    binary: bool
    size: int

    def match(self, test: np.ndarray) -> np.ndarray:
        """Each test descriptor's approximate nearest reference descriptors, then the ratio test on their distances
        (FLANN's KD-tree returns squared L2 distances, compared as such with ``ratio²``). LSH may find fewer
        candidates than asked (index -1): no nearest one, no match; a nearest one without a second passes the test
        (no other reference descriptor came close enough to share a hash bucket)."""
        if self.flann is None or len(test) == 0:
            return _no_matches()
        ratio = self.matcher.ratio
        k = 2 if ratio < 1.0 else 1
        data = np.ascontiguousarray(test, dtype=np.uint8 if self.binary else np.float32)
        indices, distances = self.flann.knnSearch(data, k, params={"checks": self.matcher.checks})
        indices = indices.reshape(len(test), k)
        keep = indices[:, 0] >= 0
        if k == 2:
            distances = distances.reshape(len(test), k).astype(np.float64)
            scale = ratio if self.binary else ratio * ratio
            keep &= (distances[:, 0] < scale * distances[:, 1]) | (indices[:, 1] < 0)
        test_idx = np.flatnonzero(keep)
        return np.column_stack([test_idx, indices[keep, 0]]).astype(np.int64)


@functools.lru_cache(maxsize=1)
def _probe_descriptors() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {"l2": rng.random((64, 32), dtype=np.float32),
            "hamming": rng.integers(0, 256, (64, 32), dtype=np.uint8)}


def _probe(matcher) -> None:
    """Index and match small random descriptor sets of each norm the matcher applies to (FLANN checks its
    parameters only when it builds an index)."""
    for norm, descriptors in _probe_descriptors().items():
        if applicability(matcher, norm) is None:
            matcher.index(descriptors, norm).match(descriptors[:8])


def applicability(matcher, norm: str, descriptor: str | None = None, against_map: bool = False) -> str | None:
    """Why a built matcher cannot match ``descriptor``'s vectors of ``norm`` (None: it can): the grid's NA cell
    reason. ``against_map``: a localization query against a map of many images (learned matchers need one image)."""
    check = getattr(matcher, "applicability", None)
    return check(norm, descriptor, against_map) if check is not None else None


def match_sides(matcher, norm: str, reference: np.ndarray, test: np.ndarray, reference_side: Side,
                test_side: Side) -> np.ndarray:
    """``(M, 2)`` (test, reference) matches of two images' descriptor rows with a built matcher; a learned matcher
    (``needs_keypoints``) also gets each side's keypoints, image size and descriptor name."""
    if getattr(matcher, "needs_keypoints", False):
        return matcher.index(reference, norm, reference_side).match(test, test_side)
    return matcher.index(reference, norm).match(test)


@dataclass(frozen=True, kw_only=True)
class MatcherSpec(Method):
    """A matcher: ``build(params)`` gives an object with ``index(reference, norm) -> MatchIndex``."""

    approximate: bool = False
    probe: Callable[[object], object] | None = _probe


_matcher = functools.partial(MatcherSpec, "matcher")
#: The survey's matcher (section 5: brute force and the ratio test, 0.7).
SURVEY_MATCHER = "bf_ratio"

MATCHERS: Registry[MatcherSpec] = Registry("matcher", [
    _matcher(SURVEY_MATCHER, "BF+ratio", BruteForce, {"ratio": 0.7, "mutual": False}),
    _matcher("mutual_nn", "mutual NN", functools.partial(BruteForce, ratio=1.0, mutual=True), {}),
    _matcher("flann", "FLANN", Flann, {"ratio": 0.7, "algorithm": "auto", "trees": 4, "checks": 32,
                                       "table_number": 6, "key_size": 12, "multi_probe_level": 1, "seed": 0},
             approximate=True),
    # LightGlue (ALIKED, DISK) and LighterGlue (XFeat), torch + shipped weights: gtsweep/stages/lightglue.py.
    _matcher("lightglue", "LightGlue", lazy_factory("gtsweep.stages.lightglue", "LightGlueMatcher"),
             {"filter_threshold": 0.1, "depth_confidence": 0.95, "width_confidence": 0.99}, extra="learned"),
], spec=MatcherSpec)
