"""Collect the reproduction's rows in chunks: each :class:`~gtsweep.reproduction.design.Unit` runs its preset's
sweep on its window of images or pairs and its cells only, and its rows become one chunk of the committed state.

A unit already in the state is not run again. A unit cut short (a signal, a lost machine) leaves its sweep's
output in the scratch folder, which the same unit's next run resumes (the sweep keeps its finished cells); the
state gains the chunk only when the unit has finished. With ``commit``, each chunk is committed to git as it is
written, so a run that outlasts a session resumes from what is committed, on any machine.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import time
from datetime import datetime, timezone
from pathlib import Path

import pandas as pd

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import PROJECT_DIR
from gtsweep.orchestration.cache import library_versions
from gtsweep.reproduction import rounds
from gtsweep.reproduction import state as states
from gtsweep.reproduction.design import Unit


def done_units(folder: Path) -> set[str]:
    return {record["unit"] for record in states.chunk_records(folder)}


def cut_overrides(unit: Unit, records: dict[str, dict[str, dict]]) -> list[str]:
    """The overrides that cut the preset's grid to the unit's cells (their methods as the state's records hold
    them: :func:`~gtsweep.reproduction.state.cell_records`)."""
    if unit.cells is None:
        return []
    cells = records.get(unit.preset) or {}
    missing = [k for k in unit.cells if k not in cells]
    if missing:
        raise BadInput(f"{unit.name}: the state holds no record of cell(s) {', '.join(missing[:3])}: run the "
                       f"preset's first window first")
    available = [c["methods"] for c in cells.values()]
    return rounds.restriction(available, [cells[k]["methods"] for k in unit.cells],
                              rounds.preset_options(unit.preset))[0]


def harvest(output: Path, unit: Unit) -> tuple[dict, pd.DataFrame]:
    """A finished sweep's cells of ``unit`` as one chunk: the cells' records and their rows (each checked to hold
    rows of the unit's window of images or pairs only)."""
    cells, frames, items = {}, [], {}
    for path in sorted((Path(output) / "cells").glob("*.json")):
        summary = json.loads(path.read_text())
        key = summary["key"]
        if unit.cells is not None and key not in unit.cells:
            continue  # a cell the cut grid could not leave out: not part of this unit
        reuse = Path(output) / "reuse" / f"{key}.json"
        coverage = json.loads(reuse.read_text()) if reuse.exists() else {}
        items.update(coverage.get("items") or {})
        record = {k: summary.get(k) for k in ("methods", "experiment", "status", "reason")}
        csv = path.with_suffix(".csv")
        if summary["status"] == "ok" and csv.exists():
            rows = pd.read_csv(csv)
            _check_window(key, rows, unit)
            frames.append(rows.assign(**{states.CELL: key}))
            record["columns"] = list(rows.columns)
        cells[key] = {**record, "reuse_key": coverage.get("reuse_key")}
    missing = sorted(set(unit.cells or ()) - set(cells))
    if missing:
        raise BadInput(f"{unit.name}: the sweep wrote no result for {', '.join(missing[:3])}")
    rows = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[states.CELL])
    return {"cells": cells, "items": items}, rows


def _check_window(key: str, rows: pd.DataFrame, unit: Unit) -> None:
    numbers = set(states.item_numbers(rows["image"]))
    if not numbers <= set(range(unit.start, unit.stop)):
        raise BadInput(f"{unit.name}: cell {key} has rows of images or pairs outside numbers "
                       f"{unit.start}-{unit.stop - 1}")


def run_unit(unit: Unit, folder: Path, work: Path, records: dict, commit: bool, log=print,
             extra: list[str] = ()) -> str:
    """Run one unit and add its chunk to the state in ``folder``; returns the chunk's name. ``extra``: overrides
    after the unit's own (tests: a smaller data set)."""
    scratch = Path(work) / "scratch" / unit.name.replace("/", "_")
    overrides = [*unit.overrides(), *cut_overrides(unit, records), *extra]  # the unit's counts replace the presets'
    log(f"gtsweep.reproduction: {unit.name} ({' '.join(overrides)})")
    started = time.time()
    result = rounds.run_preset(unit.preset, overrides, scratch, f"sqlite:///{Path(work) / 'mlflow.db'}",
                               Path(work) / "cache")
    content, rows = harvest(result["output"], unit)
    record = {"unit": unit.name, "kind": unit.kind, "preset": unit.preset, "window": [unit.start, unit.stop],
              "split": unit.split, "overrides": overrides, **content, "wall_s": round(result["wall_s"], 1),
              "peak_mb": round(result["peak_mb"]), "cache_hit_rate": result["cache_hit_rate"],
              "versions": library_versions(), "code": _head(), "started": _utc(started), "ended": _utc(time.time())}
    name = states.write_chunk(folder, unit.name.replace("/", "_"), record, rows)
    log(f"  {name}: {len(content['cells'])} cells, {len(rows)} rows, {result['wall_s'] / 60:.1f} min")
    if commit:
        commit_state(folder, [Path(folder) / "chunks" / f"{name}.{ext}" for ext in ("json", "parquet")],
                     f"reproduction state: {unit.name} ({len(rows)} rows, {result['wall_s'] / 60:.0f} min)", log)
    shutil.rmtree(scratch, ignore_errors=True)
    return name


def _utc(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, timezone.utc).isoformat(timespec="seconds")


def _head() -> str | None:
    found = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_DIR, capture_output=True, text=True)
    return found.stdout.strip() or None


def commit_state(folder: Path, paths: list[Path], message: str, log=print, tries: int = 6) -> bool:
    """Commit ``paths`` (and only them) in the repository that holds ``folder``; retried while another git
    command holds the index. A failure is logged, never fatal: the files stay for the next commit."""
    repo = Path(folder).resolve()
    for attempt in range(tries):
        added = subprocess.run(["git", "add", "--", *map(str, paths)], cwd=repo, capture_output=True, text=True)
        unchanged = added.returncode == 0 and subprocess.run(
            ["git", "diff", "--cached", "--quiet", "--", *map(str, paths)], cwd=repo).returncode == 0
        done = unchanged or (added.returncode == 0 and subprocess.run(
            ["git", "commit", "-q", "-m", message, "--", *map(str, paths)], cwd=repo, capture_output=True,
            text=True).returncode == 0)
        if done:  # committed, or already committed as they are
            return True
        time.sleep(5 * (attempt + 1))
    log(f"gtsweep.reproduction: could not commit {len(paths)} state file(s) in {repo}; they stay for the next commit")
    return False


def collect(units: list[Unit], folder: Path, work: Path, plan: dict, commit: bool = False,
            until: float | None = None, log=print, extra: list[str] = ()) -> int:
    """Run every unit the state in ``folder`` does not hold yet, in order, until ``until`` (epoch seconds: no
    unit starts after it); returns how many ran. ``work`` may be relative (to this process's directory)."""
    work = Path(work).resolve()  # the sweeps run in their own directories: a relative path would move there
    states.write_plan(folder, plan)
    if commit:
        commit_state(folder, [Path(folder) / "plan.json"], "reproduction state: the plan", log)
    ran = 0
    for unit in units:
        if unit.name in done_units(folder):
            continue
        if until is not None and time.time() >= until:
            log(f"gtsweep.reproduction: stopping before {unit.name} (time is up); the same command resumes")
            break
        run_unit(unit, folder, work, states.cell_records(folder), commit, log, extra)
        ran += 1
    return ran
