"""The parameter optimisation's objective: one parameter set scored on the optimisation views (survey section 5).

``repeatability`` (detector parameters): every optimisation image is transformed by each configured synthetic
transform at each strength; the detector (then the selector, NMS to N = 1000) runs on the reference and the test
view. Repeatability is averaged over the views of a transform, then over transforms (equal weight per transform
type). ``n_few`` counts the test views with fewer than ``min_keypoints`` keypoints. The score is

    score = repeatability - n_few

Since repeatability lies in [0, 1], one view more below N always costs more than any repeatability gain: a
lexicographic order (first as few views below N as possible, then the best repeatability) in one scalar that
Optuna maximises. ``few_share = n_few / n_views`` is reported beside it.

``pose_success`` (descriptor parameters, keypoints fixed): the share of views whose RANSAC pose is within the
success thresholds, averaged per transform type like repeatability; score = pose_success.

Plain data in, plain dict out: the driver runs :func:`evaluate` in-process or as a Ray task.
"""
from __future__ import annotations

import hashlib
import math
import time
import traceback

import numpy as np

from gtsweep.core.errors import GtsweepError
from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation.evaluate import (
    detect_and_select,
    detection_metrics,
    pairing_metrics,
)
from gtsweep.evaluation.views import views
from gtsweep.orchestration.cache import KeypointCache, detection_key, library_versions

OBJECTIVES = ("repeatability", "pose_success")


class Detections:
    """Detect-and-select with a memo per image and mask (references repeat across strengths), and optionally the
    on-disk keypoint cache (the pose objective detects with fixed parameters in every trial)."""

    def __init__(self, detector: str, params: dict, selector: str, selector_params: dict,
                 cache_dir: str | None = None):
        self.method = (detector, params, selector, selector_params)
        self.cache = KeypointCache(cache_dir) if cache_dir else None
        self.versions = library_versions() if cache_dir else None
        self.memo: dict[bytes, np.ndarray] = {}

    def __call__(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        digest = hashlib.blake2b(image.tobytes() + mask.tobytes() + str(image.shape).encode(), digest_size=16)
        key = digest.digest()
        if key not in self.memo:
            detector, params, selector, selector_params = self.method
            found = None
            if self.cache is not None:
                cache_key = detection_key(image, mask, detector, {"params": params}, selector,
                                          {"params": selector_params}, self.versions)
                found = self.cache.get(cache_key)
            if found is None:
                found = detect_and_select(image, mask, detector, params, selector, selector_params)
                if self.cache is not None:
                    self.cache.put(cache_key, *found)
            self.memo[key] = found[0]
        return self.memo[key]


def evaluate(shards: dict, job: dict) -> dict:
    """Score one parameter set; ``{"metrics": {...}}`` or ``{"error": reason}``.

    ``shards``: ``{"synthetic": shard, "pairs": shard}`` (:func:`gtsweep.evaluation.views.make_shard`). ``job``: objective,
    detector, detector_params, descriptor, descriptor_params, selector, selector_params, transforms, settings
    (min_keypoints, iou_threshold, ratio, mutual, pose), seed and cache_dir.
    """
    start = time.perf_counter()
    try:
        rows = _rows(shards, job)
    except GtsweepError as e:  # a parameter set the method rejects: this trial fails, the study goes on
        return {"error": str(e)}
    except Exception as e:  # a bug: reported with the trial
        where = traceback.extract_tb(e.__traceback__)[-1]
        return {"error": f"{type(e).__name__}: {e} (at {where.filename}:{where.lineno})"}
    metrics = summarize(rows, job["objective"])
    metrics["seconds"] = time.perf_counter() - start
    return {"metrics": metrics}


def _rows(shards: dict, job: dict) -> dict[str, list[dict]]:
    """Per transform, one row of numbers per view."""
    settings, seed = job["settings"], job["seed"]
    pose = job["objective"] == "pose_success"
    detect = Detections(job["detector"], job["detector_params"], job["selector"], job["selector_params"],
                        job.get("cache_dir") if pose else None)
    experiment = {"name": "pose", "ratio": settings.get("ratio", 0.7), "mutual": bool(settings.get("mutual")),
                  "iou_threshold": settings["iou_threshold"], "pose": settings.get("pose")}
    rows: dict[str, list[dict]] = {}
    for name, transform_cfg in job["transforms"].items():
        shard = shards["pairs" if transform_cfg["kind"] == "pairs" else "synthetic"]
        rows[name] = []
        for meta, view in views(shard, name, transform_cfg, seed):
            ref = detect(view.reference, view.reference_mask)
            test = detect(view.test, view.test_mask)
            found = detection_metrics(view, ref, test, settings["iou_threshold"], settings["min_keypoints"])
            row = {"repeatability": found["repeatability"], "few_keypoints": found["few_keypoints"],
                   "n_keypoints": float(len(test))}
            if pose:
                paired = pairing_metrics(view, ref, test, job["descriptor"], job["descriptor_params"],
                                         job["detector"], experiment, seed=stable_seed(seed, meta["view"]))
                row.update({k: paired[k] for k in ("pose_success", "precision", "n_matches", "n_correct")})
            rows[name].append(row)
    return rows


def summarize(rows: dict[str, list[dict]], objective: str) -> dict:
    """Metrics of a trial from its rows: means per transform type, their mean, n_few, few_share and the score."""
    if not any(rows.values()):
        raise GtsweepError("no views to evaluate: the optimisation split is empty")
    per_transform = {name: {key: _mean([r[key] for r in part]) for key in part[0]}
                     for name, part in rows.items() if part}
    keys = next(iter(per_transform.values())).keys()
    metrics = {key: _mean([values[key] for values in per_transform.values()]) for key in keys
               if key != "few_keypoints"}
    few = [r["few_keypoints"] for part in rows.values() for r in part]
    metrics.update(n_few=float(sum(few)), n_views=float(len(few)), few_share=sum(few) / len(few))
    for name, values in per_transform.items():
        metrics[f"{objective}/{name}"] = values[objective]
    metrics["score"] = metrics["repeatability"] - metrics["n_few"] if objective == "repeatability" \
        else metrics["pose_success"]
    return metrics


def _mean(values) -> float:
    """Mean of the finite values (NaN when there are none)."""
    finite = [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return sum(finite) / len(finite) if finite else math.nan
