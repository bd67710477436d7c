"""Pose success against the pair's rotation (issue 26): the question this field asks of learned features.

Absolute pairs are rotated by 120 degrees on average (survey 5.2); a method without orientation (Harris, FAST,
XFeat, ALIKED, DISK) matches well only near 0 degrees. For every cell of the pose experiment on absolute pairs
(every detector, descriptor, matcher and estimator) the table gives the mean pose success per bin of
:data:`BIN_DEG` = 15 degrees of the pair's rotation (the magnitude of its ground-truth rotation, 0-180 degrees,
column ``rotation`` of the per-view rows), with the number of pairs in each bin in the last row; the plot draws
one curve per distinct outcome with its Wilson interval, over a bar of the pairs per bin. Bins without a pair are
empty.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.evaluation.statistics import wilson_interval
from gtsweep.orchestration.grid import SURVEY_METHODS
from gtsweep.report.labels import label
from gtsweep.report.samples import Views
from gtsweep.report.tables import Table, write_tables

BIN_DEG = 15
EDGES = np.arange(0, 180 + BIN_DEG, BIN_DEG)
TRANSFORM = "absolute"
PAIRS_ROW = "pairs per bin"
DODGE_DEG = 8.0  # curves that would hide each other spread over this much of a bin's 15 degrees
MAX_CURVES = 8  # a larger grid's plot draws its best outcomes (by mean pose success over its pairs); the table has all
NAMES_SHOWN = 3  # a shared outcome's legend entry names this many of its cells


def bin_labels() -> list[str]:
    return [f"{int(low)}-{int(high)}" for low, high in zip(EDGES[:-1], EDGES[1:])]


def method_label(methods: dict) -> str:
    """``ALIKED-n16rot + ALIKED-n16rot, LightGlue`` (the matcher and estimator only when not the survey's)."""
    text = f"{label(methods['detector'])} + {label(methods['descriptor'])}"
    extras = [label(methods[k]) for k, survey in SURVEY_METHODS.items() if methods.get(k) and methods[k] != survey]
    return text + (", " + ", ".join(extras) if extras else "")


def bin_outcomes(frame: pd.DataFrame) -> pd.DataFrame:
    """One cell's pairs per rotation bin (rows): ``in_bin`` pairs, ``pairs`` of them with a pose outcome,
    ``successes``, the success ``rate`` and its Wilson 95 % interval ``ci_low``, ``ci_high`` (NaN: no pair)."""
    bins = pd.cut(frame["rotation"].abs(), EDGES, labels=bin_labels(), include_lowest=True)
    grouped = frame["pose_success"].groupby(bins, observed=False)
    outcomes = pd.DataFrame({"in_bin": grouped.size(), "pairs": grouped.count(), "successes": grouped.sum(),
                             "rate": grouped.mean()}).reindex(bin_labels())
    bands = [wilson_interval(round(s), n) for s, n in zip(outcomes["successes"], outcomes["pairs"])]
    outcomes["ci_low"], outcomes["ci_high"] = [low for low, _ in bands], [high for _, high in bands]
    return outcomes


def outcomes_by_rotation(summaries: list[dict], views: Views | None) -> dict[str, pd.DataFrame]:
    """:func:`bin_outcomes` of every absolute-pair pose cell, by its method label (empty: no such cell)."""
    outcomes = {}
    for summary in summaries:
        methods = summary.get("methods") or {}
        frame = (views or {}).get(summary.get("key"))
        if (methods.get("transform") != TRANSFORM or summary.get("status") != "ok" or frame is None
                or "rotation" not in frame or "pose_success" not in frame):
            continue
        outcomes[method_label(methods)] = bin_outcomes(frame)
    return outcomes


def rotation_table(summaries: list[dict], views: Views | None) -> Table | None:
    """The report table ``rotation_absolute``: pose success per 15-degree bin of the pair's rotation; its values
    hold each entry's Wilson interval and number of pairs (what the plot draws)."""
    outcomes = outcomes_by_rotation(summaries, views)
    if not outcomes:
        return None
    shown = pd.DataFrame({m: o["rate"].map(lambda v: "" if pd.isna(v) else f"{v:.2f}") for m, o in outcomes.items()}).T
    shown.loc[PAIRS_ROW] = next(iter(outcomes.values()))["in_bin"].map(str)  # the cells share their pairs
    shown.index.name = "method"
    numbers = [{"row": method, "column": column, "metric": "pose_success", "ours": row.rate, "ci_low": row.ci_low,
                "ci_high": row.ci_high, "pairs": int(row.pairs)}
               for method, frame in outcomes.items() for column, row in frame.iterrows()]
    return Table("rotation_absolute", f"Pose success against the pair's rotation (absolute pairs, bins of "
                                      f"{BIN_DEG} degrees)", shown, numbers,
                 note="A bin's entry is the mean pose success of its pairs; the last row counts the pairs.")


def _outcome_name(group: list[str]) -> str:
    """A legend entry: the cell, or ``N cells, same outcome:`` and the first :data:`NAMES_SHOWN` of them."""
    if len(group) == 1:
        return group[0]
    more = len(group) - NAMES_SHOWN
    return f"{len(group)} cells, same outcome:\n" + "\n".join(group[:NAMES_SHOWN]) + (f"\nand {more} more" if more > 0
                                                                                     else "")


def outcome_groups(values: pd.DataFrame) -> tuple[dict[tuple, list[str]], pd.DataFrame, pd.DataFrame]:
    """The table's cells grouped by outcome (the same rate and pairs in every bin), in the table's order; and the
    rates and pairs per (cell, bin)."""
    rates = values.pivot(index="row", columns="column", values="ours").reindex(columns=bin_labels())
    pairs = values.pivot(index="row", columns="column", values="pairs").reindex(columns=bin_labels())
    groups: dict[tuple, list[str]] = {}
    for method in dict.fromkeys(values["row"]):
        groups.setdefault(tuple(rates.loc[method].fillna(-1)) + tuple(pairs.loc[method]), []).append(method)
    return groups, rates, pairs


def plot_curves(table: Table, most: int = MAX_CURVES) -> tuple[pd.DataFrame, pd.Series]:
    """What ``rotation_absolute.png`` draws: one curve per distinct outcome (cells with the same rate and pairs in
    every bin share one), each moved sideways by its own small offset so that none hides another; at most ``most``
    curves, the outcomes of highest mean pose success over their pairs, best first (the table's order on a tie);
    rows (curve, bin) with ``x``, ``rate``, ``ci_low``, ``ci_high``. And the pairs per bin."""
    values = pd.DataFrame(table.values)
    groups, rates, pairs = outcome_groups(values)
    mean = {key: (rates.loc[g[0]] * pairs.loc[g[0]]).sum() / max(1, pairs.loc[g[0]].sum()) for key, g in groups.items()}
    best = sorted(groups, key=lambda key: -mean[key])[:most]  # a stable sort keeps the table's order on ties
    groups = {key: groups[key] for key in best}  # the legend lists the best first
    names = [_outcome_name(group) for group in groups.values()]
    step = min(DODGE_DEG / len(names), 2.0)
    centres = (EDGES[:-1] + EDGES[1:]) / 2
    curves = []
    for i, (name, group) in enumerate(zip(names, groups.values())):
        curve = values[values["row"] == group[0]].set_index("column").reindex(bin_labels())
        offset = (i - (len(names) - 1) / 2) * step
        curves.append(pd.DataFrame({"curve": name, "bin": bin_labels(), "x": centres + offset,
                                    "rate": curve["ours"].to_numpy(), "ci_low": curve["ci_low"].to_numpy(),
                                    "ci_high": curve["ci_high"].to_numpy()}))
    return pd.concat(curves, ignore_index=True), pairs.max().astype(int)


def write_rotation_plot(table: Table, out_dir: str | Path) -> Path:
    """``rotation_absolute.png``: pose success per rotation bin with its Wilson interval, one curve per distinct
    outcome (:func:`plot_curves`), over a bar of the pairs in each bin."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    curves, pairs = plot_curves(table)
    outcomes = len(outcome_groups(pd.DataFrame(table.values))[0])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(3, 1))
    for i, (name, curve) in enumerate(curves.groupby("curve", sort=False)):
        errors = [curve["rate"] - curve["ci_low"], curve["ci_high"] - curve["rate"]]
        top.errorbar(curve["x"], curve["rate"], yerr=errors, marker="osD^vPX*"[i % 8], markersize=4, capsize=2,
                     linewidth=1, elinewidth=0.7, label=name, linestyle=("-", "--", ":", "-.")[i // 8 % 4])
    shown = curves["curve"].nunique()
    title = table.title + (f"\nthe {shown} best of {outcomes} outcomes; every cell in rotation_absolute.csv"
                           if shown < outcomes else "")
    top.set(ylabel="pose success", ylim=(-0.02, 1.02), title=title)
    top.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="error bars: Wilson 95 % interval",
               title_fontsize=6)
    centres = (EDGES[:-1] + EDGES[1:]) / 2
    bottom.bar_label(bottom.bar(centres, pairs.to_numpy(), width=BIN_DEG * 0.8, color="0.7"), fontsize=7)
    bottom.set(xlabel="rotation of the pair (degrees)", ylabel="pairs per bin", xlim=(0, 180), xticks=EDGES,
               ylim=(0, max(1, pairs.max()) * 1.3))
    bottom.yaxis.set_major_locator(MaxNLocator(nbins=4, integer=True))
    path = Path(out_dir) / "rotation_absolute.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")  # the legend beside the axes included
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
