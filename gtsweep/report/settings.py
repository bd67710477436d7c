"""Settings of a multirun side by side, cell by cell: which cells move when one setting changes.

``python -m gtsweep -m sweeps=table4_incremental experiment.foreign_scale=own,octave0`` runs the same grid on the
same views under each setting; the combined output (:mod:`gtsweep.report.combine`) then holds, per pose-success
cell (detector, descriptor, transform), each setting's value with its 95 % interval, the paired test of every
setting against the first one (the first job's: ``own`` above) on the views both evaluated (exact McNemar for one view
per pair,
:func:`gtsweep.report.samples.compare`), and the survey's number where it has one. A cell *moves* when that
test rejects equality at ``alpha``. Written to ``combined/settings.md`` when the jobs have more than one setting.
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from gtsweep.evaluation.statistics import holm
from gtsweep.report.labels import paper_label, shown_label
from gtsweep.report.samples import compare, estimate
from gtsweep.report.tables import fmt, frame, paper

METRIC = "pose_success"
#: The survey's table of each real-pair transform (pose success per detector and descriptor).
PAPER = {"incremental": "table4_success_incremental.csv", "absolute": "table5_success_absolute.csv"}


def _setting_cells(jobs: list[dict], by_job: dict, views_by_job: dict, setting: str):
    """The cells (rows of :func:`~gtsweep.report.tables.frame`, keys made unique per job) and per-view rows of
    one setting's jobs (its repeats)."""
    cells, views = [], {}
    for job in (j for j in jobs if j["setting"] == setting):
        part = frame(by_job[job["job"]])
        if part.empty:
            continue
        part = part.assign(cell=part["key"], key=job["job"] + "|" + part["key"])
        cells.append(part)
        # repeats are strata named by their seed, so that a setting's seed-0 views pair with another's
        views.update({f"{job['job']}|{key}": rows.assign(repeat=f"seed {job['seed']}")
                      for key, rows in views_by_job[job["job"]].items()})
    return (pd.concat(cells, ignore_index=True) if cells else pd.DataFrame()), views


def _paper_value(transform: str, detector: str, descriptor: str) -> float:
    if transform not in PAPER:
        return math.nan
    table = paper(PAPER[transform]).set_index("detector")
    try:
        return float(table.loc[paper_label(detector), paper_label(descriptor)])
    except (KeyError, ValueError):
        return math.nan


def setting_labels(settings: list[str]) -> tuple[dict[str, str], str]:
    """Column labels of the settings and what they vary: the values alone when every setting is one override
    of the same key (``own``, ``octave0``; ``experiment.foreign_scale``), else the settings themselves."""
    single = all("=" in s and " " not in s for s in settings)
    keys = {s.split("=", 1)[0].lstrip("+") for s in settings} if single else set()
    if len(keys) == 1:
        return {s: s.split("=", 1)[1] for s in settings}, keys.pop()
    return {s: s for s in settings}, "settings"


