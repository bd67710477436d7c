"""Write ``docs/REPRODUCTION.md`` from the survey's table presets: ``python -m gtsweep.reproduction.command``.

The runs themselves are :mod:`gtsweep.reproduction.rounds`'s (one size, or rounds with ``--size decide``);
this module is the thin command line and the document. The survey's tables are rebuilt beside the paper's
numbers; each of the survey's findings is a pre-stated hypothesis (:mod:`gtsweep.reproduction.findings`) judged on
the same images or pairs, with ``--size decide`` under the sequential design of :mod:`gtsweep.reproduction.sequential`;
each table names the entries tied with its best. Hand-written explanations of differences are read from
``docs/reproduction_notes.md`` when it exists.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import sys
from pathlib import Path

from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import BadInput
from gtsweep.core.interrupts import SIGNALS, Interrupted, on_signal
from gtsweep.core.paths import DEFAULT_CACHE_DIR, PROJECT_DIR
from gtsweep.report.samples import load_views
from gtsweep.report.scale import annotate, load_scale
from gtsweep.report.tables import ALPHA, build_tables, frame, load_summaries
from gtsweep.report.tuning import tuning_table
from gtsweep.reproduction import rounds as runs
from gtsweep.reproduction.document import cell_counts, tally, ties_row
from gtsweep.reproduction.findings import check_findings, survey_variant
from gtsweep.reproduction.run_record import RunRecord
from gtsweep.reproduction.sequential import Sequential
from gtsweep.reproduction.tuned import TUNED, tuned_digest, tuned_line, tuning_fingerprint

PRESETS, SIZES = runs.PRESETS, runs.SIZES
CHOICES = sorted([*SIZES, "decide"])
INTERIM = ("**Interim document: this reproduction is not finished.** It shows the rounds finished so far "
           "(`--document-only` on an unfinished run); the same `make reproduce` resumes it. Each verdict is its "
           "finding's last look; a finding marked *still open* may be decided by a later round.")


def _latest(results: list[dict]) -> list[dict]:
    """Each preset's newest run (the last round that ran it), in preset order."""
    newest = {}
    for r in results:
        if r["preset"] not in newest or r.get("round", 0) >= newest[r["preset"]].get("round", 0):
            newest[r["preset"]] = r
    return [newest[p] for p in PRESETS if p in newest] + [r for p, r in newest.items() if p not in PRESETS]


def _size_line(size: str, results: list[dict]) -> str:
    if size != "decide":
        return f"size `{size}`: {' '.join(SIZES.get(size, []))} (counts per texture)"
    reached = ", ".join(f"{r['preset']} {runs.counts(r['preset'], r['counts'])}" for r in _latest(results))
    spent, full = sum(r["wall_s"] for r in results), runs.full_protocol_estimate(results)
    return (f"size `decide` (sequential rounds {', '.join('/'.join(map(str, c)) for c in runs.ROUNDS)} synthetic "
            f"images / incremental / absolute pairs per texture, each round only for the cells the undecided "
            f"findings read, each cell evaluating only the images or pairs it had not evaluated yet); counts per "
            f"texture of each preset's newest round: {reached} (each cell's own count: \"Counts per cell\" below). "
            f"Compute spent: {spent / 3600:.1f} h against an estimated {full / 3600:.1f} h for the fixed full "
            f"protocol (each preset's first round, every cell and image evaluated: its measured detection, "
            f"description, matching and pose seconds scaled to 100 per texture, its other costs as measured)")


