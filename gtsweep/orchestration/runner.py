"""Evaluate a grid on a data set: a graph of detection and pairing tasks, run by Ray or in one process.

Images are loaded once per shard (and ``ray.put`` once); one detection task per (shard, transform, detector,
selector) feeds every descriptor's pairing task on that shard. A cell is finished when all its shards are; the
``on_cell`` callback then writes it (and logs it), so a killed sweep loses only the cells in flight.
"""
from __future__ import annotations

import sys
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Callable, Iterable

import pandas as pd

from gtsweep.core.errors import BadInput
from gtsweep.evaluation.views import make_shard
from gtsweep.orchestration import tasks
from gtsweep.orchestration.grid import Cell, Grid

BACKENDS = ("ray", "serial")


@dataclass
class PairingJob:
    cell: Cell
    shard: int


@dataclass
class DetectionJob:
    transform: str
    detector: str
    selector: str
    shard: int
    cell: Cell | None = None  # the detection experiment's cell fed by this job
    pairings: list[PairingJob] = field(default_factory=list)


@dataclass
class RunStats:
    """What a run did: cache hits and misses (a miss is one detector call) and task counts."""

    cache_hits: int = 0
    cache_misses: int = 0
    detection_tasks: int = 0
    pairing_tasks: int = 0


def load_shards(dataset, grid: Grid, shard_size: int) -> dict[str, list[dict]]:
    """Shards per transform kind: "synthetic" (the synthetic split's images) and "incremental"/"absolute" pairs."""
    if shard_size < 1:
        raise BadInput(f"runner.shard_size must be >= 1, got {shard_size}")
    shards = {}
    kinds = {("synthetic" if cfg["kind"] == "synthetic" else name) for name, cfg in grid.transforms.items()}
    for kind in sorted(kinds):
        if kind == "synthetic":
            items = [{"id": s.id, "texture": s.texture, "image": s.load()} for s in dataset.images("synthetic")]
        else:
            items = [{"id": p.id, "texture": p.texture, "reference": p.reference.load(), "test": p.test.load(),
                      "H": p.H} for p in dataset.pairs(kind)]
        if not items:
            raise BadInput(f"data set '{dataset.name}' has no {kind} images: nothing to evaluate")
        kind_of_shard = "synthetic" if kind == "synthetic" else "pairs"
        shards[kind] = [make_shard(kind_of_shard, items[i:i + shard_size])
                        for i in range(0, len(items), shard_size)]
    return shards


def shard_kind(grid: Grid, transform: str) -> str:
    return "synthetic" if grid.transforms[transform]["kind"] == "synthetic" else transform


def plan(grid: Grid, n_shards: dict[str, int], pending: set[str]) -> list[DetectionJob]:
    """Detection jobs (each with its pairing jobs) for the cells whose keys are in ``pending``."""
    by_detection: dict[tuple, list[Cell]] = defaultdict(list)
    for cell in grid.cells:
        if cell.key in pending and cell.na_reason is None:
            by_detection[(cell.transform, cell.detector, cell.selector)].append(cell)
    jobs = []
    for (transform, detector, selector), cells in by_detection.items():
        for shard in range(n_shards[shard_kind(grid, transform)]):
            job = DetectionJob(transform, detector, selector, shard)
            for cell in cells:
                if cell.descriptor is None:
                    job.cell = cell
                else:
                    job.pairings.append(PairingJob(cell, shard))
            jobs.append(job)
    return jobs


