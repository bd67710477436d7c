"""Result files of a sweep, written as each cell finishes, and the aggregates the survey reports.

Layout of a sweep's output directory::

    cells/<cell>.csv     per-view rows of one cell
    cells/<cell>.json    the cell's summary; written last, so its presence marks the cell complete
    reuse/<cell>.json    which images or pairs the cell's rows cover, for reuse on a grown data set
                         (:mod:`gtsweep.orchestration.view_reuse`)
    results.csv          one row per cell (written when the sweep ends)

A cell whose ``.json`` exists with the same configuration hash and did not fail is complete: a resumed sweep
keeps it (a failed cell is computed again). A cell whose hash changed only because the data set grew keeps the
rows of the images or pairs it already evaluated (:mod:`gtsweep.orchestration.view_reuse`).
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pandas as pd

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.rundirs import CELLS, RESULTS
from gtsweep.evaluation import schema


def summarize(rows: pd.DataFrame, experiment: str | None) -> dict:
    """A cell's aggregates by the schema (:mod:`gtsweep.evaluation.schema`), overall and per step value.

    Overall means over every row, except for an experiment whose rows repeat each view per step value (its
    :attr:`~gtsweep.evaluation.schema.Rows.step`, e.g. one row per query and map size): there the overall aggregates
    and intervals are those of the step's largest value (each view once), the others in ``by_<step>``.

    Derived metrics are computed first; a column the schema does not declare for ``experiment`` (None: any
    experiment) raises :class:`~gtsweep.core.errors.GtsweepError`. Declared metrics absent from ``rows`` are skipped.
    """
    rows = schema.with_derived(rows, experiment)
    schema.check_columns(rows.columns, experiment)
    metrics = [m for m in schema.metrics_of(experiment) if schema.aggregable(m, rows)]

    def aggregates(part: pd.DataFrame) -> dict:
        return {m.name: schema.aggregate(m, part) for m in metrics}

    headline = schema.headline_rows(rows, experiment)  # localization: the largest map, each query once
    summary = {"n_rows": int(len(rows)), "metrics": aggregates(headline)}
    for metric in metrics:
        if metric.interval:
            low, high = schema.interval(metric, headline)
            summary["metrics"][f"{metric.name}_ci_low"], summary["metrics"][f"{metric.name}_ci_high"] = low, high
    summary["n_images"] = int(headline["image"].nunique()) if "image" in headline else 0
    summary["n_views"] = int(headline["view"].nunique()) if "view" in headline else int(len(headline))  # pairs
    for step in schema.STEP_KEYS:
        if step in rows and rows[step].notna().any():
            summary[f"by_{step}"] = {repr(float(value)): aggregates(group)
                                     for value, group in rows.groupby(step, sort=True)}
    return summary


def stored_rows(rows: pd.DataFrame, summary: dict) -> pd.DataFrame:
    """A cell's rows as its CSV holds them: with the derived metrics and a ``transform`` column."""
    rows = schema.with_derived(rows, summary.get("experiment"))
    transform = (summary.get("methods") or {}).get("transform")
    if transform and "transform" not in rows and "texture" in rows:  # each row names its transform
        rows.insert(rows.columns.get_loc("texture") + 1, "transform", transform)
    return rows


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
        self.cells_dir = self.directory / CELLS

    def complete(self, key: str, cell_hash: str) -> dict | None:
        """The summary of a finished cell (ok or na) with this configuration hash, else None."""
        path = self.cells_dir / f"{key}.json"
        try:
            summary = json.loads(path.read_text())
        except (FileNotFoundError, ValueError):
            return None
        return summary if summary.get("hash") == cell_hash and summary.get("status") != "error" else None

    def write_cell(self, key: str, summary: dict, rows: pd.DataFrame | None, coverage: dict | None = None) -> None:
        """Write a cell's rows (with the derived metrics) and what they cover (``coverage``, for reuse), then its
        summary (the completion marker)."""
        if rows is not None:
            rows = stored_rows(rows, summary)
            write_atomically(self.cells_dir / f"{key}.csv", rows.to_csv(index=False))
        if coverage is not None:
            write_atomically(self.reuse_dir / f"{key}.json", json.dumps(coverage, sort_keys=True))
        write_atomically(self.cells_dir / f"{key}.json", json.dumps(_json_safe(summary), indent=1, sort_keys=True))

    @property
    def reuse_dir(self) -> Path:
        return self.directory / "reuse"

    def rows(self, key: str) -> pd.DataFrame:
        """A cell's stored rows (pandas reads every float back exactly as written)."""
        path = self.cells_dir / f"{key}.csv"
        return pd.read_csv(path) if path.exists() else pd.DataFrame()

    def coverage(self, key: str) -> dict | None:
        """What a finished, evaluated (status ok) cell's rows cover (:meth:`write_cell`), else None."""
        try:
            summary = json.loads((self.cells_dir / f"{key}.json").read_text())
            coverage = json.loads((self.reuse_dir / f"{key}.json").read_text())
        except (FileNotFoundError, ValueError):
            return None
        return coverage if summary.get("status") == "ok" and (self.cells_dir / f"{key}.csv").exists() else None

    def write_table(self, summaries: list[dict]) -> Path:
        """``results.csv``: one row per cell with its methods, status and mean metrics."""
        table = summary_table(summaries)
        path = self.directory / RESULTS
        write_atomically(path, table.to_csv(index=False))
        return path


#: Method columns beyond the survey's pairing: tables show them only when a sweep has several values of one.
VARIANT_COLUMNS = ("matcher", "estimator")


def swept_variants(summaries: list[dict]) -> list[str]:
    """The variant columns (matcher, estimator) that take more than one value among ``summaries`` (a cell without
    one, e.g. a detection cell, does not count)."""
    return [k for k in VARIANT_COLUMNS if len({s["methods"].get(k) for s in summaries} - {None}) > 1]


def by_variant(summaries: list[dict]) -> dict[tuple, list[dict]]:
    """``summaries`` grouped by their swept (matcher, estimator) values, ``{((column, value), ...): [...]}``, in
    first-seen order; one group, keyed ``()``, when neither is swept. Cells without them (detection) share a group
    whose values are None."""
    swept = swept_variants(summaries)
    groups: dict[tuple, list[dict]] = {}
    for s in summaries:
        groups.setdefault(tuple((k, s["methods"].get(k)) for k in swept), []).append(s)
    return groups


def summary_table(summaries: list[dict]) -> pd.DataFrame:
    """One row per cell: its methods, status, reason, then its metrics in schema order.

    Metrics no longer declared (a summary written by an older version) follow, sorted.
    """
    records = [{**s["methods"], "status": s["status"], "reason": s.get("reason") or "", **(s.get("metrics") or {})}
               for s in summaries]
    table = pd.DataFrame.from_records(records)
    measured = {m for s in summaries for m in s.get("metrics") or {}}
    # fixed order: a kept cell's methods come back from its JSON sorted, a fresh one's in grid order
    first = [c for c in (*METHOD_GROUPS, "status", "reason") if c in table.columns]
    others = sorted(c for c in table.columns if c not in measured and c not in first)
    return table[first + others + schema.ordered(measured)]
