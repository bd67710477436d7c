"""Sweep overhead: a fixed grid through gtsweep (Ray) against a plain single-process loop of the same OpenCV calls,
the speed-up from 1 to 2 Ray workers, and the time to re-run a finished sweep (every cell kept).

    python benchmarks/bench_sweep.py

Prints figures; no pass/fail. Uses the embedded data set, 4 textures x (4 incremental + 4 absolute) pairs,
4 detectors x 4 descriptors: 64 pairs, 32 cells.
"""
from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from gtsweep.cli.overrides import compose_config
from gtsweep.datasets import load_dataset
from gtsweep.orchestration.grid import build_grid
from gtsweep.orchestration.sweep import run_sweep
from gtsweep.stages.describe import describe, descriptor_params
from gtsweep.stages.detect import detect
from gtsweep.stages.match import match_descriptors
from gtsweep.stages.pose import estimate_pose
from gtsweep.stages.select import select_nms

GRID = ["detector=[akaze,censure,orb,sift]", "descriptor=[brief,latch,orb,sift]", "selector=[nms]",
        "transform=[incremental,absolute]", "experiment=pose", "mlflow.enabled=false", "runner.progress=false",
        "report.plots=false", "dataset.textures=[fine_asphalt,carpet,gravel,tiles]", "dataset.n_incremental=4",
        "dataset.n_absolute=4", "runner.shard_size=2"]


def compose_cfg(extra: list[str]):
    return compose_config(GRID + extra)


def plain_loop(cfg) -> float:
    """The same detections and pairings, one process, no cache, no result files."""
    grid, dataset = build_grid(cfg), load_dataset(cfg.dataset)
    pairs = [p for kind in ("incremental", "absolute") for p in dataset.pairs(kind)]
    images = [(p.reference.load(), p.test.load()) for p in pairs]
    start = time.perf_counter()
    for detector, dcfg in grid.detectors.items():
        keypoints = [[select_nms(detect(im, detector, **dcfg["params"]), im.shape, 1000) for im in pair]
                     for pair in images]
        for descriptor, scfg in grid.descriptors.items():
            if any(c.na_reason for c in grid.cells if (c.detector, c.descriptor) == (detector, descriptor)):
                continue
            params = descriptor_params(scfg, detector)
            for (ref, test), (kr, kt) in zip(images, keypoints):
                kr, dr = describe(ref, kr, descriptor, detector, **params)
                kt, dt = describe(test, kt, descriptor, detector, **params)
                m = match_descriptors(dt, dr, "hamming" if dr.dtype.kind == "u" else "l2")
                estimate_pose(kt[m[:, 0], :2], kr[m[:, 1], :2])
    return time.perf_counter() - start


def timed_sweep(cfg, out: Path) -> tuple[float, object]:
    start = time.perf_counter()
    outcome = run_sweep(cfg, out)
    return time.perf_counter() - start, outcome


def main() -> None:
    import ray

    work = Path(tempfile.mkdtemp(prefix="gtsweep-bench-"))
    try:
        cfg1 = compose_cfg([f"cache.dir={work}/cache1", "runner.num_cpus=1"])
        load_dataset(cfg1.dataset)  # render the data set once, outside the timings
        loop = plain_loop(cfg1)
        print(f"plain single-process loop:              {loop:7.2f} s")
        t1, outcome = timed_sweep(cfg1, work / "run1")
        print(f"gtsweep, Ray with 1 worker (cold cache): {t1:7.2f} s  (ratio to the loop {t1 / loop:.2f}; "
              f"includes ~5 s Ray start; {len(outcome.summaries)} cells)")
        ray.shutdown()
        cfg2 = compose_cfg([f"cache.dir={work}/cache2", "runner.num_cpus=2"])
        t2, _ = timed_sweep(cfg2, work / "run2")
        print(f"gtsweep, Ray with 2 workers (cold):      {t2:7.2f} s  (speed-up from 1 to 2 workers {t1 / t2:.2f})")
        t3, outcome = timed_sweep(cfg2, work / "run2")
        print(f"re-running the finished sweep:           {t3:7.2f} s  ({outcome.resumed} cells kept)")
        t4, outcome = timed_sweep(cfg2, work / "run3")
        print(f"same grid, new output dir, warm cache:   {t4:7.2f} s  ({outcome.stats.cache_hits} cache hits, "
              f"{outcome.stats.cache_misses} misses)")
        ray.shutdown()
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