def settings_rows(jobs: list[dict], by_job: dict, views_by_job: dict, alpha: float) -> pd.DataFrame:
    """One row per pose-success cell: each setting's value and interval, the paired test against the first
    setting, the survey's value (columns labelled by :func:`setting_labels`)."""
    settings = list(dict.fromkeys(job["setting"] for job in jobs))  # in job order
    label = setting_labels(settings)[0]
    data = {s: _setting_cells(jobs, by_job, views_by_job, s) for s in settings}
    base_cells, views = data[settings[0]]
    if base_cells.empty or METRIC not in base_cells:
        return pd.DataFrame()
    for _, setting_views in data.values():
        views = {**views, **setting_views}
    rows, tests = [], {setting: {} for setting in settings[1:]}  # setting -> row index -> paired test
    for cell, base in base_cells.groupby("cell", sort=True):
        first = base.iloc[0]
        if pd.isna(first.get("descriptor")) or pd.isna(first.get(METRIC)):
            continue
        row = {"detector": first["detector"], "descriptor": first["descriptor"], "transform": first["transform"],
               "survey": _paper_value(first["transform"], first["detector"], first["descriptor"])}
        value, low, high = estimate(base, METRIC, views)
        row[label[settings[0]]] = fmt(value, low=low, high=high)
        for setting in settings[1:]:
            cells = data[setting][0]
            other = cells[cells["cell"] == cell] if not cells.empty else cells
            if other.empty or METRIC not in other or other[METRIC].isna().all():  # e.g. only failed cells
                row[label[setting]] = "NA"
                continue
            value_b, low_b, high_b = estimate(other, METRIC, views)
            row[label[setting]] = fmt(value_b, low=low_b, high=high_b)
            test = compare(other, base, METRIC, views)
            if test is not None:
                tests[setting][len(rows)] = test
        rows.append(row)
    rows = pd.DataFrame(rows)
    for setting, found in tests.items():  # Holm across the cells of one setting: a cell moves at the table's level
        adjusted = dict(zip(found, holm([t.p_value for t in found.values()])))
        for i, test in found.items():
            rows.loc[i, f"{label[setting]} - {label[settings[0]]}"] = \
                f"{test.difference:+.2f} (p = {test.p_value:.2g}, Holm {adjusted[i]:.2g})"
            rows.loc[i, f"moves ({label[setting]})"] = "yes" if adjusted[i] < alpha else ""
    return rows


def settings_markdown(rows: pd.DataFrame, settings: list[str], alpha: float) -> str:
    """The table of :func:`settings_rows` with a line per setting: cells that move, and the mean absolute
    distance to the survey over the cells it reports."""
    label, varied = setting_labels(settings)
    settings = [label[s] for s in settings]
    lines = [f"**{varied} side by side: {METRIC} per cell with its 95 % interval; paired test of each setting "
             f"against `{settings[0]}` on the same views, Holm-adjusted across the cells (a cell moves at "
             f"alpha = {alpha} after Holm)**", ""]
    columns = ["detector", "descriptor", "transform", *[c for c in rows.columns
                                                          if c not in ("detector", "descriptor", "transform")]]
    lines += ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows.itertuples(index=False):
        values = dict(zip(rows.columns, row))
        shown = {**values, "detector": shown_label(values["detector"]),
                 "descriptor": shown_label(values["descriptor"]),
                 "survey": "" if pd.isna(values["survey"]) else f"{values['survey']:.2f}"}
        lines.append("| " + " | ".join("" if pd.isna(shown.get(c)) else str(shown.get(c)) for c in columns) + " |")
    lines.append("")
    surveyed = rows[rows["survey"].notna()]
    values = {setting: pd.to_numeric(surveyed[setting].astype(str).str.split(" ").str[0], errors="coerce")
              for setting in settings}
    common = pd.concat(values, axis=1).notna().all(axis=1)
    for setting in settings:
        moved = rows.get(f"moves ({setting})")
        count = "" if moved is None else f"{int((moved == 'yes').sum())} of {len(rows)} cells move; "
        distance = (values[setting] - surveyed["survey"]).abs()
        if not distance.notna().any():
            lines.append(f"- `{setting}`: {count}no cell with a value that the survey reports")
            continue
        both = f" ({distance[common].mean():.3f} over the {int(common.sum())} that every setting has)" \
            if common.any() else ""
        lines.append(f"- `{setting}`: {count}mean |ours - survey| {distance.mean():.3f} over "
                     f"{int(distance.notna().sum())} cells the survey reports{both}")
    return "\n".join(lines) + "\n"


def write_settings(out: Path, jobs: list[dict], by_job: dict, views_by_job: dict, alpha: float) -> list[Path]:
    """``out/settings.md`` and ``settings.csv`` when the jobs hold more than one setting (else nothing)."""
    settings = list(dict.fromkeys(job["setting"] for job in jobs))  # in job order
    if len(settings) < 2:
        return []
    rows = settings_rows(jobs, by_job, views_by_job, alpha)
    if rows.empty:
        return []
    paths = [out / "settings.csv", out / "settings.md"]
    rows.to_csv(paths[0], index=False)
    paths[1].write_text(settings_markdown(rows, settings, alpha))
    return paths
