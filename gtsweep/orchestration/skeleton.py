"""The one sweep skeleton every kind of sweep runs on: build the grid, check the services, load the data, keep the
cells an earlier run finished (resume), evaluate the others, write the results and the run record.

A kind of sweep gives its grid, its data and its evaluation as a :class:`CellWork` (:data:`PAIRS` for the pair
experiments, :data:`gtsweep.orchestration.localization.LOCALIZATION`). The skeleton alone writes result files
(and, through ``hooks``, to MLflow); workers return plain rows.
"""
from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Callable, Mapping

import pandas as pd

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import plain
from gtsweep.core.errors import BadInput
from gtsweep.datasets import load_dataset
from gtsweep.datasets.pixels import check_dataset
from gtsweep.orchestration.cache import cache_state
from gtsweep.orchestration.cluster import check_address, cluster_record
from gtsweep.orchestration.executor import backend
from gtsweep.orchestration.grid import Cell, Grid, build_grid, matcher_na_line
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.results import ResultStore, summarize
from gtsweep.orchestration.runner import RunStats, plan, run
from gtsweep.orchestration.shards import load_shards
from gtsweep.orchestration.view_reuse import ViewReuse

#: Called as ``hook(cell, summary, rows)`` for every cell as it finishes, and for cells kept from an earlier run
#: (rows None for those and for NA cells).
CellHook = Callable[[Cell, dict, "pd.DataFrame | None"], None]
log = logging.getLogger(__name__)


@dataclass
class SweepOutcome:
    output_dir: Path
    grid: Grid
    summaries: list[dict]
    stats: RunStats
    resumed: int  # cells found complete from an earlier run
    dataset_fingerprint: str
    seconds: float
    table: Path | None = None
    failed: list[str] = field(default_factory=list)
    skipped_items: list[str] = field(default_factory=list)  # bad data items skipped under dataset.skip_bad
    cache: str = ""  # the keypoint cache: "on: <dir>" or "off: <why>"


def cell_summary(cell: Cell, cell_hash: str, outcome: Mapping, experiment: str) -> dict:
    """The summary written for a cell: methods, experiment, status (ok, na, error), reason and aggregate metrics,
    and when its tasks ran (``started``, ``ended``: seconds since the epoch)."""
    summary = {"key": cell.key, "methods": cell.methods, "hash": cell_hash, "experiment": experiment,
               **{k: outcome[k] for k in ("started", "ended") if outcome.get(k) is not None}}
    if "rows" in outcome:
        return {**summary, "status": "ok", **summarize(outcome["rows"], experiment)}
    if "na" in outcome:
        return {**summary, "status": "na", "reason": outcome["na"]}
    return {**summary, "status": "error", "reason": outcome["error"]}


@dataclass(frozen=True)
class CellWork:
    """What one kind of sweep gives the skeleton (:func:`run_sweep`): its grid (cells with ``key``, ``methods``,
    ``na_reason``; ``cell_hash``; ``experiment``), its data and how its pending cells are evaluated.

    ``load_data(cfg, grid)`` returns the data with ``name``, ``fingerprint`` and ``skipped`` (bad items skipped);
    ``evaluate(grid, data, cells, runner_cfg, seed, cache_dir, finish, on_started)`` reads (and so checks) its inputs,
    calls ``on_started()`` once the executor is up, ``finish(cell, outcome)`` for every cell, and returns its
    :class:`RunStats`."""

    build_grid: Callable[[Mapping], object]
    load_data: Callable[[Mapping, object], object]
    evaluate: Callable[..., RunStats]
    #: ``reuse(store, grid, data, seed)``: a :class:`~gtsweep.orchestration.view_reuse.ViewReuse` that lets a
    #: cell keep the rows of the items it already evaluated on a smaller data set (None: whole cells only).
    reuse: Callable[..., ViewReuse] | None = None


