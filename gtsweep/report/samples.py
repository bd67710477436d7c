"""The per-view rows behind a table entry, its interval, and paired tests between entries.

A table entry (one number of a survey table) is made of one or more cells, e.g. a pairing on every synthetic
transform (survey Table 6 averages over transforms with equal weight). Its value is, per stratum (transform; and
repeat in a multirun), the cell's aggregate over its views, then the mean over strata; its interval and the
paired tests between entries come from the cells' per-view rows (``cells/<cell>.csv``, or the child runs'
artifacts in MLflow) with :mod:`gtsweep.evaluation.statistics`, resampling or swapping whole images (clusters:
texture + image or pair id), never by averaging intervals. Two entries are matched on the images both have.

An entry of one cell shows the cell's own ``<metric>_ci_low/_ci_high`` (the numbers of results.csv and MLflow:
Wilson for a rate, a bootstrap over views otherwise); an entry over several cells, strengths or repeats a Wilson
interval for a success rate with one view per pair, else the bootstrap over images (a rate of exactly 0 or 1
leaves a bootstrap nothing to resample: Wilson with one trial per image instead); without per-view rows no
interval.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.evaluation import schema, statistics

#: Per-view rows of each cell, by cell key (a multirun's rows carry a ``repeat`` column).
Views = Mapping[str, pd.DataFrame]
CLUSTER = ("texture", "image")


def load_views(source: str | Path) -> dict[str, pd.DataFrame]:
    """The per-view rows of a sweep's cells (``cells/<cell>.csv``) by cell key."""
    return {p.stem: pd.read_csv(p) for p in sorted(Path(source).glob("cells/*.csv"))}


def _long(cells: pd.DataFrame, metric: str, views: Views, where: Mapping | None) -> pd.DataFrame | None:
    """Columns cluster, stratum, sum, count of an entry's views (None when a cell's rows are missing)."""
    declared = schema.METRICS[metric]
    parts = []
    for cell in cells.itertuples(index=False):
        rows = views.get(getattr(cell, "key", None))
        if rows is None or rows.empty:
            return None
        rows = schema.with_derived(rows)
        for column, value in (where or {}).items():
            rows = rows[np.isclose(pd.to_numeric(rows[column], errors="coerce"), value)]
        if not schema.aggregable(declared, rows) or not all(c in rows for c in CLUSTER):
            return None
        if declared.of:
            num, den = (pd.to_numeric(rows[c], errors="coerce") for c in declared.of)
        else:
            num = pd.to_numeric(rows[metric], errors="coerce")
            den = pd.Series(1.0, index=rows.index)
        keep = np.isfinite(num) & np.isfinite(den)
        repeat = rows["repeat"].astype(str) if "repeat" in rows else ""
        parts.append(pd.DataFrame({"cluster": rows["texture"].astype(str) + "/" + rows["image"].astype(str),
                                   "stratum": f"{cell.transform}|" + repeat, "sum": num.where(keep, 0.0),
                                   "count": den.where(keep, 0.0)}))
    return pd.concat(parts, ignore_index=True) if parts else None


def _matrices(long: pd.DataFrame, clusters=None, strata=None) -> tuple[np.ndarray, np.ndarray]:
    table = long.pivot_table(index="cluster", columns="stratum", values=["sum", "count"], aggfunc="sum",
                             fill_value=0.0)
    clusters = sorted(long["cluster"].unique()) if clusters is None else clusters
    strata = sorted(long["stratum"].unique()) if strata is None else strata
    pick = lambda name: table[name].reindex(index=clusters, columns=strata, fill_value=0.0).to_numpy(float)
    return pick("sum"), pick("count")


def estimate(cells: pd.DataFrame, metric: str, views: Views | None, where: Mapping | None = None,
             seed: int = 0) -> tuple[float, float, float]:
    """``(value, low, high)`` of an entry made of ``cells`` (rows of :func:`~gtsweep.report.tables.frame`):
    from the per-view rows when every cell has them, else a one-cell entry's own interval, else none."""
    declared = schema.METRICS.get(metric)
    long = _long(cells, metric, views, where) if views and declared is not None and len(cells) else None
    own = len(cells) == 1 and where is None and f"{metric}_ci_low" in cells  # one cell: its own interval
    if long is not None and not (own and long["stratum"].nunique() == 1):
        sums, counts = _matrices(long)
        value = statistics.clustered_mean(sums, counts)
        if not declared.interval:
            return value, math.nan, math.nan
        if declared.aggregation == "rate" and sums.shape[1] == 1 and counts.max() <= 1:  # one view per pair
            return (value, *statistics.wilson_interval(int(sums.sum()), int(counts.sum())))
        if declared.aggregation == "rate" and value in (0.0, 1.0):  # no variation for a bootstrap to resample:
            clusters = int((counts.sum(axis=1) > 0).sum())  # Wilson with one trial per image (conservative)
            return (value, *statistics.wilson_interval(int(round(value * clusters)), clusters))
        return (value, *statistics.clustered_interval(sums, counts, seed=seed))
    values = pd.to_numeric(cells[metric], errors="coerce") if metric in cells else pd.Series(dtype=float)
    value = float(values.mean()) if values.notna().any() else math.nan
    if own:
        low, high = (pd.to_numeric(cells[f"{metric}_ci_{s}"], errors="coerce").iloc[0] for s in ("low", "high"))
        return value, float(low), float(high)
    return value, math.nan, math.nan


