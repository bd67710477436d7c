"""Cost per pairing at the survey's 1288 x 964: detection per detector, description per (detector, descriptor),
and each foreign pairing's description cost as a multiple of its descriptor's native one (issue 25).

    python benchmarks/bench_pairings.py                      # survey Table 4's grid, foreign keypoints at own scale
    python benchmarks/bench_pairings.py --compare octave0    # also the octave-0 description (gtsweep before 25)
    python benchmarks/bench_pairings.py --detectors surf sift --descriptors surf sift   # SURF against SIFT only

The image is one rendered `dataset=survey` view (1288 x 964; rendered once into .gtsweep_cache, ~15 s); the
detectors run with the table presets' tuned parameters, keypoints reduced to the 1000 strongest (NMS), as in
Tables 4 and 5. Times are the CPU time of the calling thread (``time.thread_time``) for the detection and for the
description (keypoint preparation included), best of --repeat, OpenCV on 1 thread as in a Ray task: unlike wall
time they hold when other processes share the cores. ms per image; each descriptor's pairings (native, foreign,
every option) are timed in one block, repeats interleaved. "native" is the descriptor on its own family's keypoints
(SIFT on SIFT's, ...); descriptors without a detector of their own (BRIEF, LATCH, FREAK, DAISY) have no ratio. Target:
no foreign pairing above 2x its descriptor's native cost. The last lines compare gtsweep's NumPy SURF describing its own
1000 keypoints with OpenCV's SIFT describing its own (target: at most 2x). Prints figures; no pass/fail.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import time

import cv2
import numpy as np

from gtsweep.cli.overrides import compose_config
from gtsweep.core.errors import GtsweepError
from gtsweep.datasets import load_dataset
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.stages.applicability import applicability, describe_timed
from gtsweep.stages.describe import DESCRIPTORS, describe_batch, descriptor_params
from gtsweep.stages.detect import detect_timed
from gtsweep.stages.scales import FOREIGN_SCALES, OWN
from gtsweep.stages.select import select_nms

TARGET = 2.0  # issue 25: no foreign pairing's description above 2x its descriptor's native one
SURF_TARGET = 2.0  # SURF's native description at most 2x SIFT's native one (both 1000 keypoints of the view)


def survey_view(texture: str) -> np.ndarray:
    """One synthetic-split view of ``texture`` from the survey-size data set (1288 x 964, capture physics)."""
    cfg = compose_config(["dataset=survey", f"dataset.textures=[{texture}]", "dataset.n_synthetic=1",
                          "dataset.n_incremental=0", "dataset.n_absolute=0", "dataset.n_optimisation=0"])
    return load_dataset(cfg.dataset).images("synthetic")[0].load()


def cpu_seconds(run):
    """``run()``'s result and the CPU time of this thread it took."""
    start = time.thread_time()
    result = run()
    return result, time.thread_time() - start


def detections(image, grid, repeat: int) -> dict[str, tuple[np.ndarray, float]]:
    """Per detector: the 1000 strongest keypoints and the detection's CPU time (s, best of ``repeat``)."""
    found = {}
    for name, cfg in grid.detectors.items():
        runs = [cpu_seconds(lambda: detect_timed(image, name, None, **cfg["params"])) for _ in range(repeat)]
        found[name] = select_nms(runs[-1][0][0], image.shape, n=1000), min(s for _, s in runs)
    return found


def descriptions(image, grid, found, options, repeat: int) -> dict[tuple[str, str, str], float | str]:
    """Per (option, detector, descriptor): the description's CPU time (s, best of ``repeat``), "NA" or the
    error's one line. Native pairings are timed once (no option applies to them) and shown under every option."""
    costs: dict[tuple[str, str, str], float | str] = {}
    for descriptor, cfg in grid.descriptors.items():
        for _ in range(repeat):
            for detector, (keypoints, _) in found.items():
                runs = [OWN] if detector == descriptor else options
                for option in runs:
                    key = (option, detector, descriptor)
                    if isinstance(costs.get(key), str):
                        continue
                    if applicability(detector, descriptor):
                        costs[key] = "NA"
                        continue
                    params = descriptor_params(cfg, detector)
                    try:
                        _, seconds = cpu_seconds(
                            lambda: describe_timed(image, keypoints, descriptor, detector, option, **params))
                    except GtsweepError as e:
                        costs[key] = f"error: {e}"
                        continue
                    costs[key] = min(seconds, costs.get(key, seconds))
        for option in options:
            costs[option, descriptor, descriptor] = costs.get((OWN, descriptor, descriptor), "NA")
    return costs


