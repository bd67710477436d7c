"""Work units of a sweep, as plain functions: an executor (:mod:`gtsweep.orchestration.executor`) runs them
in-process or as Ray tasks.

A *shard* is a few images (synthetic transforms) or image pairs (real pairs) with their pixels. One detection task
runs per (shard, transform, detector, selector); its keypoints are reused by every descriptor's pairing task. A
pairing task describes each pair once and evaluates every (matcher, estimator) combination of the grid on those
descriptors; a matcher or estimator that fails costs only its own combinations.
Keypoints travel as ``(N, 7)`` arrays (``cv2.KeyPoint`` does not pickle). A task never raises: an NA pairing
found at run time comes back as ``{"na": reason}``; anything else that stops it (a method not available, a
parameter OpenCV rejects, a bug) as ``{"error": reason}`` (:func:`failure`).
"""
from __future__ import annotations

import math
import time

from gtsweep.core.errors import NotApplicable
from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation import budget
from gtsweep.evaluation.evaluate import (
    describe_pair,
    detection_metrics,
    match_metrics,
    pose_metrics,
    survey_methods,
)
from gtsweep.evaluation.reuse import DescribeOnce
from gtsweep.evaluation.views import views
from gtsweep.orchestration.cache import KeypointCache, detect_cached
from gtsweep.orchestration.executor import describe_error
from gtsweep.orchestration.grid import declare
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.pose import ESTIMATORS

#: A (matcher, estimator) combination; the estimator is None outside the pose experiment.
Combination = tuple[str, "str | None"]


def failure(error: Exception) -> dict:
    """A task's status for ``error``: ``{"na": reason}`` for a pairing the survey could not evaluate, else
    ``{"error": reason}`` (a one-line reason; a bug's also says where it was raised)."""
    if isinstance(error, NotApplicable):
        return {"na": error.reason}
    return {"error": describe_error(error)}


def _timed(started: float, result: dict) -> dict:
    """``result`` with the task's wall-clock start and end (seconds since the epoch): a cell's compute time."""
    return {**result, "started": started, "ended": time.time()}


def detect_shard(shard: dict, transform: str, transform_cfg: dict, method: dict, experiment: dict, seed: int,
                 cache_dir: str | None, declared: dict | None = None):
    """Detect and select on every view of a shard; returns ``(payload, summary)``.

    ``method``: detector, detector_cfg, selector, selector_cfg. ``payload`` (for the pairing tasks) holds the
    keypoints and rows per view; ``summary`` (for the driver) holds the rows, the cache counts (:func:`counts`; a
    miss is one detector call) and when the task ran. ``declared``: the grid's methods declared in YAML.
    """
    started = time.time()
    cache = KeypointCache(cache_dir)
    try:
        declare(declared or {})
        keypoints, rows = detect_views(cache, shard, transform, transform_cfg, method, experiment, seed)
    except Exception as e:  # reported with the cell; the sweep goes on
        failed = {**failure(e), **counts(cache)}
        return failed, _timed(started, failed)
    summary = {"rows": rows, **counts(cache)}
    return {"keypoints": keypoints, "rows": rows}, _timed(started, summary)


def counts(cache: KeypointCache) -> dict:
    """A task's cache counts for the driver: hits, misses, bad entries replaced, failed writes."""
    return {"hits": cache.hits, "misses": cache.misses, "corrupt": cache.corrupt, "write_errors": cache.write_errors}


def pair_shard(shard: dict, transform: str, transform_cfg: dict, detection: dict, detector: str, descriptor: str,
               descriptor_params: dict, experiment: dict, seed: int, declared: dict | None = None,
               methods: dict | None = None) -> dict:
    """Describe, match and estimate poses for every view of a shard; returns ``{"by_method": {(matcher,
    estimator): {"rows": [...]} or a failure}}``, or one failure for all (the detection's, or the descriptor's),
    with when the task ran. ``methods``: ``{"matchers": {name: params}, "estimators": {name: params}}`` (no
    estimators outside the pose experiment); None: the survey's (``bf_ratio``, ``ransac``)."""
    started = time.time()
    if "keypoints" not in detection:
        return _timed(started, {k: v for k, v in detection.items() if k in ("na", "error")})
    try:
        declare(declared or {})
        matchers, estimators = build_methods(methods, experiment)
        outcome = evaluate_views(shard, transform, transform_cfg, detection["keypoints"], detection["rows"],
                                 detector, descriptor, descriptor_params, experiment, seed, matchers, estimators)
    except Exception as e:
        return _timed(started, failure(e))
    return _timed(started, {"by_method": {combination: failure(result) if isinstance(result, Exception)
                                          else {"rows": result} for combination, result in outcome.items()}})


