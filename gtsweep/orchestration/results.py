"""Result files of a sweep, written as each cell finishes, and the aggregates the survey reports.

Layout of a sweep's output directory::

    cells/<cell>.csv     per-view rows of one cell
    cells/<cell>.json    the cell's summary; written last, so its presence marks the cell complete
    results.csv          one row per cell (written when the sweep ends)

A cell whose ``.json`` exists with the same configuration hash is complete: a resumed sweep keeps it.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.core.atomic import write_atomically

#: Metrics averaged over a cell's rows (survey section 4); missing ones are skipped.
METRICS = ("repeatability", "ambiguity", "few_keypoints", "n_detected", "n_kp_test", "n_matches", "n_correct",
           "precision", "pose_success", "position_error", "orientation_error", "n_inliers",
           "t_detect", "t_describe", "t_match", "t_pose")
STEP_KEYS = ("strength", "reference_count")


def _mean(values: pd.Series) -> float:
    values = pd.to_numeric(values, errors="coerce").astype(float)
    values = values[np.isfinite(values)]
    return float(values.mean()) if len(values) else math.nan


def summarize(rows: pd.DataFrame) -> dict:
    """Means of every metric over a cell's rows, plus the means per step (transform strength, reference count)."""
    summary = {"n_rows": int(len(rows)),
               "metrics": {m: _mean(rows[m]) for m in METRICS if m in rows}}
    summary["n_images"] = int(rows["image"].nunique()) if "image" in rows else 0
    for step in STEP_KEYS:
        if step in rows and rows[step].notna().any():
            summary[f"by_{step}"] = {
                repr(float(value)): {m: _mean(group[m]) for m in METRICS if m in group}
                for value, group in rows.groupby(step, sort=True)
            }
    return summary


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


class ResultStore:
    """The result files of one sweep in ``directory``."""

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.cells_dir = self.directory / "cells"

    def complete(self, key: str, cell_hash: str) -> dict | None:
        """The summary of a finished cell with this configuration hash, else None."""
        path = self.cells_dir / f"{key}.json"
        try:
            summary = json.loads(path.read_text())
        except (FileNotFoundError, ValueError):
            return None
        return summary if summary.get("hash") == cell_hash else None

    def write_cell(self, key: str, summary: dict, rows: pd.DataFrame | None) -> None:
        """Write a cell's rows, then its summary (the completion marker)."""
        if rows is not None:
            write_atomically(self.cells_dir / f"{key}.csv", rows.to_csv(index=False))
        write_atomically(self.cells_dir / f"{key}.json", json.dumps(_json_safe(summary), indent=1, sort_keys=True))

    def rows(self, key: str) -> pd.DataFrame:
        path = self.cells_dir / f"{key}.csv"
        return pd.read_csv(path) if path.exists() else pd.DataFrame()

    def write_table(self, summaries: list[dict]) -> Path:
        """``results.csv``: one row per cell with its methods, status and mean metrics."""
        table = summary_table(summaries)
        path = self.directory / "results.csv"
        write_atomically(path, table.to_csv(index=False))
        return path


def summary_table(summaries: list[dict]) -> pd.DataFrame:
    """One row per cell: detector, selector, descriptor, transform, status, reason and the mean metrics."""
    records = []
    for s in summaries:
        record = {**s["methods"], "status": s["status"], "reason": s.get("reason") or ""}
        record.update({m: v for m, v in (s.get("metrics") or {}).items()})
        records.append(record)
    return pd.DataFrame.from_records(records)
