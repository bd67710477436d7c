"""``experiment=localization``: build a map per floor and localize queries against it, for every cell of
detector x selector x descriptor x matcher x estimator (as Micro-GPS localizes, Zhang et al. ICRA 2019).

The task graph: mapping images are detected and described in shards (``runner.shard_size`` images per task,
through the keypoint cache), then assembled into one map per (detector, selector, descriptor, floor), which is cached
content-addressed (``<cache.dir>/../maps/``) and shared by every matcher and estimator of that pairing; queries are
localized in shards, one task per (pairing, matcher, floor, shard) that runs every estimator on the same matches.
A cell is written when all its query shards are in (``cells/<cell>.csv`` with one row per query and map size).
"""
from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from gtsweep.core.config import METHOD_GROUPS, plain
from gtsweep.core.errors import BadInput
from gtsweep.core.ranges import check_all
from gtsweep.datasets.core import read_gray
from gtsweep.datasets.mapping import check as check_data_options
from gtsweep.datasets.mapping import covered_area, load_localization
from gtsweep.experiments.localization import tasks as loctasks
from gtsweep.experiments.localization.settings import SETTINGS
from gtsweep.orchestration.executor import make_executor
from gtsweep.orchestration.grid import (MethodCell, MethodGrid, pairings_of, resolve_group, selectors_of,
                                        with_survey_method)
from gtsweep.orchestration.skeleton import CellWork, SweepOutcome, run_sweep
from gtsweep.orchestration.tasks import RunStats
from gtsweep.stages.applicability import applicability
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.match import applicability as matcher_applicability

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LocCell(MethodCell):
    """One cell; its ``transform`` is "map" (MLflow run names read it: ``sift·sift·map·flann·magsac``)."""

    NAMED = METHOD_GROUPS
    KEY = ("detector", "selector", "descriptor", "matcher", "estimator")

    detector: str
    selector: str
    descriptor: str
    matcher: str
    estimator: str
    na_reason: str | None = None

    transform = "map"


@dataclass
class LocGrid(MethodGrid):
    """The methods of the localization cells (no transforms: a map's cells have none)."""

    DECLARED_GROUPS = ("detector", "selector", "descriptor")
    experiment: dict
    detectors: dict
    selectors: dict
    descriptors: dict
    matchers: dict
    estimators: dict
    cells: list[LocCell] = field(default_factory=list)
    transforms: dict = field(default_factory=dict)


def build_localization_grid(cfg: Mapping) -> LocGrid:
    """The localization cells of ``cfg``; its experiment's settings and methods checked first (one line on bad
    input; the run settings are checked where the job is composed)."""
    check_all(plain(cfg.get("experiment")) or {}, SETTINGS, prefix="experiment.")
    check_data_options(plain(cfg.get("experiment")) or {})
    grid = LocGrid(plain(cfg.get("experiment")) or {}, resolve_group(cfg, "detector"),
                   resolve_group(cfg, "selector"), resolve_group(cfg, "descriptor"),
                   resolve_group(with_survey_method(cfg, "matcher"), "matcher"),
                   resolve_group(with_survey_method(cfg, "estimator"), "estimator"))
    selected = selectors_of(cfg, grid)
    for detector, descriptor in pairings_of(cfg, grid):
        norm = DESCRIPTORS.get(descriptor).norm
        for selector in selected[detector]:
            for matcher, matcher_cfg in grid.matchers.items():
                reason = applicability(detector, descriptor) or matcher_applicability(
                    MATCHERS.get(matcher).build(matcher_cfg["params"]), norm, descriptor, against_map=True)
                grid.cells += [LocCell(detector, selector, descriptor, matcher, estimator, reason)
                               for estimator in grid.estimators]
    return grid


def _load(cfg: Mapping, grid: LocGrid):
    data = load_localization(cfg["dataset"], grid.experiment)
    log.info("localization data '%s': %s mapping images, %d queries, map sizes %s", data.name,
             {t: len(m) for t, m in data.maps.items()}, len(data.queries), data.map_sizes)
    return data


def _evaluate(grid: LocGrid, data, cells: list[LocCell], runner_cfg: dict, seed: int, cache_dir, finish,
              on_started) -> RunStats:
    stats = RunStats()
    executor = make_executor(runner_cfg)
    on_started()
    _run(grid, data, cells, executor, runner_cfg, seed, cache_dir, finish, stats)
    return stats


#: ``experiment=localization``: a map per floor, queries against it.
LOCALIZATION = CellWork(build_localization_grid, _load, _evaluate)


def run_localization(cfg: Mapping, output_dir: str | Path, **options) -> SweepOutcome:
    """Evaluate the localization grid of ``cfg`` into ``output_dir`` on the sweep skeleton (:func:`gtsweep.
    orchestration.skeleton.run_sweep`: finished cells of an earlier run with the same configuration are kept)."""
    return run_sweep(cfg, output_dir, work=LOCALIZATION, **options)


def _run(grid: LocGrid, data, cells: list[LocCell], executor, runner_cfg: dict, seed: int, cache_dir, finish,
         stats: RunStats) -> None:
    """Submit the map and query tasks of ``cells`` and report each cell as its query shards come in."""
    map_refs, query_refs, areas = _put_data(data, executor, int(runner_cfg["shard_size"]))
    groups: dict[tuple, list[LocCell]] = defaultdict(list)
    for cell in cells:
        groups[(cell.detector, cell.selector, cell.descriptor, cell.matcher)].append(cell)
    maps: dict[tuple, dict] = {}
    tracker: dict[tuple, dict] = {}
    for (detector, selector, descriptor, matcher), members in groups.items():
        method = {"detector": detector, "detector_params": grid.detectors[detector]["params"],
                  "selector": selector, "selector_params": grid.selectors[selector]["params"],
                  "descriptor": descriptor,
                  "descriptor_params": descriptor_params(grid.descriptors[descriptor], detector),
                  "foreign_scale": grid.experiment.get("foreign_scale")}
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
                                (matcher, grid.matchers[matcher]["params"]), estimators, grid.experiment, seed,
                                cache_dir, grid.declared, tag=("query", job))
    _collect(executor, tracker, stats, finish)


def _put_data(data, executor, size: int) -> tuple[dict, dict, dict]:
    """Per floor: the mapping images' and the queries' shards put to the executor, and each map size's covered
    area (m2). Mapping images are read in their tasks (a real map has thousands); the queries here, once."""
    mapping = {t: [{"path": s.path, "pose": s.pose} for s in samples] for t, samples in data.maps.items()}
    shapes = {t: read_gray(m[0]["path"]).shape for t, m in mapping.items() if m}
    queries = [{"id": q.sample.id, "texture": q.texture, "in_map": q.in_map, "pose": q.sample.pose,
                "image": q.sample.load()} for q in data.queries]
    areas = {t: {n: covered_area([s.pose for s in data.maps[t][:n]], shapes[t]) /
                 (data.px_per_mm ** 2 * 1e6) for n in data.sizes(t)} for t in data.maps if data.maps[t]}
    map_refs = {t: [executor.put(m[i:i + size]) for i in range(0, len(m), size)] for t, m in mapping.items()}
    query_refs = {t: [executor.put(part[i:i + size]) for i in range(0, len(part), size)]
                  for t in data.maps for part in [[q for q in queries if q["texture"] == t]] if part}
    return map_refs, query_refs, areas


def _collect(executor, tracker: dict[tuple, dict], stats: RunStats, finish) -> None:
    """Count every task's cache use; finish a job's cells once all its query shards are in."""
    import pandas as pd

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
