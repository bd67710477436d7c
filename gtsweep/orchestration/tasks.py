"""Work units of a sweep, as plain functions: an executor (:mod:`gtsweep.orchestration.executor`) runs them
in-process or as Ray tasks.

A *shard* is a few images (synthetic transforms) or image pairs (real pairs) with their pixels. One detection task
runs per (shard, transform, detector, selector); its keypoints are reused by every descriptor's pairing task.
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
from gtsweep.evaluation.evaluate import detection_metrics, pairing_metrics
from gtsweep.evaluation.views import views
from gtsweep.orchestration.cache import KeypointCache, detect_cached
from gtsweep.orchestration.executor import describe_error
from gtsweep.orchestration.grid import declare


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
               descriptor_params: dict, experiment: dict, seed: int, declared: dict | None = None) -> dict:
    """Describe, match and estimate poses for every view of a shard; returns ``{"rows": [...]}`` or a failure,
    with when the task ran."""
    started = time.time()
    if "keypoints" not in detection:
        return _timed(started, {k: v for k, v in detection.items() if k in ("na", "error")})
    try:
        declare(declared or {})
        return _timed(started, {"rows": pair_views(shard, transform, transform_cfg, detection["keypoints"],
                                                   detection["rows"], detector, descriptor, descriptor_params,
                                                   experiment, seed)})
    except Exception as e:
        return _timed(started, failure(e))


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
    """A row of matching (and pose) metrics per view of a shard and reference count; raises on failure."""
    counts = experiment.get("reference_counts") or [None]
    rows = []
    for (meta, view), (ref, test), det_row in zip(views(shard, transform, transform_cfg, seed), keypoints,
                                                   detection_rows):
        for count in counts:
            metrics = pairing_metrics(view, ref, test, descriptor, descriptor_params, detector, experiment,
                                      seed=stable_seed(seed, meta["view"]), reference_count=count)
            rows.append({**det_row, "reference_count": count if count is not None else math.nan, **metrics})
    return rows
