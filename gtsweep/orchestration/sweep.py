"""One sweep from a composed config: build the grid, load the data set, skip finished cells, run, write results.

This is the driver. It alone writes result files (and, through ``hooks``, to MLflow); workers return plain rows.
"""
from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

import pandas as pd

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import plain
from gtsweep.datasets import load_dataset
from gtsweep.orchestration.cache import cache_state
from gtsweep.orchestration.cluster import check_address, cluster_record
from gtsweep.orchestration.executor import backend
from gtsweep.orchestration.grid import Cell, Grid, build_grid
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.results import ResultStore, summarize
from gtsweep.orchestration.runner import RunStats, plan, run
from gtsweep.orchestration.shards import load_shards

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


def run_sweep(cfg: Mapping, output_dir: str | Path, hooks: tuple[CellHook, ...] = (),
              on_start: Callable[[Grid, str], None] | None = None, progress: Progress | None = None,
              on_checked: Callable[[], None] | None = None) -> SweepOutcome:
    """Evaluate the grid of ``cfg`` into ``output_dir``; cells already complete (same config) are kept, failed
    ones recomputed. ``progress`` shows the phases and counts the cells (none: the job's log only);
    ``on_checked`` runs once the settings and the Ray address are checked, before any work."""
    start = time.perf_counter()
    progress = progress or Progress(enabled=False)
    grid = build_grid(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    log.info("grid: %d cells (%s experiment), %d detector(s), %d selector(s), %d descriptor(s), %d transform(s)",
             len(grid.cells), grid.experiment["name"], len(grid.detectors), len(grid.selectors),
             len(grid.descriptors), len(grid.transforms))
    if backend(runner_cfg) == "ray":
        check_address(runner_cfg)  # a cluster that does not answer stops here, in seconds
    if on_checked is not None:
        on_checked()
    cache_dir, cache_note = cache_state(cfg)
    progress.phase("render data set")
    dataset = load_dataset(cfg["dataset"])
    fingerprint = dataset.fingerprint()
    log.info("data set '%s', fingerprint %s", dataset.name, fingerprint)
    seed = int(cfg.get("seed", 0))
    store = ResultStore(output_dir)
    if on_start is not None:
        on_start(grid, fingerprint)
    summaries: dict[str, dict] = {}
    hashes = {cell.key: grid.cell_hash(cell, fingerprint, seed) for cell in grid.cells}

    def finish(cell: Cell, outcome: Mapping) -> None:
        summary = cell_summary(cell, hashes[cell.key], outcome, grid.experiment["name"])
        rows = outcome.get("rows")
        store.write_cell(cell.key, summary, rows)
        summaries[cell.key] = summary
        log.info("cell %s: %s%s", cell.key, summary["status"], f" ({summary['reason']})" if summary.get("reason")
                 else "")
        progress.cell_done()
        for hook in hooks:
            hook(cell, summary, rows)

    pending, not_applicable, resumed = set(), [], 0
    for cell in grid.cells:
        done = store.complete(cell.key, hashes[cell.key])
        if done is not None:
            summaries[cell.key], resumed = done, resumed + 1
            for hook in hooks:  # hooks skip what they already have (e.g. cells logged before a kill)
                hook(cell, done, None)
        elif cell.na_reason is not None:
            not_applicable.append(cell)
        else:
            pending.add(cell.key)
    # Load (and so check) every image before the first result file is written: bad data stops the run clean.
    shards = load_shards(dataset, grid.transforms, int(runner_cfg.get("shard_size", 4))) if pending else {}
    log.info("%d cell(s) to evaluate, %d kept from an earlier run, %d not applicable", len(pending), resumed,
             len(not_applicable))

    def start_evaluating() -> None:  # the executor is up: NA cells are written, the bar counts every cell
        progress.phase("evaluate", total=len(grid.cells), done=resumed)
        for cell in not_applicable:
            finish(cell, {"na": cell.na_reason})

    stats = RunStats()
    if pending:
        jobs = plan(grid, {kind: len(s) for kind, s in shards.items()}, pending)
        if backend(runner_cfg) == "ray":
            progress.phase("start Ray")
        stats = run(grid, shards, jobs, runner_cfg, seed, cache_dir, finish, on_started=start_evaluating)
    else:
        start_evaluating()
    if stats.cache_write_errors:
        cache_note = f"{cache_note} ({stats.cache_write_errors} task(s) could not write to it and went on without)"
        log.warning("%d task(s) could not write to the keypoint cache %s; they ran without it",
                    stats.cache_write_errors, cache_dir)
        print(f"gtsweep: warning: {stats.cache_write_errors} task(s) could not write to the keypoint cache "
              f"{cache_dir}; they ran without it", file=sys.stderr)
    ordered = [summaries[cell.key] for cell in grid.cells]
    outcome = SweepOutcome(Path(output_dir), grid, ordered, stats, resumed, fingerprint,
                           time.perf_counter() - start, failed=[s["key"] for s in ordered if s["status"] == "error"],
                           skipped_items=list(getattr(dataset, "skipped", [])), cache=cache_note)
    outcome.table = store.write_table(ordered)
    _write_run_record(outcome, dataset)
    return outcome


def _write_run_record(outcome: SweepOutcome, dataset) -> None:
    record = {
        "dataset": dataset.name,
        "dataset_fingerprint": outcome.dataset_fingerprint,
        "skipped_items": outcome.skipped_items,
        "cells": len(outcome.summaries),
        "resumed_cells": outcome.resumed,
        "cache": outcome.cache,
        "cluster": cluster_record(),  # where the tasks ran: serial, or Ray's address, nodes and CPUs
        "cache_hits": outcome.stats.cache_hits,
        "cache_misses": outcome.stats.cache_misses,
        "cache_corrupt": outcome.stats.cache_corrupt,  # bad entries found, removed and recomputed
        "detection_tasks": outcome.stats.detection_tasks,
        "pairing_tasks": outcome.stats.pairing_tasks,
        "seconds": round(outcome.seconds, 3),
    }
    write_atomically(outcome.output_dir / "run.json", json.dumps(record, indent=1))
