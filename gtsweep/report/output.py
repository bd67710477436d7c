"""Write the report of a pair experiments' sweep, and what any kind's report may use (:class:`ReportOptions`); the
report command, ``python -m gtsweep.report``, is :mod:`gtsweep.experiments.report_command`: it picks each kind's
report.

The report (:mod:`gtsweep.report.tables`) holds every survey table the cells can fill, each entry ``ours
±half-width (paper)`` with the entries tied with the best below it, the per-cell table, the synthetic results per
transform and strength, and the plots. ``by="texture"`` (``report.by=texture``) adds all of that per texture
under ``by_texture/<texture>/`` (:mod:`gtsweep.report.breakdown`).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from gtsweep.core.errors import GtsweepError
from gtsweep.orchestration.results import by_variant
from gtsweep.report.breakdown import strength_table, texture_summaries, texture_views, textures
from gtsweep.report.labels import shown_label, variant_slug
from gtsweep.report.rotation import write_rotation
from gtsweep.report.samples import Views
from gtsweep.report.scale import Scale, annotate
from gtsweep.report.tables import ALPHA, BY, Table, build_tables, table_cells, write_tables
from gtsweep.stages.select import SELECTORS

#: The survey tables whose entries are pairings (a detector's selector is not a column of them).
PAIRING_TABLES = ("table4", "table5", "table6", "table7")


@dataclass(frozen=True)
class ReportOptions:
    """What a report may use besides the cells' summaries: plots or not, the per-view rows (loaded on demand),
    per-texture breakdowns, the paired tests' significance level, the data set's scale."""

    plots: bool = True
    views: Callable[[], Views | None] = lambda: None
    by: str | None = None
    alpha: float = ALPHA
    scale: Scale | None = None


def selector_note(summaries: list[dict]) -> str:
    """``"; selector NMS, MSER: ANMS"`` when the pairing cells use one selector per detector and not the same one
    for all (``selector_for``), else "": the tables then say which selector each detector's entries used."""
    used: dict[str, set] = {}
    for s in summaries:
        if s.get("methods", {}).get("descriptor"):
            used.setdefault(s["methods"]["detector"], set()).add(s["methods"]["selector"])
    if not used or any(len(selectors) != 1 for selectors in used.values()):
        return ""
    chosen = {detector: next(iter(selectors)) for detector, selectors in used.items()}
    counts = Counter(chosen.values())
    if len(counts) < 2:
        return ""
    common = counts.most_common(1)[0][0]
    others = ", ".join(f"{shown_label(d)}: {_selector_label(chosen[d])}" for d in sorted(chosen)
                       if chosen[d] != common)
    return f"; selector {_selector_label(common)}, {others}"


def _selector_label(name: str) -> str:
    spec = SELECTORS.get(name, None)
    return spec.label if spec else name


def _write_set(summaries: list[dict], views: Views | None, out_dir: Path, plots: bool, alpha: float,
               scale: Scale, note: str = "") -> tuple[list[Table], list[Path]]:
    tables = build_tables(summaries, views, alpha)
    annotate(tables, scale)
    pinned = selector_note(summaries)
    for table in tables:
        table.title += (pinned if table.name.startswith(PAIRING_TABLES) else "") + note
    extra = [t for t in (table_cells(summaries), strength_table(summaries, views, note=note)) if t is not None]
    files = write_tables(tables + extra, out_dir) + write_rotation(summaries, views, out_dir, plots)
    if plots:
        from gtsweep.report.plots import write_plots

        groups = by_variant(summaries)  # with several matchers or estimators, plots per (matcher, estimator)
        for variant, part in groups.items():
            files += write_plots(part, out_dir / variant_slug(variant) if len(groups) > 1 else out_dir, views)
    return tables, files


def write_report(summaries: list[dict], out_dir: str | Path, plots: bool = True, views: Views | None = None,
                 by: str | None = None, alpha: float = ALPHA,
                 scale: Scale | None = None) -> tuple[list[Table], list[Path]]:
    """Write every survey table, the per-cell table and the per-strength table as .md, .tex and .csv (and the
    plots) into ``out_dir``, and with ``by="texture"`` all of them per texture into ``by_texture/<texture>/``;
    returns the survey tables (over every texture) and every file. ``views``: the cells' per-view rows;
    ``scale``: the run's px/mm and thresholds, stated in mm under the tables (None: Micro-GPS' scale, assumed)."""
    if by not in BY:
        raise GtsweepError(f"report.by must be one of {', '.join(str(b).lower() for b in BY)}, not {by!r}")
    out_dir = Path(out_dir)
    scale = scale or Scale()
    tables, files = _write_set(summaries, views, out_dir, plots, alpha, scale)
    if by == "texture":
        if not views:
            raise GtsweepError("report.by=texture needs the cells' per-view rows (cells/*.csv)")
        for texture in textures(views):
            files += _write_set(texture_summaries(summaries, views, texture), texture_views(views, texture),
                                out_dir / "by_texture" / texture, plots, alpha, scale, f", texture {texture}")[1]
    return tables, files
