"""The survey's evaluation of one image pair (sections 4 and 5), composed from the stage modules.

:func:`detect_and_select` runs detection then selection on one image; :func:`detection_metrics` scores the
keypoints of a reference/test pair (repeatability, ambiguity, < N KPs); :func:`pairing_metrics` describes, matches
and estimates the pose for one detector-descriptor pairing, from its parts (:func:`describe_pair` once per pair,
:func:`match_metrics` per matcher, :func:`pose_metrics` per estimator), which a grid of several matchers and
estimators calls directly. Everything is plain data in, plain dicts out, so the
orchestration (grid, Ray, cache, tracking) can stay elsewhere. Every key of the returned dicts is a column declared
in :mod:`gtsweep.evaluation.schema` (which says how a cell aggregates it); an undeclared one stops the sweep.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from gtsweep.evaluation import metrics
from gtsweep.evaluation.reuse import DescribeOnce
from gtsweep.evaluation.transforms import ViewPair
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import detect_timed
from gtsweep.stages.lightglue import Side
from gtsweep.stages.match import MATCHERS, match_sides
from gtsweep.stages.pose import ESTIMATORS
from gtsweep.stages.select import select


def detect_raw(image, mask, detector: str, detector_params: dict):
    """The detector's own keypoints in ``image`` (inside ``mask``): ``(keypoints, n_detected, seconds)``."""
    found, seconds = detect_timed(image, detector, mask, **detector_params)
    return found, len(found), seconds


def select_detected(raw, image_shape, selector: str, selector_params: dict):
    """Select from a :func:`detect_raw` result: ``(keypoints, n_detected, detect + select seconds)``."""
    found, n_detected, seconds = raw
    start = time.perf_counter()
    selected = select(found, selector, image_shape, **selector_params)
    return selected, n_detected, seconds + (time.perf_counter() - start)


def detect_and_select(image, mask, detector: str, detector_params: dict, selector: str, selector_params: dict):
    """Detect in ``image`` (inside ``mask``) and select; returns ``(keypoints, n_detected, seconds)``."""
    return select_detected(detect_raw(image, mask, detector, detector_params), image.shape, selector,
                           selector_params)


def detection_metrics(view: ViewPair, ref_kps, test_kps, iou_threshold=0.5, min_keypoints=100) -> dict:
    """Repeatability, ambiguity and "< N KPs" of one pair (survey 4.1); only the mask intersection counts."""
    result = metrics.repeatability(test_kps, ref_kps, view.H, test_mask=view.test_mask,
                                   ref_mask=view.reference_mask, ref_shape=view.reference.shape,
                                   test_shape=view.test.shape, iou_threshold=iou_threshold)
    return {
        "repeatability": result.repeatability,
        "ambiguity": result.ambiguity,
        "n_test_valid": result.n_test,
        "n_ref_valid": result.n_ref,
        "n_repeated": result.n_repeated,
        "few_keypoints": float(metrics.too_few_keypoints(len(test_kps), min_keypoints)),
    }


@dataclass(frozen=True)
class Described:
    """The descriptors of one pair: the keypoints each descriptor kept, their rows, and the describe time (s)."""

    ref_kps: np.ndarray
    ref_desc: np.ndarray
    test_kps: np.ndarray
    test_desc: np.ndarray
    seconds: float
    descriptor: str = ""


def describe_pair(view: ViewPair, ref_kps, test_kps, descriptor: str, descriptor_params: dict, detector: str,
                  experiment: dict, reference_count: int | None = None,
                  memo: DescribeOnce | None = None) -> Described:
    """Describe both images of a pair once (every matcher and estimator of a grid reuses the result).

    ``reference_count`` keeps only the strongest reference keypoints (survey Table 7) and
    ``experiment["test_count"]`` the strongest test keypoints; the selectors sort keypoints by response. Raises
    :class:`~gtsweep.core.errors.NotApplicable` for the survey's NA pairings. ``memo``: a task's
    :class:`~gtsweep.evaluation.reuse.DescribeOnce`, so images seen before (a reference under several strengths,
    several reference counts) are not described again.
    """
    memo = memo or DescribeOnce(descriptor, detector, descriptor_params)
    if experiment.get("test_count") is not None:
        test_kps = test_kps[:experiment["test_count"]]
    ref_kept, ref_desc, t_ref = memo.describe(view.reference, ref_kps, reference_count)
    test_kept, test_desc, t_test = memo.describe(view.test, test_kps)
    return Described(ref_kept, ref_desc, test_kept, test_desc, t_ref + t_test, descriptor)