def run_sweep(cfg: Mapping, output_dir: str | Path, hooks: tuple[CellHook, ...] = (),
              on_start: Callable[[Grid, str], None] | None = None, progress: Progress | None = None,
              on_checked: Callable[[], None] | None = None, work: CellWork | None = None) -> SweepOutcome:
    """Evaluate the grid of ``cfg`` into ``output_dir``; cells already complete (same config) are kept, failed
    ones recomputed. ``work``: the kind of sweep (None: the pair experiments, :data:`PAIRS`); ``progress`` shows
    the phases and counts the cells (none: the job's log only); ``on_checked`` runs once the settings and the Ray
    address are checked, before any work."""
    start = time.perf_counter()
    work = work or PAIRS
    progress = progress or Progress(enabled=False)
    grid = work.build_grid(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    log.info("grid: %d cells (%s experiment)", len(grid.cells), grid.experiment["name"])
    say_not_applicable(grid.cells)
    if backend(runner_cfg) == "ray":
        check_address(runner_cfg)  # a cluster that does not answer stops here, in seconds
    if on_checked is not None:
        on_checked()
    cache_dir, cache_note = cache_state(cfg)
    progress.phase("render data set")
    data = work.load_data(cfg, grid)
    check_dataset(getattr(data, "dataset", data), grid.cells, runner_cfg)  # largest image x workers x B/px
    log.info("data set '%s', fingerprint %s", data.name, data.fingerprint)
    seed = int(cfg.get("seed", 0))
    store = ResultStore(output_dir)
    if on_start is not None:
        on_start(grid, data.fingerprint)
    summaries: dict[str, dict] = {}
    hashes = {cell.key: grid.cell_hash(cell, data.fingerprint, seed) for cell in grid.cells}
    reuse = work.reuse(store, grid, data, seed) if work.reuse is not None else None

    def finish(cell, outcome: Mapping) -> None:
        if reuse is not None:
            outcome = reuse.complete(cell, outcome)
        summary = cell_summary(cell, hashes[cell.key], outcome, grid.experiment["name"])
        rows = outcome.get("rows")
        covered = reuse.coverage(cell) if reuse is not None and summary["status"] == "ok" else None
        store.write_cell(cell.key, summary, rows, covered)
        summaries[cell.key] = summary
        log.info("cell %s: %s%s", cell.key, summary["status"], f" ({summary['reason']})" if summary.get("reason")
                 else "")
        progress.cell_done()
        for hook in hooks:
            hook(cell, summary, rows)

    pending, not_applicable, resumed = [], [], 0
    for cell in grid.cells:
        done = store.complete(cell.key, hashes[cell.key])
        if done is not None:
            summaries[cell.key], resumed = done, resumed + 1
            for hook in hooks:  # hooks skip what they already have (e.g. cells logged before a kill)
                hook(cell, done, None)
        elif cell.na_reason is not None:
            not_applicable.append(cell)
        else:
            pending.append(cell)
    log.info("%d cell(s) to evaluate, %d kept from an earlier run, %d not applicable", len(pending), resumed,
             len(not_applicable))

    def start_evaluating() -> None:  # the executor is up: NA cells are written, the bar counts every cell
        progress.phase("evaluate cells", total=len(grid.cells), done=resumed)
        for cell in not_applicable:
            finish(cell, {"na": cell.na_reason})

    ready, groups = reuse.plan(pending) if reuse is not None else ([], [(data, pending)] if pending else [])
    if reuse is not None:
        log.info("view reuse: %d (cell, image or pair) rows kept from an earlier run, %d to evaluate",
                 reuse.reused, reuse.evaluated)
    stats, started = RunStats(), []

    def started_once() -> None:
        if not started:
            started.append(True)
            start_evaluating()

    if groups and backend(runner_cfg) == "ray":
        progress.phase("start Ray")
    for part, cells in groups:  # one group per set of items still to evaluate (usually one)
        stats = _added(stats, work.evaluate(grid, part, cells, runner_cfg, seed, cache_dir, finish, started_once))
    started_once()
    for cell in ready:  # every item's rows kept: nothing to evaluate
        finish(cell, {"rows": pd.DataFrame()})
    if stats.cache_write_errors:
        cache_note = f"{cache_note} ({stats.cache_write_errors} task(s) could not write to it and went on without)"
        log.info("%d task(s) could not write to the keypoint cache %s; they ran without it",  # the log file's copy
                 stats.cache_write_errors, cache_dir)
        print(f"gtsweep: warning: {stats.cache_write_errors} task(s) could not write to the keypoint cache "
              f"{cache_dir}; they ran without it", file=sys.stderr)
    if stats.dense_write_errors:
        cache_note = f"{cache_note} ({stats.dense_write_errors} task(s) could not store dense descriptor maps)"
        log.info("%d task(s) could not write dense descriptor maps under %s", stats.dense_write_errors, cache_dir)
        print(f"gtsweep: warning: {stats.dense_write_errors} task(s) could not write dense descriptor maps to "
              f"{Path(cache_dir) / 'dense'}; they computed them without storing", file=sys.stderr)
    ordered = [summaries[cell.key] for cell in grid.cells]
    outcome = SweepOutcome(Path(output_dir), grid, ordered, stats, resumed, data.fingerprint,
                           time.perf_counter() - start, failed=[s["key"] for s in ordered if s["status"] == "error"],
                           skipped_items=list(getattr(data, "skipped", ())), cache=cache_note)
    outcome.table = store.write_table(ordered)
    write_run_record(outcome, data, reuse)
    return outcome


def say_not_applicable(cells) -> None:
    """Before any work: the cells a matcher cannot run, in one line; a grid none of whose cells can run is a
    one-line BadInput (nothing would be computed)."""
    note = matcher_na_line(cells)
    if cells and all(cell.na_reason for cell in cells):
        reasons = note or "; ".join(dict.fromkeys(cell.na_reason for cell in cells))
        raise BadInput(f"none of the grid's {len(cells)} cell(s) can run: {reasons}")
    if note:
        log.info("%s", note)
        print(f"gtsweep: note: {note}", file=sys.stderr)


@dataclass(frozen=True)
class PairData:
    """A data set of images and pairs (:func:`gtsweep.datasets.load_dataset`) as the skeleton reads it."""

    dataset: object
    fingerprint: str

    @property
    def name(self) -> str:
        return self.dataset.name

    @property
    def skipped(self) -> list[str]:
        return list(getattr(self.dataset, "skipped", []))


def _added(a: RunStats, b: RunStats) -> RunStats:
    return RunStats(**{f.name: getattr(a, f.name) + getattr(b, f.name) for f in fields(RunStats)})


def _load_pairs(cfg: Mapping, grid: Grid) -> PairData:
    dataset = load_dataset(cfg["dataset"])
    for kind in [name for name, transform in grid.transforms.items() if transform.get("kind") == "pairs"]:
        if not dataset.pairs(kind):  # a data set too small for the pair rules: one line before any work
            why = dataset.empty_kinds.get(kind, f"dataset.n_{kind}?")
            raise BadInput(f"data set '{dataset.name}' has no {kind} pairs: {why}")
    if cfg["dataset"].get("pose_check") and dataset.pairs("incremental"):
        check_the_poses(dataset)
    return PairData(dataset, dataset.fingerprint())


def check_the_poses(dataset) -> None:
    """Before any work: poses that disagree with the images stop the sweep in one line (which convention would
    fit); poses that agree are said in the log."""
    from gtsweep.datasets.posecheck import check_poses

    found = check_poses(dataset)
    log.info("%s", found.line())
    if not found.consistent:
        raise BadInput(f"{found.line()}; or dataset.pose_check=false to run anyway")


def _evaluate_pairs(grid: Grid, data: PairData, cells: list, runner_cfg: dict, seed: int, cache_dir, finish,
                    on_started) -> RunStats:
    # Load (and so check) every image the cells read before the first result file is written: bad data stops the
    # run clean.
    transforms = {name: grid.transforms[name] for name in sorted({cell.transform for cell in cells})}
    shards = load_shards(data.dataset, transforms, int(runner_cfg["shard_size"]))
    jobs = plan(grid, {kind: len(s) for kind, s in shards.items()}, {cell.key for cell in cells})
    return run(grid, shards, jobs, runner_cfg, seed, cache_dir, finish, on_started=on_started)


#: The pair experiments (detection, matching, pose): detector x selector (x descriptor x matcher x estimator) x
#: transform on images and image pairs.
PAIRS = CellWork(build_grid, _load_pairs, _evaluate_pairs,
                 reuse=lambda store, grid, data, seed: ViewReuse(store, grid, data.dataset, seed,
                                                                 lambda part: PairData(part, data.fingerprint)))


def write_run_record(outcome: SweepOutcome, data, reuse: ViewReuse | None = None) -> None:
    """``run.json``: the data set, cache and task counts, (cell, image or pair) rows kept and evaluated, wall
    time."""
    record = {
        "dataset": data.name,
        "dataset_fingerprint": outcome.dataset_fingerprint,
        "skipped_items": outcome.skipped_items,
        "cells": len(outcome.summaries),
        "resumed_cells": outcome.resumed,
        "cache": outcome.cache,
        "cluster": cluster_record(),  # where the tasks ran: serial, or Ray's address, nodes and CPUs
        "cache_hits": outcome.stats.cache_hits,
        "cache_misses": outcome.stats.cache_misses,
        "cache_corrupt": outcome.stats.cache_corrupt,  # bad entries found, removed and recomputed
        "cache_write_errors": outcome.stats.cache_write_errors,
        "dense_map_hits": outcome.stats.dense_hits,  # dense descriptor maps (XFeat's) read from the cache
        "dense_map_misses": outcome.stats.dense_misses,  # computed (one network run each)
        "dense_map_write_errors": outcome.stats.dense_write_errors,
        "detection_tasks": outcome.stats.detection_tasks,
        "pairing_tasks": outcome.stats.pairing_tasks,
        "seconds": round(outcome.seconds, 3),
    }
    if reuse is not None:  # (cell, image or pair) combinations: rows kept from an earlier run, evaluated now
        record["items_reused"], record["items_evaluated"] = reuse.reused, reuse.evaluated
    write_atomically(outcome.output_dir / "run.json", json.dumps(record, indent=1))
