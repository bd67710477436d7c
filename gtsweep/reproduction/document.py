"""``docs/REPRODUCTION.md`` from the committed state alone: every look taken, nothing computed.

The state's rows are read as each preset's cells (:class:`~gtsweep.reproduction.state.State`), rounds 1-5
are replayed on their prefixes (:func:`~gtsweep.reproduction.looks.replay`), the amendment's looks are taken where
their data is complete, and the document gives for each finding its verdict, the look and n that decided it, the
test, the margin with the survey's words, the correction and, for an undecided finding, the images that would
decide it at its last look's level and for a new study at alpha = 0.05.
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import yaml

from gtsweep.core.atomic import write_atomically
from gtsweep.core.paths import CONF_DIR
from gtsweep.evaluation.verdicts import UNDECIDED, images_to_decide
from gtsweep.report.scale import annotate, scale_from_config
from gtsweep.report.tables import build_tables
from gtsweep.report.tuning import tuning_table
from gtsweep.reproduction import looks as looking
from gtsweep.reproduction import verify
from gtsweep.reproduction.design import DESIGN_PAGE, NEW_WINDOWS
from gtsweep.reproduction.rounds import PRESETS
from gtsweep.reproduction.state import State
from gtsweep.reproduction.tuned import TUNED, tuned_line

#: The fixed full protocol's cost on 2 cores, from the measured task costs after MSD's port (README, Performance).
FULL_PROTOCOL_H = 18.8
STUDY_ALPHA = 0.05


def task_hours(state: State) -> dict[str, float]:
    """Recorded task CPU-seconds / 2 (the machine's cores), in hours, per part of the work."""
    spent: dict[str, float] = {}
    for chunk in state.chunks:
        spent[chunk["kind"]] = spent.get(chunk["kind"], 0.0) + chunk["task_s"] / 2 / 3600
    return spent


def _decide_numbers(finding, level: float) -> str:
    """'' or the images that would decide an undecided finding: at its last look's level and for a new study."""
    if finding.verdict != UNDECIDED or not finding.parts:
        return ""
    undecided = [p for p in finding.parts if not isinstance(p, str)]
    at_level = [images_to_decide(p, level) for p in undecided]
    fresh = [images_to_decide(p, STUDY_ALPHA) for p in undecided]
    if all(x == math.inf for x in at_level):
        return " (no number of images decides it: its interval is over the methods compared)"
    finite = lambda xs: max((x for x in xs if math.isfinite(x)), default=math.nan)  # noqa: E731
    a, b = finite(at_level), finite(fresh)
    if not (math.isfinite(a) and math.isfinite(b)):
        return ""
    return (f" (~{math.ceil(a)} images or pairs would decide it at its last look's level {level:.2g}, "
            f"~{math.ceil(b)} for a new study at alpha {STUDY_ALPHA:g}; now {finding.n})")


def findings_rows(sequential, amended: dict) -> list[str]:
    """The findings table: the twelve as pre-stated, each at its last look (rounds 1-5, or the amendment's)."""
    rows = ["| finding | verdict | decided at (look, n per texture, level) | test | margin (the survey's words) "
            "| correction | evidence |", "|---|---|---|---|---|---|---|"]
    for status in sequential.status:
        f, h = status.finding, status.hypothesis
        if f is None:
            rows.append(f"| {h.text} | not rebuilt yet | - | {h.test} | {h.margin} | - | - |")
            continue
        pending = next((lk for lk in amended["final"] if lk.finding.text == h.text and lk.missing), None)
        look = f"round {status.round}, {status.per_texture}, {status.nominal:.2g}" if status.round else "-"
        verdict = f.verdict + _decide_numbers(f, status.nominal) + \
            (f" (its final look at 100 per texture is pending: {pending.missing})" if pending else "")
        rows.append(f"| {h.text} | {verdict} | {look} | {f.test or h.test} | {h.margin}; {h.claim} | "
                    f"{f.correction or '-'} | {f.evidence.replace('|', '/') or '-'} |")
    return rows


def looks_rows(found: list) -> list[str]:
    rows = ["| finding | verdict | look (n per texture, level) | test | margin | correction | evidence |",
            "|---|---|---|---|---|---|---|"]
    for lk in found:
        f = lk.finding
        verdict = f.verdict + (f" ({lk.missing})" if lk.missing else _decide_numbers(f, lk.level))
        rows.append(f"| {f.text} | {verdict} | {lk.n_per_texture}, {lk.level:.2g} | {f.test} | {f.margin} | "
                    f"{f.correction or '-'} | {f.evidence.replace('|', '/') or '-'} |")
    return rows


def header(state: State, finished: bool, done_parts: set[str]) -> list[str]:
    spent = task_hours(state)
    wall = sum(c.get("wall_s", 0.0) for c in state.chunks) / 3600
    status = ("The run is finished: every chunk of the amended design is in the state."
              if finished else "**The run is not finished**: the chunks still to collect are listed under "
              "'Work'; `make reproduce` resumes it (`python -m gtsweep.reproduction collect --commit`).")
    return ["# Reproducing the survey", "",
            "Generated by `python -m gtsweep.reproduction document` (`make reproduce`) from the committed state "
            "`docs/reproduction/state/` alone: every look is taken on its rows, nothing is computed. Design: "
            f"`{DESIGN_PAGE.relative_to(DESIGN_PAGE.parents[1])}` with its amendment of 2026-11-27 (digest "
            f"{state.plan.get('design')}). Data: the embedded rendered data set (`dataset=survey`: 1288×964 "
            "views, capture physics).", "", status, "",
            f"Compute spent, counted as recorded task CPU-seconds / 2 (2 cores; a detection taken from the "
            f"keypoint cache of an earlier chunk counted once, as the protocol's estimate counts it): "
            f"**{sum(spent.values()):.1f} h** "
            f"({', '.join(f'{k} {v:.1f} h' for k, v in sorted(spent.items()))}) against ~{FULL_PROTOCOL_H} h for "
            f"the fixed full protocol (with MSD's port); wall time of the chunks {wall:.1f} h. "
            f"{_parts_line(done_parts)}"]


def _parts_line(done_parts: set[str]) -> str:
    """'Parts of the new data complete: 1 of 4 (extension); to come: round6, ...'."""
    done = [p for p in NEW_WINDOWS if p in done_parts]
    to_come = [p for p in NEW_WINDOWS if p not in done_parts]
    return (f"Parts of the new data complete: {len(done)} of {len(NEW_WINDOWS)} ({', '.join(done) or 'none'})"
            + (f"; to come: {', '.join(to_come)}." if to_come else "."))


def write(state: State, docs: Path, alpha: float, done_parts: set[str], finished: bool,
          tuning: str | None = None) -> Path:
    """Write ``docs/REPRODUCTION.md`` and its tables (``docs/reproduction/``) from ``state``."""
    sequential = looking.replay(state, alpha)
    checks = verify.check(sequential)
    amended = looking.amended_looks(state, sequential, alpha, done_parts)
    assets = Path(docs) / "reproduction"
    assets.mkdir(parents=True, exist_ok=True)
    for old in assets.iterdir():
        if old.is_file():
            old.unlink()
    lines = header(state, finished, done_parts)
    if tuning:
        lines += ["", tuned_line(tuning), "", tuning_table(TUNED)]
    lines += ["", "## The survey's findings", "", "Each finding as pre-stated (`docs/statistics_design.md`), at "
              "its last look: rounds 1-5 of the sequential design, replayed on the state's rows, then the "
              "amendment's final look at the survey's count for the findings still open.", "",
              *findings_rows(sequential, amended), "", "## The amendment's looks", "",
              "Findings 3, 4 and 9 at their final look (frozen round-5 picks, old half 1 + new images, the remaining "
              "alpha):", "", *looks_rows(amended["final"]), "",
              "Restated findings (new data only, alpha 0.05 each; reported beside the originals, never in their "
              "place):", "", *looks_rows(amended["restated"]), "",
              "Table 2 extension (7 fresh images per texture, alpha 0.05; beside the survey-count verdicts above):",
              "", *looks_rows(amended["extension"]), "", "## The rebuild against its record", "",
              *[f"{line}  " for line in verify.report(checks)]]
    lines += _tables(state, assets, alpha)
    path = Path(docs) / "REPRODUCTION.md"
    write_atomically(path, "\n".join(lines) + "\n")
    return path


def _tables(state: State, assets: Path, alpha: float) -> list[str]:
    """Every preset's tables and counts per cell, from the state's rows."""
    lines, counted, ties = ["", "## The tables", ""], [], []
    scale = scale_from_config({"dataset": yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())})
    for preset in [p for p in PRESETS if p in state.presets]:
        summaries, views = state.summaries(preset), state.views(preset)
        per_cell = cell_counts(summaries, views)
        per_cell.to_csv(assets / f"{preset}__cell_counts.csv", index=False)
        counted.append(f"| {preset} | {tally(per_cell)} |")
        for table in build_tables(summaries, views, alpha):
            if table.name != preset and not table.name.startswith(f"{preset}_"):
                continue
            annotate([table], scale)
            lines += ["", table.markdown(note=True)]
            (assets / f"{table.name}.csv").write_text(table.cells.to_csv())
            if table.ties is not None and table.ties.best:
                ties.append(ties_row(table))
    return ["", "## Counts per cell", "", "| preset | per texture: cells |", "|---|---|", *counted,
            "", "## Ties with the best", "", "| table | best | tied with the best | which |", "|---|---|---|---|",
            *ties, *lines]