def write_document(results: list[dict], size: str, docs: Path, alpha: float = ALPHA,
                   sequential: Sequential | None = None, tuning: str | None = None,
                   interim: bool = False) -> Path:
    """``docs/REPRODUCTION.md`` plus the tables' CSVs and the plots in ``docs/reproduction/``: the measurements,
    every finding's verdict with its test, margin and numbers, and every table with the entries tied with its
    best (each preset's newest run)."""
    assets = docs / "reproduction"
    assets.mkdir(parents=True, exist_ok=True)
    for old in assets.iterdir():  # the generated tables and plots; the state and references in folders stay
        if old.is_file():
            old.unlink()
    latest = _latest(results)
    scale = load_scale(latest[0]["output"] if latest else docs)  # the presets share one data set
    rounds = any("round" in r for r in results)
    lines = _measurements(results, size, alpha, scale, rounds, interim, tuning)
    summaries, views, ties, counted, tables = _preset_tables(latest, assets, alpha)
    frames = {k: frame(v) for k, v in summaries.items()}
    found = sequential.findings() if sequential else check_findings(frames, views, alpha)
    lines += findings_section(found, survey_variant(frames)[1], alpha, sequential, results)
    lines += _counts_and_ties(rounds, counted, ties, alpha)
    notes = docs / "reproduction_notes.md"
    if notes.exists():
        lines += ["", notes.read_text().strip()]
    lines += tables
    path = docs / "REPRODUCTION.md"
    write_atomically(path, "\n".join(lines) + "\n")
    return path


def _measurements(results: list[dict], size: str, alpha: float, scale, rounds: bool, interim: bool,
                  tuning: str | None) -> list[str]:
    """The document's head: how it was made, the scale, the tuning, and each run's measurements."""
    command = f"python -m gtsweep.reproduction.command --size {size}" + \
        (f" --alpha {alpha:g}" if alpha != ALPHA else "")
    lines = ["# Reproducing the survey", "",
             f"Generated by `{command}` (`make reproduce`) on the embedded rendered data set (the table presets "
             f"select `dataset=survey`: 1288×964 views, capture physics), {_size_line(size, results)}. Wall time "
             f"on this machine ({os.cpu_count()} cores): {sum(r['wall_s'] for r in results) / 60:.0f} min for all "
             f"runs{_resumed(results)}. Cells read `ours [low, high] (paper)`: the ends of our 95 % interval over "
             "images (a t interval; a design-effect Wilson interval for a rate); NA = not applicable.",
             *(["", INTERIM] if interim else []), "", scale.line(), "",
             *([tuned_line(tuning), "", tuning_table(TUNED), ""] if tuning else []),
             ("| round " if rounds else "") + "| preset | cells | wall time (s) | peak memory (MB) | cache hit rate "
             "| MLflow runs |" + (" images or pairs evaluated (kept) |" if rounds else ""),
             ("|---" if rounds else "") + "|---|---|---|---|---|---|" + ("---|" if rounds else "")]
    lines += [(f"| {r['round']} " if rounds else "") + f"| {r['preset']} | {_cells(r)} | {r['wall_s']:.0f} | "
              f"{r['peak_mb']:.0f} | {r['cache_hit_rate']:.2f} | {r['mlflow_runs']} |" + (_items(r) if rounds else "")
              for r in results]
    lines += [("| " if rounds else "") + f"| all | {sum(r['cells'] for r in results)} | "
              f"{sum(r['wall_s'] for r in results):.0f} | {max((r['peak_mb'] for r in results), default=0):.0f} | "
              f"| {sum(r['mlflow_runs'] for r in results)} |" + (" |" if rounds else ""), "",
              "Wall time and peak resident memory (sampled every 0.5 s, the whole process tree: driver and Ray "
              f"workers) of each preset's own `python -m gtsweep` process on this machine ({os.cpu_count()} cores); "
              "cache hit rate: share of its keypoint detections found in the cache shared by the presets (and "
              "rounds); MLflow runs: the preset's parent run plus one child run per cell."
              + (" With rounds: cells = the cells the round ran (+ cells the cut grid could not leave out); "
                 "images or pairs evaluated = (cell, image or pair) combinations computed, kept = those whose "
                 "per-view rows a cell kept from its previous round." if rounds else "")]
    return lines