def compare(a: pd.DataFrame, b: pd.DataFrame, metric: str, views: Views | None, where: Mapping | None = None,
            where_b: Mapping | None = None, seed: int = 0) -> statistics.Comparison | None:
    """Paired test of entry A against entry B on the images both have: an exact McNemar test for a success rate
    with one view per pair on one transform (survey Tables 4, 5, 7), else a permutation test swapping A and B
    within images (:func:`~gtsweep.evaluation.statistics.clustered_difference`). None without per-view rows.
    ``where`` selects A's views (and B's, unless ``where_b`` does), e.g. a reference feature count."""
    if not views or metric not in schema.METRICS:
        return None
    long_a, long_b = _long(a, metric, views, where), _long(b, metric, views, where if where_b is None else where_b)
    if long_a is None or long_b is None:
        return None
    clusters = sorted(set(long_a["cluster"]) & set(long_b["cluster"]))
    strata = sorted(set(long_a["stratum"]) | set(long_b["stratum"]))
    if not clusters:
        return None
    (sa, ca), (sb, cb) = _matrices(long_a, clusters, strata), _matrices(long_b, clusters, strata)
    single = len(strata) == 1 and ca.max() <= 1 and cb.max() <= 1
    if schema.METRICS[metric].aggregation == "rate" and single:
        with np.errstate(invalid="ignore"):
            return statistics.mcnemar_exact(np.where(ca > 0, sa, np.nan)[:, 0], np.where(cb > 0, sb, np.nan)[:, 0])
    return statistics.clustered_difference(sa, ca, sb, cb, seed=seed)


@dataclass
class Ties:
    """The entries of a table statistically tied with its best: a paired test of each against the best at
    ``alpha`` (:func:`compare`) is not significant."""

    metric: str
    alpha: float
    best: str = ""
    best_value: float = math.nan
    tied: list[str] = field(default_factory=list)
    tests: dict[str, statistics.Comparison] = field(default_factory=dict)
    untested: list[str] = field(default_factory=list)  # entries without per-view rows

    def describe(self) -> str:
        if not self.best:
            return ""
        if not self.tests:
            why = "no per-view rows to test ties" if self.untested else "the only entry"
            return f"best {self.metric}: {self.best} {self.best_value:.2f}; {why}"
        apart = [label for label in self.tests if label not in self.tied]
        tied = f"{len(self.tied)} tied with it ({', '.join(self.tied)})" if self.tied else "none tied with it"
        if len(self.tied) > 8:  # a long list: name the few the test sets apart instead
            tied = f"{len(self.tied)} tied with it (all but {', '.join(apart)})" if apart else \
                f"all {len(self.tied)} others tied with it"
        return (f"best {self.metric}: {self.best} {self.best_value:.2f}; {tied} (paired test vs the best, "
                f"alpha = {self.alpha:g}; of {len(self.tests)} tested)")


def tied_with_best(entries: Mapping[str, pd.DataFrame], metric: str, views: Views | None, alpha: float,
                   higher: bool = True, where: Mapping | None = None) -> Ties:
    """Which of ``entries`` (label: its cells) tie with the best one on ``metric``."""
    ties = Ties(metric, alpha)
    values = {label: estimate(cells, metric, views, where)[0] for label, cells in entries.items()}
    values = {k: v for k, v in values.items() if math.isfinite(v)}
    if not values:
        return ties
    ties.best = (max if higher else min)(values, key=values.get)
    ties.best_value = values[ties.best]
    for label in values:
        if label == ties.best:
            continue
        result = compare(entries[label], entries[ties.best], metric, views, where)
        if result is None:
            ties.untested.append(label)
            continue
        ties.tests[label] = result
        if statistics.verdict(result, alpha) == statistics.INCONCLUSIVE:
            ties.tied.append(label)
    return ties