def table(found, costs, descriptors, option: str) -> tuple[str, list[tuple[float, str]]]:
    """The markdown cost table (ms) and each foreign pairing's (ratio to native, name)."""
    native = {d: costs.get((d, d)) for d in descriptors}
    lines = [f"description CPU ms per image (foreign keypoints: {option}); ratio to the descriptor's native cost",
             "", "| detector | detect ms | " + " | ".join(descriptors) + " |", "|---" * (len(descriptors) + 2) + "|"]
    ratios = []
    for detector, (keypoints, seconds) in found.items():
        cells = []
        for descriptor in descriptors:
            cost = costs[detector, descriptor]
            if isinstance(cost, str):
                cells.append("NA" if cost == "NA" else "error")
                continue
            reference = native[descriptor]
            if detector == descriptor or not isinstance(reference, float) or reference <= 0:
                cells.append(f"{cost * 1e3:.1f}" + (" (native)" if detector == descriptor else ""))
                continue
            ratio = cost / reference
            ratios.append((ratio, f"{detector}-{descriptor}"))
            cells.append(f"{cost * 1e3:.1f} ({ratio:.2f}x)")
        lines.append(f"| {detector} ({len(keypoints)} kp) | {seconds * 1e3:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines), ratios


def together(image, grid, found, descriptor: str, every: dict, repeat: int) -> str:
    """A descriptor with ``together`` (DAISY, SIFT) on every applicable detector's keypoints of the image: the
    separate calls' CPU time (from ``every``) against the grouped calls (``runner.describe_together``)."""
    detectors = [d for d in found if applicability(d, descriptor) is None]
    apart = 1000 * sum(every[(OWN, d, descriptor)] for d in detectors)
    params = descriptor_params(grid.descriptors[descriptor], detectors[0])
    requests = [(d, found[d][0]) for d in detectors]
    one = 1000 * min(cpu_seconds(lambda: describe_batch(image, requests, descriptor, OWN, **params))[1]
                     for _ in range(repeat))
    return (f"\n{descriptor} on the keypoints of its {len(detectors)} applicable detectors: {len(detectors)} calls "
            f"{apart:.0f} ms, grouped (runner.describe_together) {one:.0f} ms ({one / apart - 1:+.0%})")


def surf_against_sift(every: dict) -> str:
    """The SURF-vs-SIFT line: each describing its own 1000 keypoints (CPU ms, best of the repeats)."""
    surf, sift = every.get((OWN, "surf", "surf")), every.get((OWN, "sift", "sift"))
    if not isinstance(surf, float) or not isinstance(sift, float):
        return "\nSURF vs SIFT description: needs both surf and sift among the detectors and descriptors"
    from gtsweep.stages.surf.windows import compiled_loop

    kernel = "compiled (Numba)" if compiled_loop() is not None else "NumPy"
    return (f"\nSURF describe {surf * 1e3:.1f} ms vs SIFT describe {sift * 1e3:.1f} ms per view (1000 own keypoints "
            f"each; SURF windows {kernel}): ratio {surf / sift:.2f} (target <= {SURF_TARGET:g})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--texture", default="coarse_asphalt")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--compare", choices=[o for o in FOREIGN_SCALES if o != OWN], nargs="*", default=[],
                        help="also time foreign keypoints under these options")
    parser.add_argument("--sweep", default="table4_incremental", help="the preset whose grid is timed")
    parser.add_argument("--detectors", nargs="*", help="only these of the preset's detectors")
    parser.add_argument("--descriptors", nargs="*", help="only these of the preset's descriptors")
    args = parser.parse_args()
    grid = build_grid(compose_config([f"sweeps={args.sweep}", "mlflow.enabled=false"]))
    for chosen, methods in ((args.detectors, grid.detectors), (args.descriptors, grid.descriptors)):
        for name in [m for m in methods if chosen is not None and m not in chosen]:
            del methods[name]
    image = survey_view(args.texture)
    cv2.setNumThreads(1)
    start = time.perf_counter()
    found = detections(image, grid, 1)  # CPU time: one run suffices (MSD alone takes ~10 s)
    print(f"{image.shape[1]}x{image.shape[0]} survey view ({args.texture}); {args.sweep}'s detectors (tuned) and "
          f"descriptors; NMS to 1000; OpenCV {cv2.__version__}, 1 thread; CPU ms, best of {args.repeat}")
    options = [OWN, *args.compare]
    every = descriptions(image, grid, found, options, args.repeat)
    for option in options:
        costs = {(d, s): c for (o, d, s), c in every.items() if o == option}
        for detector in found:
            for descriptor in grid.descriptors:
                costs.setdefault((detector, descriptor), "NA")
        text, ratios = table(found, costs, list(grid.descriptors), option)
        print()
        print(text)
        errors = sorted({f"{d}-{s}: {c}" for (d, s), c in costs.items() if isinstance(c, str) and c != "NA"})
        print("\n".join(errors))
        worst = max(ratios, default=(float("nan"), "-"))
        over = [name for ratio, name in ratios if ratio > TARGET]
        print(f"\n[{option}] largest foreign/native description ratio: {worst[0]:.2f}x ({worst[1]}); "
              f"{len(over)} of {len(ratios)} foreign pairings above {TARGET:g}x" + (f": {', '.join(over)}" if over
                                                                                  else ""))
    for descriptor in (d for d in grid.descriptors if DESCRIPTORS.get(d).together):
        print(together(image, grid, found, descriptor, every, args.repeat))
    print(surf_against_sift(every))
    print(f"\nbenchmark wall time {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