def run(grid: Grid, shards: dict[str, list[dict]], jobs: list[DetectionJob], runner_cfg: dict, seed: int,
        cache_dir: str | None, on_cell: Callable[[Cell, dict], None]) -> RunStats:
    """Run ``jobs``; ``on_cell(cell, outcome)`` is called as each cell finishes, with ``outcome`` either
    ``{"rows": DataFrame}`` or ``{"na": reason}`` / ``{"error": message}``."""
    backend = runner_cfg.get("backend", "ray")
    if backend not in BACKENDS:
        raise BadInput(f"runner.backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    execute = _ray_execute if backend == "ray" else _serial_execute
    stats = RunStats(detection_tasks=len(jobs), pairing_tasks=sum(len(j.pairings) for j in jobs))
    tracker = _CellTracker(jobs, on_cell)
    total = stats.detection_tasks + stats.pairing_tasks
    with _progress(total, runner_cfg.get("progress", True)) as bar:
        for job, result in execute(grid, shards, jobs, runner_cfg, seed, cache_dir):
            if isinstance(job, DetectionJob):
                stats.cache_hits += result.get("hits", 0)
                stats.cache_misses += result.get("misses", 0)
            tracker.add(job, result)
            bar.update(1)
    return stats


class _CellTracker:
    """Collects shard results per cell and reports each cell once all its shards are in."""

    def __init__(self, jobs: list[DetectionJob], on_cell):
        self.on_cell = on_cell
        self.remaining: dict[str, int] = defaultdict(int)
        self.parts: dict[str, dict[int, dict]] = defaultdict(dict)
        self.cells: dict[str, Cell] = {}
        for job in jobs:
            for cell in ([job.cell] if job.cell else []) + [p.cell for p in job.pairings]:
                self.remaining[cell.key] += 1
                self.cells[cell.key] = cell

    def add(self, job, result: dict) -> None:
        cell = job.cell
        if cell is None:  # a detection job that only feeds pairing cells
            return
        self.parts[cell.key][job.shard] = result
        self.remaining[cell.key] -= 1
        if self.remaining[cell.key] == 0:
            self.on_cell(cell, _merge(self.parts.pop(cell.key)))


def _merge(parts: dict[int, dict]) -> dict:
    for shard in sorted(parts):
        if "error" in parts[shard]:
            return {"error": parts[shard]["error"]}
    for shard in sorted(parts):
        if "na" in parts[shard]:
            return {"na": parts[shard]["na"]}
    rows = [row for shard in sorted(parts) for row in parts[shard]["rows"]]
    return {"rows": pd.DataFrame.from_records(rows)}


def _detection_args(grid: Grid, job: DetectionJob, seed: int, cache_dir):
    method = {"detector": job.detector, "detector_cfg": grid.detectors[job.detector],
              "selector": job.selector, "selector_cfg": grid.selectors[job.selector]}
    return job.transform, grid.transforms[job.transform], method, grid.experiment, seed, cache_dir


def _pairing_args(grid: Grid, pairing: PairingJob, seed: int):
    from gtsweep.stages.describe import descriptor_params

    cell = pairing.cell
    params = descriptor_params(grid.descriptors[cell.descriptor], cell.detector)
    return cell.detector, cell.descriptor, params, grid.experiment, seed


def _serial_execute(grid, shards, jobs, runner_cfg, seed, cache_dir) -> Iterable:
    for job in jobs:
        shard = shards[shard_kind(grid, job.transform)][job.shard]
        payload, summary = tasks.detect_shard(shard, *_detection_args(grid, job, seed, cache_dir))
        yield job, summary
        for pairing in job.pairings:
            detector, descriptor, params, experiment, seed_ = _pairing_args(grid, pairing, seed)
            yield pairing, tasks.pair_shard(shard, job.transform, grid.transforms[job.transform], payload,
                                            detector, descriptor, params, experiment, seed_)


def _ray_execute(grid, shards, jobs, runner_cfg, seed, cache_dir) -> Iterable:
    import ray

    from gtsweep.orchestration.cluster import connect

    connect(runner_cfg)
    threads = runner_cfg.get("opencv_threads", 1)
    detect_remote = ray.remote(num_returns=2)(_with_opencv_threads(tasks.detect_shard, threads))
    pair_remote = ray.remote(_with_opencv_threads(tasks.pair_shard, threads))
    shard_refs = {kind: [ray.put(s) for s in kind_shards] for kind, kind_shards in shards.items()}
    pending = {}
    for job in jobs:
        shard_ref = shard_refs[shard_kind(grid, job.transform)][job.shard]
        payload_ref, summary_ref = detect_remote.remote(shard_ref, *_detection_args(grid, job, seed, cache_dir))
        pending[summary_ref] = job
        for pairing in job.pairings:
            detector, descriptor, params, experiment, seed_ = _pairing_args(grid, pairing, seed)
            ref = pair_remote.remote(shard_ref, job.transform, grid.transforms[job.transform], payload_ref,
                                     detector, descriptor, params, experiment, seed_)
            pending[ref] = pairing
    while pending:  # collect finished tasks in batches: one ray.wait per result would be quadratic
        done, _ = ray.wait(list(pending), num_returns=min(64, len(pending)), timeout=0.2)
        for ref in done:
            yield pending.pop(ref), ray.get(ref)


def _with_opencv_threads(function, threads: int | None):
    """``function`` run with OpenCV limited to ``threads`` threads: Ray runs one task per CPU, so OpenCV's own
    thread pool in every worker would only make the workers compete for the same cores."""
    import functools

    @functools.wraps(function)
    def run(*args):
        if threads:
            import cv2

            cv2.setNumThreads(int(threads))
        return function(*args)

    return run


def _progress(total: int, enabled: bool):
    """A tqdm bar (a context manager) on an interactive terminal; silent in CI logs and pipes."""
    from tqdm import tqdm

    return tqdm(total=total, unit="task", desc="gtsweep", file=sys.stderr,
                disable=not (enabled and sys.stderr.isatty()), mininterval=0.5)

