"""``python -m gtsweep.report <run dir>`` (or ``<parent run id> --mlflow``): rebuild a run's report with the report
of the experiment kind its cells recorded (:func:`gtsweep.experiments.kinds.recorded_kind`)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gtsweep.core.errors import GtsweepError
from gtsweep.experiments.kinds import ReportOptions, recorded_kind
from gtsweep.report.samples import load_views
from gtsweep.report.scale import load_scale, scale_from_config
from gtsweep.report.tables import ALPHA, load_summaries


def main(argv: list[str] | None = None) -> int:
    """The report command; returns its exit code (2 and one line for bad input)."""
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
            from gtsweep.tracking.readback import config_from_mlflow, summaries_from_mlflow, views_from_mlflow

            summaries = summaries_from_mlflow(args.source, args.tracking_uri)
            views = lambda: views_from_mlflow(args.source, args.tracking_uri)  # noqa: E731
            scale = scale_from_config(config_from_mlflow(args.source, args.tracking_uri))
        else:
            summaries, views = load_summaries(args.source), lambda: load_views(args.source)
            scale = load_scale(args.source)
        experiment = recorded_kind(summaries)  # e.g. a localization run: its own report, no survey tables
        options = ReportOptions(plots=not args.no_plots, views=views, by=args.by, alpha=args.alpha, scale=scale)
        tables, files = experiment.report(summaries, out, options)
    except GtsweepError as e:
        print(f"gtsweep.report: error: {e}", file=sys.stderr)
        return 2
    for table in tables:
        print(table.markdown(), end="\n\n")
    print(scale.line(detection=experiment.budget_scale))
    print(f"{len(files)} files in {out}")
    return 0
