"""The report of ``experiment=localization``: success, false localization and latency per cell, and against the
map size per pairing (table and plot), from the cell summaries (``by_map_images`` of
:func:`gtsweep.orchestration.results.summarize`).

Success is the share of in-map queries with ground truth localized within 30 px and 1.5 deg (Micro-GPS' rule, the
survey's thresholds), with its Wilson 95 % interval; false localization the share of queries from a floor not in
the map that were accepted; latency the mean time per query (detection, description, matching, voting, pose).
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from gtsweep.report.tables import Table

METHODS = ("detector", "selector", "descriptor", "matcher", "estimator")
SUCCESS = "success (% of in-map queries) [95 % CI]"


def _pct(value) -> str:
    return "NA" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100 * value:.0f} %"


def _num(value, digits: int = 1, scale: float = 1.0) -> str:
    return "NA" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{scale * value:.{digits}f}"


def _label(summary: dict, several_selectors: bool) -> dict:
    methods = summary["methods"]
    row = {"pairing": f"{methods['detector']}/{methods['descriptor']}", "matcher": methods.get("matcher"),
           "estimator": methods.get("estimator")}
    if several_selectors:
        row["selector"] = methods["selector"]
    return row


def cell_table(summaries: list[dict]) -> Table:
    """Per cell: success with interval, false localization, position/orientation error of successes, time per
    query, map memory and build time (of the largest map)."""
    several = len({s["methods"]["selector"] for s in summaries}) > 1
    rows = []
    for s in summaries:
        m = s.get("metrics") or {}
        # the largest map's values; without them (one map size: MLflow logs no series) the cell's own, which are
        # the largest map's too (:func:`gtsweep.evaluation.schema.headline_rows`)
        largest = (s.get("by_map_images") or {}).get(max(s.get("by_map_images") or {"nan": 0}, key=float)) or m
        if s["status"] != "ok":
            rows.append({**_label(s, several), SUCCESS: s["status"].upper(), "reason": s.get("reason", "")})
            continue
        rows.append({**_label(s, several),
                     SUCCESS: f"{_pct(m.get('localization_success'))} [{_pct(m.get('localization_success_ci_low'))}"
                              f", {_pct(m.get('localization_success_ci_high'))}]",
                     "false loc. (% of foreign queries)": _pct(m.get("false_localization")),
                     "pos. err (px)": _num(m.get("success_position_error"), 2),
                     "ori. err (deg)": _num(m.get("success_orientation_error"), 3),
                     "time per query (ms)": _num(m.get("t_query"), 0, 1000),
                     "map (MB)": _num(largest.get("map_bytes"), 2, 1e-6),
                     "map (kB/m2)": _num(largest.get("map_bytes_per_m2"), 0, 1e-3),
                     "map build (s)": _num(largest.get("map_build_s"), 1), "reason": ""})
    frame = pd.DataFrame(rows).set_index("pairing").fillna("")
    frame = frame[[c for c in frame.columns if c != "reason"] + ["reason"]]  # last, even when an NA cell is first
    if not (frame["reason"] != "").any():
        frame = frame.drop(columns="reason")
    return Table("localization_cells", "Localization per cell: success [95 % CI], false localization, errors of "
                 "successes, latency and the largest map", frame)


def size_table(summaries: list[dict]) -> Table | None:
    """Success and time per query against map size (columns: map images), one row per cell."""
    rows = []
    for s in summaries:
        by_size = s.get("by_map_images") or {}
        if s["status"] != "ok" or not by_size:
            continue
        row = {"cell": " / ".join(str(s["methods"].get(k)) for k in ("detector", "descriptor", "matcher", "estimator"))}
        for size in sorted(by_size, key=float):
            values = by_size[size]
            row[f"{int(float(size))} images"] = (f"{_pct(values.get('localization_success'))}, "
                                                 f"{_num(values.get('t_query'), 0, 1000)} ms")
        rows.append(row)
    if not rows:
        return None
    return Table("localization_map_size", "Success (% of in-map queries) and time per query (ms) against map size "
                 "(columns: mapping images in the map)", pd.DataFrame(rows).set_index("cell"))


def plot_map_size(summaries: list[dict], out_dir: Path) -> list[Path]:
    """Success and latency against map size, one line per cell, one panel per pairing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [s for s in summaries if s["status"] == "ok" and s.get("by_map_images")]
    pairings = sorted({(s["methods"]["detector"], s["methods"]["descriptor"]) for s in ok})
    if not pairings:
        return []
    fig, axes = plt.subplots(2, len(pairings), figsize=(4.2 * len(pairings), 6.5), squeeze=False)
    estimators = sorted({s["methods"].get("estimator") for s in ok})
    matchers = sorted({s["methods"].get("matcher") for s in ok})
    dashes, markers = ("-", "--", ":", "-."), ("o", "s", "^", "v", "D")  # colour: estimator; dash, marker: matcher
    for column, (detector, descriptor) in enumerate(pairings):
        for s in ok:
            if (s["methods"]["detector"], s["methods"]["descriptor"]) != (detector, descriptor):
                continue
            sizes = sorted(s["by_map_images"], key=float)
            x = [float(v) for v in sizes]
            matcher, estimator = s["methods"].get("matcher"), s["methods"].get("estimator")
            k = matchers.index(matcher)
            style = {"color": f"C{estimators.index(estimator) % 10}", "linestyle": dashes[k % 4],
                     "marker": markers[k % 5], "label": f"{matcher}+{estimator}"}
            axes[0][column].plot(x, [s["by_map_images"][v].get("localization_success", math.nan) for v in sizes],
                                 **style)
            axes[1][column].plot(x, [1000 * s["by_map_images"][v].get("t_query", math.nan) for v in sizes], **style)
        axes[0][column].set_title(f"{detector} / {descriptor}")
        axes[0][column].set_ylim(-0.05, 1.05)
        axes[0][column].set_ylabel("success (30 px, 1.5 deg)")
        axes[1][column].set_ylabel("time per query (ms)")
        axes[1][column].set_xlabel("map size (mapping images)")
    axes[0][0].legend(fontsize=7)
    path = out_dir / "localization_map_size.png"
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]


