"""Plots of a sweep (matplotlib, PNG): metrics against transform strength, success against the number of reference
features (survey Table 7 as curves), and detector x descriptor heat maps of pose success (Tables 4 and 5). Which
metrics, their axes and ranges come from :mod:`gtsweep.evaluation.schema`.

With the cells' per-view rows, each point of a curve gets its 95 % interval as a shaded band
(:func:`gtsweep.report.samples.estimate`).

Methods often score the same (pose success 1.0 at small rotations): each line gets its own marker and dash pattern
and a small sideways offset, so that lines lying on top of each other stay visible."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from gtsweep.evaluation import schema  # noqa: E402
from gtsweep.report.labels import STRENGTH_AXIS, label  # noqa: E402
from gtsweep.report.samples import Views, estimate  # noqa: E402
from gtsweep.report.tables import paper, paper_order  # noqa: E402

#: The survey's success rate of the estimated poses (Tables 4-7): its heat maps, its plots' file name "success".
SUCCESS = "pose_success"


def _series_name(methods: dict) -> str:
    parts = [label(methods["detector"])]
    if methods.get("descriptor"):
        parts.append(label(methods["descriptor"]))
    return "-".join(parts) + f" [{methods['selector']}]"


def _steps(by_step: dict, metric: str):
    points = sorted((float(k), v.get(metric)) for k, v in by_step.items() if v.get(metric) is not None)
    return [p[0] for p in points], [p[1] for p in points]


MARKERS = "osD^vP*Xph<>"
DASHES = ["-", "--", "-.", ":"]
BANDS = "; bands: 95 % intervals"
SPREAD = 0.05  # the lines' sideways offsets span this share of the x range (of its decades on a log axis)


def _band(cell: dict, step_key: str, metric: str, xs, views: Views | None):
    """The 95 % interval of ``metric`` at each step of a cell, from its per-view rows (None without them)."""
    if not views or cell.get("key") not in views:
        return None
    row = pd.DataFrame([{"key": cell["key"], "transform": cell["methods"]["transform"], metric: np.nan}])
    ends = [estimate(row, metric, views, {step_key: x})[1:] for x in xs]
    return None if all(np.isnan(low) for low, _ in ends) else ([e[0] for e in ends], [e[1] for e in ends])


def _plot_lines(ax, cells: list[dict], step_key: str, metric: str, log_x: bool = False,
                views: Views | None = None) -> None:
    """One line per cell, each with its own marker and dashes and a small offset along x (a factor on log x), and
    its interval as a band when the per-view rows are given."""
    series = [(_series_name(s["methods"]), *_steps(s[f"by_{step_key}"], metric), s) for s in cells]
    series = [(name, xs, ys, s) for name, xs, ys, s in sorted(series, key=lambda t: t[0]) if xs]
    every = [x for _, xs, _, _ in series for x in xs]
    if not every:
        return
    low, high = (np.log10(min(every)), np.log10(max(every))) if log_x else (min(every), max(every))
    width = (high - low) or 1.0
    for i, (name, xs, ys, cell) in enumerate(series):
        band = _band(cell, step_key, metric, xs, views)
        shift = (i - (len(series) - 1) / 2) * SPREAD * width / max(len(series) - 1, 1)
        xs = [x * 10 ** shift for x in xs] if log_x else [x + shift for x in xs]
        (line,) = ax.plot(xs, ys, marker=MARKERS[i % len(MARKERS)], linestyle=DASHES[i % len(DASHES)],
                          linewidth=1.2, markersize=5, markerfacecolor="none" if i % 2 else None, alpha=0.85,
                          label=name)
        if band is not None:
            ax.fill_between(xs, *band, color=line.get_color(), alpha=0.12, linewidth=0)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if len(series) > 1:
        ax.annotate("lines offset sideways\nto stay visible", xy=(1.01, 0.0), xycoords="axes fraction", fontsize=7,
                    color="0.4", va="bottom")


def _axis(metric: str) -> str:
    """Axis label from the schema: the metric and its unit."""
    return f"{_name(metric)} ({schema.METRICS[metric].unit})"


def _name(metric: str) -> str:
    return metric.replace("_", " ")


def _bound(ax, metric: str) -> None:
    if schema.METRICS[metric].bounded:
        ax.set_ylim(-0.02, 1.02)


def _stem(metric: str) -> str:
    """File name stem of a metric's plot; the pose headline keeps the survey's word, "success"."""
    return "success" if metric == SUCCESS else metric


def _by_headline(summaries: list[dict], step_key: str) -> dict[str, list[dict]]:
    """Evaluated cells with values per ``step_key``, by their experiment's headline metric."""
    groups = defaultdict(list)
    for s in summaries:
        if s["status"] == "ok" and s.get(f"by_{step_key}"):
            groups[schema.headline(schema.experiment_of(s))].append(s)
    return groups


