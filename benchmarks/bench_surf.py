"""Time SURF (gtsweep's NumPy port of OpenCV's surf.cpp, Bay et al. CVIU 2008) next to OpenCV's SIFT and AKAZE.

On a 1288x964 texture image (scikit-image's gravel, upsampled), prints detect and detect+describe times (best of
a few runs) and keypoint counts. OpenCV runs single-threaded (``cv2.setNumThreads(1)``) so the comparison is
like for like; OpenCV's own SURF is timed too when this OpenCV is a nonfree build.

    python benchmarks/bench_surf.py [--repeat N]
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import skimage.data

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from gtsweep.stages.surf import NumpySURF, opencv_surf_available  # noqa: E402

SHAPE = (964, 1288)  # rows, cols: the survey's camera resolution


def texture_image() -> np.ndarray:
    """Gravel upsampled (bicubic) to 1288x964."""
    return cv2.resize(skimage.data.gravel(), SHAPE[::-1], interpolation=cv2.INTER_CUBIC)


def best_time(run, repeat: int):
    """Shortest wall time of ``repeat`` calls, and the last result."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        result = run()
        times.append(time.perf_counter() - start)
    return min(times), result


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    image = texture_image()
    methods = {
        "SURF (gtsweep-numpy)": NumpySURF(),
        "SURF extended (gtsweep-numpy)": NumpySURF(extended=True),
        "SURF upright (gtsweep-numpy)": NumpySURF(upright=True),
        "SIFT (opencv)": cv2.SIFT_create(),
        "AKAZE (opencv)": cv2.xfeatures2d.AKAZE_create(),
    }
    if opencv_surf_available():
        methods["SURF (opencv nonfree)"] = cv2.xfeatures2d.SURF_create()
    print(f"image {SHAPE[1]}x{SHAPE[0]} (gravel, upsampled); OpenCV {cv2.__version__}, 1 thread; "
          f"best of {args.repeat}")
    print(f"{'method':32s} {'keypoints':>9s} {'detect s':>9s} {'detect+describe s':>18s} {'us/kp':>7s}")
    for name, method in methods.items():
        detect_s, keypoints = best_time(lambda: method.detect(image, None), args.repeat)
        both_s, (kps, _) = best_time(lambda: method.detectAndCompute(image, None), args.repeat)
        print(f"{name:32s} {len(kps):9d} {detect_s:9.3f} {both_s:18.3f} {1e6 * both_s / max(len(kps), 1):7.1f}")


if __name__ == "__main__":
    main()
