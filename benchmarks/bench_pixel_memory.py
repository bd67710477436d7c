"""Peak memory per image pixel of each detector and descriptor: the figures behind
:data:`gtsweep.datasets.pixels.BYTES_PER_PIXEL`.

Each method runs in a fresh process on a gray image of ``--side`` x ``--side`` px (the gravel photograph tiled):
the process's peak resident memory (``ru_maxrss``) after the call, less before it, divided by the pixels. A
descriptor describes 1000 FAST keypoints (its own detector's, for the learned ones). Prints one line per method.

    python benchmarks/bench_pixel_memory.py [--side 2048] [--only sift,orb]
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import json
import subprocess
import sys

CHILD = """
import json, resource, sys
import numpy as np, skimage.data
from gtsweep.stages.detect import DETECTORS, detect
from gtsweep.stages.describe import describe
kind, name, side = sys.argv[1], sys.argv[2], int(sys.argv[3])
tile = skimage.data.gravel()
image = np.ascontiguousarray(np.tile(tile, (side // tile.shape[0] + 1, side // tile.shape[1] + 1))[:side, :side])
detector = name if kind == "detector" or name not in ("orb", "brief", "latch", "freak", "daisy", "beblid", "teblid",
    "brisk", "sift", "surf", "akaze", "kaze") else "fast"
if kind == "descriptor" and name in ("akaze", "kaze"):
    detector = name
small = image[:256, :256].copy()
keypoints = detect(small, detector)  # imports and first-use allocations before the baseline
if kind == "descriptor":
    describe(small, keypoints[:50], name, detector)
keypoints = detect(image, detector) if kind == "descriptor" else None
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
if kind == "detector":
    detect(image, name)
else:
    describe(image, keypoints[:1000], name, detector)
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"bytes_per_pixel": (after - before) / image.size, "rss_gib": after / 2**30}))
"""


def main() -> None:
    from gtsweep.stages.describe import DESCRIPTORS
    from gtsweep.stages.detect import DETECTORS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=int, default=2048)
    parser.add_argument("--only", default="")
    args = parser.parse_args()
    only = set(filter(None, args.only.split(",")))
    for kind, names in (("detector", list(DETECTORS)), ("descriptor", list(DESCRIPTORS))):
        for name in names:
            if only and name not in only:
                continue
            result = subprocess.run([sys.executable, "-c", CHILD, kind, name, str(args.side)], capture_output=True,
                                    text=True, timeout=900)
            if result.returncode:
                print(f"{kind:10s} {name:14s} failed: {result.stderr.strip().splitlines()[-1:]}", flush=True)
                continue
            figures = json.loads(result.stdout.strip().splitlines()[-1])
            print(f"{kind:10s} {name:14s} {figures['bytes_per_pixel']:7.1f} B/px  (peak {figures['rss_gib']:.2f} GiB "
                  f"at {args.side}x{args.side})", flush=True)


if __name__ == "__main__":
    main()
