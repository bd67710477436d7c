"""``experiment=localization``: build a map per floor and localize queries against it, for every cell of
detector x selector x descriptor x matcher x estimator (issue 19; Micro-GPS, Zhang et al. ICRA 2019).

The task graph: mapping images are detected and described in shards (``runner.shard_size`` images per task,
through the keypoint cache), then assembled into one map per (detector, selector, descriptor, floor), which is cached
content-addressed (``<cache.dir>/../maps/``) and shared by every matcher and estimator of that pairing; queries are
localized in shards, one task per (pairing, matcher, floor, shard) that runs every estimator on the same matches.
A cell is written when all its query shards are in (``cells/<cell>.csv`` with one row per query and map size).
"""
from __future__ import annotations

import logging
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput
from gtsweep.core.ranges import Choice, Range, check_all
from gtsweep.datasets.mapping import check as check_data_options
from gtsweep.datasets.core import read_gray
from gtsweep.datasets.mapping import covered_area, load_localization
from gtsweep.orchestration import loctasks
from gtsweep.orchestration.cache import cache_state
from gtsweep.orchestration.executor import backend, check_address, make_executor
from gtsweep.orchestration.grid import _pairings, _surveys, declared_methods, resolve_group
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.results import ResultStore
from gtsweep.orchestration.runner import RunStats
from gtsweep.orchestration.settings import check_settings
from gtsweep.orchestration.sweep import SweepOutcome, _write_run_record, cell_summary
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.match import applicability as matcher_applicability
from gtsweep.stages.pairing import applicability

log = logging.getLogger(__name__)
EXPERIMENT = "localization"
SETTINGS = {
    "experiment.voting": Choice((True, False)),
    "experiment.vote_cell": Range(0, None, low_open=True),
    "experiment.map_dedupe": Choice((True, False)),
    "experiment.min_inliers": Range(2, None, integer=True),
    "experiment.min_inlier_ratio": Range(0, 1),
    "experiment.max_position_error": Range(0, None, low_open=True),
    "experiment.max_orientation_error": Range(0, 180, low_open=True),
}


@dataclass(frozen=True)
class LocCell:
    """One cell; its ``transform`` is "map" (MLflow run names read it: ``sift·sift·map·flann·magsac``)."""

    detector: str
    selector: str
    descriptor: str
    matcher: str
    estimator: str
    na_reason: str | None = None

    @property
    def key(self) -> str:
        return "__".join([self.detector, self.selector, self.descriptor, self.matcher, self.estimator])

    transform = "map"

    @property
    def methods(self) -> dict:
        return {"detector": self.detector, "selector": self.selector, "descriptor": self.descriptor,
                "transform": self.transform, "matcher": self.matcher, "estimator": self.estimator}


@dataclass
class LocGrid:
    experiment: dict
    detectors: dict
    selectors: dict
    descriptors: dict
    matchers: dict
    estimators: dict
    cells: list[LocCell] = field(default_factory=list)
    transforms: dict = field(default_factory=dict)

    @property
    def declared(self) -> dict:
        return declared_methods({"detector": self.detectors, "selector": self.selectors,
                                 "descriptor": self.descriptors})

    def cell_config(self, cell: LocCell, dataset_fingerprint: str, seed: int) -> dict:
        return {"methods": cell.methods, "detector": self.detectors[cell.detector],
                "selector": self.selectors[cell.selector], "descriptor": self.descriptors[cell.descriptor],
                "transform": {}, "matcher": self.matchers[cell.matcher], "estimator": self.estimators[cell.estimator],
                "experiment": self.experiment, "dataset": dataset_fingerprint, "seed": seed}

    def cell_hash(self, cell: LocCell, dataset_fingerprint: str, seed: int) -> str:
        return config_hash(self.cell_config(cell, dataset_fingerprint, seed))