def build_methods(methods: dict | None, experiment: dict) -> tuple[dict, dict]:
    """The built matchers and estimators of ``methods`` (see :func:`pair_shard`), ``{name: built}``; the estimators
    are ``{None: None}`` outside the pose experiment."""
    if methods is None:
        matcher, estimator = survey_methods(experiment)
        matchers, estimators = {"bf_ratio": matcher}, {"ransac": estimator}
    else:
        matchers = {name: MATCHERS.get(name).build(params) for name, params in methods["matchers"].items()}
        estimators = {name: ESTIMATORS.get(name).build(params)
                      for name, params in (methods.get("estimators") or {}).items()}
    return matchers, (estimators if experiment.get("name") == "pose" else {None: None})


def detect_views(cache: KeypointCache, shard: dict, transform: str, transform_cfg: dict, method: dict,
                 experiment: dict, seed: int) -> tuple[list, list[dict]]:
    """Keypoints ``(reference, test)`` and a row of detection metrics per view of a shard; raises on failure."""
    keypoints, rows = [], []
    for meta, view in views(shard, transform, transform_cfg, seed):
        selection, min_keypoints = budget.scaled(method["selector_cfg"].get("params") or {},
                                                 experiment.get("min_keypoints", 100), experiment, view.test.shape)
        detection = (method["detector"], method["detector_cfg"].get("params") or {}, method["selector"], selection)
        ref, n_ref, _ = detect_cached(cache, view.reference, view.reference_mask, *detection)
        test, n_test, seconds = detect_cached(cache, view.test, view.test_mask, *detection)
        row = {**meta, "n_detected": n_test, "n_kp_ref": len(ref), "n_kp_test": len(test), "t_detect": seconds}
        row.update(detection_metrics(view, ref, test, experiment.get("iou_threshold", 0.5), min_keypoints))
        keypoints.append((ref, test))
        rows.append(row)
    return keypoints, rows


def pair_views(shard: dict, transform: str, transform_cfg: dict, keypoints: list, detection_rows: list[dict],
               detector: str, descriptor: str, descriptor_params: dict, experiment: dict, seed: int) -> list[dict]:
    """A row of matching (and pose) metrics per view of a shard and reference count with the survey's matcher and
    estimator built from ``experiment`` (the optimiser's settings); raises on failure."""
    matchers, estimators = build_methods(None, experiment)
    (result,) = evaluate_views(shard, transform, transform_cfg, keypoints, detection_rows, detector, descriptor,
                               descriptor_params, experiment, seed, matchers, estimators).values()
    if isinstance(result, Exception):
        raise result
    return result


def evaluate_views(shard: dict, transform: str, transform_cfg: dict, keypoints: list, detection_rows: list[dict],
                   detector: str, descriptor: str, descriptor_params: dict, experiment: dict, seed: int,
                   matchers: dict, estimators: dict) -> dict[Combination, list[dict] | Exception]:
    """Per (matcher, estimator): a row of matching (and pose) metrics per view of a shard and reference count, or
    the exception that stopped that combination. Each pair is described once; each matcher matches it once and
    every estimator works on those matches. A descriptor that fails raises (it stops every combination)."""
    counts = experiment.get("reference_counts") or [None]
    norm, iou = DESCRIPTORS.get(descriptor).norm, experiment.get("iou_threshold", 0.5)
    results: dict[Combination, list[dict] | Exception] = {(m, e): [] for m in matchers for e in estimators}
    # every image of the shard described once
    memo = DescribeOnce(descriptor, detector, descriptor_params, experiment.get("foreign_scale"))
    for (meta, view), (ref, test), det_row in zip(views(shard, transform, transform_cfg, seed), keypoints,
                                                   detection_rows):
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