def plot_strength_curves(summaries: list[dict], out_dir: Path, views: Views | None = None) -> list[Path]:
    """One figure per transform and metric (the schema's curves of each cell's experiment), a line per method."""
    groups = defaultdict(list)
    for s in summaries:
        if s["status"] == "ok" and s.get("by_strength"):
            for metric in schema.curves(schema.experiment_of(s)):
                groups[(s["methods"]["transform"], metric)].append(s)
    files = []
    for (transform, metric), cells in sorted(groups.items()):
        fig, ax = plt.subplots(figsize=(9, 4.5))
        _plot_lines(ax, cells, "strength", metric, views=views)
        ax.set(xlabel=STRENGTH_AXIS.get(transform, "strength"), ylabel=_axis(metric),
               title=f"{_name(metric)} against {transform} ({_per_point(cells, 'strength', views)} views per "
                     f"point{BANDS if views else ''})")
        _bound(ax, metric)
        ax.grid(alpha=0.3)
        files.append(_save(fig, out_dir / f"{metric}_vs_{transform}.png"))
    return files


def plot_reference_counts(summaries: list[dict], out_dir: Path, views: Views | None = None) -> list[Path]:
    """Survey Table 7 as curves: the headline metric (pose success) against the number of reference features."""
    files = []
    for metric, cells in sorted(_by_headline(summaries, "reference_count").items()):
        fig, ax = plt.subplots(figsize=(9, 4.5))
        _plot_lines(ax, cells, "reference_count", metric, log_x=True, views=views)
        ax.set_xscale("log")
        ax.set(xlabel="reference features per image", ylabel=_axis(metric),
               title=f"{_name(metric)} against reference features ({_per_point(cells, 'reference_count', views)} "
                     f"pairs per point{BANDS if views else ''})")
        _bound(ax, metric)
        ax.grid(alpha=0.3, which="both")
        files.append(_save(fig, out_dir / f"{_stem(metric)}_vs_reference_features.png"))
    return files


CELL_INCHES = (1.25, 0.62)  # width, height of a heat map cell: room for the value and its interval
NA_COLOUR = "0.88"


