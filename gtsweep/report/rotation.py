"""Pose success against the pair's rotation (issue 26): the question this field asks of learned features.

Absolute pairs are rotated by 120 degrees on average (survey 5.2); a method without orientation (Harris, FAST,
XFeat, ALIKED, DISK) matches well only near 0 degrees. For every cell of the pose experiment on absolute pairs
(every detector, descriptor, matcher and estimator) the table gives the mean pose success per bin of
:data:`BIN_DEG` = 15 degrees of the pair's rotation (the magnitude of its ground-truth rotation, 0-180 degrees,
column ``rotation`` of the per-view rows), with the number of pairs in each bin in the last row; the plot draws
one line per cell. Bins without a pair are empty.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.report.labels import label
from gtsweep.report.samples import Views
from gtsweep.report.tables import Table, write_tables

BIN_DEG = 15
EDGES = np.arange(0, 180 + BIN_DEG, BIN_DEG)
TRANSFORM = "absolute"
PAIRS_ROW = "pairs per bin"


def bin_labels() -> list[str]:
    return [f"{int(low)}-{int(high)}" for low, high in zip(EDGES[:-1], EDGES[1:])]


def method_label(methods: dict) -> str:
    """``ALIKED-n16rot + ALIKED-n16rot, LightGlue`` (the matcher and estimator only when not the survey's)."""
    text = f"{label(methods['detector'])} + {label(methods['descriptor'])}"
    extras = [label(methods[k]) for k, survey in (("matcher", "bf_ratio"), ("estimator", "ransac"))
              if methods.get(k) and methods[k] != survey]
    return text + (", " + ", ".join(extras) if extras else "")


def success_by_rotation(summaries: list[dict], views: Views | None) -> pd.DataFrame | None:
    """Mean pose success (rows: cells, columns: rotation bins) of the absolute-pair pose cells; None if none."""
    rows, counts = {}, None
    for summary in summaries:
        methods = summary.get("methods") or {}
        frame = (views or {}).get(summary.get("key"))
        if (summary.get("experiment") != "pose" or methods.get("transform") != TRANSFORM or summary.get("status")
                != "ok" or frame is None or "rotation" not in frame or "pose_success" not in frame):
            continue
        bins = pd.cut(frame["rotation"].abs(), EDGES, labels=bin_labels(), include_lowest=True)
        grouped = frame["pose_success"].groupby(bins, observed=False)
        rows[method_label(methods)] = grouped.mean()
        counts = grouped.size() if counts is None else counts
    if not rows:
        return None
    table = pd.DataFrame(rows).T.reindex(columns=bin_labels())
    table.loc[PAIRS_ROW] = counts.reindex(bin_labels()).astype(float)
    table.index.name = "method"
    return table


def rotation_table(summaries: list[dict], views: Views | None) -> Table | None:
    """The report table ``rotation_absolute``: pose success per 15-degree bin of the pair's rotation."""
    values = success_by_rotation(summaries, views)
    if values is None:
        return None
    shown = values.map(lambda v: "" if pd.isna(v) else f"{v:.2f}")
    shown.loc[PAIRS_ROW] = values.loc[PAIRS_ROW].map(lambda v: "" if pd.isna(v) else str(int(v)))
    numbers = [{"row": row, "column": column, "metric": "pose_success", "ours": value}
               for row, series in values.drop(PAIRS_ROW).iterrows() for column, value in series.items()]
    return Table("rotation_absolute", f"Pose success against the pair's rotation (absolute pairs, bins of "
                                      f"{BIN_DEG} degrees)", shown, numbers,
                 note="A bin's entry is the mean pose success of its pairs; the last row counts the pairs.")


def write_rotation_plot(table: Table, out_dir: str | Path) -> Path:
    """``rotation_absolute.png``: pose success per rotation bin, one line per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = pd.DataFrame(table.values).pivot(index="row", columns="column", values="ours")
    values = values.reindex(columns=bin_labels())
    centres = (EDGES[:-1] + EDGES[1:]) / 2
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for i, (row, series) in enumerate(values.iterrows()):
        ax.plot(centres, series.to_numpy(dtype=float), marker="o", label=row,
                linestyle=("-", "--", ":", "-.")[i // 10 % 4])
    ax.set(xlabel="rotation of the pair (degrees)", ylabel="pose success", xlim=(0, 180), ylim=(-0.02, 1.02),
           xticks=EDGES, title=table.title)
    ax.legend(fontsize=6, ncol=2, loc="best")
    fig.tight_layout()
    path = Path(out_dir) / "rotation_absolute.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_rotation(summaries: list[dict], views: Views | None, out_dir: str | Path, plots: bool = True) -> list[Path]:
    """The rotation table (.md, .tex, .csv, _values.csv) and plot in ``out_dir``; nothing without absolute pose
    cells."""
    table = rotation_table(summaries, views)
    if table is None:
        return []
    files = write_tables([table], out_dir)
    return files + ([write_rotation_plot(table, out_dir)] if plots else [])
