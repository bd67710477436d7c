"""Plots of a sweep (matplotlib, PNG): metrics against transform strength, success against the number of reference
features (survey Table 7 as curves), and detector x descriptor heat maps of pose success (Tables 4 and 5). Which
metrics, their axes and ranges come from :mod:`gtsweep.evaluation.schema`."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from gtsweep.evaluation import schema  # noqa: E402
from gtsweep.report.labels import label  # noqa: E402

STRENGTH_AXIS = {"rotation": "rotation angle (deg)", "translation": "IoU of reference and test masks",
                 "noise": "noise sigma", "gamma": "gamma"}


def _series_name(methods: dict) -> str:
    parts = [label(methods["detector"])]
    if methods.get("descriptor"):
        parts.append(label(methods["descriptor"]))
    return "-".join(parts) + f" [{methods['selector']}]"


def _steps(by_step: dict, metric: str):
    points = sorted((float(k), v.get(metric)) for k, v in by_step.items() if v.get(metric) is not None)
    return [p[0] for p in points], [p[1] for p in points]


def _axis(metric: str) -> str:
    """Axis label from the schema: the metric and its unit (shares have none)."""
    declared = schema.METRICS[metric]
    return metric.replace("_", " ") + ("" if declared.bounded else f" ({declared.unit})")


def _bound(ax, metric: str) -> None:
    if schema.METRICS[metric].bounded:
        ax.set_ylim(-0.02, 1.02)


def _stem(metric: str) -> str:
    """File name stem of a metric's plot; the pose headline keeps the survey's word, "success"."""
    return "success" if metric == schema.headline("pose") else metric


def _by_headline(summaries: list[dict], step_key: str) -> dict[str, list[dict]]:
    """Evaluated cells with values per ``step_key``, by their experiment's headline metric."""
    groups = defaultdict(list)
    for s in summaries:
        if s["status"] == "ok" and s.get(f"by_{step_key}"):
            groups[schema.headline(schema.experiment_of(s))].append(s)
    return groups


def plot_strength_curves(summaries: list[dict], out_dir: Path) -> list[Path]:
    """One figure per transform and metric (the schema's curves of each cell's experiment), a line per method."""
    groups = defaultdict(list)
    for s in summaries:
        if s["status"] == "ok" and s.get("by_strength"):
            for metric in schema.CURVES[schema.experiment_of(s)]:
                groups[(s["methods"]["transform"], metric)].append(s)
    files = []
    for (transform, metric), cells in sorted(groups.items()):
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for s in sorted(cells, key=lambda c: _series_name(c["methods"])):
            xs, ys = _steps(s["by_strength"], metric)
            ax.plot(xs, ys, marker="o", label=_series_name(s["methods"]))
        ax.set(xlabel=STRENGTH_AXIS.get(transform, "strength"), ylabel=_axis(metric), title=f"{metric}: {transform}")
        _bound(ax, metric)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        files.append(_save(fig, out_dir / f"{metric}_vs_{transform}.png"))
    return files


def plot_reference_counts(summaries: list[dict], out_dir: Path) -> list[Path]:
    """Survey Table 7 as curves: the headline metric (pose success) against the number of reference features."""
    files = []
    for metric, cells in sorted(_by_headline(summaries, "reference_count").items()):
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for s in cells:
            xs, ys = _steps(s["by_reference_count"], metric)
            ax.plot(xs, ys, marker="o", label=_series_name(s["methods"]))
        ax.set_xscale("log")
        ax.set(xlabel="reference features", ylabel=_axis(metric), title=f"{metric} against reference features")
        _bound(ax, metric)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, ncol=2)
        files.append(_save(fig, out_dir / f"{_stem(metric)}_vs_reference_features.png"))
    return files


def plot_success_heatmaps(summaries: list[dict], out_dir: Path) -> list[Path]:
    """Detector x descriptor heat map of the pose headline (success) per pair kind (survey Tables 4 and 5)."""
    metric = schema.headline("pose")
    files = []
    for transform in ("incremental", "absolute"):
        cells = [s for s in summaries if s["methods"]["transform"] == transform and s["methods"].get("descriptor")
                 and schema.experiment_of(s) == "pose" and not s.get("by_reference_count")]
        if not cells:
            continue
        detectors = sorted({s["methods"]["detector"] for s in cells})
        descriptors = sorted({s["methods"]["descriptor"] for s in cells})
        values = np.full((len(detectors), len(descriptors)), np.nan)
        for s in cells:
            if s["status"] == "ok":
                i, j = detectors.index(s["methods"]["detector"]), descriptors.index(s["methods"]["descriptor"])
                value = (s.get("metrics") or {}).get(metric)
                values[i, j] = np.nan if value is None else value
        fig, ax = plt.subplots(figsize=(1.2 + 0.7 * len(descriptors), 1.2 + 0.45 * len(detectors)))
        image = ax.imshow(np.ma.masked_invalid(values), vmin=0, vmax=1, cmap="viridis")
        ax.set_xticks(range(len(descriptors)), [label(d) for d in descriptors], rotation=45, ha="right")
        ax.set_yticks(range(len(detectors)), [label(d) for d in detectors])
        for (i, j), v in np.ndenumerate(values):
            ax.text(j, i, "NA" if np.isnan(v) else f"{v:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if np.isnan(v) or v < 0.6 else "black")
        fig.colorbar(image, ax=ax, label=_axis(metric))
        ax.set_title(f"{metric}, {transform} pairs")
        files.append(_save(fig, out_dir / f"{_stem(metric)}_heatmap_{transform}.png"))
    return files


def write_plots(summaries: list[dict], out_dir: str | Path) -> list[Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [*plot_strength_curves(summaries, out_dir), *plot_reference_counts(summaries, out_dir),
            *plot_success_heatmaps(summaries, out_dir)]


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