def write_localization_report(summaries: list[dict], out_dir: str | Path,
                              plots: bool = True) -> tuple[list[Table], list[Path]]:
    """The localization tables (.md, .csv) and the map-size plot in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tables = [t for t in (cell_table(summaries), size_table(summaries)) if t is not None]
    files = []
    for table in tables:
        for suffix, text in ((".md", table.markdown() + "\n"), (".csv", table.cells.to_csv())):
            files.append(out_dir / f"{table.name}{suffix}")
            files[-1].write_text(text)
    return tables, files + (plot_map_size(summaries, out_dir) if plots else [])


def report(summaries: list[dict], out_dir: Path, options) -> tuple[list[Table], list[Path]]:
    """The kind's report (its entry's): the localization tables and the map-size plot."""
    return write_localization_report(summaries, out_dir, options.plots)


def format_localization(outcome, tables: list[Table] = ()) -> str:
    """The terminal summary: totals, then per cell success, false localization and latency."""
    statuses = pd.Series([s["status"] for s in outcome.summaries])
    lines = [f"gtsweep: {len(outcome.summaries)} localization cells ({(statuses == 'ok').sum()} evaluated, "
             f"{(statuses == 'na').sum()} not applicable, {(statuses == 'error').sum()} failed, "
             f"{outcome.resumed} kept from an earlier run) in {outcome.seconds:.1f} s",
             f"keypoint cache: {outcome.stats.cache_hits} hits, {outcome.stats.cache_misses} misses; "
             f"map tasks: {outcome.stats.detection_tasks}",
             f"results: {outcome.table}"]
    for table in tables:
        lines += ["", table.markdown()]
    return "\n".join(lines)
