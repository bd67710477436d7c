"""Metric names in MLflow: the headline metrics plain, the rest grouped under a ``prefix/``.

MLflow's UI draws one chart per metric and groups the charts of a run (and of an experiment) into sections by the
part of the name before the first ``/``; metrics without one form its first section, "Model metrics". So a cell's
quality metrics and counts stay plain (``pose_success``, ``n_matches``) and the rest moves to its own section:

- ``ci/<m>_ci_low``, ``ci/<m>_ci_high``: a metric's 95 % interval (the names of results.csv after the prefix);
- ``time/<t_...>``: the timings (schema unit ``s``);
- ``curves/<m>_vs_<step>``: a series against a step key (``pose_success_vs_strength``, step = strength);
- ``sweep/<total>``: a sweep's own totals on its run (cells, cache hits, wall time).

MLflow 3.17 puts a run's prefixed sections before "Model metrics" (its named sections sorted, then the unnamed
one); the experiment's saved view (:mod:`gtsweep.tracking.views`) orders them as :data:`SECTIONS`.

:func:`summary_name` turns any of these back into the name of a cell summary (runs logged before the prefixes,
with plain names, read the same).
"""
from __future__ import annotations

from gtsweep.evaluation import schema

INTERVAL, TIME, CURVES, SWEEP = "ci/", "time/", "curves/", "sweep/"
PREFIXES = (INTERVAL, TIME, CURVES, SWEEP)
#: MLflow's chart sections in the order a reader wants them: its name for unprefixed metrics first.
SECTIONS = ("Model metrics", CURVES[:-1], INTERVAL[:-1], TIME[:-1], SWEEP[:-1], "System metrics")
INTERVAL_SUFFIXES = ("_ci_low", "_ci_high")


def mlflow_name(name: str) -> str:
    """The MLflow metric name of a summary metric or series: ``precision_ci_low`` -> ``ci/precision_ci_low``."""
    if schema.parse_series(name):
        return CURVES + name
    if name.endswith(INTERVAL_SUFFIXES):
        return INTERVAL + name
    declared = schema.METRICS.get(name)
    if declared is not None and declared.unit == "s":
        return TIME + name
    return name


def summary_name(key: str) -> str:
    """The summary name of an MLflow metric (the inverse of :func:`mlflow_name`; plain names pass unchanged)."""
    for prefix in PREFIXES:
        if key.startswith(prefix):
            return key[len(prefix):]
    return key
