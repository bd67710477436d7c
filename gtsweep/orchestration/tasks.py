"""Work units of a sweep, as plain functions: the runner calls them in-process or as Ray tasks.

A *shard* is a few images (synthetic transforms) or image pairs (real pairs) with their pixels. One detection task
runs per (shard, transform, detector, selector); its keypoints are reused by every descriptor's pairing task.
Keypoints travel as ``(N, 7)`` arrays (``cv2.KeyPoint`` does not pickle). Failures that the user should see in the
results (a method not available, an NA pairing found at run time) come back as ``{"na": reason}``.
"""
from __future__ import annotations

import math
import traceback

from gtsweep.core.errors import GtsweepError, NotApplicable
from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation.evaluate import (
    detect_and_select,
    detection_metrics,
    pairing_metrics,
)
from gtsweep.evaluation.views import views
from gtsweep.orchestration.cache import KeypointCache, detection_key, library_versions


def _detect_cached(cache: KeypointCache, image, mask, method: dict, versions: dict):
    key = detection_key(image, mask, method["detector"], method["detector_cfg"], method["selector"],
                        method["selector_cfg"], versions)
    found = cache.get(key)
    if found is None:
        found = detect_and_select(image, mask, method["detector"], method["detector_cfg"].get("params") or {},
                                  method["selector"], method["selector_cfg"].get("params") or {})
        cache.put(key, *found)
    return found


def detect_shard(shard: dict, transform: str, transform_cfg: dict, method: dict, experiment: dict, seed: int,
                 cache_dir: str | None):
    """Detect and select on every view of a shard; returns ``(payload, summary)``.

    ``method``: detector, detector_cfg, selector, selector_cfg. ``payload`` (for the pairing tasks) holds the
    keypoints and rows per view; ``summary`` (for the driver) holds the rows and the cache hits and misses; a miss
    is one detector call.
    """
    cache = KeypointCache(cache_dir)
    versions = library_versions()
    keypoints, rows = [], []
    try:
        for meta, view in views(shard, transform, transform_cfg, seed):
            ref, n_ref, _ = _detect_cached(cache, view.reference, view.reference_mask, method, versions)
            test, n_test, seconds = _detect_cached(cache, view.test, view.test_mask, method, versions)
            row = {**meta, "n_detected": n_test, "n_kp_ref": len(ref), "n_kp_test": len(test),
                   "t_detect": seconds}
            row.update(detection_metrics(view, ref, test, experiment.get("iou_threshold", 0.5),
                                         experiment.get("min_keypoints", 100)))
            keypoints.append((ref, test))
            rows.append(row)
    except GtsweepError as e:  # method unavailable or not applicable: the cell is NA, the sweep goes on
        failure = {"na": str(e), "hits": cache.hits, "misses": cache.misses}
        return failure, failure
    except Exception as e:  # a bug: reported with the cell, the sweep goes on
        failure = {"error": _describe_bug(e), "hits": cache.hits, "misses": cache.misses}
        return failure, failure
    summary = {"rows": rows, "hits": cache.hits, "misses": cache.misses}
    return {"keypoints": keypoints, "rows": rows}, summary


def pair_shard(shard: dict, transform: str, transform_cfg: dict, detection: dict, detector: str, descriptor: str,
               descriptor_params: dict, experiment: dict, seed: int) -> dict:
    """Describe, match and estimate poses for every view of a shard; returns ``{"rows": [...]}`` or a failure."""
    if "keypoints" not in detection:
        return {k: v for k, v in detection.items() if k in ("na", "error")}
    counts = experiment.get("reference_counts") or [None]
    rows = []
    try:
        for (meta, view), (ref, test), det_row in zip(views(shard, transform, transform_cfg, seed),
                                                       detection["keypoints"], detection["rows"]):
            for count in counts:
                metrics = pairing_metrics(view, ref, test, descriptor, descriptor_params, detector, experiment,
                                          seed=stable_seed(seed, meta["view"]), reference_count=count)
                rows.append({**det_row, "reference_count": count if count is not None else math.nan, **metrics})
    except NotApplicable as e:
        return {"na": e.reason}
    except GtsweepError as e:
        return {"na": str(e)}
    except Exception as e:
        return {"error": _describe_bug(e)}
    return {"rows": rows}


def _describe_bug(error: Exception) -> str:
    where = traceback.extract_tb(error.__traceback__)[-1]
    return f"{type(error).__name__}: {error} (at {where.filename}:{where.lineno})"