def build_localization_grid(cfg: Mapping) -> LocGrid:
    """The localization cells of ``cfg``; every setting and method checked first (one line on bad input)."""
    check_settings(cfg)
    check_all({"experiment": plain(cfg.get("experiment")) or {}}, SETTINGS)
    check_data_options(plain(cfg.get("experiment")) or {})
    grid = LocGrid(plain(cfg.get("experiment")) or {}, resolve_group(cfg, "detector"),
                   resolve_group(cfg, "selector"), resolve_group(cfg, "descriptor"),
                   resolve_group(_surveys(cfg, "matcher"), "matcher"),
                   resolve_group(_surveys(cfg, "estimator"), "estimator"))
    for detector, descriptor in _pairings(cfg, grid):
        norm = DESCRIPTORS.get(descriptor).norm
        for selector in grid.selectors:
            for matcher, matcher_cfg in grid.matchers.items():
                reason = applicability(detector, descriptor) or matcher_applicability(
                    MATCHERS.get(matcher).build(matcher_cfg["params"]), norm, descriptor, against_map=True)
                grid.cells += [LocCell(detector, selector, descriptor, matcher, estimator, reason)
                               for estimator in grid.estimators]
    return grid


def run_localization(cfg: Mapping, output_dir: str | Path, hooks=(), on_start=None, progress: Progress | None = None,
                     on_checked=None) -> SweepOutcome:
    """Evaluate the localization grid of ``cfg`` into ``output_dir`` (as :func:`gtsweep.orchestration.sweep.
    run_sweep`: finished cells of an earlier run with the same configuration are kept)."""
    start = time.perf_counter()
    progress = progress or Progress(enabled=False)
    grid = build_localization_grid(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    if backend(runner_cfg) == "ray":
        check_address(runner_cfg)
    if on_checked is not None:
        on_checked()
    cache_dir, cache_note = cache_state(cfg)
    progress.phase("render data set")
    data = load_localization(cfg["dataset"], grid.experiment)
    log.info("localization data '%s': %s mapping images, %d queries, map sizes %s", data.name,
             {t: len(m) for t, m in data.maps.items()}, len(data.queries), data.map_sizes)
    seed = int(cfg.get("seed", 0))
    store = ResultStore(output_dir)
    if on_start is not None:
        on_start(grid, data.fingerprint)
    hashes = {c.key: grid.cell_hash(c, data.fingerprint, seed) for c in grid.cells}
    summaries: dict[str, dict] = {}

    def finish(cell: LocCell, outcome: Mapping) -> None:
        summary = cell_summary(cell, hashes[cell.key], outcome, EXPERIMENT)
        store.write_cell(cell.key, summary, outcome.get("rows"))
        summaries[cell.key] = summary
        log.info("cell %s: %s%s", cell.key, summary["status"], f" ({summary.get('reason')})"
                 if summary.get("reason") else "")
        progress.cell_done()
        for hook in hooks:
            hook(cell, summary, outcome.get("rows"))

    pending, resumed = [], 0
    for cell in grid.cells:
        done = store.complete(cell.key, hashes[cell.key])
        if done is not None:
            summaries[cell.key], resumed = done, resumed + 1
            for hook in hooks:
                hook(cell, done, None)
        elif cell.na_reason is None:
            pending.append(cell)
    stats = RunStats()
    executor = make_executor(runner_cfg) if pending else None
    progress.phase("evaluate", total=len(grid.cells), done=resumed)
    for cell in grid.cells:
        if cell.key not in summaries and cell.na_reason is not None:
            finish(cell, {"na": cell.na_reason})
    if pending:
        _run(grid, data, pending, executor, runner_cfg, seed, cache_dir, finish, stats)
    ordered = [summaries[c.key] for c in grid.cells]
    outcome = SweepOutcome(Path(output_dir), grid, ordered, stats, resumed, data.fingerprint,
                           time.perf_counter() - start, failed=[s["key"] for s in ordered if s["status"] == "error"],
                           cache=cache_note)
    outcome.table = store.write_table(ordered)
    _write_run_record(outcome, data)
    return outcome


def _run(grid: LocGrid, data, cells: list[LocCell], executor, runner_cfg: dict, seed: int, cache_dir, finish,
         stats: RunStats) -> None:
    """Submit the map and query tasks of ``cells`` and report each cell as its query shards come in."""
    import pandas as pd

    size = int(runner_cfg.get("shard_size", 4))
    experiment = grid.experiment
    # mapping images are read in their tasks (a real map has thousands); the queries here, once
    mapping = {t: [{"path": s.path, "pose": s.pose} for s in samples] for t, samples in data.maps.items()}
    shapes = {t: read_gray(m[0]["path"]).shape for t, m in mapping.items() if m}
    queries = [{"id": q.sample.id, "texture": q.texture, "in_map": q.in_map, "pose": q.sample.pose,
                "image": q.sample.load()} for q in data.queries]
    areas = {t: {n: covered_area([s.pose for s in data.maps[t][:n]], shapes[t]) /
                 (data.px_per_mm ** 2 * 1e6) for n in data.sizes(t)} for t in data.maps if data.maps[t]}
    map_refs = {t: [executor.put(m[i:i + size]) for i in range(0, len(m), size)] for t, m in mapping.items()}
    query_refs = {t: [executor.put(part[i:i + size]) for i in range(0, len(part), size)]
                  for t in data.maps for part in [[q for q in queries if q["texture"] == t]] if part}
    groups: dict[tuple, list[LocCell]] = defaultdict(list)
    for cell in cells:
        groups[(cell.detector, cell.selector, cell.descriptor, cell.matcher)].append(cell)
    maps: dict[tuple, dict] = {}
    tracker: dict[tuple, dict] = {}
    for (detector, selector, descriptor, matcher), members in groups.items():
        method = {"detector": detector, "detector_params": grid.detectors[detector]["params"],
                  "selector": selector, "selector_params": grid.selectors[selector]["params"],
                  "descriptor": descriptor,
                  "descriptor_params": descriptor_params(grid.descriptors[descriptor], detector)}
        estimators = {c.estimator: grid.estimators[c.estimator]["params"] for c in members}
        job = (detector, selector, descriptor, matcher)
        tracker[job] = {"cells": members, "remaining": 0, "rows": defaultdict(list), "failure": None,
                        "started": [], "ended": []}
        for texture in query_refs:
            handle = _map_handle(maps, executor, grid, data, texture, method, map_refs[texture], cache_dir, stats)
            for shard in query_refs[texture]:
                tracker[job]["remaining"] += 1
                stats.pairing_tasks += 1
                executor.submit(loctasks.query_shard, shard, handle, areas[texture], method,
                                (matcher, grid.matchers[matcher]["params"]), estimators, experiment, seed,
                                cache_dir, grid.declared, tag=("query", job))
    for tag, result in executor.results():
        stats.cache_hits += result.get("hits", 0)
        stats.cache_misses += result.get("misses", 0)
        stats.cache_corrupt += result.get("corrupt", 0)
        stats.cache_write_errors += result.get("write_errors", 0)
        if tag[0] != "query":
            continue
        state = tracker[tag[1]]
        state["remaining"] -= 1
        state["started"].append(result.get("started"))
        state["ended"].append(result.get("ended"))
        if "by_estimator" in result:
            for name, rows in result["by_estimator"].items():
                state["rows"][name] += rows
        elif state["failure"] is None:
            state["failure"] = {k: v for k, v in result.items() if k in ("na", "error")}
        if state["remaining"] == 0:
            ran = {"started": min(filter(None, state["started"]), default=None),
                   "ended": max(filter(None, state["ended"]), default=None)}
            for cell in state["cells"]:
                outcome = state["failure"] or {"rows": pd.DataFrame.from_records(state["rows"][cell.estimator])}
                finish(cell, {**outcome, **ran})


def _map_handle(maps: dict, executor, grid: LocGrid, data, texture: str, method: dict, refs: list, cache_dir,
                stats: RunStats):
    """The map of ``texture`` for ``method``: from the map cache, or from map tasks (submitted once)."""
    parts = (data.fingerprint, texture, [s.id for s in data.maps[texture]], method,
             bool(grid.experiment.get("map_dedupe", True)))
    key = loctasks.map_key(*parts)
    if key in maps:
        return maps[key]
    path = loctasks.map_path(cache_dir, key)
    cached = loctasks.read_map(path, key)
    if cached is not None:
        log.info("map %s of %s (%s): from the map cache", key, texture, method["descriptor"])
        maps[key] = executor.put(cached)
        return maps[key]
    shards = [executor.submit(loctasks.map_shard, ref, method, cache_dir, grid.declared, tag=("map", key))
              for ref in refs]
    stats.detection_tasks += len(shards)
    if not data.maps[texture]:
        raise BadInput(f"floor {texture} has no mapping images")
    maps[key] = executor.submit(loctasks.assemble_map, bool(grid.experiment.get("map_dedupe", True)),
                                str(path) if path else None, key, *shards)
    return maps[key]
