"""Time the keypoint selectors on random keypoints in a 1288 x 964 image (the survey's camera size).

Usage: PYTHONPATH=. .venv/bin/python benchmarks/bench_select.py
Prints, per keypoint count, the best of a few runs in milliseconds and the number of keypoints selected.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import time

import numpy as np

from gtsweep.stages.keypoints import COLUMNS, RESPONSE, X, Y
from gtsweep.stages.select import select

IMAGE_SHAPE = (964, 1288)
COUNTS = (10_000, 60_000, 225_000)
SELECTORS = ("nms", "anms", "bucketing")
REPEATS = 3


def random_keypoints(count: int, seed: int = 0) -> np.ndarray:
    """Uniformly placed keypoints with integer-valued responses (so that ties occur, as with FAST)."""
    rng = np.random.default_rng(seed)
    kps = np.zeros((count, len(COLUMNS)))
    kps[:, X] = rng.uniform(0, IMAGE_SHAPE[1], count)
    kps[:, Y] = rng.uniform(0, IMAGE_SHAPE[0], count)
    kps[:, RESPONSE] = rng.integers(0, 256, count)
    return kps


def best_time(func) -> tuple[float, int]:
    times, size = [], 0
    for _ in range(REPEATS):
        start = time.perf_counter()
        size = len(func())
        times.append(time.perf_counter() - start)
    return min(times) * 1e3, size


def main() -> None:
    print(f"image {IMAGE_SHAPE[1]}x{IMAGE_SHAPE[0]}, best of {REPEATS} runs")
    print(f"{'keypoints':>10} {'selector':>10} {'ms':>9} {'kept':>6}")
    for count in COUNTS:
        kps = random_keypoints(count)
        for name in SELECTORS:
            ms, kept = best_time(lambda: select(kps, name, IMAGE_SHAPE))
            print(f"{count:>10} {name:>10} {ms:>9.1f} {kept:>6}")


if __name__ == "__main__":
    main()
