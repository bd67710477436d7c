"""Evaluate a grid on a data set: a graph of detection and pairing tasks, run by an executor (Ray or serial).

Images are loaded once per shard (and put to the executor once); one detection task per (shard, transform,
detector, selector) feeds every descriptor's pairing task on that shard; one pairing task per (shard, descriptor)
serves every matcher and estimator cell of that descriptor (descriptors are computed once). A descriptor that
describes keypoint sets ``together`` (DAISY, whose cost is a pass over the image; SIFT, whose pyramid depends only
on the lowest octave) gets one pairing task per (shard, transform) for all detectors, which describes each image
once per group (``runner.describe_together``; the results are the same either way). A cell is finished when all
its shards are; the ``on_cell`` callback then writes it (and logs it), so a killed sweep loses only the cells in
flight.
"""
from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Callable

import pandas as pd

from gtsweep.experiments.pairs import tasks
from gtsweep.experiments.pairs.grid import Cell, Grid
from gtsweep.orchestration.executor import make_executor
from gtsweep.orchestration.settings import default
from gtsweep.orchestration.shards import shard_kind
from gtsweep.orchestration.tasks import RunStats
from gtsweep.stages import device as devices
from gtsweep.stages.describe import DESCRIPTORS


@dataclass
class PairingJob:
    """One pairing task: the cells of one (transform, detector, selector, descriptor) on one shard, one per
    (matcher, estimator) combination."""

    cells: list[Cell]
    shard: int


@dataclass
class PairingGroup:
    """One pairing task for several detectors' pairing jobs of one shard (a descriptor with ``together``), and
    each job's own :func:`~gtsweep.experiments.pairs.tasks.pair_shard` arguments (``alone``): if the group's task
    crashes (its worker died, or one member's detection task did), each job runs by itself, as without groups."""

    pairings: list[PairingJob]
    alone: list[tuple] = field(default_factory=list)


@dataclass
class DetectionJob:
    transform: str
    detector: str
    selector: str
    shard: int
    cell: Cell | None = None  # the detection experiment's cell fed by this job
    pairings: list[PairingJob] = field(default_factory=list)
    keep_raw: bool = True  # the detector's raw output to disk: another job selects from it too


def plan(grid: Grid, n_shards: dict[str, int], pending: set[str]) -> list[DetectionJob]:
    """Detection jobs (each with its pairing jobs) for the cells whose keys are in ``pending``. A job keeps its
    detector's raw output in the cache only when another selector of the run selects from the same detection."""
    by_detection: dict[tuple, list[Cell]] = defaultdict(list)
    for cell in grid.cells:
        if cell.key in pending and cell.na_reason is None:
            by_detection[(cell.transform, cell.detector, cell.selector)].append(cell)
    selectors = Counter((transform, detector) for transform, detector, _ in by_detection)
    jobs = []
    for (transform, detector, selector), cells in by_detection.items():
        for shard in range(n_shards[shard_kind(transform, grid.transforms[transform])]):
            job = DetectionJob(transform, detector, selector, shard, keep_raw=selectors[transform, detector] > 1)
            by_descriptor: dict[str, list[Cell]] = defaultdict(list)
            for cell in cells:
                if cell.descriptor is None:
                    job.cell = cell
                else:
                    by_descriptor[cell.descriptor].append(cell)
            job.pairings = [PairingJob(same, shard) for same in by_descriptor.values()]
            jobs.append(job)
    return jobs


