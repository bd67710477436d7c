"""The survey's evaluation of one image pair (sections 4 and 5), composed from the stage modules.

:func:`detect_and_select` runs detection then selection on one image; :func:`detection_metrics` scores the
keypoints of a reference/test pair (repeatability, ambiguity, < N KPs); a pairing is described once per pair
(:func:`describe_pair`), matched per matcher (:func:`match_metrics`) and posed per estimator (:func:`pose_metrics`).
Over the views of a shard: :func:`detect_views` (keypoint budget scaled to the view) and :func:`evaluate_views`
(the reference-count loop of survey Table 7; a matcher or estimator that fails costs only its own combinations).
Everything is plain data in, plain dicts out, so the
orchestration (grid, Ray, cache, tracking) can stay elsewhere. Every key of the returned dicts is a column declared
in :mod:`gtsweep.evaluation.schema` (which says how a cell aggregates it); an undeclared one stops the sweep.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation import budget, metrics
from gtsweep.evaluation.reuse import DescribeOnce, describe_together
from gtsweep.evaluation.transforms import ViewPair
from gtsweep.evaluation.views import views
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import detect_timed
from gtsweep.stages.lightglue import Side
from gtsweep.stages.match import MATCHERS, SURVEY_MATCHER, match_sides
from gtsweep.stages.pose import ESTIMATORS, SURVEY_ESTIMATOR
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
    memo = memo or DescribeOnce(descriptor, detector, descriptor_params, experiment.get("foreign_scale"))
    test_kps = _test_keypoints(test_kps, experiment)
    ref_kept, ref_desc, t_ref = memo.describe(view.reference, ref_kps, reference_count)
    test_kept, test_desc, t_test = memo.describe(view.test, test_kps)
    return Described(ref_kept, ref_desc, test_kept, test_desc, t_ref + t_test, descriptor)


def _test_keypoints(test_kps, experiment: dict):
    """The test keypoints a pair is described with: the strongest ``experiment["test_count"]`` (None: all)."""
    return test_kps if experiment.get("test_count") is None else test_kps[:experiment["test_count"]]


def _asked(built: list, keypoints: list, experiment: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (image, keypoints) descriptions :func:`describe_pair` will ask for over ``built`` views."""
    counts = experiment.get("reference_counts") or [None]
    asked = []
    for (_, view), (ref, test) in zip(built, keypoints):
        asked += [(view.reference, ref if count is None else np.asarray(ref)[:count]) for count in counts]
        asked.append((view.test, _test_keypoints(test, experiment)))
    return asked


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


#: A (matcher, estimator) combination; the estimator is None where no pose is estimated.
Combination = tuple[str, "str | None"]


def build_methods(methods: dict | None) -> tuple[dict, dict]:
    """The built matchers and estimators of ``methods`` (``{"matchers": {name: params}, "estimators": {name:
    params}}``; None: the survey's, with their defaults), ``{name: built}``; the estimators are ``{None: None}``
    when it names none (no pose estimated)."""
    methods = methods or {"matchers": {SURVEY_MATCHER: {}}, "estimators": {SURVEY_ESTIMATOR: {}}}
    matchers = {name: MATCHERS.get(name).build(params) for name, params in methods["matchers"].items()}
    estimators = {name: ESTIMATORS.get(name).build(params)
                  for name, params in (methods.get("estimators") or {}).items()}
    return matchers, estimators or {None: None}


def detect_views(detect, shard: dict, transform: str, transform_cfg: dict, method: dict, experiment: dict,
                 seed: int) -> tuple[list, list[dict]]:
    """Keypoints ``(reference, test)`` and a row of detection metrics per view of a shard; raises on failure.

    ``detect(image, mask, detector, detector_params, selector, selector_params) -> (keypoints, n_detected,
    seconds)`` detects and selects (a sweep's goes through the keypoint cache); the selector's ``n`` and the
    "< N KPs" threshold are scaled to each view's area with ``experiment.budget_per_mpx``."""
    keypoints, rows = [], []
    for meta, view in views(shard, transform, transform_cfg, seed):
        selection, min_keypoints = budget.scaled(method["selector_cfg"].get("params") or {},
                                                 experiment.get("min_keypoints", 100), experiment, view.test.shape)
        detection = (method["detector"], method["detector_cfg"].get("params") or {}, method["selector"], selection)
        ref, n_ref, _ = detect(view.reference, view.reference_mask, *detection)
        test, n_test, seconds = detect(view.test, view.test_mask, *detection)
        row = {**meta, "n_detected": n_test, "n_kp_ref": len(ref), "n_kp_test": len(test), "t_detect": seconds}
        row.update(detection_metrics(view, ref, test, experiment.get("iou_threshold", 0.5), min_keypoints))
        keypoints.append((ref, test))
        rows.append(row)
    return keypoints, rows


def pair_views(shard: dict, transform: str, transform_cfg: dict, keypoints: list, detection_rows: list[dict],
               detector: str, descriptor: str, descriptor_params: dict, experiment: dict, seed: int,
               methods: dict) -> list[dict]:
    """A row of matching (and pose) metrics per view of a shard and reference count with one matcher and estimator
    (``methods``, as :func:`build_methods` takes them); raises on failure."""
    matchers, estimators = build_methods(methods)
    (result,) = evaluate_views(shard, transform, transform_cfg, keypoints, detection_rows, detector, descriptor,
                               descriptor_params, experiment, seed, matchers, estimators).values()
    if isinstance(result, Exception):
        raise result
    return result


