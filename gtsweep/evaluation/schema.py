"""The metric contract, declared once: every column of a sweep's per-view rows and how a cell aggregates it.

Per-view rows (:mod:`gtsweep.evaluation.evaluate`, each kind's tasks) hold the :data:`META` columns and metrics.
Everything downstream reads this module: the cell summaries and ``results.csv``
(:func:`gtsweep.orchestration.results.summarize`), MLflow, the report and the terminal summary. A column that is
not declared here is an error, so a new metric needs only its :class:`Metric` entry (and a derived one only that:
give it ``per_view``). Which metrics an experiment kind's rows hold, its headline, curves and step are its entry's
(:class:`Rows`, declared here by the experiment registry): this module names no kind.

Aggregations over a cell's views (or the views of one step):

- ``mean``: mean of the finite per-view values (NaN, e.g. ambiguity when nothing repeats, is skipped);
- ``ratio``: pooled over views, Σ numerator / Σ denominator of the two columns in ``of``;
- ``rate``: share of views with outcome 1 among the views with a 0/1 outcome.

Metrics with an ``interval`` also get a 95 % interval over the cell's views (``<name>_ci_low``/``_ci_high`` in the
summary, results.csv and MLflow; :mod:`gtsweep.evaluation.statistics`): Wilson for rates, a seeded bootstrap over
views for means and pooled ratios (resampling views, so a ratio keeps its numerator and denominator together).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping

import numpy as np
import pandas as pd

from gtsweep.core.errors import GtsweepError

#: Columns that identify a view (not aggregated); the cell CSV keeps its transform too, so each row names its
#: texture, transform and strength (the report's breakdowns, gtsweep.report.breakdown). Synthetic views have a
#: strength, pairs NaN; reference_count is the number of reference keypoints kept (survey Table 7), NaN without
#: experiment.reference_counts; rotation is a pair's ground-truth rotation in degrees (0-180; synthetic views have
#: none: report/rotation.py). A kind's own identity columns follow (:attr:`Rows.meta`, added as it is declared).
META = ["view", "image", "texture", "transform", "strength", "rotation", "reference_count"]
#: Meta columns a cell is also aggregated per value of (``by_<step>`` in the summary, ``<metric>_vs_<step>``); a
#: kind's :attr:`Rows.step` is added as it is declared.
STEP_KEYS = ["strength", "reference_count"]
AGGREGATIONS = ("mean", "ratio", "rate")
SCHEMA_FILE = "gtsweep/evaluation/schema.py"


@dataclass(frozen=True)
class Metric:
    """One per-view column and its cell aggregate."""

    name: str
    unit: str
    description: str  # one line, citing the survey section
    aggregation: str = "mean"
    reported: bool = True  # shown in the report's per-cell table
    per_view: Callable[[pd.DataFrame], pd.Series] | None = None  # derived from other per-view columns
    of: tuple[str, str] | None = None  # (numerator, denominator) columns of a ratio
    digits: int = 2  # decimals in the report
    interval: bool = False  # a 95 % interval over views (Wilson for a rate, bootstrap otherwise)

    @property
    def bounded(self) -> bool:
        """Values lie in [0, 1]."""
        return self.unit == "share"


def _declare(*metrics: Metric) -> dict[str, Metric]:
    return {m.name: m for m in metrics}


METRICS: dict[str, Metric] = _declare(
    Metric("repeatability", "share", "test keypoints with a reference keypoint of IoU > 0.5 (survey 4.1)",
           interval=True),
    Metric("ambiguity", "matches", "mean number of reference matches of a repeated test keypoint (4.1)",
           interval=True),
    Metric("few_keypoints", "share", "views with fewer than N test keypoints, '< N KPs' (survey 4.1)",
           aggregation="rate", interval=True),
    Metric("n_detected", "keypoints", "test keypoints found by the detector before selection (survey Table 2)",
           digits=0),
    Metric("n_kp_test", "keypoints", "test keypoints after selection (survey 2.2)", digits=0),
    Metric("n_kp_ref", "keypoints", "reference keypoints after selection (survey 2.2)", reported=False),
    Metric("n_test_valid", "keypoints", "test keypoints inside both masks (survey 4)", reported=False),
    Metric("n_ref_valid", "keypoints", "reference keypoints inside both masks (survey 4)", reported=False),
    Metric("n_repeated", "keypoints", "test keypoints that repeat, repeatability's numerator (4.1)",
           reported=False),
    Metric("n_described_ref", "keypoints", "reference keypoints the descriptor kept (survey 2.3)",
           reported=False),
    Metric("n_described_test", "keypoints", "test keypoints the descriptor kept (survey 2.3)",
           reported=False),
    Metric("n_matches", "matches", "matches passing the ratio test 0.7 (survey 5)", digits=1),
    Metric("n_correct", "matches", "number of correct matches, IoU > 0.5 (survey 4.2)", digits=1,
           interval=True),
    Metric("precision", "share", "correct / all matches, pooled over views: the survey's ratio (4.2)",
           aggregation="ratio", of=("n_correct", "n_matches"), interval=True),
    Metric("precision_per_view", "share", "mean of the views' correct / all matches (views with matches)",
           per_view=lambda rows: rows["precision"], interval=True),
    Metric("pose_success", "share", "success rate: position error < 30 px, orientation < 1.5 deg (4.3)",
           aggregation="rate", interval=True),
    Metric("position_error", "px", "distance of the estimated to the true position (survey 4.3)", digits=1,
           interval=True),
    Metric("orientation_error", "deg", "orientation error of the estimated pose (survey 4.3)",
           interval=True),
    Metric("n_inliers", "matches", "RANSAC inliers of the estimated pose (survey 5)", digits=1),
    Metric("t_detect", "s", "detection and selection time of the test image (survey Table 3)", digits=3),
    Metric("t_describe", "s", "description time of reference and test image (not in the survey; a call that "
           "described several detectors' keypoints, DAISY's, counts its equal share)", digits=3),
    Metric("t_match", "s", "matching time (not in the survey)", digits=3),
    Metric("t_pose", "s", "pose estimation time (not in the survey)", digits=3),
)


def _check(metric: Metric) -> Metric:
    problems = []
    if metric.aggregation not in AGGREGATIONS:
        problems.append(f"aggregation {metric.aggregation!r} is not one of {', '.join(AGGREGATIONS)}")
    if (metric.aggregation == "ratio") != (metric.of is not None):
        problems.append("a ratio needs of=(numerator, denominator), and only a ratio has it")
    if metric.name in META or "_vs_" in metric.name:
        problems.append("the name is a meta column or contains '_vs_'")
    if problems:
        raise GtsweepError(f"metric '{metric.name}' in {SCHEMA_FILE}: {'; '.join(problems)}")
    return metric


for _metric in METRICS.values():
    _check(_metric)
#: The metrics the evaluation computes (:mod:`gtsweep.evaluation.evaluate`), declared above; a kind's own metrics
#: are declared with its rows (:class:`Rows`).
EVALUATED = tuple(METRICS)


@dataclass(frozen=True)
class Rows:
    """What an experiment kind's per-view rows hold, as its entry declares it (``gtsweep.experiments``): its
    metrics (names declared here, or its own :class:`Metric` entries), the headline metric the terminal summary
    and the multirun summary show, the curves drawn against the transform strength, its own identity columns
    (``meta``), and ``step``: a meta column each view is repeated once per value of (each query against every
    map size), whose largest value the cell's aggregates (and intervals) are taken at, so each view counts once
    (every value is in ``by_<step>``). ``recognizes(summary)``: a summary written before cells recorded their
    kind is of this kind (None: never)."""

    metrics: tuple[Metric | str, ...]
    headline: str
    curves: tuple[str, ...] = ()
    meta: tuple[str, ...] = ()
    step: str | None = None
    recognizes: Callable[[Mapping], bool] | None = None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m if isinstance(m, str) else m.name for m in self.metrics)


#: The rows of every experiment kind, by its name: filled by the experiment registry (``gtsweep.experiments``) as
#: each kind is registered, and read by the engine and the report, which name no kind.
ROWS: dict[str, Rows] = {}


def register(metric: Metric) -> None:
    """Declare one more metric (a kind's, or a test's); its name must be new."""
    if metric.name in METRICS:
        raise GtsweepError(f"metric '{metric.name}' is already declared in {SCHEMA_FILE}")
    METRICS[_check(metric).name] = metric


def unregister(name: str) -> None:
    METRICS.pop(name, None)


def declare_rows(kind: str, rows: Rows) -> None:
    """Declare the rows of experiment kind ``kind``: its own metrics, meta columns and step join the schema. The
    experiment registry calls this once per kind (a plug-in's too)."""
    if kind in ROWS:
        raise GtsweepError(f"the rows of experiment '{kind}' are already declared")
    own = [m for m in rows.metrics if not isinstance(m, str) and METRICS.get(m.name) is not m]
    for metric in own:
        register(metric)
    undeclared = [name for name in (*rows.names, rows.headline, *rows.curves) if name not in METRICS]
    if undeclared:
        for metric in own:
            unregister(metric.name)
        raise GtsweepError(f"experiment '{kind}': metric(s) {', '.join(undeclared)} not declared in {SCHEMA_FILE}")
    META.extend(c for c in (*rows.meta, *([rows.step] if rows.step else [])) if c not in META)
    if rows.step and rows.step not in STEP_KEYS:
        STEP_KEYS.append(rows.step)
    ROWS[kind] = rows


def forget_rows(kind: str) -> None:
    """Undo :func:`declare_rows` (a plug-in's entry removed, e.g. after a test)."""
    rows = ROWS.pop(kind, None)
    if rows is None:
        return
    for metric in rows.metrics:
        if not isinstance(metric, str) and not any(metric.name in other.names for other in ROWS.values()):
            unregister(metric.name)


def rows_of(experiment: str) -> Rows:
    """The declared rows of an experiment kind; one line for a kind no entry has registered."""
    try:
        return ROWS[experiment]
    except (KeyError, TypeError):
        raise GtsweepError(f"experiment kind {experiment!r} is not registered (registered: {', '.join(ROWS)}); "
                           "its entry registers it (gtsweep.experiments)") from None


def metrics_of(experiment: str | None) -> list[Metric]:
    """The metrics of an experiment's rows in schema order (every metric for None)."""
    if experiment is None:
        return list(METRICS.values())
    names = set(rows_of(experiment).names)
    return [m for m in METRICS.values() if m.name in names]


def headline(experiment: str) -> str:
    return rows_of(experiment).headline


def curves(experiment: str) -> tuple[str, ...]:
    """The metrics of an experiment drawn against the transform strength (report plots, MLflow figures)."""
    return rows_of(experiment).curves


def experiment_of(summary: Mapping) -> str | None:
    """A cell summary's experiment kind: the one it recorded, else the first kind that recognizes it (a summary
    written before cells recorded their kind)."""
    if summary.get("experiment") in ROWS:
        return summary["experiment"]
    return next((kind for kind, rows in ROWS.items() if rows.recognizes and rows.recognizes(summary)),
                summary.get("experiment"))


def series_name(metric: str, step: str) -> str:
    """The MLflow series of a metric against a step key: ``pose_success_vs_strength``."""
    return f"{metric}_vs_{step}"


def parse_series(name: str) -> tuple[str, str] | None:
    """``(metric, step)`` of a series name (see :func:`series_name`), else None."""
    metric, sep, step = name.partition("_vs_")
    return (metric, step) if sep and step in STEP_KEYS else None


def ordered(names: Iterable[str]) -> list[str]:
    """Metric names in schema order; names no longer declared (older results) follow, sorted."""
    names = set(names)
    return [m for m in METRICS if m in names] + sorted(names - set(METRICS))


def with_derived(rows: pd.DataFrame, experiment: str | None = None) -> pd.DataFrame:
    """``rows`` plus the derived (``per_view``) metrics whose input columns are present."""
    derived = {}
    for metric in metrics_of(experiment):
        compute = metric.per_view
        if compute is None and metric.of and metric.name not in rows:  # a ratio's per-view value
            compute = lambda r, num=metric.of[0], den=metric.of[1]: r[num] / r[den]  # noqa: E731
        if compute is not None:
            try:
                derived[metric.name] = compute(rows)
            except KeyError:  # an input column is missing: so is the metric
                continue
    return rows.assign(**derived) if derived else rows


def check_columns(columns: Iterable[str], experiment: str | None) -> None:
    """Raise :class:`GtsweepError` naming every column that is not declared for ``experiment``."""
    declared = {*META, *(m.name for m in metrics_of(experiment))}
    unknown = [c for c in columns if c not in declared]
    if unknown:
        scope = f" for the {experiment} experiment" if experiment else ""
        raise GtsweepError(f"column(s) {', '.join(map(repr, unknown))} of the per-view rows not declared{scope} "
                           f"in {SCHEMA_FILE}; add a Metric entry there")


def _numbers(values: pd.Series) -> pd.Series:
    return pd.to_numeric(values, errors="coerce").astype(float)


def headline_rows(rows: pd.DataFrame, experiment: str | None) -> pd.DataFrame:
    """The rows a cell's aggregates are taken over: all, or those of the largest :attr:`Rows.step` value per
    texture (each floor's own largest map: a real data set's floors have maps of different sizes)."""
    step = ROWS[experiment].step if experiment in ROWS else None
    if step is None or step not in rows or not rows[step].notna().any():
        return rows
    values = _numbers(rows[step])
    largest = values.groupby(rows["texture"]).transform("max") if "texture" in rows else values.max()
    return rows[values == largest]


def as_floats(values: pd.Series) -> np.ndarray:
    """:func:`_numbers` as a float64 NumPy array (a float64 column as it is, without a copy; another NumPy number
    column converted directly, as :func:`_numbers` would)."""
    if values.dtype == np.float64:
        return values.to_numpy()
    if isinstance(values.dtype, np.dtype) and values.dtype.kind in "biuf":
        return values.to_numpy(dtype=np.float64)
    return _numbers(values).to_numpy(dtype=np.float64)


def aggregate(metric: Metric, rows: pd.DataFrame) -> float:
    """The metric over ``rows`` (a cell's views, or one step's) by its aggregation."""
    if metric.aggregation == "ratio":
        num, den = (as_floats(rows[c]) for c in metric.of)
        keep = np.isfinite(num) & np.isfinite(den)
        total = den[keep].sum()
        return float(num[keep].sum() / total) if total else math.nan
    values = as_floats(rows[metric.name])
    values = values[np.isfinite(values)]
    if metric.aggregation == "rate" and not np.isin(values, (0.0, 1.0)).all():
        raise GtsweepError(f"metric '{metric.name}' is a rate in {SCHEMA_FILE} but has values other than 0 and 1")
    return float(values.mean()) if len(values) else math.nan


def aggregable(metric: Metric, rows: pd.DataFrame) -> bool:
    """The columns ``metric`` aggregates are in ``rows``."""
    return all(c in rows for c in (metric.of or (metric.name,)))


def interval(metric: Metric, rows: pd.DataFrame, seed: int = 0) -> tuple[float, float]:
    """The metric's 95 % interval over ``rows`` (views): Wilson for a rate, a seeded bootstrap for a mean, a
    paired bootstrap of Σ numerator / Σ denominator for a pooled ratio."""
    from gtsweep.evaluation import statistics

    if metric.aggregation == "rate":
        values = as_floats(rows[metric.name])
        values = values[np.isfinite(values)]
        return statistics.wilson_interval(int(values.sum()), len(values))
    if metric.aggregation == "ratio":
        num, den = (as_floats(rows[c]) for c in metric.of)
        keep = np.isfinite(num) & np.isfinite(den)
        return statistics.ratio_interval(num[keep], den[keep], seed=seed)
    return statistics.bootstrap_interval(as_floats(rows[metric.name]), seed=seed)
