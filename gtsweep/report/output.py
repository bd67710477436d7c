"""Write a sweep's report, and the report command: ``python -m gtsweep.report <run dir>`` (or ``--mlflow``).

The report (:mod:`gtsweep.report.tables`) holds every survey table the cells can fill, each entry ``ours
±half-width (paper)`` with the entries tied with the best below it, the per-cell table, the synthetic results per
transform and strength, and the plots. ``by="texture"`` (``report.by=texture``) adds all of that per texture
under ``by_texture/<texture>/`` (:mod:`gtsweep.report.breakdown`).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gtsweep.core.errors import GtsweepError
from gtsweep.orchestration.results import by_variant
from gtsweep.report.breakdown import (
    strength_table,
    texture_summaries,
    texture_views,
    textures,
)
from gtsweep.report.labels import variant_slug
from gtsweep.report.samples import Views, load_views
from gtsweep.report.rotation import write_rotation
from gtsweep.report.scale import Scale, annotate, load_scale, scale_from_config
from gtsweep.report.tables import (
    ALPHA,
    BY,
    Table,
    build_tables,
    load_summaries,
    table_cells,
    write_tables,
)


def _write_set(summaries: list[dict], views: Views | None, out_dir: Path, plots: bool, alpha: float,
               scale: Scale, note: str = "") -> tuple[list[Table], list[Path]]:
    tables = build_tables(summaries, views, alpha)
    annotate(tables, scale)
    if note:
        for table in tables:
            table.title += note
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.report", description=__doc__.splitlines()[0])
    parser.add_argument("source", help="a sweep's output directory (it holds cells/ and results.csv), or with "
                                       "--mlflow the id of a sweep's parent run (a sweep or experiment=localization)")
    parser.add_argument("--mlflow", action="store_true", help="read the cells (and their per-view rows, the child "
                                                              "runs' artifacts) from MLflow child runs of SOURCE")
    parser.add_argument("--tracking-uri", help="MLflow store (default: $MLFLOW_TRACKING_URI or ./mlflow.db)")
    parser.add_argument("--out", help="where to write tables and plots (default: <source>/report, or ./report)")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    parser.add_argument("--by", choices=["texture"], help="also every table per texture (report.by)")
    parser.add_argument("--alpha", type=float, default=ALPHA,
                        help=f"significance level of the paired tests for the ties with the best (default {ALPHA})")
    args = parser.parse_args(argv)
    if not 0 < args.alpha < 1:
        parser.error(f"--alpha must be in (0, 1), not {args.alpha}")
    out = Path(args.out or ("report" if args.mlflow else Path(args.source) / "report"))
    try:
        if args.mlflow:
            from gtsweep.tracking.sweep import (
                config_from_mlflow,
                summaries_from_mlflow,
                views_from_mlflow,
            )

            summaries = summaries_from_mlflow(args.source, args.tracking_uri)
            views = views_from_mlflow(args.source, args.tracking_uri)
            scale = scale_from_config(config_from_mlflow(args.source, args.tracking_uri))
        else:
            summaries, views = load_summaries(args.source), load_views(args.source)
            scale = load_scale(args.source)
        localization = bool(summaries) and all(s.get("experiment") == "localization" for s in summaries)
        if localization:  # e.g. --mlflow of an experiment=localization run: its own report, no survey tables
            from gtsweep.report.localization import write_localization_report

            tables, files = write_localization_report(summaries, out, not args.no_plots)
        else:
            tables, files = write_report(summaries, out, not args.no_plots, views, args.by, args.alpha, scale)
    except GtsweepError as e:
        print(f"gtsweep.report: error: {e}", file=sys.stderr)
        return 2
    for table in tables:
        print(table.markdown(), end="\n\n")
    print(scale.line(detection=not localization))
    print(f"{len(files)} files in {out}")
    return 0