def run(grid: Grid, shards: dict[str, list[dict]], jobs: list[DetectionJob], runner_cfg: dict, seed: int,
        cache_dir: str | None, on_cell: Callable[[Cell, dict], None],
        on_started: Callable[[], None] | None = None) -> RunStats:
    """Run ``jobs``; ``on_cell(cell, outcome)`` is called as each cell finishes, with ``outcome`` either
    ``{"rows": DataFrame}`` or ``{"na": reason}`` / ``{"error": message}`` (and when its tasks ran);
    ``on_started()`` once the executor (Ray) is up."""
    executor = make_executor(runner_cfg)
    if on_started is not None:
        on_started()
    stats = RunStats(detection_tasks=len(jobs))
    tracker = _CellTracker(jobs, on_cell)
    stats.pairing_tasks = submit(executor, grid, shards, jobs, seed, cache_dir,
                                 runner_cfg.get("describe_together", default("runner.describe_together")),
                                 runner_cfg.get("gpus_per_task", default("runner.gpus_per_task")))
    for job, result in executor.results():
        if isinstance(job, PairingGroup) and "parts" not in result:  # crashed: each job by itself
            for pairing, args in zip(job.pairings, job.alone):
                executor.submit(tasks.pair_shard, *args, tag=pairing)
            stats.pairing_tasks += len(job.pairings)
            continue
        if isinstance(job, DetectionJob):
            stats.cache_hits += result.get("hits", 0)
            stats.cache_misses += result.get("misses", 0)
            stats.cache_corrupt += result.get("corrupt", 0)
            stats.cache_write_errors += result.get("write_errors", 0)
        else:
            dense = result.get("dense", {})
            stats.dense_hits += dense.get("hits", 0)
            stats.dense_misses += dense.get("misses", 0)
            stats.dense_write_errors += dense.get("write_errors", 0)
        if isinstance(job, PairingGroup):  # each detector's part, with when the task ran
            ran = {k: result[k] for k in ("started", "ended") if k in result}
            for pairing, part in zip(job.pairings, result["parts"]):
                tracker.add(pairing, {**part, **ran})
        else:
            tracker.add(job, result)
    return stats


def submit(executor, grid: Grid, shards: dict[str, list[dict]], jobs: list[DetectionJob], seed: int,
           cache_dir: str | None, together: bool = True, gpus_per_task: float = 0.25) -> int:
    """The task graph: each detection task's keypoints are passed to its pairing tasks; every task is tagged
    with its job. With ``together``, the pairing jobs of one (transform, shard) whose descriptor describes
    keypoint sets together (DAISY, SIFT) share one task (:class:`PairingGroup`), submitted as soon as its last
    member's detection is. Returns the number of pairing tasks. Each shard in ``shards`` is replaced by its
    handle as it is put, so the driver does not keep a second copy of the images once Ray's object store holds
    them (1.5 GB at Table 4's 600 pairs of 1288×964 views). A task that runs a method on the GPU
    (``grid.device``) asks Ray for ``gpus_per_task`` of one (``num_gpus``), so a cluster sends it to a GPU node."""
    for kind_shards in shards.values():
        for i in range(len(kind_shards)):
            kind_shards[i] = executor.put(kind_shards[i])
    refs = shards
    planned = [(job, pairing, _pairing_args(grid, pairing, seed)) for job in jobs for pairing in job.pairings]
    key = {id(pairing): (job.transform, job.shard, repr(args[1:])) for job, pairing, args in planned
           if together and DESCRIPTORS.get(args[1]).together}
    size = Counter(key.values())
    groups: dict[tuple, PairingGroup] = {}
    submitted, args_of = 0, {id(pairing): args for _, pairing, args in planned}
    for job in jobs:
        transform_cfg = grid.transforms[job.transform]
        shard = refs[shard_kind(job.transform, transform_cfg)][job.shard]
        detection_args = _detection_args(grid, job, seed, cache_dir)
        payload, _ = executor.submit(tasks.detect_shard, shard, *detection_args, tag=job, num_returns=2,
                                     num_gpus=_gpus(detection_args[2], gpus_per_task))
        for pairing in job.pairings:
            alone = (shard, job.transform, transform_cfg, payload, *args_of[id(pairing)], cache_dir, together)
            gpus = _gpus(args_of[id(pairing)][-1], gpus_per_task)
            if id(pairing) not in key:
                executor.submit(tasks.pair_shard, *alone, tag=pairing, num_gpus=gpus)
                submitted += 1
                continue
            group = groups.setdefault(key[id(pairing)], PairingGroup([]))
            group.pairings.append(pairing)
            group.alone.append(alone)
            if len(group.pairings) == size[key[id(pairing)]]:  # its last member: submit it now
                _, *args = args_of[id(pairing)]
                executor.submit(tasks.pair_shard_members, shard, job.transform, transform_cfg,
                                [p.cells[0].detector for p in group.pairings], *args, cache_dir, together,
                                *[detection for _, _, _, detection, *_ in group.alone], tag=group, num_gpus=gpus)
                submitted += 1
    return submitted