def plot_success_heatmaps(summaries: list[dict], out_dir: Path) -> list[Path]:
    """Detector x descriptor heat map of the pose headline (success) per pair kind (survey Tables 4 and 5): each
    cell its value and 95 % interval, NA (grey) where the pairing cannot be evaluated; rows and columns in the
    survey table's order, the figure sized to its cells."""
    metric = SUCCESS
    files = []
    for transform in ("incremental", "absolute"):
        cells = [s for s in summaries if s["methods"]["transform"] == transform and s["methods"].get("descriptor")
                 and schema.headline(schema.experiment_of(s)) == SUCCESS and not s.get("by_reference_count")]
        if not cells:
            continue
        theirs = paper(f"table{4 if transform == 'incremental' else 5}_success_{transform}.csv")  # its order
        detectors = paper_order({s["methods"]["detector"] for s in cells}, theirs["detector"])
        descriptors = paper_order({s["methods"]["descriptor"] for s in cells}, theirs.columns[1:])
        values = np.full((3, len(detectors), len(descriptors)), np.nan)  # value, low, high
        for s in cells:
            if s["status"] == "ok":
                i, j = detectors.index(s["methods"]["detector"]), descriptors.index(s["methods"]["descriptor"])
                found = s.get("metrics") or {}
                values[:, i, j] = [np.nan if found.get(k) is None else found[k]
                                   for k in (metric, f"{metric}_ci_low", f"{metric}_ci_high")]
        width, height = CELL_INCHES
        fig, ax = plt.subplots(figsize=(2.6 + width * len(descriptors), 1.9 + height * len(detectors)))
        ax.set_facecolor(NA_COLOUR)
        image = ax.imshow(np.ma.masked_invalid(values[0]), vmin=0, vmax=1, cmap="viridis", aspect="auto")
        ax.set_xticks(range(len(descriptors)), [label(d) for d in descriptors], rotation=30, ha="right")
        ax.set_yticks(range(len(detectors)), [label(d) for d in detectors])
        ax.set(xlabel="descriptor", ylabel="detector")
        for (i, j), v in np.ndenumerate(values[0]):
            low, high = values[1, i, j], values[2, i, j]
            text = "NA" if np.isnan(v) else f"{v:.2f}" + ("" if np.isnan(low) else f"\n[{low:.2f}, {high:.2f}]")
            ax.text(j, i, text, ha="center", va="center", fontsize=8,
                    color="black" if np.isnan(v) or v >= 0.6 else "white")
        fig.colorbar(image, ax=ax, label=_axis(metric), fraction=0.08 if len(descriptors) > 2 else 0.15)
        n = _views(cells)
        ax.set_title(f"{_name(metric).capitalize()}, {transform} pairs\n{n} pairs per cell; [95 % interval]; "
                     "NA: not applicable", fontsize=10)
        files.append(_save(fig, out_dir / f"{_stem(metric)}_heatmap_{transform}.png"))
    return files


def _views(cells: list[dict]) -> str:
    """Views (or pairs) per cell of a plot: ``27``, or ``12–27`` when the cells differ."""
    return _span([c.get("n_views", c.get("n_rows")) for c in cells if c["status"] == "ok"])


def _per_point(cells: list[dict], step_key: str, views: Views | None) -> str:
    """Views (or pairs) behind each point of a curve: counted per step in the cells' per-view rows; without them,
    a cell's views when each is repeated at every step (a pair at every reference count), else shared evenly by
    the steps (an image rotated by each angle is a view per angle)."""
    counts = []
    for cell in (c for c in cells if c["status"] == "ok"):
        rows = (views or {}).get(cell.get("key"))
        steps = len(cell.get(f"by_{step_key}") or {})
        n_views, n_rows = cell.get("n_views", cell.get("n_rows")), cell.get("n_rows")
        if rows is not None and step_key in rows:
            counts += pd.to_numeric(rows[step_key], errors="coerce").dropna().value_counts().tolist()
        elif steps and n_views is not None:
            repeated = n_rows is not None and n_rows >= n_views * steps
            counts.append(int(n_views) if repeated else int(n_views) // steps)
    return _span(counts)


def _span(counts) -> str:
    """``9``, or ``8–9`` when they differ; ``no`` without any."""
    counts = [int(n) for n in counts if n is not None]
    if not counts:
        return "no"
    return str(min(counts)) if min(counts) == max(counts) else f"{min(counts)}–{max(counts)}"


def write_plots(summaries: list[dict], out_dir: str | Path, views: Views | None = None) -> list[Path]:
    """Every plot of the cells into ``out_dir``; ``views`` (the cells' per-view rows) adds the interval bands."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [*plot_strength_curves(summaries, out_dir, views), *plot_reference_counts(summaries, out_dir, views),
            *plot_success_heatmaps(summaries, out_dir)]


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")  # nothing cut: titles, legends beside the axes
    plt.close(fig)
    return path
