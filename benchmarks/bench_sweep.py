"""Sweep overhead against a true floor: the same grid as bare OpenCV calls in one process, through gtsweep serial,
and through Ray with 1 and 2 workers; then re-running the finished sweep.

    python benchmarks/bench_sweep.py            # 640 x 480 views (the embedded default)
    python benchmarks/bench_sweep.py --survey   # also the grid at the survey's 1288 x 964

The floor is what a hand-written script does for each pair: ``detect``, keep the 1000 strongest keypoints,
``compute``, ``BFMatcher.knnMatch(k=2)`` + ratio 0.7, ``cv2.estimateAffinePartial2D(RANSAC, 3 px, 2000 iterations)``
— no metrics, no cache, no result files. gtsweep computes the survey's metrics on top (repeatability, correct
matches, pose error), so part of its time is work the floor does not do. Prints figures; no pass/fail. Grid: 4
textures x (4 incremental + 4 absolute) pairs, 4 detectors x 4 descriptors (32 cells, 3 of them NA). The runs
set against the floor describe each detector's keypoints separately, as the floor does
(``runner.describe_together=false``); one more serial run shows the default, where SIFT describes the 4
detectors' keypoints of an image in one call per first octave.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import multiprocessing
import os
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from gtsweep.cli.overrides import compose_config
from gtsweep.core.memory import PeakMemory, cpu_split, tree_cpu
from gtsweep.datasets import load_dataset
from gtsweep.experiments.kinds import run_sweep
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration.executor import connect, make_executor
from gtsweep.stages import keypoints as kp
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params, prepare_keypoints
from gtsweep.stages.detect import DETECTORS

GRID = ["detector=[akaze,censure,orb,sift]", "descriptor=[brief,latch,orb,sift]", "selector=[nms]",
        "transform=[incremental,absolute]", "experiment=pose", "mlflow.enabled=false", "runner.progress=false",
        "report.plots=false", "dataset.textures=[fine_asphalt,carpet,gravel,tiles]", "dataset.n_incremental=4",
        "dataset.n_absolute=4", "runner.shard_size=2"]


def floor(cfg, threads: int, part: int = 0, parts: int = 1, ready=None) -> tuple[float, float]:
    """The bare-OpenCV loop over the grid's applicable pairings, OpenCV on ``threads`` threads (-1: its default,
    as gtsweep's serial backend; 1: as each Ray task): its wall and CPU seconds. ``part`` of ``parts``: every
    ``parts``-th pair from ``part`` on; ``ready``: a barrier the loop waits at before its clock starts."""
    grid, dataset = build_grid(cfg), load_dataset(cfg.dataset)
    pairs = [(p.reference.load(), p.test.load()) for kind in ("incremental", "absolute") for p in dataset.pairs(kind)]
    pairs = pairs[part::parts]
    cv2.setNumThreads(threads)
    if ready is not None:
        ready.wait()
    start, cpu = time.perf_counter(), time.process_time()
    for detector, dcfg in grid.detectors.items():
        det = DETECTORS.get(detector).build(dcfg["params"])
        found = []
        for pair in pairs:
            strongest = []
            for image in pair:
                keypoints = det.detect(image, None)
                keypoints = sorted(keypoints, key=lambda k: -k.response)[:1000]
                strongest.append(keypoints)
            found.append(strongest)
        for descriptor, scfg in grid.descriptors.items():
            if any(c.na_reason for c in grid.cells if (c.detector, c.descriptor) == (detector, descriptor)):
                continue
            spec = DESCRIPTORS.get(descriptor)
            extractor = spec.build(descriptor_params(scfg, detector))
            matcher = cv2.BFMatcher(cv2.NORM_HAMMING if spec.norm == "hamming" else cv2.NORM_L2)
            for (ref, test), (kr, kt) in zip(pairs, found):
                # as gtsweep gives keypoints to a descriptor (foreign ones at their own scale: stages/scales.py)
                kr, kt = (kp.to_keypoints(prepare_keypoints(kp.to_array(k), detector, spec, extractor, ref.shape))
                          for k in (kr, kt))
                kr, dr = extractor.compute(ref, kr)
                kt, dt = extractor.compute(test, kt)
                if dr is None or dt is None or len(dr) < 2:
                    continue
                good = [m[0] for m in matcher.knnMatch(dt, dr, k=2)
                        if len(m) == 2 and m[0].distance < 0.7 * m[1].distance]
                if len(good) >= 2:
                    src = np.float32([kt[m.queryIdx].pt for m in good])
                    dst = np.float32([kr[m.trainIdx].pt for m in good])
                    cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0, maxIters=2000)
    cv2.setNumThreads(-1)
    return time.perf_counter() - start, time.process_time() - cpu


def _floor_part(cfg, part: int, parts: int, ready, results) -> None:
    results.put(floor(cfg, 1, part, parts, ready))


def floor_in_parallel(cfg, processes: int = 2) -> tuple[float, float]:
    """The 1-thread floor split over ``processes`` processes started together (each every ``processes``-th pair):
    the wall time until the last one ends and their CPU seconds. Against the 1-thread floor in one process this is
    the machine's own ceiling for ``processes`` Ray workers: what running OpenCV on the other cores costs (shared
    caches, memory bandwidth, the host's clocks), with no orchestration at all."""
    context = multiprocessing.get_context("spawn")
    ready, results = context.Barrier(processes), context.Queue()
    workers = [context.Process(target=_floor_part, args=(cfg, i, processes, ready, results))
               for i in range(processes)]
    for worker in workers:
        worker.start()
    timings = [results.get() for _ in workers]
    for worker in workers:
        worker.join()
    return max(wall for wall, _ in timings), sum(cpu for _, cpu in timings)