class _CellTracker:
    """Collects shard results per cell and reports each cell once all its shards are in, with when its tasks ran
    (a pairing cell's include the detection tasks that fed it)."""

    def __init__(self, jobs: list[DetectionJob], on_cell):
        self.on_cell = on_cell
        self.remaining: dict[str, int] = defaultdict(int)
        self.parts: dict[str, dict[int, dict]] = defaultdict(dict)
        self.cells: dict[str, Cell] = {}
        self.fed_by: dict[int, DetectionJob] = {}  # id(pairing job) -> its detection job
        self.ran: dict[int, tuple] = {}  # id(detection job) -> (started, ended)
        for job in jobs:
            for cell in ([job.cell] if job.cell else []) + [c for p in job.pairings for c in p.cells]:
                self.remaining[cell.key] += 1
                self.cells[cell.key] = cell
            self.fed_by.update((id(p), job) for p in job.pairings)

    def add(self, job, result: dict) -> None:
        if isinstance(job, DetectionJob):
            self.ran[id(job)] = (result.get("started"), result.get("ended"))
        elif id(job) in self.fed_by:
            started, ended = self.ran.get(id(self.fed_by[id(job)]), (None, None))
            result = {**result, "started": _first(started, result.get("started"), min),
                      "ended": _first(ended, result.get("ended"), max)}
        if isinstance(job, DetectionJob):
            cells = [job.cell] if job.cell is not None else []  # none: it only feeds pairing cells
        else:
            cells = job.cells
        for cell in cells:
            self._add(cell, job.shard, _for_cell(result, cell))

    def _add(self, cell: Cell, shard: int, result: dict) -> None:
        self.parts[cell.key][shard] = result
        self.remaining[cell.key] -= 1
        if self.remaining[cell.key] == 0:
            self.on_cell(cell, _merge(self.parts.pop(cell.key)))


def _for_cell(result: dict, cell: Cell) -> dict:
    """A cell's share of a pairing task's result: its (matcher, estimator) entry, with when the task ran; a
    failure of the whole task is every cell's."""
    by_method = result.get("by_method")
    if by_method is None:
        return result
    ran = {k: result[k] for k in ("started", "ended") if k in result}
    return {**by_method[(cell.matcher, cell.estimator)], **ran}


def _first(a, b, pick):
    values = [v for v in (a, b) if v is not None]
    return pick(values) if values else None


def _merge(parts: dict[int, dict]) -> dict:
    """A cell's outcome from its shards' results, with the span of its tasks (``started``, ``ended``)."""
    starts = [p["started"] for p in parts.values() if p.get("started") is not None]
    ends = [p["ended"] for p in parts.values() if p.get("ended") is not None]
    ran = {"started": min(starts), "ended": max(ends)} if starts and ends else {}
    for shard in sorted(parts):
        if "error" in parts[shard]:
            return {"error": parts[shard]["error"], **ran}
    for shard in sorted(parts):
        if "na" in parts[shard]:
            return {"na": parts[shard]["na"], **ran}
    rows = [row for shard in sorted(parts) for row in parts[shard]["rows"]]
    return {"rows": pd.DataFrame.from_records(rows), **ran}


def _gpus(methods: dict, gpus_per_task: float) -> float:
    """The GPU share a task asks Ray for: ``gpus_per_task`` when its methods compute on CUDA, else none."""
    return float(gpus_per_task) if methods.get("device", devices.CPU) != devices.CPU else 0.0


def _detection_args(grid: Grid, job: DetectionJob, seed: int, cache_dir):
    method = {"detector": job.detector, "detector_cfg": grid.detectors[job.detector],
              "selector": job.selector, "selector_cfg": grid.selectors[job.selector],
              **devices.key_entry("detector", job.detector, grid.device)}
    return (job.transform, grid.transforms[job.transform], method, grid.experiment, seed, cache_dir, grid.declared,
            job.keep_raw)


def _pairing_args(grid: Grid, pairing: PairingJob, seed: int):
    from gtsweep.stages.describe import descriptor_params

    cell = pairing.cells[0]
    params = descriptor_params(grid.descriptors[cell.descriptor], cell.detector)
    methods = {"matchers": {c.matcher: grid.matcher_params(c.matcher) for c in pairing.cells},
               "estimators": {c.estimator: grid.estimator_params(c.estimator) for c in pairing.cells
                              if c.estimator is not None}}
    moved = [("descriptor", cell.descriptor)] + [("matcher", c.matcher) for c in pairing.cells]
    if any(devices.key_entry(group, name, grid.device) for group, name in moved):
        methods["device"] = grid.device
    return cell.detector, cell.descriptor, params, grid.experiment, seed, grid.declared, methods