def evaluate_members(shard: dict, transform: str, transform_cfg: dict, members: list[tuple], descriptor: str,
                     descriptor_params: dict, experiment: dict, seed: int, matchers: dict, estimators: dict,
                     dense=None, together: bool = True) -> list[dict[Combination, list[dict] | Exception] | Exception]:
    """:func:`evaluate_views` for several detectors' keypoints (``members``: ``(detector, keypoints,
    detection_rows)``) described by one descriptor on one shard, each member's outcome or the exception that
    stopped it. With ``together``, a descriptor that describes keypoint sets together (DAISY, SIFT) describes
    every member's keypoints of an image, and every reference count, in one call per group
    (:func:`~gtsweep.evaluation.reuse.describe_together`), one shard item (its views) at a time."""
    if not (together and DESCRIPTORS.get(descriptor).together):
        return [_evaluated(lambda: evaluate_views(shard, transform, transform_cfg, keypoints, rows, detector,
                                                  descriptor, descriptor_params, experiment, seed, matchers,
                                                  estimators, dense)) for detector, keypoints, rows in members]
    outcomes: list = [{(m, e): [] for m in matchers for e in estimators} for _ in members]
    done = 0  # views of the items before this one
    for item in shard["items"]:
        part = {**shard, "items": [item]}
        built = list(views(part, transform, transform_cfg, seed))
        span = slice(done, done + len(built))
        done = span.stop
        asked = [(detector, _asked(built, keypoints[span], experiment)) for detector, keypoints, _ in members]
        memos = describe_together(asked, descriptor, descriptor_params, experiment.get("foreign_scale"), dense)
        for i, ((detector, keypoints, rows), memo) in enumerate(zip(members, memos)):
            if isinstance(outcomes[i], Exception):
                continue
            found = _evaluated(lambda: evaluate_views(part, transform, transform_cfg, keypoints[span], rows[span],
                                                      detector, descriptor, descriptor_params, experiment, seed,
                                                      matchers, estimators, dense, memo=memo, built=built))
            outcomes[i] = found if isinstance(found, Exception) else _extended(outcomes[i], found)
    return outcomes


def _extended(so_far: dict, found: dict) -> dict:
    """Per combination, the rows so far followed by ``found``'s, or the first exception that stopped it."""
    return {combination: rows if isinstance(rows, Exception) else
            found[combination] if isinstance(found[combination], Exception) else rows + found[combination]
            for combination, rows in so_far.items()}


def _evaluated(evaluate):
    """``evaluate()``, or the exception that stopped it (one member's failure is its own)."""
    try:
        return evaluate()
    except Exception as error:
        return error


def evaluate_views(shard: dict, transform: str, transform_cfg: dict, keypoints: list, detection_rows: list[dict],
                   detector: str, descriptor: str, descriptor_params: dict, experiment: dict, seed: int,
                   matchers: dict, estimators: dict, dense=None, memo: DescribeOnce | None = None,
                   built: list | None = None) -> dict[Combination, list[dict] | Exception]:
    """Per (matcher, estimator): a row of matching (and pose) metrics per view of a shard and reference count, or
    the exception that stopped that combination. Each pair is described once; each matcher matches it once and
    every estimator works on those matches. A descriptor that fails raises (it stops every combination).
    ``dense``: where dense descriptor maps are kept between tasks (:func:`~gtsweep.stages.describe.describe_timed`).
    ``memo`` and ``built``: the task's describe memo and its views, when :func:`evaluate_members` made them."""
    counts = experiment.get("reference_counts") or [None]
    norm, iou = DESCRIPTORS.get(descriptor).norm, experiment.get("iou_threshold", 0.5)
    results: dict[Combination, list[dict] | Exception] = {(m, e): [] for m in matchers for e in estimators}
    # every image of the shard described once
    memo = memo or DescribeOnce(descriptor, detector, descriptor_params, experiment.get("foreign_scale"), dense)
    built = built if built is not None else views(shard, transform, transform_cfg, seed)
    for (meta, view), (ref, test), det_row in zip(built, keypoints, detection_rows):
        view_seed = stable_seed(seed, meta["view"])
        for count in counts:
            described = describe_pair(view, ref, test, descriptor, descriptor_params, detector, experiment, count,
                                      memo)
            base = {**det_row, "reference_count": count if count is not None else math.nan}
            for m, matcher in matchers.items():
                live = [e for e in estimators if not isinstance(results[(m, e)], Exception)]
                if not live:
                    continue
                try:
                    matches, row = match_metrics(view, described, norm, matcher, iou)
                except Exception as error:  # this matcher's combinations fail; the others go on
                    results.update({(m, e): error for e in live})
                    continue
                for e in live:
                    try:
                        pose = {} if e is None else pose_metrics(view, described, matches, estimators[e],
                                                                 experiment["pose"], view_seed)
                    except Exception as error:
                        results[(m, e)] = error
                        continue
                    results[(m, e)].append({**base, **row, **pose})
    return results
