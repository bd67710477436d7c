"""The metric contract, declared once: every column of a sweep's per-view rows and how a cell aggregates it.

Per-view rows (:mod:`gtsweep.evaluation.evaluate`, :mod:`gtsweep.orchestration.tasks`) hold the :data:`META`
columns and metrics. Everything downstream reads this module: the cell summaries and ``results.csv``
(:func:`gtsweep.orchestration.results.summarize`), MLflow, the report and the terminal summary. A column that is
not declared here is an error, so a new metric needs only its :class:`Metric` entry (and a derived one only that:
give it ``per_view``).

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

#: The experiments whose rows the schema describes, each extending the one before it.
EXPERIMENT_ROWS = ("detection", "matching", "pose", "localization")
#: Columns that identify a view (not aggregated); the cell CSV keeps its transform too, so each row names its
#: texture, transform and strength (the report's breakdowns, gtsweep.report.breakdown). Synthetic views have a
#: strength, pairs NaN; reference_count is the number of reference keypoints kept (survey Table 7), NaN without
#: experiment.reference_counts; rotation is a pair's ground-truth rotation in degrees (0-180; synthetic views have
#: none: report/rotation.py).
META = ("view", "image", "texture", "transform", "strength", "rotation", "reference_count")
#: Identity columns of a localization row (one per query and map size): the query image, whether its floor is in
#: the map (0: a foreign floor that must be rejected), the map's size, and the estimated pose in map coordinates
#: (map px of the query's centre; degrees, atan2(P[1, 0], P[0, 0]) of the image -> map pose; NaN when none).
LOCALIZATION_META = ("query", "in_map", "map_images", "est_x", "est_y", "est_theta")
META = META + LOCALIZATION_META
#: Meta columns a cell is also aggregated per value of (``by_<step>`` in the summary, ``<metric>_vs_<step>``).
STEP_KEYS = ("strength", "reference_count", "map_images")
#: Experiments whose rows repeat each view once per value of a step (localization: each query against every map
#: size): their cell aggregates (and intervals) are those of the largest step value, so each view counts once;
#: every value is in ``by_<step>``.
HEADLINE_STEP = {"localization": "map_images"}
#: The metric the terminal summary shows, per experiment.
HEADLINE = {"detection": "repeatability", "matching": "precision", "pose": "pose_success",
            "localization": "localization_success"}
#: Metrics drawn against the transform strength, per experiment (report plots).
CURVES = {"detection": ("repeatability",), "matching": ("precision",), "pose": ("pose_success", "precision"),
          "localization": ("localization_success", "t_query")}
AGGREGATIONS = ("mean", "ratio", "rate")
#: Experiment kinds added by :func:`add_experiment` (a plug-in's): their rows have only their own metrics.
STANDALONE: set[str] = set()
SCHEMA_FILE = "gtsweep/evaluation/schema.py"


@dataclass(frozen=True)
class Metric:
    """One per-view column and its cell aggregate."""

    name: str
    since: str  # the first experiment whose rows have it; the later ones have it too
    unit: str
    description: str  # one line, citing the survey section
    aggregation: str = "mean"
    reported: bool = True  # shown in the report's per-cell table
    per_view: Callable[[pd.DataFrame], pd.Series] | None = None  # derived from other per-view columns
    of: tuple[str, str] | None = None  # (numerator, denominator) columns of a ratio
    digits: int = 2  # decimals in the report
    interval: bool = False  # a 95 % interval over views (Wilson for a rate, bootstrap otherwise)

    @property
    def experiments(self) -> tuple[str, ...]:
        if self.since in STANDALONE:
            return (self.since,)
        return EXPERIMENT_ROWS[EXPERIMENT_ROWS.index(self.since):]

    @property
    def bounded(self) -> bool:
        """Values lie in [0, 1]."""
        return self.unit == "share"


def _declare(*metrics: Metric) -> dict[str, Metric]:
    return {m.name: m for m in metrics}


_DET, _MATCH, _POSE, _LOC = EXPERIMENT_ROWS
METRICS: dict[str, Metric] = _declare(
    Metric("repeatability", _DET, "share", "test keypoints with a reference keypoint of IoU > 0.5 (survey 4.1)",
           interval=True),
    Metric("ambiguity", _DET, "matches", "mean number of reference matches of a repeated test keypoint (4.1)",
           interval=True),
    Metric("few_keypoints", _DET, "share", "views with fewer than N test keypoints, '< N KPs' (survey 4.1)",
           aggregation="rate", interval=True),
    Metric("n_detected", _DET, "keypoints", "test keypoints found by the detector before selection (survey Table 2)",
           digits=0),
    Metric("n_kp_test", _DET, "keypoints", "test keypoints after selection (survey 2.2)", digits=0),
    Metric("n_kp_ref", _DET, "keypoints", "reference keypoints after selection (survey 2.2)", reported=False),
    Metric("n_test_valid", _DET, "keypoints", "test keypoints inside both masks (survey 4)", reported=False),
    Metric("n_ref_valid", _DET, "keypoints", "reference keypoints inside both masks (survey 4)", reported=False),
    Metric("n_repeated", _DET, "keypoints", "test keypoints that repeat, repeatability's numerator (4.1)",
           reported=False),
    Metric("n_described_ref", _MATCH, "keypoints", "reference keypoints the descriptor kept (survey 2.3)",
           reported=False),
    Metric("n_described_test", _MATCH, "keypoints", "test keypoints the descriptor kept (survey 2.3)",
           reported=False),
    Metric("n_matches", _MATCH, "matches", "matches passing the ratio test 0.7 (survey 5)", digits=1),
    Metric("n_correct", _MATCH, "matches", "number of correct matches, IoU > 0.5 (survey 4.2)", digits=1,
           interval=True),
    Metric("precision", _MATCH, "share", "correct / all matches, pooled over views: the survey's ratio (4.2)",
           aggregation="ratio", of=("n_correct", "n_matches"), interval=True),
    Metric("precision_per_view", _MATCH, "share", "mean of the views' correct / all matches (views with matches)",
           per_view=lambda rows: rows["precision"], interval=True),
    Metric("pose_success", _POSE, "share", "success rate: position error < 30 px, orientation < 1.5 deg (4.3)",
           aggregation="rate", interval=True),
    Metric("position_error", _POSE, "px", "distance of the estimated to the true position (survey 4.3)", digits=1,
           interval=True),
    Metric("orientation_error", _POSE, "deg", "orientation error of the estimated pose (survey 4.3)",
           interval=True),
    Metric("n_inliers", _POSE, "matches", "RANSAC inliers of the estimated pose (survey 5)", digits=1),
    Metric("t_detect", _DET, "s", "detection and selection time of the test image (survey Table 3)", digits=3),
    Metric("t_describe", _MATCH, "s", "description time of reference and test image (not in the survey; a call that "
           "described several detectors' keypoints, DAISY's, counts its equal share)", digits=3),
    Metric("t_match", _MATCH, "s", "matching time (not in the survey)", digits=3),
    Metric("t_pose", _POSE, "s", "pose estimation time (not in the survey)", digits=3),
    # Absolute localization against a map (the survey's outlook; Micro-GPS, Zhang et al. ICRA 2019).
    Metric("localized", _LOC, "share", "queries whose pose was accepted (experiment.min_inliers, min_inlier_ratio)",
           aggregation="rate"),
    Metric("localization_success", _LOC, "share", "in-map queries with ground truth localized within 30 px and "
           "1.5 deg in map px (Micro-GPS' rule)", aggregation="rate", interval=True),
    Metric("false_localization", _LOC, "share", "queries from a floor not in the map that were accepted (should "
           "be 0)", aggregation="rate", interval=True),
    Metric("wrong_localization", _LOC, "share", "in-map queries accepted with a pose outside 30 px / 1.5 deg",
           aggregation="rate"),
    Metric("success_position_error", _LOC, "px", "position error of the successful queries (map px)",
           per_view=lambda r: r["position_error"].where(r["localization_success"] == 1), digits=2),
    Metric("success_orientation_error", _LOC, "deg", "orientation error of the successful queries",
           per_view=lambda r: r["orientation_error"].where(r["localization_success"] == 1), digits=3),
    Metric("n_voted", _LOC, "matches", "matches kept by the voting step (all matches without voting)", digits=1),
    Metric("inlier_ratio", _LOC, "share", "inliers / matches given to the estimator", reported=False),
    Metric("t_vote", _LOC, "s", "voting time per query", digits=4, reported=False),
    Metric("t_query", _LOC, "s", "time per query: detection, description, matching, voting, pose", digits=3,
           interval=True),
    Metric("t_index", _LOC, "s", "building the matcher's index of the map (once per map)", digits=3,
           reported=False),
    Metric("map_features", _LOC, "features", "features in the map", digits=0),
    Metric("map_bytes", _LOC, "bytes", "memory of the map's features: descriptors, positions, orientations, ids",
           digits=0),
    Metric("map_bytes_per_m2", _LOC, "bytes/m2", "map memory per m2 of floor covered (data set's px/mm)",
           digits=0),
    Metric("map_build_s", _LOC, "s", "map build time: detection and description of every mapping image",
           digits=2),
)


def _check(metric: Metric) -> Metric:
    problems = []
    if metric.since not in EXPERIMENT_ROWS and metric.since not in STANDALONE:
        problems.append(f"experiment {metric.since!r} is not one of {', '.join([*EXPERIMENT_ROWS, *STANDALONE])}")
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
if not {*HEADLINE.values(), *(m for names in CURVES.values() for m in names)} <= set(METRICS):
    raise GtsweepError(f"HEADLINE and CURVES in {SCHEMA_FILE} must name declared metrics")


def register(metric: Metric) -> None:
    """Declare one more metric (a plugin's, or a test's); its name must be new."""
    if metric.name in METRICS:
        raise GtsweepError(f"metric '{metric.name}' is already declared in {SCHEMA_FILE}")
    METRICS[_check(metric).name] = metric


def unregister(name: str) -> None:
    METRICS.pop(name, None)


def add_experiment(name: str, headline_metric: str, *metrics: Metric, curves: tuple[str, ...] = ()) -> None:
    """Declare a new experiment kind's rows: its own ``metrics`` (``since=name``), the headline the terminal
    summary shows and the metrics drawn against strength. A plug-in's experiment kind calls this once."""
    if name in EXPERIMENT_ROWS or name in STANDALONE:
        raise GtsweepError(f"experiment '{name}' is already declared in {SCHEMA_FILE}")
    STANDALONE.add(name)
    for metric in metrics:
        register(metric)
    HEADLINE[name], CURVES[name] = headline_metric, curves
    if not {headline_metric, *curves} <= set(METRICS):
        remove_experiment(name)
        raise GtsweepError(f"experiment '{name}': its headline and curves must name declared metrics")