def _preset_tables(latest: list[dict], assets: Path, alpha: float):
    """Each preset's summaries and views, its tables (written to ``assets`` with its cell counts and plots) as
    markdown lines, the rows of its ties with the best and of its counts per cell."""
    summaries, views, ties, counted = {}, {}, [], []
    tables = ["", "## The tables", "", "Each preset's table in the survey's layout, `ours [low, high] (paper)`, "
              "with the entries tied with its best below it, and its plots."]
    for r in latest:
        summaries[r["preset"]], views[r["preset"]] = load_summaries(r["output"]), load_views(r["output"])
        per_cell = cell_counts(summaries[r["preset"]], views[r["preset"]])
        per_cell.to_csv(assets / f"{r['preset']}__cell_counts.csv", index=False)
        counted.append(f"| {r['preset']} | {tally(per_cell)} |")
        for table in build_tables(summaries[r["preset"]], views[r["preset"]], alpha):
            if table.name != r["preset"] and not table.name.startswith(f"{r['preset']}_"):  # one per variant
                continue  # e.g. the Table 2 sweep also fills Table 3; its own preset shows it
            annotate([table], load_scale(r["output"]))
            tables += ["", table.markdown(note=True)]
            (assets / f"{table.name}.csv").write_text(table.cells.to_csv())
            if table.ties is not None and table.ties.best:
                ties.append(ties_row(table))
        for png in sorted(_report_dir(r, summaries[r["preset"]], views[r["preset"]], alpha).glob("*.png")):
            target = assets / f"{r['preset']}__{png.name}"
            shutil.copy(png, target)
            tables += ["", f"![{png.stem}](reproduction/{target.name})"]
    return summaries, views, ties, counted, tables


def _counts_and_ties(rounds: bool, counted: list[str], ties: list[str], alpha: float) -> list[str]:
    """The sections "Counts per cell" (with rounds) and "Ties with the best" (where a table has ties)."""
    lines = []
    if rounds:
        lines += ["", "## Counts per cell", "",
                  "Every table shows every cell of its preset at the count that cell last reached (a cell no "
                  "undecided finding reads is not run again). Images (Tables 2, 3, 6) or pairs (Tables 4, 5, 7) per "
                  "texture, per preset; each cell's in `reproduction/<preset>__cell_counts.csv`.", "",
                  "| preset | per texture: cells |", "|---|---|", *counted]
    if ties:
        lines += ["", "## Ties with the best", "",
                  "Per table, the entries whose paired t test over images against the best is not significant "
                  f"after Holm's correction across the table's entries (family-wise alpha = {alpha:g}): the data "
                  "cannot rank them below the best.", "", "| table | best | tied with the best | which |",
                  "|---|---|---|---|"]
        lines += ties
    return lines


def _cells(r: dict) -> str:
    return f"{r['cells'] - r['extra_cells']} + {r['extra_cells']}" if r.get("extra_cells") else f"{r['cells']}"


def _items(r: dict) -> str:
    return f" {r['items_evaluated']} ({r['items_reused']}) |" if r.get("items_evaluated") is not None else " - |"


def _report_dir(r: dict, summaries: list[dict], views: dict, alpha: float) -> Path:
    """The plots of a run; of every cell when the round ran only some of them (rebuilt from all its cells)."""
    if r.get("extra_cells") is None or len(summaries) <= r["cells"]:
        return Path(r["output"]) / "report"
    from gtsweep.report.output import write_report

    out = Path(r["output"]) / "report_every_cell"
    write_report(summaries, out, plots=True, views=views, alpha=alpha, scale=load_scale(r["output"]))
    return out


