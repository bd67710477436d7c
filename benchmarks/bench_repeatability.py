"""Time gtsweep.evaluation.metrics.repeatability on large keypoint sets.

1. AGAST without selection (survey Table 2: ~0.18 kp/px² in 1288×964 → 225 000 keypoints of size 7).
2. 30 000 SIFT-like keypoints with log-uniform sizes 2..100 px.
Both use a small rotation about the image centre as H. Run: ``python benchmarks/bench_repeatability.py``.
"""
import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import math
import time

import numpy as np

from gtsweep.evaluation.metrics import repeatability

W, H_PX = 1288, 964


def small_rotation(deg=2.0):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    cx, cy = (W - 1) / 2, (H_PX - 1) / 2
    return np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0, 0, 1.0]])


def random_keypoints(rng, n, sizes):
    return np.column_stack([rng.uniform(0, W, n), rng.uniform(0, H_PX, n), sizes])


def timed(name, test, ref, H, repeats=3):
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        result = repeatability(test, ref, H, ref_shape=(H_PX, W), test_shape=(H_PX, W))
        best = min(best, time.perf_counter() - start)
    print(f"{name}: {best:.2f} s (best of {repeats}); repeatability {result.repeatability:.3f}, "
          f"ambiguity {result.ambiguity:.3f}, counted {result.n_test} × {result.n_ref}, "
          f"{result.n_correspondences} correspondences")


def main():
    rng = np.random.default_rng(0)
    H = small_rotation()
    n = 225_000
    timed(f"AGAST-like {n} × {n}, size 7", random_keypoints(rng, n, np.full(n, 7.0)),
          random_keypoints(rng, n, np.full(n, 7.0)), H)
    n = 30_000
    log_sizes = lambda: np.exp(rng.uniform(math.log(2), math.log(100), n))  # noqa: E731
    timed(f"SIFT-like {n} × {n}, sizes 2..100", random_keypoints(rng, n, log_sizes()),
          random_keypoints(rng, n, log_sizes()), H)


if __name__ == "__main__":
    main()
