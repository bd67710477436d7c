"""A cell's per-strength curves as a figure artifact of its MLflow run, with labelled axes.

MLflow draws a ``curves/<metric>_vs_strength`` series against an axis it calls "Step" (the strength times
``gtsweep.step_scale.strength``); the figure says what the axes are: the transform's strength in its unit and the
metric with its unit. Every run with strengths logs it under the same name, :data:`FIGURE`, so MLflow's compare
page shows the runs' figures side by side.
"""
from __future__ import annotations

import math
import textwrap
from typing import Mapping

from gtsweep.evaluation import schema
from gtsweep.evaluation.transforms import STRENGTH_AXIS

FIGURE = "strength_curves.png"
STEP = "strength"


def curve_metrics(summary: Mapping, experiment: str) -> list[str]:
    """The experiment's curve metrics (:func:`gtsweep.evaluation.schema.curves`) that the cell has per strength."""
    by_strength = summary.get(f"by_{STEP}") or {}
    curves = schema.curves(experiment) if experiment in schema.ROWS else ()
    return [m for m in curves if any(m in values for values in by_strength.values())]


def axis_label(metric: str) -> str:
    """``pose_success (share)``: the metric and its schema unit."""
    declared = schema.METRICS.get(metric)
    return f"{metric} ({declared.unit})" if declared is not None else metric


def strength_figure(summary: Mapping, experiment: str, title: str):
    """A matplotlib figure: one panel per curve metric against the strength (None: fewer than two strengths)."""
    by_strength = summary.get(f"by_{STEP}") or {}
    metrics = curve_metrics(summary, experiment)
    if len(by_strength) < 2 or not metrics:
        return None
    from matplotlib.figure import Figure  # only here: a cell without curves does not pay matplotlib's import

    strengths = sorted(by_strength, key=float)
    xs = [float(s) for s in strengths]
    transform = (summary.get("methods") or {}).get("transform", "")
    width = max(6.0, 4.2 * len(metrics))  # inches at 100 dpi: the run's name fits above one panel too
    figure = Figure(figsize=(width, 3.6), layout="constrained")
    for ax, metric in zip(figure.subplots(1, len(metrics), squeeze=False)[0], metrics):
        ys = [_value(by_strength[s].get(metric)) for s in strengths]
        ax.plot(xs, ys, marker="o")
        ax.set(xlabel=STRENGTH_AXIS.get(transform, f"{transform} strength"), ylabel=axis_label(metric),
               title=metric)
        if schema.METRICS[metric].bounded:
            ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    figure.suptitle(textwrap.fill(title, int(width * 11)), fontsize=10)
    return figure


def _value(value) -> float:
    return math.nan if value is None else float(value)
