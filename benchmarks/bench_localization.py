"""Query latency and map memory of map-scale localization for maps of 10, 100 and 1000 images (issue 19).

Usage: PYTHONPATH=. .venv/bin/python benchmarks/bench_localization.py [--sizes 10 100 1000] [--rendered 100]

Maps of up to ``--rendered`` images are rendered from the embedded data set (fine asphalt, 640 x 480 views, 50 %
overlap, SIFT on NMS-1000 keypoints, features deduplicated by first sighting). Larger maps are NOT rendered (too slow
on 2 cores): the rendered map is extended with synthetic features at positions far from the queries, as many per
image as the rendered map keeps: real SIFT descriptors of the rendered map with their 16 spatial cells (4 x 4 cells
of 8 orientation bins) randomly permuted, i.e. descriptors with the statistics of real ones that describe other
patches. Per map size and matcher (bf_ratio: exhaustive, flann: KD-trees) it prints the map's features and bytes,
the index build time (bf_ratio: none; it is skipped beyond ``--bf-max`` images, ~20 s per query at 1000), the
median time per query of matching + voting + RANSAC (detection and description of the
query excluded: they do not depend on the map) and how many in-map queries were localized (30 px, 1.5 deg).
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import time

import numpy as np

from gtsweep.datasets.mapping import load_localization
from gtsweep.evaluation.evaluate import detect_and_select
from gtsweep.stages.describe import describe
from gtsweep.stages.localize import Acceptance, FeatureMap, build_map, judge, localize, pose_columns
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.pose import ESTIMATORS


def features(image):
    keypoints, _, seconds = detect_and_select(image, None, "sift", {}, "nms", {"n": 1000})
    kept, descriptors = describe(image, keypoints, "sift", "sift")
    return kept, descriptors


def extended(feature_map: FeatureMap, n_images: int, rng: np.random.Generator) -> FeatureMap:
    """``feature_map`` grown to ``n_images`` with resampled real descriptors (see the module's docstring)."""
    have = int(feature_map.image.max()) + 1
    if n_images <= have:
        return feature_map.first(n_images)
    per_image = len(feature_map) // have
    extra = (n_images - have) * per_image
    pick = rng.integers(0, len(feature_map), extra)
    cells = feature_map.descriptors[pick].reshape(extra, 16, -1)  # SIFT: 4 x 4 cells x 8 orientation bins
    order = np.argsort(rng.random((extra, 16)), axis=1)
    descriptors = np.ascontiguousarray(np.take_along_axis(cells, order[:, :, None], axis=1).reshape(extra, -1))
    far = feature_map.xy.max(axis=0) + 5000.0  # distractors: far from every query
    xy = (far + rng.uniform(0, 50000, (extra, 2))).astype(np.float32)
    return FeatureMap(np.concatenate([feature_map.xy, xy]), np.concatenate([feature_map.angle,
                      rng.uniform(0, 360, extra).astype(np.float32)]),
                      np.concatenate([feature_map.descriptors, descriptors]),
                      np.concatenate([feature_map.image, have + np.arange(extra, dtype=np.int32) // per_image]),
                      feature_map.build_seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000])
    parser.add_argument("--rendered", type=int, default=100, help="largest map that is rendered")
    parser.add_argument("--queries", type=int, default=3)
    parser.add_argument("--bf-max", type=int, default=100, help="largest map matched exhaustively (bf_ratio)")
    args = parser.parse_args()
    rendered = min(args.rendered, max(args.sizes))
    start = time.perf_counter()
    data = load_localization({"loader": "synthetic"}, {"textures": ["fine_asphalt"], "map_images": [
        min(args.sizes), rendered], "n_queries": args.queries, "n_foreign": 0})
    print(f"rendered {rendered} mapping images + {args.queries} queries in {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    parts = []
    for sample in data.maps["fine_asphalt"]:
        image = sample.load()
        parts.append((*features(image), sample.pose, image.shape, 0.0))
    full = build_map(parts)
    print(f"detected and described the rendered map in {time.perf_counter() - start:.1f} s: {len(full)} features "
          f"kept of {sum(len(p[0]) for p in parts)} (dedupe)")
    queries = [(q.sample.load(), q.sample.pose) for q in data.queries]
    queries = [(image, pose, features(image)) for image, pose in queries]
    estimator = {"ransac": ESTIMATORS.get("ransac").build({})}
    rng = np.random.default_rng(0)
    print(f"{'images':>7} {'features':>9} {'map MB':>8} {'matcher':>9} {'index s':>8} {'ms/query':>9} {'localized':>9}")
    for size in sorted(args.sizes):
        feature_map = extended(full, size, rng)
        for matcher in ("bf_ratio", "flann") if size <= args.bf_max else ("flann",):
            t0 = time.perf_counter()
            index = MATCHERS.get(matcher).build({}).index(feature_map.descriptors, "l2")
            t_index = time.perf_counter() - t0
            times, hits = [], 0
            for image, pose, (kept, descriptors) in queries:
                t0 = time.perf_counter()
                result = localize(kept, descriptors, image.shape, feature_map, index, estimator, Acceptance())
                times.append(time.perf_counter() - t0)
                estimate, _, accepted = result["poses"]["ransac"]
                hits += accepted and judge(pose_columns(estimate.matrix, image.shape), pose, image.shape)["within"]
            print(f"{size:>7} {len(feature_map):>9} {feature_map.nbytes / 1e6:>8.1f} {matcher:>9} {t_index:>8.2f} "
                  f"{1000 * np.median(times):>9.0f} {hits:>6}/{len(queries)}")


if __name__ == "__main__":
    main()
