"""The one sweep skeleton every kind of sweep runs on: build the grid, check the services, load the data, keep the
cells an earlier run finished (resume), evaluate the others, write the results and the run record.

A kind of sweep gives its grid, its data and its evaluation as a :class:`CellWork` (its experiment's
:attr:`~gtsweep.experiments.kinds.Experiment.cells`; the kinds live in ``gtsweep/experiments/<kind>/``). The
skeleton alone writes result files (and, through ``hooks``, to MLflow); workers return plain rows.
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
from gtsweep.datasets.pixels import check_dataset
from gtsweep.orchestration.cache import cache_state
from gtsweep.orchestration.cluster import check_address, cluster_record
from gtsweep.orchestration.executor import backend
from gtsweep.orchestration.grid import MethodCell, MethodGrid, matcher_na_line
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.results import ResultStore, summarize
from gtsweep.orchestration.tasks import RunStats
from gtsweep.orchestration.view_reuse import ViewReuse

#: Called as ``hook(cell, summary, rows)`` for every cell as it finishes, and for cells kept from an earlier run
#: (rows None for those and for NA cells).
CellHook = Callable[[MethodCell, dict, "pd.DataFrame | None"], None]
log = logging.getLogger(__name__)


@dataclass
class SweepOutcome:
    output_dir: Path
    grid: MethodGrid
    summaries: list[dict]
    stats: RunStats
    resumed: int  # cells found complete from an earlier run
    dataset_fingerprint: str
    seconds: float
    table: Path | None = None
    failed: list[str] = field(default_factory=list)
    skipped_items: list[str] = field(default_factory=list)  # bad data items skipped under dataset.skip_bad
    cache: str = ""  # the keypoint cache: "on: <dir>" or "off: <why>"


def cell_summary(cell: MethodCell, cell_hash: str, outcome: Mapping, experiment: str) -> dict:
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


def run_sweep(cfg: Mapping, output_dir: str | Path, work: CellWork, hooks: tuple[CellHook, ...] = (),
              on_start: Callable[[MethodGrid, str], None] | None = None, progress: Progress | None = None,
              on_checked: Callable[[], None] | None = None) -> SweepOutcome:
    """Evaluate the grid of ``cfg`` into ``output_dir``; cells already complete (same config) are kept, failed
    ones recomputed. ``work``: the kind of sweep (its experiment's :attr:`~gtsweep.experiments.kinds.Experiment.
    cells`); ``progress`` shows the phases and counts the cells (none: the job's log only); ``on_checked`` runs once
    the settings and the Ray address are checked, before any work."""
    start = time.perf_counter()
    progress = progress or Progress(enabled=False)
    grid, runner_cfg = _checked_grid(cfg, work, on_checked)
    cache_dir, cache_note = cache_state(cfg)
    progress.phase("render data set")
    data = work.load_data(cfg, grid)
    check_dataset(getattr(data, "dataset", data), grid.cells, runner_cfg)  # largest image x workers x B/px
    log.info("data set '%s', fingerprint %s", data.name, data.fingerprint)
    seed = int(cfg.get("seed", 0))
    store = ResultStore(output_dir)
    if on_start is not None:
        on_start(grid, data.fingerprint)
    cells = _Cells(grid, store, {cell.key: grid.cell_hash(cell, data.fingerprint, seed) for cell in grid.cells},
                   hooks, progress)
    reuse = work.reuse(store, grid, data, seed) if work.reuse is not None else None
    cells.reuse = reuse
    pending = cells.sort_out()
    stats = _evaluate(work, grid, data, pending, reuse, cells, runner_cfg, seed, cache_dir)
    cache_note = _cache_warnings(stats, cache_note, cache_dir)
    ordered = [cells.summaries[cell.key] for cell in grid.cells]
    outcome = SweepOutcome(Path(output_dir), grid, ordered, stats, cells.resumed, data.fingerprint,
                           time.perf_counter() - start, failed=[s["key"] for s in ordered if s["status"] == "error"],
                           skipped_items=list(getattr(data, "skipped", ())), cache=cache_note)
    outcome.table = store.write_table(ordered)
    write_run_record(outcome, data, reuse)
    return outcome


def _checked_grid(cfg: Mapping, work: CellWork, on_checked: Callable[[], None] | None) -> tuple[MethodGrid, dict]:
    """The grid of ``cfg`` and its run settings, once its cells and the Ray address are checked (before any
    work)."""
    grid = work.build_grid(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    log.info("grid: %d cells (%s experiment)", len(grid.cells), grid.experiment["name"])
    say_not_applicable(grid.cells)
    if backend(runner_cfg) == "ray":
        check_address(runner_cfg)  # a cluster that does not answer stops here, in seconds
    if on_checked is not None:
        on_checked()
    return grid, runner_cfg


class _Cells:
    """The cells of one sweep as they are kept, evaluated and written: their summaries, and ``finish`` for each
    cell whose outcome is in."""

    def __init__(self, grid: MethodGrid, store: ResultStore, hashes: dict[str, str], hooks, progress: Progress):
        self.grid, self.store, self.hashes, self.hooks, self.progress = grid, store, hashes, hooks, progress
        self.reuse: ViewReuse | None = None
        self.summaries: dict[str, dict] = {}
        self.not_applicable: list = []
        self.resumed = 0
        self.started = False

    def sort_out(self) -> list:
        """Keep the cells an earlier run finished (same hash); returns those to evaluate (the NA ones wait for
        :meth:`start`)."""
        pending = []
        for cell in self.grid.cells:
            done = self.store.complete(cell.key, self.hashes[cell.key])
            if done is not None:
                self.summaries[cell.key], self.resumed = done, self.resumed + 1
                for hook in self.hooks:  # hooks skip what they already have (e.g. cells logged before a kill)
                    hook(cell, done, None)
            elif cell.na_reason is not None:
                self.not_applicable.append(cell)
            else:
                pending.append(cell)
        log.info("%d cell(s) to evaluate, %d kept from an earlier run, %d not applicable", len(pending),
                 self.resumed, len(self.not_applicable))
        return pending

    def start(self) -> None:
        """Once, when the executor is up: NA cells are written, the bar counts every cell."""
        if self.started:
            return
        self.started = True
        self.progress.phase("evaluate cells", total=len(self.grid.cells), done=self.resumed)
        for cell in self.not_applicable:
            self.finish(cell, {"na": cell.na_reason})

    def finish(self, cell, outcome: Mapping) -> None:
        """Write a cell whose outcome is in (rows, NA or error), and tell the hooks."""
        reuse = self.reuse
        if reuse is not None:
            outcome = reuse.complete(cell, outcome)
        summary = cell_summary(cell, self.hashes[cell.key], outcome, self.grid.experiment["name"])
        rows = outcome.get("rows")
        covered = reuse.coverage(cell) if reuse is not None and summary["status"] == "ok" else None
        self.store.write_cell(cell.key, summary, rows, covered)
        self.summaries[cell.key] = summary
        log.info("cell %s: %s%s", cell.key, summary["status"], f" ({summary['reason']})" if summary.get("reason")
                 else "")
        self.progress.cell_done()
        for hook in self.hooks:
            hook(cell, summary, rows)


def _evaluate(work: CellWork, grid: MethodGrid, data, pending: list, reuse: ViewReuse | None, cells: _Cells,
              runner_cfg: dict, seed: int, cache_dir) -> RunStats:
    """Evaluate the pending cells, one group per set of items still to evaluate (usually one)."""
    ready, groups = reuse.plan(pending) if reuse is not None else ([], [(data, pending)] if pending else [])
    if reuse is not None:
        log.info("view reuse: %d (cell, image or pair) rows kept from an earlier run, %d to evaluate",
                 reuse.reused, reuse.evaluated)
    stats = RunStats()
    if groups and backend(runner_cfg) == "ray":
        cells.progress.phase("start Ray")
    for part, members in groups:
        stats = _added(stats, work.evaluate(grid, part, members, runner_cfg, seed, cache_dir, cells.finish,
                                            cells.start))
    cells.start()
    for cell in ready:  # every item's rows kept: nothing to evaluate
        cells.finish(cell, {"rows": pd.DataFrame()})
    return stats


def _cache_warnings(stats: RunStats, cache_note: str, cache_dir) -> str:
    """The cache's note with the writes that failed, which are also said in the log and on stderr."""
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
    return cache_note


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


def _added(a: RunStats, b: RunStats) -> RunStats:
    return RunStats(**{f.name: getattr(a, f.name) + getattr(b, f.name) for f in fields(RunStats)})


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
