"""The per-view rows behind a table entry, its interval, and paired tests between entries.

A table entry (one number of a survey table) is made of one or more cells, e.g. a pairing on every synthetic
transform (survey Table 6 averages over transforms with equal weight). Its value is, per stratum (transform; and
repeat in a multirun), the cell's aggregate over its views, then the mean over strata; its interval and the
paired tests between entries come from the cells' per-view rows (``cells/<cell>.csv``, or the child runs'
artifacts in MLflow) with :mod:`gtsweep.evaluation.statistics`, over whole images (clusters:
texture + image or pair id), never by averaging intervals. Two entries are matched on the images both have.

An entry's interval is over images, from its cells' per-view rows
(:func:`~gtsweep.evaluation.statistics.clustered_interval`: a t interval; for a rate a design-effect Wilson
interval, one formula for every rate including 0 and 1, Wilson's own with one view per pair); an entry of one
cell without per-view rows shows the cell's own ``<metric>_ci_low/_ci_high`` (results.csv, MLflow); else none.
Paired tests are t tests over images; the ties of a table are Holm-corrected across the table's entries.
"""
from __future__ import annotations

import math
import re
import zlib
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


def half_of(image: str, texture_rank: int = 0) -> int:
    """0 or 1: which half of the images an image (``texture/.../k``) belongs to: the parity of k plus its texture's
    rank among the data set's textures (sorted by name). Stable when images are added, balanced within each
    texture, and with one image per texture the textures alternate (3 + 3 of the survey's six). A rival or "best"
    picked from the data is picked on half 0 and tested on half 1 (docs/statistics_design.md)."""
    digits = re.findall(r"\d+", str(image))
    number = int(digits[-1]) if digits else zlib.crc32(str(image).encode())
    return (number + texture_rank) % 2


def textures_of(views: Views | None) -> list[str]:
    """The data set's textures (sorted by name): those of every cell's per-view rows."""
    found = (map(str, v["texture"].unique()) for v in (views or {}).values() if "texture" in v)
    return sorted(set().union(*found))


def _halves(rows: pd.DataFrame, textures: list[str] | None) -> np.ndarray:
    """:func:`half_of` of each row, its texture ranked among ``textures`` (the data set's, so that an image is in
    the same half in every entry, also where a cell has no rows of some texture); None: the rows' own."""
    names, images = rows["texture"].astype(str), rows["image"].astype(str)
    known = list(textures) if textures else []
    rank = {t: i for i, t in enumerate(known + sorted(set(names.unique()) - set(known)))}
    codes, clusters = pd.factorize(names + "\0" + images)  # once per image, not per view
    halves = [half_of(image, rank[texture]) for texture, image in (c.split("\0", 1) for c in clusters)]
    return np.asarray(halves, dtype=int)[codes] if len(codes) else np.zeros(0, dtype=int)


def in_half(rows: pd.DataFrame, half, textures: list[str] | None = None) -> np.ndarray:
    """Which rows belong to ``half``: 0 or 1 (:func:`half_of`), or a test set defined on the halves, a callable
    ``(rows, halves) -> mask`` (e.g. one half of the first images plus every later image)."""
    halves = _halves(rows, textures)
    return np.asarray(half(rows, halves), dtype=bool) if callable(half) else halves == half


