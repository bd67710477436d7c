"""The results broken down: per texture (``report.by=texture``) and the synthetic transforms per type and strength.

The survey published its numbers per texture and per transformation in its supplementary material; gtsweep's
tables average them away. From the cells' per-view rows (each row keeps its texture, transform and strength):

- :func:`texture_summaries`: every cell's summary recomputed on one texture's views
  (:func:`gtsweep.orchestration.results.summarize`, so the same aggregates and intervals), from which every survey
  table is rebuilt per texture;
- :func:`strength_table`: per cell, transform and strength, the experiment's curve metrics (survey Figure-style
  curves as a table) with their intervals.

:func:`mean_summary` averages one cell's summaries over the repeats of a multirun.
"""
from __future__ import annotations

import math

import pandas as pd

from gtsweep.evaluation import schema
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.orchestration.results import summarize
from gtsweep.report.labels import shown_label, strength_label
from gtsweep.report.samples import Views
from gtsweep.report.tables import Table, frame, with_unit


def mean_summary(summaries: list[dict]) -> dict:
    """One cell's summaries over repeats: metrics (and per-step values) averaged over the repeats that evaluated
    it; ``ok`` when any did, else the first repeat's status and reason."""
    ok = [s for s in summaries if s["status"] == "ok"]
    if not ok:
        return dict(summaries[0])
    merged = {k: v for k, v in ok[0].items() if not k.startswith("by_") and k != "metrics"}
    merged["metrics"] = _mean_dicts([s.get("metrics") or {} for s in ok])
    for key in {k for s in ok for k in s if k.startswith("by_")}:
        steps = {step for s in ok for step in s.get(key) or {}}
        merged[key] = {step: _mean_dicts([(s.get(key) or {}).get(step) or {} for s in ok]) for step in steps}
    merged["n_repeats"] = len(ok)
    return merged


def _mean_dicts(dicts: list[dict]) -> dict:
    names = schema.ordered({k for d in dicts for k in d})
    means = {}
    for name in names:
        values = [float(d[name]) for d in dicts if isinstance(d.get(name), (int, float))
                  and math.isfinite(float(d[name]))]
        means[name] = sum(values) / len(values) if values else None
    return means


def textures(views: Views) -> list[str]:
    """The textures of the per-view rows."""
    return sorted({str(t) for rows in views.values() if "texture" in rows for t in rows["texture"].dropna()})


def texture_views(views: Views, texture: str) -> dict[str, pd.DataFrame]:
    """The per-view rows of one texture (cells without any such view left out)."""
    out = {key: rows[rows["texture"].astype(str) == texture] for key, rows in views.items() if "texture" in rows}
    return {key: rows for key, rows in out.items() if len(rows)}


def texture_summaries(summaries: list[dict], views: Views, texture: str) -> list[dict]:
    """Every cell's summary on one texture's views: the aggregates, intervals and per-step values recomputed from
    its rows (the mean over repeats in a multirun); cells without rows (not applicable, failed) as they are."""
    mine = texture_views(views, texture)
    out = []
    for summary in summaries:
        rows = mine.get(summary.get("key"))
        if rows is None:
            if summary.get("key") not in views:  # no per-view rows at all: NA or failed cell
                out.append(summary)
            continue
        experiment = schema.experiment_of(summary)
        groups = [group for _, group in rows.groupby("repeat")] if "repeat" in rows else [rows]
        repeats = [{**summary, **summarize(group.drop(columns=["repeat"], errors="ignore"), experiment)}
                   for group in groups]
        out.append(repeats[0] if len(repeats) == 1 else mean_summary(repeats))
    return out


def strength_table(summaries: list[dict], views: Views | None, name: str = "synthetic_by_strength",
                   note: str = "") -> Table | None:
    """Per cell on a synthetic transform and per strength (with its unit): the curve metrics of its experiment,
    ``ours [low, high]``, headed with their units (survey section 5: results per transformation type and
    strength)."""
    df = frame(summaries)
    part = df[df["transform"].isin(list(TRANSFORMS)) & (df["status"] == "ok")]
    if part.empty or not views:
        return None
    by_cell = {s.get("key"): s for s in summaries}
    metrics = [m for m in schema.ordered({m for s in summaries if s.get("key") in set(part["key"])
                                          for m in schema.curves(schema.experiment_of(s))})
               if any(schema.aggregable(schema.METRICS[m], schema.with_derived(views.get(k, pd.DataFrame())))
                      for k in part["key"])]
    table = Table(name, f"Synthetic transforms per type and strength{note}: ours [95 % interval]", pd.DataFrame())
    out = []
    for index, cell in part.iterrows():
        rows = views.get(cell["key"])
        if rows is None or "strength" not in rows:
            continue
        methods = by_cell[cell["key"]]["methods"]
        label = "-".join(shown_label(methods[k]) for k in ("detector", "descriptor") if methods.get(k))
        label += f" [{methods['selector']}]"
        for strength in sorted(pd.to_numeric(rows["strength"], errors="coerce").dropna().unique()):
            record = {"pairing": label, "transform": cell["transform"],
                      "strength": strength_label(cell["transform"], strength)}
            for metric in metrics:
                if schema.aggregable(schema.METRICS[metric], schema.with_derived(rows)):
                    declared = schema.METRICS[metric]
                    record[with_unit(metric, declared.unit)] = table.show(
                        label, f"{cell['transform']} {strength:g} {metric}", part.loc[[index]], metric, None,
                        declared.digits, views, {"strength": float(strength)})
            out.append(record)
    if not out:
        return None
    table.cells = pd.DataFrame(out).set_index("pairing").sort_values(["transform", "pairing"], kind="stable")
    return table
