#!/usr/bin/env python3
"""Timing of gtsweep's XFeat (Potje et al., CVPR 2024; Apache-2.0) through cv2.dnn: detect, detect+describe.

Run from the repository root: ``nice -n 19 .venv/bin/python benchmarks/bench_xfeat.py [--repeats N]``.
Prints the median wall time per image for the survey's image size (1288x964) and for 640x480, split into the
network (cv2.dnn) and the NumPy post-processing, and the description of foreign keypoints from a stored dense map
(``DenseMapCache``: a pairing table's XFeat column computes each image's map once, for its first detector).
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import skimage.data

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gtsweep.orchestration.cache import DenseMapCache  # noqa: E402
from gtsweep.stages.xfeat import XFeat_create, run_network, to_network_input  # noqa: E402

SIZES = ((1288, 964), (640, 480))  # (width, height)


def median_seconds(function, repeats: int) -> float:
    function()  # warm-up: model load, allocations
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    detector = XFeat_create()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, median of {args.repeats} runs")
    for width, height in SIZES:
        image = cv2.resize(skimage.data.gravel(), (width, height), interpolation=cv2.INTER_CUBIC)
        net_input, _, _ = to_network_input(image)
        network = median_seconds(lambda: run_network(net_input), args.repeats)
        detect = median_seconds(lambda: detector.detect(image), args.repeats)
        both = median_seconds(lambda: detector.detectAndCompute(image, None), args.repeats)
        foreign = cv2.FastFeatureDetector_create(threshold=30).detect(image)[:4096]
        describe = median_seconds(lambda: detector.compute(image, foreign), args.repeats)
        stored = XFeat_create()
        with tempfile.TemporaryDirectory() as directory:
            stored.use_dense_cache(DenseMapCache(directory))
            from_map = median_seconds(lambda: stored.compute(image, foreign), args.repeats)  # warm-up stores it
        print(f"{width}x{height}: {len(detector.detect(image))} keypoints | network {network * 1e3:6.1f} ms"
              f" | detect {detect * 1e3:6.1f} ms | detect+describe {both * 1e3:6.1f} ms"
              f" | describe {len(foreign)} FAST keypoints {describe * 1e3:6.1f} ms, from a stored map"
              f" {from_map * 1e3:6.1f} ms ({describe / from_map:.1f}x)")


if __name__ == "__main__":
    main()
