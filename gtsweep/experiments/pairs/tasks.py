"""The pair experiments' work units, as plain functions: an executor (:mod:`gtsweep.orchestration.executor`) runs
them in-process or as Ray tasks.

A *shard* is a few images (synthetic transforms) or image pairs (real pairs) with their pixels. One detection task
runs per (shard, transform, detector, selector); its keypoints are reused by every descriptor's pairing task. A
pairing task evaluates every (matcher, estimator) combination of the grid on one descriptor's pairs, for one
detector, or for every detector of a descriptor that describes keypoint sets together (DAISY, SIFT), which then
describes each image once (per group). What is
computed per view (the keypoint budget, the reference counts, a failing matcher or estimator costing only its own
combinations) is science: :mod:`gtsweep.evaluation.evaluate`; these functions only ship it.
Keypoints travel as ``(N, 7)`` arrays (``cv2.KeyPoint`` does not pickle). A task never raises: an NA pairing
found at run time comes back as ``{"na": reason}``; anything else that stops it (a method not available, a
parameter OpenCV rejects, a bug) as ``{"error": reason}`` (:func:`~gtsweep.orchestration.tasks.failure`).
"""
from __future__ import annotations

import time
from functools import partial

from gtsweep.evaluation.evaluate import build_methods, detect_views, evaluate_members
from gtsweep.orchestration.cache import DenseMapCache, KeypointCache, detect_cached
from gtsweep.orchestration.grid import declare
from gtsweep.orchestration.tasks import counts, dense_counts, failure, timed
from gtsweep.stages import device as devices


def detect_shard(shard: dict, transform: str, transform_cfg: dict, method: dict, experiment: dict, seed: int,
                 cache_dir: str | None, declared: dict | None = None, keep_raw: bool = True):
    """Detect and select on every view of a shard; returns ``(payload, summary)``.

    ``method``: detector, detector_cfg, selector, selector_cfg. ``payload`` (for the pairing tasks) holds the
    keypoints and rows per view; ``summary`` (for the driver) holds the rows, the cache counts (:func:`counts`; a
    miss is one detector call) and when the task ran. ``declared``: the grid's methods declared in YAML;
    ``keep_raw``: store the detector's raw output in the cache (:func:`~gtsweep.orchestration.cache.detect_cached`).
    """
    started = time.time()
    cache = KeypointCache(cache_dir, keep_raw=keep_raw)
    try:
        declare(declared or {})
        with devices.using(method.get("device")):
            keypoints, rows = detect_views(partial(detect_cached, cache), shard, transform, transform_cfg, method,
                                           experiment, seed)
    except Exception as e:  # reported with the cell; the sweep goes on
        failed = {**failure(e), **counts(cache)}
        return failed, timed(started, failed)
    summary = {"rows": rows, **counts(cache)}
    return {"keypoints": keypoints, "rows": rows}, timed(started, summary)


def pair_shard(shard: dict, transform: str, transform_cfg: dict, detection: dict, detector: str, descriptor: str,
               descriptor_params: dict, experiment: dict, seed: int, declared: dict | None = None,
               methods: dict | None = None, cache_dir: str | None = None, together: bool = True) -> dict:
    """Describe, match and estimate poses for every view of a shard; returns ``{"by_method": {(matcher,
    estimator): {"rows": [...]} or a failure}}``, or one failure for all (the detection's, or the descriptor's),
    with when the task ran. ``methods``: ``{"matchers": {name: params}, "estimators": {name: params}}`` (no
    estimators outside the pose experiment); None: the survey's (``bf_ratio``, ``ransac``). ``cache_dir``: the
    keypoint cache's directory, which also keeps dense descriptor maps (:class:`DenseMapCache`). ``together``
    (``runner.describe_together``): a descriptor that describes keypoint sets together does so for Table 7's
    reference counts of an image."""
    result = pair_shard_members(shard, transform, transform_cfg, [detector], descriptor, descriptor_params,
                                experiment, seed, declared, methods, cache_dir, together, detection)
    (part,) = result.pop("parts")
    return {**part, **result}


def pair_shard_members(shard: dict, transform: str, transform_cfg: dict, detectors: list[str], descriptor: str,
                       descriptor_params: dict, experiment: dict, seed: int, declared: dict | None,
                       methods: dict | None, cache_dir: str | None, together: bool, *detections: dict) -> dict:
    """:func:`pair_shard` for several detectors' detections of one shard (``detections``, one per detector, as
    top-level arguments so the executor resolves them) described by one descriptor: ``{"parts": [each
    detector's pair_shard result without its timing], "dense": counts}``, with when the task ran. A descriptor
    with ``together`` (DAISY, SIFT) describes all detectors' keypoints of an image in one call per group
    (:func:`~gtsweep.evaluation.evaluate.evaluate_members`); one detector's failure is its own."""
    started = time.time()
    dense = DenseMapCache(cache_dir)
    parts: list[dict | None] = [None if "keypoints" in d else {k: v for k, v in d.items() if k in ("na", "error")}
                                for d in detections]
    members = [(detector, d["keypoints"], d["rows"]) for detector, d, part in zip(detectors, detections, parts)
               if part is None]
    try:
        declare(declared or {})
        with devices.using((methods or {}).get("device")):
            matchers, estimators = build_methods(methods)
            outcomes = evaluate_members(shard, transform, transform_cfg, members, descriptor, descriptor_params,
                                        experiment, seed, matchers, estimators, dense, together) if members else []
    except Exception as e:
        outcomes = [e] * len(members)
    outcomes = iter(outcomes)
    for i, part in enumerate(parts):
        if part is None:
            outcome = next(outcomes)
            parts[i] = failure(outcome) if isinstance(outcome, Exception) else {"by_method": {
                combination: failure(result) if isinstance(result, Exception) else {"rows": result}
                for combination, result in outcome.items()}}
    return timed(started, {"parts": parts, "dense": dense_counts(dense)})
