"""The report of a pair experiments' sweep: the survey's tables with intervals and ties, the per-cell and
per-strength tables and the plots (:func:`gtsweep.report.output.write_report`)."""
from __future__ import annotations

from pathlib import Path

from gtsweep.report.output import ReportOptions, write_report


def report(summaries: list[dict], out_dir: Path, options: ReportOptions):
    """The survey's tables with intervals and ties, the per-cell and per-strength tables and the plots."""
    return write_report(summaries, out_dir, plots=options.plots, views=options.views(), by=options.by,
                        alpha=options.alpha, scale=options.scale)
