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

A trial runs the sweep's work units (:mod:`gtsweep.orchestration.tasks`) on the optimisation shards, in one
task: plain data in, plain dict out; the executor runs :func:`evaluate` in-process or as a Ray task.
"""
from __future__ import annotations

import math
import time
from functools import partial

from gtsweep.core.errors import GtsweepError
from gtsweep.evaluation.evaluate import detect_views, pair_views
from gtsweep.orchestration.cache import KeypointCache, detect_cached
from gtsweep.orchestration.executor import describe_error
from gtsweep.orchestration.grid import declare
from gtsweep.orchestration.shards import shard_kind

OBJECTIVES = ("repeatability", "pose_success")
#: What a trial keeps of a pairing row, beside repeatability, few_keypoints and n_keypoints.
PAIRING_KEYS = ("pose_success", "precision", "n_matches", "n_correct")


def evaluate(shards: dict, job: dict) -> dict:
    """Score one parameter set; ``{"metrics": {...}}`` or ``{"error": reason}``.

    ``shards``: :func:`gtsweep.orchestration.shards.load_shards`'s. ``job``: objective, detector, detector_params,
    descriptor, descriptor_params, selector, selector_params, transforms, settings (min_keypoints, iou_threshold,
    pose: the success thresholds, methods: the matcher and estimator with their parameters), seed and cache_dir.
    """
    start = time.perf_counter()
    try:
        declare(job.get("declared") or {})
        metrics = trial_metrics(_rows(shards, job), job["objective"])
    except Exception as e:  # a parameter set the method rejects, or a bug: this trial fails, the study goes on
        return {"error": describe_error(e)}
    metrics["seconds"] = time.perf_counter() - start
    return {"metrics": metrics}


def _rows(shards: dict, job: dict) -> dict[str, list[dict]]:
    """Per transform, one row of numbers per view. Detections are cached in memory for the trial (references
    repeat across transforms and strengths), for the pose objective on disk too (its trials all detect with the
    same parameters)."""
    settings, seed = job["settings"], job["seed"]
    pose = job["objective"] == "pose_success"
    cache = KeypointCache(job.get("cache_dir") if pose else None)
    experiment = {"iou_threshold": settings["iou_threshold"], "min_keypoints": settings["min_keypoints"],
                  "pose": settings.get("pose"), "budget_per_mpx": settings.get("budget_per_mpx")}
    method = {"detector": job["detector"], "detector_cfg": {"params": job["detector_params"]},
              "selector": job["selector"], "selector_cfg": {"params": job["selector_params"]}}
    rows: dict[str, list[dict]] = {}
    for name, transform_cfg in job["transforms"].items():
        rows[name] = []
        for shard in shards[shard_kind(name, transform_cfg)]:
            keypoints, found = detect_views(partial(detect_cached, cache), shard, name, transform_cfg, method,
                                            experiment, seed)
            if pose:
                found = pair_views(shard, name, transform_cfg, keypoints, found, job["detector"], job["descriptor"],
                                   job["descriptor_params"], experiment, seed, settings["methods"])
            rows[name] += [{"repeatability": row["repeatability"], "few_keypoints": row["few_keypoints"],
                            "n_keypoints": float(row["n_kp_test"]), **{k: row[k] for k in PAIRING_KEYS if pose}}
                           for row in found]
    return rows


def trial_metrics(rows: dict[str, list[dict]], objective: str) -> dict:
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