def remove_experiment(name: str) -> None:
    """Undo :func:`add_experiment` (a test's clean-up)."""
    for metric in [m for m in METRICS.values() if m.since == name]:
        unregister(metric.name)
    STANDALONE.discard(name)
    HEADLINE.pop(name, None)
    CURVES.pop(name, None)


def metrics_of(experiment: str | None) -> list[Metric]:
    """The metrics of an experiment's rows in schema order (every metric for None)."""
    return [m for m in METRICS.values() if experiment is None or experiment in m.experiments]


def headline(experiment: str) -> str:
    return HEADLINE[experiment]


def experiment_of(summary: Mapping) -> str:
    """A cell summary's experiment; summaries written before it was recorded: guessed from methods and metrics."""
    if summary.get("experiment") in EXPERIMENT_ROWS or summary.get("experiment") in STANDALONE:
        return summary["experiment"]
    if not (summary.get("methods") or {}).get("descriptor"):
        return "detection"
    return "pose" if headline("pose") in (summary.get("metrics") or {}) else "matching"


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
    """The rows a cell's aggregates are taken over: all, or those of the largest :data:`HEADLINE_STEP` value per
    texture (each floor's own largest map: a real data set's floors have maps of different sizes)."""
    step = HEADLINE_STEP.get(experiment)
    if step is None or step not in rows or not rows[step].notna().any():
        return rows
    values = _numbers(rows[step])
    largest = values.groupby(rows["texture"]).transform("max") if "texture" in rows else values.max()
    return rows[values == largest]


def as_floats(values: pd.Series) -> np.ndarray:
    """:func:`_numbers` as a float64 NumPy array (a float64 column as it is, without a copy)."""
    if values.dtype == np.float64:
        return values.to_numpy()
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
