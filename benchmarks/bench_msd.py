"""MSD at the survey's 1288 x 964: OpenCV's msd.cpp against gtsweep's vectorised port (gtsweep.stages.msd), which
the detector registry uses. Per texture one survey view, the tuned parameters (conf/detector/tuned/msd.yaml), CPU
seconds of this thread (best of ``--repeat``), OpenCV on 1 thread as in each Ray task, and whether the keypoints are
identical (every column of every keypoint). Prints figures; no pass/fail.

    python benchmarks/bench_msd.py [--repeat N] [--textures a,b,...]
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np
from bench_pairings import cpu_seconds, survey_view

from gtsweep.cli.overrides import compose_config
from gtsweep.stages import keypoints as kp
from gtsweep.stages.msd import MSD_create

TEXTURES = ("fine_asphalt", "carpet", "gravel", "tiles")


def best(run, repeat: int):
    """The shortest CPU time of ``repeat`` calls of ``run`` and the last result."""
    runs = [cpu_seconds(run) for _ in range(repeat)]
    return min(seconds for _, seconds in runs), runs[-1][0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--textures", default=",".join(TEXTURES))
    args = parser.parse_args()
    params = dict(compose_config(["detector=[tuned/msd]"]).detector.msd.params)
    cv2.setNumThreads(1)
    opencv, ours = cv2.xfeatures2d.MSDDetector_create(**params), MSD_create(**params)
    print(f"MSD {params}; OpenCV {cv2.__version__}, 1 thread; CPU s, best of {args.repeat}")
    print("| view | keypoints | OpenCV msd.cpp s | gtsweep s | faster | identical |\n|---|---|---|---|---|---|")
    ratios = []
    for texture in args.textures.split(","):
        image = survey_view(texture)
        theirs_s, theirs = best(lambda: kp.to_array(opencv.detect(image, None)), args.repeat)
        ours_s, mine = best(lambda: ours.detect_array(image, None), args.repeat)
        ratios.append(theirs_s / ours_s)
        print(f"| {texture} | {len(theirs)} | {theirs_s:.2f} | {ours_s:.2f} | {ratios[-1]:.2f}x | "
              f"{theirs.shape == mine.shape and bool(np.array_equal(theirs, mine))} |")
    print(f"geometric mean: {np.exp(np.mean(np.log(ratios))):.2f}x faster")


if __name__ == "__main__":
    main()
