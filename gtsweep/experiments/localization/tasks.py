"""Work units of ``experiment=localization`` (plain functions an executor runs in-process or as Ray tasks), and the
content-addressed map cache.

- :func:`map_shard`: detect (through the keypoint cache) and describe a few mapping images;
- :func:`assemble_map`: stack the shards' features into the map of one floor (:func:`gtsweep.stages.localize.
  build_map`) and write it to the map cache, so every matcher and estimator that shares detector, selector and
  descriptor reuses it (and so does the next run);
- :func:`query_shard`: detect and describe a few queries, index the map once per map size with the cell's
  matcher, match, vote and estimate with every estimator: one row per query and map size, per estimator.

Tasks never raise: a failure comes back as ``{"error": reason}`` or, for a pairing that cannot be evaluated,
``{"na": reason}`` (:func:`gtsweep.orchestration.tasks.failure`).
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import config_hash
from gtsweep.datasets.core import read_gray
from gtsweep.orchestration.cache import KeypointCache, detect_cached, library_versions
from gtsweep.orchestration.grid import declare
from gtsweep.orchestration.tasks import counts, failure
from gtsweep.stages.applicability import describe_timed
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.localize import Acceptance, FeatureMap, build_map, judge, localize, pose_columns
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.pose import ESTIMATORS

MAP_FIELDS = ("xy", "angle", "descriptors", "image", "build_seconds")


def map_key(*parts) -> str:
    """The map cache key: everything that determines a map (data set fingerprint, texture, mapping image ids,
    detector, selector, descriptor and their parameters, dedupe) and the library versions."""
    return config_hash([*parts, library_versions()])


def map_path(cache_dir: str | None, key: str) -> Path | None:
    """Where the map of ``key`` is cached: ``<cache.dir>/../maps/<key>.npz`` (None without a cache)."""
    return None if not cache_dir else Path(cache_dir).parent / "maps" / f"{key}.npz"


def read_map(path: Path | None, key: str) -> dict | None:
    """A cached map (its arrays and ``key``), or None when absent or damaged (then removed)."""
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as entry:
            found = {name: entry[name] for name in MAP_FIELDS}
            ok = str(entry["key"]) == key
    except Exception:  # truncated or not an npz: recompute
        ok = False
    if not ok:
        path.unlink(missing_ok=True)
        return None
    return found


def _detect_describe(cache: KeypointCache, image, method: dict):
    keypoints, _, t_detect = detect_cached(cache, image, None, method["detector"], method["detector_params"],
                                           method["selector"], method["selector_params"])
    kept, descriptors, t_describe = describe_timed(image, keypoints, method["descriptor"], method["detector"],
                                                   method.get("foreign_scale"), **method["descriptor_params"])
    return keypoints, kept, descriptors, t_detect, t_describe


def map_shard(images: list[dict], method: dict, cache_dir: str | None, declared: dict | None = None) -> dict:
    """Features of mapping images (``{"path", "pose"}`` each, read here): ``{"parts": [(keypoints, descriptors,
    pose, shape, seconds)], **cache counts}``, or a failure (an unreadable image: the cell's one-line error)."""
    cache = KeypointCache(cache_dir)
    try:
        declare(declared or {})
        parts = []
        for item in images:
            image = read_gray(item["path"])
            _, kept, descriptors, t_detect, t_describe = _detect_describe(cache, image, method)
            parts.append((kept, descriptors, item["pose"], image.shape, t_detect + t_describe))
    except Exception as e:
        return {**failure(e), **counts(cache)}
    return {"parts": parts, **counts(cache)}


def assemble_map(dedupe: bool, path: str | None, key: str, *shards: dict) -> dict:
    """The map of one floor from its shards (in mapping order), written to the map cache at ``path``."""
    for shard in shards:
        if "parts" not in shard:
            return {k: v for k, v in shard.items() if k in ("na", "error")}
    try:
        feature_map = build_map([p for shard in shards for p in shard["parts"]], dedupe=dedupe)
    except Exception as e:
        return failure(e)
    arrays = {name: getattr(feature_map, name) for name in MAP_FIELDS}
    if path is not None:
        try:
            write_atomically(path, lambda f: np.savez(f, key=key, **arrays))
        except OSError:  # a read-only cache: the run goes on with the map in memory
            pass
    return arrays


def query_shard(queries: list[dict], feature_map: dict, sizes: dict, method: dict, matcher: tuple,
                estimators: dict, experiment: dict, seed: int, cache_dir: str | None,
                declared: dict | None = None) -> dict:
    """Localize every query of a shard in the map of each size (``sizes``: ``{n_images: covered m²}``) with the
    cell's ``matcher`` (name, params) and every estimator of ``estimators`` (``{name: params}``). Returns
    ``{"by_estimator": {name: rows}, "started", "ended", **cache counts}`` or a failure."""
    started = time.time()
    cache = KeypointCache(cache_dir)
    if "xy" not in feature_map:
        return {**{k: v for k, v in feature_map.items() if k in ("na", "error")}, "started": started,
                "ended": time.time()}
    try:
        declare(declared or {})
        rows = _localize_all(cache, queries, FeatureMap(**feature_map), sizes, method, matcher, estimators,
                             experiment, seed)
    except Exception as e:
        return {**failure(e), **counts(cache), "started": started, "ended": time.time()}
    return {"by_estimator": rows, **counts(cache), "started": started, "ended": time.time()}


def _localize_all(cache, queries, full_map: FeatureMap, sizes, method, matcher, estimators, experiment, seed):
    norm = DESCRIPTORS.get(method["descriptor"]).norm
    built_matcher = MATCHERS.get(matcher[0]).build(matcher[1])
    built = {name: ESTIMATORS.get(name).build(params) for name, params in estimators.items()}
    acceptance = Acceptance(int(experiment.get("min_inliers", 10)), float(experiment.get("min_inlier_ratio", 0.0)))
    features = [_detect_describe(cache, q["image"], method) for q in queries]
    # voting reads keypoint orientations: a detector without them (Harris, FAST, ...) estimates from all matches
    voting = bool(experiment.get("voting", True)) and DETECTORS.get(method["detector"]).orientation
    rows: dict[str, list] = {name: [] for name in estimators}
    for n_images, area_m2 in sorted(sizes.items()):
        feature_map = full_map.first(int(n_images))
        start = time.perf_counter()
        index = built_matcher.index(feature_map.descriptors, norm)
        t_index = time.perf_counter() - start
        shared_map = {"map_images": int(n_images), "map_features": len(feature_map), "map_bytes": feature_map.nbytes,
                      "map_bytes_per_m2": feature_map.nbytes / area_m2 if area_m2 > 0 else math.nan,
                      "map_build_s": float(feature_map.build_seconds.sum()), "t_index": t_index}
        for query, (keypoints, kept, descriptors, t_detect, t_describe) in zip(queries, features):
            result = localize(kept, descriptors, query["image"].shape, feature_map, index, built,
                              acceptance, voting=voting,
                              vote_cell=float(experiment.get("vote_cell", 60.0)), seed=seed)
            base = {"query": query["id"], "texture": query["texture"], "in_map": int(query["in_map"]),
                    **shared_map, "n_kp_test": len(keypoints), "n_described_test": len(kept),
                    "n_matches": result["n_matches"], "n_voted": result["n_voted"], "t_detect": t_detect,
                    "t_describe": t_describe,
                    "t_match": result["t_match"], "t_vote": result["t_vote"]}
            for name, (estimate, t_pose, accepted) in result["poses"].items():
                rows[name].append({**base, **_judged(query, estimate, accepted, result["n_voted"], experiment),
                                   "t_pose": t_pose, "t_query": t_detect + t_describe + result["t_match"] +
                                   result["t_vote"] + t_pose})
    return rows


def _judged(query: dict, estimate, accepted: bool, n_given: int, experiment: dict) -> dict:
    """The row's pose columns and outcome: success (in-map queries with ground truth), false localization
    (foreign queries), wrong localization (accepted in-map queries outside the thresholds)."""
    shape = query["image"].shape
    columns = {**pose_columns(estimate.matrix, shape), "localized": float(accepted), "n_inliers": estimate.n_inliers,
               "inlier_ratio": estimate.n_inliers / n_given if n_given else math.nan,
               "position_error": math.nan, "orientation_error": math.nan, "localization_success": math.nan,
               "false_localization": math.nan, "wrong_localization": math.nan}
    if not query["in_map"]:
        columns["false_localization"] = float(accepted)
    elif query["pose"] is not None:
        verdict = judge(columns, query["pose"], shape, float(experiment.get("max_position_error", 30.0)),
                        float(experiment.get("max_orientation_error", 1.5)))
        columns.update(position_error=verdict["position_error"], orientation_error=verdict["orientation_error"],
                       localization_success=float(accepted and verdict["within"]),
                       wrong_localization=float(accepted and not verdict["within"]))
    return columns