def timed_sweep(cfg, out: Path):
    """Run the sweep; its wall time, outcome, and the peak memory and CPU seconds of the driver, the Ray workers
    and Ray's own processes (on 2 cores, what the driver and Ray use is taken from the workers)."""
    start, cpu = time.perf_counter(), tree_cpu(os.getpid())
    with PeakMemory() as memory:
        outcome = run_sweep(cfg, out)
    seconds = time.perf_counter() - start
    used = cpu_split(cpu, tree_cpu(os.getpid()), os.getpid())
    return seconds, outcome, (f"    {memory.line()}; {outcome.stats.detection_tasks} detection + "
                              f"{outcome.stats.pairing_tasks} pairing tasks\n    CPU: driver {used['driver']:.2f} s, "
                              f"Ray workers {used['workers']:.2f} s, Ray's own processes {used['ray']:.2f} s")


def ray_start(cfg) -> float:
    """Seconds to start the embedded Ray of ``cfg.runner`` (a fixed cost per command, apart from the grid's size);
    the sweep then joins it."""
    start = time.perf_counter()
    connect(dict(cfg.runner))
    return time.perf_counter() - start


def _noop(value):
    return value


def task_overhead(runner_cfg: dict, n: int = 400) -> float:
    """Seconds per task of gtsweep's Ray executor on tasks that do nothing (submit, run, collect), Ray already up."""
    executor = make_executor(runner_cfg)
    payload = executor.put(np.zeros(16))
    for i in range(20):
        executor.submit(_noop, payload, tag=i)
    list(executor.results())
    start = time.perf_counter()
    for i in range(n):
        executor.submit(_noop, payload, tag=i)
    list(executor.results())
    return (time.perf_counter() - start) / n


def bench(label: str, extra: list[str]) -> None:
    import ray

    work = Path(tempfile.mkdtemp(prefix="gtsweep-bench-"))
    try:
        apart = ["runner.describe_together=false"]
        compose = lambda more: compose_config(GRID + extra + apart + more)  # noqa: E731
        cfg = compose([f"cache.dir={work}/c0", "runner.backend=serial"])
        load_dataset(cfg.dataset)  # render the data set once, outside the timings
        bare, _ = floor(cfg, -1)
        print(f"[{label}] bare OpenCV loop (the floor):       {bare:7.2f} s  (OpenCV's default threads)")
        serial, outcome, memory = timed_sweep(cfg, work / "serial")
        print(f"[{label}] gtsweep serial (cold cache):        {serial:7.2f} s  ({serial / bare:.2f}x the floor, "
              f"{serial - bare:.2f} s over it; {len(outcome.summaries)} cells)")
        print(memory)
        together, outcome, _ = timed_sweep(compose([f"cache.dir={work}/c3", "runner.backend=serial",
                                                    "runner.describe_together=true"]), work / "together")
        print(f"[{label}] gtsweep serial, describing together:{together:7.2f} s  ({together / bare:.2f}x the floor, "
              f"{together / serial - 1:+.1%} against separate calls; {outcome.stats.pairing_tasks} pairing tasks)")
        bare1, cpu1 = floor(cfg, 1)
        print(f"[{label}] bare OpenCV loop, 1 thread:         {bare1:7.2f} s  ({cpu1:.2f} CPU-s)")
        bare2, cpu2 = floor_in_parallel(cfg)
        print(f"[{label}] bare OpenCV loop, 2 processes:      {bare2:7.2f} s  ({bare1 / bare2:.2f}x faster than 1: "
              f"the machine's ceiling for 2 workers; {cpu2:.2f} CPU-s, {cpu2 / cpu1 - 1:+.1%} against 1 process)")
        cfg1 = compose([f"cache.dir={work}/c1", "runner.num_cpus=1"])
        start1 = ray_start(cfg1)
        one, _, memory1 = timed_sweep(cfg1, work / "ray1")
        print(f"[{label}] gtsweep Ray, 1 worker (cold):       {start1 + one:7.2f} s  "
              f"({(start1 + one) / bare1:.2f}x the "
              f"1-thread floor; Ray's start {start1:.2f} s + the sweep {one:.2f} s, {one / bare1:.2f}x)")
        print(memory1)
        ray.shutdown()
        cfg2 = compose([f"cache.dir={work}/c2", "runner.num_cpus=2"])
        start2 = ray_start(cfg2)
        two, outcome, memory2 = timed_sweep(cfg2, work / "ray2")
        print(f"[{label}] gtsweep Ray, 2 workers (cold):      {start2 + two:7.2f} s  ({(start2 + two) / bare:.2f}x the "
              f"floor; {(start1 + one) / (start2 + two):.2f}x faster than 1 worker; Ray's start {start2:.2f} s + "
              f"the sweep {two:.2f} s, {one / two:.2f}x faster than 1 worker's sweep)")
        print(memory2)
        per_task = task_overhead(dict(cfg2.runner))
        n_tasks = outcome.stats.detection_tasks + outcome.stats.pairing_tasks
        print(f"[{label}] Ray's cost per task (no-op tasks):  {per_task * 1e3:7.2f} ms  ({n_tasks} tasks: "
              f"{n_tasks * per_task:.2f} s of work, {n_tasks * per_task / 2 / two:.1%} of the 2-worker wall time)")
        again, outcome, _ = timed_sweep(cfg2, work / "ray2")
        print(f"[{label}] re-running the finished sweep:      {again:7.2f} s  ({again / two:.1%} of its first run; "
              f"{outcome.resumed} cells kept)")
        ray.shutdown()
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survey", action="store_true", help="also the grid at the survey's 1288 x 964 views")
    args = parser.parse_args()
    bench("640x480", [])
    if args.survey:
        bench("1288x964", ["dataset=survey"])


if __name__ == "__main__":
    main()