def findings_section(findings: list, variant: str, alpha: float, sequential: Sequential | None = None,
                     results: list[dict] = ()) -> list[str]:
    """The findings table: per finding its verdict, test, margin, n, intervals, correction (and with rounds: the
    round and count per texture of its verdict, the level of that look; undecided: the images that would
    decide it at the observed effect)."""
    counts = {}
    for f in findings:
        counts[f.verdict] = counts.get(f.verdict, 0) + 1
    tally = ", ".join(f"{n} {verdict}" for verdict, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    design = (" Rounds under the sequential design of `gtsweep/reproduction/sequential.py` (Lan-DeMets Pocock-type "
              f"alpha spending, total alpha = {alpha:g} per verdict kind per finding)." if sequential else "")
    head = ["", "## The survey's findings on our data", "",
            f"{tally}. Each finding is a hypothesis fixed before the results (`gtsweep/reproduction/findings.py`, "
            "`docs/statistics_design.md`): *holds* = the survey's claim shown, *fails* = its opposite shown (Holm "
            "across the finding's comparisons), *equivalent* = equal within the margin, *undecided* = the data "
            f"cannot tell; one-sided tests at alpha = {alpha:g}, intervals at 1 - 2 alpha.{design}"
            + (f" {variant}" if variant else ""), ""]
    if sequential:
        rows = ["| finding | verdict | decided at (round, n per texture, level) | compute: its preset's rounds to "
                "this verdict / full protocol (est.) | test | margin | correction | evidence |",
                "|---|---|---|---|---|---|---|---|"]
        for s in sequential.status:
            f = s.finding or findings[sequential.status.index(s)]
            at = f"round {s.round}, {s.per_texture}, {s.nominal:.2g}" if s.round else "-"
            preset = s.hypothesis.preset
            cost = (f"{runs.spent(results, preset, s.round) / 60:.1f} / "
                    f"{runs.full_protocol_estimate(results, preset) / 60:.1f} min") if s.round and results else "-"
            still = ("" if s.final else " (still open: the next round adds data)" if s.asks_for_data
                     else " (still open: judged again when its preset runs for another finding)")
            rows.append(f"| {f.text} | {f.verdict}{still}{_more(f)} | {at} | {cost} | {f.test or '-'} | {f.margin} | "
                        f"{f.correction or '-'} | {f.evidence.replace('|', '/')} |")
        return head + rows
    return head + ["| finding | verdict | test | margin | n | correction | evidence |",
                   "|---|---|---|---|---|---|---|"] + \
        [f"| {f.text} | {f.verdict}{_more(f)} | {f.test or '-'} | {f.margin} | {f.n} | {f.correction or '-'} | "
         f"{f.evidence.replace('|', '/')} |" for f in findings]


def _more(finding) -> str:
    need = finding.to_decide
    if need == math.inf:
        return (f" (more images do not narrow its interval, which is over the {finding.n} methods compared, "
                f"as the survey's statement is)")
    if not math.isfinite(need) or not finding.n:
        return ""
    return f" (~{math.ceil(need)} images or pairs would decide it at the observed effect, now {finding.n})"


def _resumed(results: list[dict]) -> str:
    """How often the reproduction was interrupted and resumed (its wall time includes the cut attempts)."""
    cut = sum(r.get("attempts", 1) - 1 for r in results)
    return f" (interrupted and resumed {cut} time(s); the wall times include the interrupted attempts)" if cut else ""


def open_progress(work: Path, plan: dict, fresh: bool) -> RunRecord:
    """The record of the reproduction in ``work``: an unfinished one of the same ``plan`` is resumed (said in one
    line); ``fresh`` (or none there) starts an empty ``work``."""
    path = work / "progress.json"
    if fresh or not path.exists():
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        return RunRecord(path, plan)
    try:
        progress = RunRecord.resume(path, plan)
    except BadInput as e:
        raise SystemExit(f"gtsweep.reproduce: error: {e}") from None
    print(f"gtsweep.reproduce: resuming the reproduction in {work}: {len(progress)} preset run(s) finished, "
          f"{progress.interrupted_seconds() / 60:.0f} min in interrupted attempts", flush=True)
    return progress


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.reproduction.command", description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=CHOICES, default="decide",
                        help="a fixed size, or `decide`: rounds of growing counts until every finding is decided")
    parser.add_argument("--presets", nargs="*", default=list(PRESETS), choices=PRESETS)
    parser.add_argument("--work", default=str(DEFAULT_CACHE_DIR / "reproduce"), help="where the runs go")
    parser.add_argument("--docs", default=str(PROJECT_DIR / "docs"), help="where REPRODUCTION.md goes")
    parser.add_argument("--alpha", type=float, default=ALPHA,
                        help=f"significance level of the findings' tests and the ties (default {ALPHA})")
    parser.add_argument("--fresh", action="store_true",
                        help="discard an unfinished reproduction in --work instead of resuming it")
    parser.add_argument("--document-only", action="store_true",
                        help="rebuild REPRODUCTION.md from the runs already in --work (e.g. after editing "
                             "docs/reproduction_notes.md), without running anything; on an unfinished "
                             "reproduction, an interim document of the rounds finished so far")
    args = parser.parse_args(argv)
    if not 0 < args.alpha < 1:
        parser.error(f"--alpha must be in (0, 1), not {args.alpha}")
    if args.size == "decide" and not args.document_only:  # the sequential run lives in its committed state now
        from gtsweep.reproduction.cli import main as state_run

        return state_run(["collect"]) or state_run(["document"])
    work = Path(args.work).resolve()
    record = work / "measurements.json"
    if args.document_only:
        size, results, interim = saved_runs(work)
        sequential = _replay(results, args.alpha) if size == "decide" else None
        tuning = tuning_fingerprint() if size != "tiny" else None  # tiny: not dataset=survey
        path = write_document(results, size, Path(args.docs), args.alpha, sequential, tuning, interim=interim)
        print(f"wrote {path}" + (" (interim: the reproduction is not finished)" if interim else ""))
        return 0
    progress = open_progress(work, {"size": args.size, "presets": list(args.presets), "alpha": args.alpha,
                                    "tuned": tuned_digest()}, fresh=args.fresh or record.exists())
    for s in SIGNALS:
        signal.signal(s, on_signal)
    log = lambda m: print(m, flush=True)  # noqa: E731
    sequential = None
    try:
        if args.size == "decide":
            sequential = Sequential(args.alpha)
            results = runs.run_rounds(args.presets, sequential.update, work, log=log, record=progress)
        else:
            results = runs.run_fixed(args.presets, SIZES[args.size], work, log=log, record=progress)
    except Interrupted as e:
        print(f"gtsweep.reproduce: {e}; {len(progress)} preset run(s) finished and kept in {work}: the same "
              f"command resumes it", file=sys.stderr)
        return 128 + e.signum
    runs.save(record, {"size": args.size, "presets": results})
    tuning = tuning_fingerprint() if args.size != "tiny" else None
    print(f"wrote {write_document(results, args.size, Path(args.docs), args.alpha, sequential, tuning)}")
    return 0