def _long(cells: pd.DataFrame, metric: str, views: Views, where: Mapping | None,
          half: int | None = None, textures: list[str] | None = None) -> pd.DataFrame | None:
    """Columns cluster, stratum, sum, count of an entry's views (None when a cell's rows are missing); with
    ``half``, only that half's clusters (:func:`half_of`, textures ranked among ``textures``:
    :func:`textures_of`)."""
    declared = schema.METRICS[metric]
    needed = declared.of or (metric,)
    keys = cells["key"] if "key" in cells else [None] * len(cells)
    parts = []
    for key, transform in zip(keys, cells["transform"]):
        rows = views.get(key)
        if rows is None or rows.empty:
            return None
        if not all(c in rows for c in needed):  # a derived metric: computed from its input columns
            rows = schema.with_derived(rows)
        for column, value in (where or {}).items():
            rows = rows[np.isclose(pd.to_numeric(rows[column], errors="coerce"), value)]
        if not schema.aggregable(declared, rows) or not all(c in rows for c in CLUSTER):
            return None
        num, den = (schema.as_floats(rows[c]) for c in declared.of) if declared.of else \
            (schema.as_floats(rows[metric]), np.ones(len(rows)))
        keep = np.isfinite(num) & np.isfinite(den)
        repeat = rows["repeat"].astype(str).to_numpy(object) if "repeat" in rows else np.full(len(rows), "", object)
        part = {"cluster": (rows["texture"].astype(str) + "/" + rows["image"].astype(str)).to_numpy(object),
                "stratum": f"{transform}|" + repeat, "sum": np.where(keep, num, 0.0),
                "count": np.where(keep, den, 0.0)}
        if half is not None:
            chosen = in_half(rows, half, textures)
            part = {name: column[chosen] for name, column in part.items()}
        parts.append(part)
    if not parts:
        return None
    return pd.DataFrame({name: np.concatenate([part[name] for part in parts]) for name in parts[0]})


def _matrices(long: pd.DataFrame, clusters=None, strata=None) -> tuple[np.ndarray, np.ndarray]:
    """(sums, counts), ``clusters`` x ``strata`` (default: every one, sorted): each view's sum and count added
    into its cell; views of a cluster or stratum not listed are left out."""
    clusters = sorted(long["cluster"].unique()) if clusters is None else clusters
    strata = sorted(long["stratum"].unique()) if strata is None else strata
    row = pd.Index(clusters).get_indexer(long["cluster"])
    column = pd.Index(strata).get_indexer(long["stratum"])
    listed = (row >= 0) & (column >= 0)
    flat = row[listed] * len(strata) + column[listed]
    shape = (len(clusters), len(strata))
    total = lambda name: np.bincount(flat, weights=long[name].to_numpy(float)[listed],  # noqa: E731
                                     minlength=shape[0] * shape[1]).reshape(shape)
    return total("sum"), total("count")


