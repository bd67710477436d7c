"""MSD at the survey's 1288 x 964: OpenCV's msd.cpp against gtsweep's port (gtsweep.stages.msd), which the detector
registry uses, with each of its saliencies: the NumPy path and, where Numba is installed, the compiled loop
(gtsweep.stages.msd_compiled), timed back to back in the same run. Per texture one survey view, the tuned parameters
(conf/detector/tuned/msd.yaml, or --defaults for OpenCV's), CPU seconds of this thread and wall seconds (best of
``--repeat`` each), OpenCV on 1 thread as in each Ray task, and whether each port's keypoints are identical to
OpenCV's (every column of every keypoint). Target: the registry's port at most 0.45 CPU-s per view. Prints figures;
no pass/fail.

    python benchmarks/bench_msd.py [--repeat N] [--textures a,b,...] [--defaults]
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import contextlib
import time

import cv2
import numpy as np
from bench_pairings import survey_view

from gtsweep.cli.overrides import compose_config
from gtsweep.stages import keypoints as kp
from gtsweep.stages import msd
from gtsweep.stages.msd import MSD_create
from gtsweep.stages.msd_compiled import compiled_kernel

TEXTURES = ("fine_asphalt", "carpet", "gravel", "tiles")
TARGET = 0.45


@contextlib.contextmanager
def numpy_saliency():
    """The port with its NumPy saliency while inside."""
    compiled, msd.saliency_compiled = msd.saliency_compiled, lambda *args: None
    try:
        yield
    finally:
        msd.saliency_compiled = compiled


def best(run, repeat: int):
    """The shortest CPU time (this thread) and wall time of ``repeat`` calls of ``run``, and the last result."""
    cpu, wall = [], []
    for _ in range(repeat):
        start_cpu, start_wall = time.thread_time(), time.perf_counter()
        result = run()
        cpu.append(time.thread_time() - start_cpu)
        wall.append(time.perf_counter() - start_wall)
    return min(cpu), min(wall), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--textures", default=",".join(TEXTURES))
    parser.add_argument("--defaults", action="store_true", help="OpenCV's default parameters instead of the tuned")
    args = parser.parse_args()
    params = {} if args.defaults else dict(compose_config(["detector=[tuned/msd]"]).detector.msd.params)
    cv2.setNumThreads(1)
    opencv, ours = cv2.xfeatures2d.MSDDetector_create(**params), MSD_create(**params)
    compiled = compiled_kernel(*(int(ours.params[name]) for name in ("m_patch_radius", "m_search_area_radius",
                                                                       "m_kNN"))) is not None  # compiled here
    print(f"MSD {params or 'defaults'}; OpenCV {cv2.__version__}, 1 thread; best of {args.repeat}; compiled "
          f"saliency: {'yes' if compiled else 'no (Numba not installed)'}; CPU s (wall s)")
    print("| view | keypoints | OpenCV msd.cpp | gtsweep, NumPy saliency | gtsweep, compiled saliency | identical |\n"
          "|---|---|---|---|---|---|")
    ports = []
    for texture in args.textures.split(","):
        image = survey_view(texture)
        theirs = best(lambda: kp.to_array(opencv.detect(image, None)), args.repeat)
        with numpy_saliency():
            numpy_port = best(lambda: ours.detect_array(image, None), args.repeat)
        mine = [numpy_port] + ([best(lambda: ours.detect_array(image, None), args.repeat)] if compiled else [])
        ports.append(mine[-1][0])
        same = [bool(np.array_equal(theirs[2], m[2])) for m in mine]
        cells = [f"{cpu:.2f} ({wall:.2f})" for cpu, wall, _ in (theirs, *mine)] + (["-"] if not compiled else [])
        print(f"| {texture} | {len(theirs[2])} | {' | '.join(cells)} | {' / '.join(map(str, same))} |")
    print(f"the registry's port: {max(ports):.2f} CPU-s per view at most, mean {np.mean(ports):.2f} "
          f"(target {TARGET})")


if __name__ == "__main__":
    main()