def match_metrics(view: ViewPair, described: Described, norm: str, matcher, iou_threshold: float = 0.5):
    """Match a described pair with a built matcher (survey 4.2); returns ``(matches, row)``. ``t_match`` includes
    indexing the reference descriptors (a FLANN index's build)."""
    start = time.perf_counter()
    matches = match_sides(matcher, norm, described.ref_desc, described.test_desc,
                          Side(described.ref_kps, view.reference.shape, described.descriptor),
                          Side(described.test_kps, view.test.shape, described.descriptor))
    t_match = time.perf_counter() - start
    matching = metrics.matching_precision(described.test_kps, described.ref_kps, matches, view.H, iou_threshold)
    return matches, {
        "n_described_ref": len(described.ref_kps),
        "n_described_test": len(described.test_kps),
        "n_matches": matching.n_matches,
        "n_correct": matching.n_correct,
        "precision": matching.precision,
        "t_describe": described.seconds,
        "t_match": t_match,
    }


def pose_metrics(view: ViewPair, described: Described, matches, estimator, cfg: dict, seed: int) -> dict:
    """Estimate the test→reference pose from ``matches`` with a built estimator and judge it with the survey's
    thresholds ``cfg`` (``max_position_error`` px, ``max_orientation_error`` degrees; survey 4.3)."""
    start = time.perf_counter()
    estimate = estimator.estimate(described.test_kps[matches[:, 0], :2], described.ref_kps[matches[:, 1], :2],
                                  seed=seed)
    seconds = time.perf_counter() - start
    position, orientation = metrics.pose_error(estimate.matrix, view.H, view.test.shape)
    success = metrics.pose_success(position, orientation, cfg["max_position_error"], cfg["max_orientation_error"])
    return {
        "pose_success": float(success),
        "position_error": position if math.isfinite(position) else float("nan"),
        "orientation_error": orientation if math.isfinite(orientation) else float("nan"),
        "n_inliers": estimate.n_inliers,
        "t_pose": seconds,
    }


def survey_methods(experiment: dict):
    """The survey's matcher and estimator, ``(bf_ratio, ransac)``, built with the settings an experiment dict may
    still carry (the optimiser's ``ratio``, ``mutual`` and ``pose.{model,iterations,threshold}``)."""
    matcher = {k: experiment[k] for k in ("ratio", "mutual") if k in experiment}
    pose = experiment.get("pose") or {}
    estimator = {k: pose[k] for k in ("model", "iterations", "threshold") if k in pose}
    return MATCHERS.get("bf_ratio").build(matcher), ESTIMATORS.get("ransac").build(estimator)


def pairing_metrics(view: ViewPair, ref_kps, test_kps, descriptor: str, descriptor_params: dict, detector: str,
                    experiment: dict, seed: int = 0, reference_count: int | None = None, matcher=None,
                    estimator=None) -> dict:
    """Describe, match and (for the pose experiment) estimate the pose of one pair (survey 4.2, 4.3).

    ``matcher`` and ``estimator`` are built methods (:data:`~gtsweep.stages.match.MATCHERS`,
    :data:`~gtsweep.stages.pose.ESTIMATORS`); None: the survey's (:func:`survey_methods`). ``reference_count`` and
    ``experiment["test_count"]``: :func:`describe_pair`.
    """
    if matcher is None or estimator is None:
        survey_matcher, survey_estimator = survey_methods(experiment)
        matcher, estimator = matcher or survey_matcher, estimator or survey_estimator
    described = describe_pair(view, ref_kps, test_kps, descriptor, descriptor_params, detector, experiment,
                              reference_count)
    matches, row = match_metrics(view, described, DESCRIPTORS.get(descriptor).norm, matcher,
                                 experiment.get("iou_threshold", 0.5))
    if experiment.get("name") == "pose":
        row.update(pose_metrics(view, described, matches, estimator, experiment["pose"], seed))
    return row