def saved_runs(work: Path) -> tuple[str, list[dict], bool]:
    """The size and preset runs of the reproduction in ``work``, and whether it is unfinished: a finished one's
    ``measurements.json``, else an unfinished one's finished runs so far (``progress.json``: an interim document)."""
    record, progress = work / "measurements.json", work / "progress.json"
    try:
        if record.exists():
            saved = json.loads(record.read_text())
            return saved["size"], [{**r, "output": Path(r["output"])} for r in saved["presets"]], False
        if progress.exists():
            saved = json.loads(progress.read_text())
            finished = [{**r, "output": Path(r["output"])} for r in saved["finished"].values()]
            if finished:
                order = {p: i for i, p in enumerate(PRESETS)}
                finished.sort(key=lambda r: (r.get("round", 0), order.get(r["preset"], len(order))))
                return saved["plan"]["size"], finished, True
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"gtsweep.reproduce: cannot read the reproduction's record in {work} ({e})") from None
    raise SystemExit(f"gtsweep.reproduce: no reproduction with a finished run in {work} (missing {record.name})")


def _replay(results: list[dict], alpha: float) -> Sequential:
    """The sequential verdicts of saved rounds, judged again look by look."""
    sequential, latest = Sequential(alpha), {}
    for k in range(max(r["round"] for r in results)):
        latest.update({r["preset"]: r for r in results if r["round"] == k + 1})
        sequential.update(k, latest)
    return sequential


if __name__ == "__main__":
    sys.exit(main())