def cell_counts(summaries: list[dict], views: dict) -> pd.DataFrame:
    """Per cell: its key, status, images or pairs, and images or pairs per texture (from its per-view rows)."""
    rows = []
    for s in summaries:
        cell = views.get(s.get("key"))
        textures = cell["texture"].nunique() if cell is not None and len(cell) else 0
        n = int(s.get("n_images") or 0)
        rows.append({"cell": s.get("key"), "status": s.get("status"), "images_or_pairs": n,
                     "per_texture": round(n / textures) if textures else None})
    return pd.DataFrame(rows, columns=["cell", "status", "images_or_pairs", "per_texture"])


def tally(per_cell: pd.DataFrame) -> str:
    known = per_cell.dropna(subset=["per_texture"])
    found = known.groupby("per_texture").size().sort_index(ascending=False)
    text = "; ".join(f"{int(n)}: {k} cells" for n, k in found.items())
    rest = len(per_cell) - len(known)
    return text + (f"; {rest} cells without rows (not applicable or failed)" if rest else "")


def ties_row(table) -> str:
    t = table.ties
    untested = f"; {len(t.untested)} without per-view rows" if t.untested else ""
    return (f"| {table.name} | {t.best} ({t.metric} {t.best_value:.2f}) | {len(t.tied)} of {len(t.tests)}{untested} "
            f"| {', '.join(t.tied) or '-'} |")