def matrices(cells: pd.DataFrame, metric: str, views: Views | None, where: Mapping | None = None,
             half: int | None = None, textures: list[str] | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """(sums, counts), clusters x strata, of an entry's per-view rows; None without them."""
    if not views or metric not in schema.METRICS or not len(cells):
        return None
    long = _long(cells, metric, views, where, half, textures)
    return None if long is None or long.empty else _matrices(long)


def estimate(cells: pd.DataFrame, metric: str, views: Views | None, where: Mapping | None = None,
             half: int | None = None, confidence: float = statistics.CONFIDENCE,
             textures: list[str] | None = None) -> tuple[float, float, float]:
    """``(value, low, high)`` of an entry made of ``cells`` (rows of :func:`~gtsweep.report.tables.frame`):
    from the per-view rows when every cell has them (:func:`~gtsweep.evaluation.statistics.clustered_interval`:
    a t interval over images, a design-effect Wilson interval for a rate), else a one-cell entry's own interval,
    else none."""
    declared = schema.METRICS.get(metric)
    own = len(cells) == 1 and where is None and half is None and f"{metric}_ci_low" in cells
    long = _long(cells, metric, views, where, half, textures) if views and declared is not None and len(cells) else None
    if long is not None and not long.empty:
        sums, counts = _matrices(long)
        value = statistics.clustered_mean(sums, counts)
        if not declared.interval:
            return value, math.nan, math.nan
        return (value, *statistics.clustered_interval(sums, counts, confidence, declared.aggregation == "rate"))
    values = pd.to_numeric(cells[metric], errors="coerce") if metric in cells else pd.Series(dtype=float)
    value = float(values.mean()) if values.notna().any() else math.nan
    if own:
        low, high = (pd.to_numeric(cells[f"{metric}_ci_{s}"], errors="coerce").iloc[0] for s in ("low", "high"))
        return value, float(low), float(high)
    return value, math.nan, math.nan


def compare(a: pd.DataFrame, b: pd.DataFrame, metric: str, views: Views | None, where: Mapping | None = None,
            where_b: Mapping | None = None, half: int | None = None,
            confidence: float = statistics.CONFIDENCE,
            textures: list[str] | None = None) -> statistics.Comparison | None:
    """Paired test of entry A against entry B on the images (pairs) both have: the paired t over images of
    :func:`~gtsweep.evaluation.statistics.clustered_difference` (one method for rates, means and ratios). None
    without per-view rows. ``where`` selects A's views (and B's, unless ``where_b`` does), e.g. a reference
    feature count; ``half`` restricts both to one half of the images (:func:`half_of`; ``textures``: the data
    set's, :func:`textures_of`)."""
    if not views or metric not in schema.METRICS:
        return None
    long_a = _long(a, metric, views, where, half, textures)
    long_b = _long(b, metric, views, where if where_b is None else where_b, half, textures)
    if long_a is None or long_b is None:
        return None
    clusters = sorted(set(long_a["cluster"]) & set(long_b["cluster"]))
    strata = sorted(set(long_a["stratum"]) | set(long_b["stratum"]))
    if not clusters:
        return None
    (sa, ca), (sb, cb) = _matrices(long_a, clusters, strata), _matrices(long_b, clusters, strata)
    return statistics.clustered_difference(sa, ca, sb, cb, confidence, schema.METRICS[metric].aggregation == "rate")


def against(cells: pd.DataFrame, metric: str, views: Views | None, target: float, where: Mapping | None = None,
            confidence: float = statistics.CONFIDENCE) -> statistics.Comparison | None:
    """An entry against a fixed number (e.g. the survey's "about 1.5"): value - ``target`` with the entry's
    cluster-robust SE and a t test; None without per-view rows."""
    pair = matrices(cells, metric, views, where)
    if pair is None:
        return None
    e = statistics.clustered_estimate(*pair)
    if e.n < 2:
        return None
    return statistics.from_estimate("t over images", e.value, e.se, e.df, e.n, confidence, target)


def rate_within(cells: pd.DataFrame, metric: str, views: Views | None, band: tuple[float, float],
                confidence: float) -> statistics.Comparison | None:
    """A rate against a band ``[low, high]`` (e.g. the survey's "about 10 % to 15 %"): the Comparison's interval
    is the rate's design-effect Wilson interval at ``confidence`` minus the band's centre, so that its decision
    is by interval (no SE: a rate of 0 has none)."""
    pair = matrices(cells, metric, views)
    if pair is None:
        return None
    value = statistics.clustered_mean(*pair)
    low, high = statistics.clustered_interval(*pair, confidence, rate=True)
    centre = (band[0] + band[1]) / 2
    n = int((pair[1].sum(axis=1) > 0).sum())
    return statistics.Comparison("design-effect Wilson interval", value - centre, math.nan, low - centre,
                                 high - centre, n=n)


@dataclass
class Ties:
    """The entries of a table statistically tied with its best: the paired test of each against the best
    (:func:`compare`), Holm-corrected across the table's list (family-wise error ``alpha``), is not significant.
    The best is the table's descriptive best on the same images, so the list says "the data cannot rank these
    below the best", never "these are as good"."""

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
        return (f"best {self.metric}: {self.best} {self.best_value:.2f}; {tied} (paired t vs the best, Holm over "
                f"{len(self.tests)} tests, alpha = {self.alpha:g})")


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
    labels = list(ties.tests)
    adjusted = statistics.holm([ties.tests[k].p_value if math.isfinite(ties.tests[k].p_value) else 1.0
                                for k in labels])
    ties.tied = [k for k, p in zip(labels, adjusted) if not (p < alpha and ties.tests[k].difference != 0)]
    return ties
