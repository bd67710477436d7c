"""The survey's evaluation of one image pair (sections 4 and 5), composed from the stage modules.

:func:`detect_and_select` runs detection then selection on one image; :func:`detection_metrics` scores the
keypoints of a reference/test pair (repeatability, ambiguity, < N KPs); :func:`pairing_metrics` describes, matches
and estimates the pose for one detector-descriptor pairing. Everything is plain data in, plain dicts out, so the
orchestration (grid, Ray, cache, tracking) can stay elsewhere. Every key of the returned dicts is a column declared
in :mod:`gtsweep.evaluation.schema` (which says how a cell aggregates it); an undeclared one stops the sweep.
"""
from __future__ import annotations

import math
import time

from gtsweep.evaluation import metrics
from gtsweep.evaluation.transforms import ViewPair
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import detect_timed
from gtsweep.stages.match import match_descriptors
from gtsweep.stages.pairing import describe_timed
from gtsweep.stages.pose import estimate_pose
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


def pairing_metrics(view: ViewPair, ref_kps, test_kps, descriptor: str, descriptor_params: dict, detector: str,
                    experiment: dict, seed: int = 0, reference_count: int | None = None) -> dict:
    """Describe, match and (for the pose experiment) estimate the pose of one pair (survey 4.2, 4.3).

    ``reference_count`` keeps only the strongest reference keypoints (survey Table 7) and
    ``experiment["test_count"]`` the strongest test keypoints; the selectors sort keypoints by response. Raises :class:`~gtsweep.core.errors.NotApplicable` for the survey's NA pairings.
    """
    if reference_count is not None:
        ref_kps = ref_kps[:reference_count]
    if experiment.get("test_count") is not None:
        test_kps = test_kps[:experiment["test_count"]]
    ref_kept, ref_desc, t_ref = describe_timed(view.reference, ref_kps, descriptor, detector, **descriptor_params)
    test_kept, test_desc, t_test = describe_timed(view.test, test_kps, descriptor, detector, **descriptor_params)
    start = time.perf_counter()
    matches = match_descriptors(test_desc, ref_desc, DESCRIPTORS.get(descriptor).norm, experiment.get("ratio", 0.7),
                                mutual=experiment.get("mutual", False))
    t_match = time.perf_counter() - start
    iou = experiment.get("iou_threshold", 0.5)
    matching = metrics.matching_precision(test_kept, ref_kept, matches, view.H, iou)
    row = {
        "n_described_ref": len(ref_kept),
        "n_described_test": len(test_kept),
        "n_matches": matching.n_matches,
        "n_correct": matching.n_correct,
        "precision": matching.precision,
        "t_describe": t_ref + t_test,
        "t_match": t_match,
    }
    if experiment.get("name") == "pose":
        row.update(_pose_metrics(view, ref_kept, test_kept, matches, experiment["pose"], seed))
    return row


def _pose_metrics(view: ViewPair, ref_kps, test_kps, matches, cfg: dict, seed: int) -> dict:
    start = time.perf_counter()
    estimate = estimate_pose(test_kps[matches[:, 0], :2], ref_kps[matches[:, 1], :2], model=cfg["model"],
                             iterations=cfg["iterations"], threshold=cfg["threshold"], seed=seed)
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

