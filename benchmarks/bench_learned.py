"""Milliseconds per 1288 x 964 image and peak memory of each learned method (issue 26).

Usage: PYTHONPATH=. .venv/bin/python benchmarks/bench_learned.py [--threads 2] [--repeats 2] [--methods ...]

Each method runs in a process of its own (so that its peak resident memory, ``ru_maxrss``, is its own): one
warm-up call, then the median of ``--repeats`` timed calls on a 1288 x 964 image (the survey's Micro-GPS size)
of smoothed noise at two scales. Detector/descriptors (ALIKED-n16, ALIKED-n16rot, DISK: torch; XFeat: cv2.dnn, for
comparison) are timed for detect + describe of N = 1000 keypoints in one process, as a sweep's serial run does
(one network pass: the describe step reuses the detection's pass; the memo of passes is emptied before each call);
``lightglue:<descriptor>`` times LightGlue (LighterGlue for XFeat) matching two such images' 1000 keypoints each
(features computed before the clock starts). torch and OpenCV use ``--threads`` threads. Besides wall time, the
process's CPU time (user + system) per call is printed: on a shared machine the wall time grows with the load,
the CPU time much less. Say so when quoting.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import cv2
import numpy as np

DETECTORS = ("aliked_n16", "aliked_n16rot", "disk", "xfeat")
MATCHING = ("lightglue:aliked_n16rot", "lightglue:disk", "lightglue:xfeat")
SIZE = (964, 1288)  # (height, width)


def texture(seed: int) -> np.ndarray:
    noise = np.random.default_rng(seed).random(SIZE).astype(np.float32)
    mixed = cv2.GaussianBlur(noise, (0, 0), 1.0) + 2 * cv2.GaussianBlur(noise, (0, 0), 3.0)
    return cv2.normalize(mixed, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def features(image: np.ndarray, name: str):
    from gtsweep.stages.describe import describe
    from gtsweep.stages.detect import detect

    if name != "xfeat":
        from gtsweep.stages.learned import DETECTIONS

        DETECTIONS.clear()  # time a pass, not a memo hit

    params = {"top_k": 1000} if name == "xfeat" else {"max_num_keypoints": 1000}
    return describe(image, detect(image, name, **params), name, name)


def measure(method: str, repeats: int) -> dict:
    """ms per call (median) and this process's peak memory (MB) for one method."""
    image = texture(0)
    if method.startswith("lightglue:"):
        from gtsweep.stages.match import MATCHERS, Side, match_sides

        descriptor = method.split(":", 1)[1]
        (ref, ref_desc), (test, test_desc) = features(image, descriptor), features(texture(1), descriptor)
        matcher = MATCHERS.get("lightglue").build({})

        def run():
            match_sides(matcher, "l2", ref_desc, test_desc, Side(ref, SIZE, descriptor), Side(test, SIZE, descriptor))
    else:
        def run():
            features(image, method)
    run()  # warm-up: loads the weights
    times, cpu_times = [], []
    for _ in range(repeats):
        start, cpu_start = time.perf_counter(), cpu_seconds()
        run()
        times.append(1000 * (time.perf_counter() - start))
        cpu_times.append(1000 * (cpu_seconds() - cpu_start))
    return {"method": method, "ms": statistics.median(times), "cpu_ms": statistics.median(cpu_times),
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def cpu_seconds() -> float:
    """This process's user + system CPU time (all its threads)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--methods", nargs="+", default=[*DETECTORS, *MATCHING])
    parser.add_argument("--one", help=argparse.SUPPRESS)  # the child process: measure one method, print JSON
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)
    if args.one:
        print(json.dumps(measure(args.one, args.repeats)))
        return 0
    print(f"learned methods on a {SIZE[1]}x{SIZE[0]} image, {args.threads} threads, median of {args.repeats} "
          f"(detectors: detect + describe N = 1000; lightglue: one pair of 1000 + 1000 keypoints)")
    print(f"{'method':<26}{'ms':>10}{'CPU ms':>10}{'peak MB':>10}")
    for method in args.methods:
        child = subprocess.run([sys.executable, __file__, "--one", method, "--threads", str(args.threads),
                                "--repeats", str(args.repeats)], capture_output=True, text=True)
        if child.returncode != 0:
            print(f"{method:<26} failed: {(child.stderr.strip().splitlines() or ['?'])[-1]}")
            return 1
        row = json.loads(child.stdout.strip().splitlines()[-1])
        print(f"{method:<26}{row['ms']:>10.0f}{row['cpu_ms']:>10.0f}{row['peak_mb']:>10.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
