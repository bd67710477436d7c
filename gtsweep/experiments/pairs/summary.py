"""The terminal summary of a pair experiment's sweep: totals, then the survey tables it fills (else the headline
metric per transform)."""
from __future__ import annotations

import pandas as pd

from gtsweep.evaluation import schema
from gtsweep.orchestration.results import swept_variants
from gtsweep.orchestration.skeleton import SweepOutcome
from gtsweep.report.tables import Table, frame, sample_note


def headline_tables(outcome: SweepOutcome) -> dict[str, pd.DataFrame]:
    """Per transform: the experiment's headline metric, detector rows x descriptor (or selector) columns; the
    descriptor columns split by matcher and estimator when the grid has several."""
    table = frame(outcome.summaries)
    metric = schema.headline(outcome.grid.experiment["name"])
    columns = ["selector"] if outcome.grid.experiment["name"] == "detection" else \
        ["descriptor", *swept_variants(outcome.summaries)]
    tables = {}
    for _transform, part in table.groupby("transform", sort=False):
        values = part[metric] if metric in part else pd.Series(float("nan"), index=part.index)
        shown = values.map(lambda v: "NA" if pd.isna(v) else f"{v:.2f}").where(part["status"] == "ok", "NA")
        pivot = part.assign(value=shown).pivot_table(index="detector", columns=columns, values="value",
                                                     aggfunc="first", sort=False)
        tables[f"{metric} ({sample_note(part)})"] = pivot
    return tables


def format_outcome(outcome: SweepOutcome, tables: list[Table] = ()) -> str:
    """Totals, then the survey's tables that the sweep fills (else the headline metric per transform)."""
    statuses = pd.Series([s["status"] for s in outcome.summaries])
    lines = [
        f"gtsweep: {len(outcome.summaries)} cells ({(statuses == 'ok').sum()} evaluated, "
        f"{(statuses == 'na').sum()} not applicable, {(statuses == 'error').sum()} failed, "
        f"{outcome.resumed} kept from an earlier run) in {outcome.seconds:.1f} s",
        f"keypoint cache: {outcome.stats.cache_hits} hits, {outcome.stats.cache_misses} misses "
        f"(= detector calls)" + (f", {outcome.stats.cache_corrupt} damaged entries replaced"
                                 if outcome.stats.cache_corrupt else ""),
        f"results: {outcome.table}",
    ]
    if outcome.skipped_items:
        lines.append(f"data set: {len(outcome.skipped_items)} bad item(s) skipped (dataset.skip_bad=true); "
                     f"listed in {outcome.output_dir / 'run.json'}")
    if tables:
        for table in tables:
            lines += ["", table.markdown()]
        lines += ["", "cells read 'ours [95 % interval] (paper)'; NA = not applicable"]
    else:
        for title, pivot in headline_tables(outcome).items():
            lines += ["", title, pivot.to_string()]
    return "\n".join(lines)
