"""Rebuild the survey's tables from a sweep, with the paper's number beside ours: ``python -m gtsweep.report``.

Each table is built from whatever cells a sweep has (its result files, or its MLflow runs) and printed in the
paper's layout: a cell reads ``ours (paper)``; ``NA`` marks a pairing that cannot be evaluated. Detection metrics
are averaged with equal weight per transform type, as in the survey (section 5). Tables are written as Markdown,
LaTeX and CSV, next to the plots of :mod:`gtsweep.report.plots`; ``cells`` lists every cell with each metric
that :mod:`gtsweep.evaluation.schema` marks as reported.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from gtsweep.core.errors import GtsweepError
from gtsweep.core.paths import PACKAGE_DIR
from gtsweep.evaluation import schema
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.orchestration.results import by_variant, summary_table, swept_variants
from gtsweep.report.labels import paper_label, shown_label, variant_label, variant_slug

PAPER_DIR = PACKAGE_DIR / "data" / "survey"
METHODS = ("detector", "selector", "descriptor", "transform")


def paper(name: str) -> pd.DataFrame:
    return pd.read_csv(PAPER_DIR / name, keep_default_na=False)


def fmt(ours: float, theirs=None, digits: int = 2) -> str:
    """``ours (paper)`` with the same number of digits; NA where ours is missing."""
    text = "NA" if _missing(ours) else f"{ours:.{digits}f}"
    if _missing(theirs) or theirs == "":
        return text
    try:
        theirs = f"{float(theirs):.{digits}f}"
    except ValueError:
        theirs = str(theirs)
    return text if text == theirs == "NA" else f"{text} ({theirs})"


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


@dataclass
class Table:
    name: str
    title: str
    cells: pd.DataFrame  # strings as shown: "ours (paper)"

    def markdown(self) -> str:
        frame = self.cells.reset_index()
        header = [str(c) for c in frame.columns]
        lines = [f"**{self.title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
        return "\n".join(lines)

    def latex(self) -> str:
        body = self.cells.reset_index().to_latex(index=False, escape=True)
        return f"% {self.title}\n{body}"


def load_summaries(source: str | Path) -> list[dict]:
    """Cell summaries from a sweep's output directory (``cells/*.json``)."""
    cells = sorted(Path(source).glob("cells/*.json"))
    if not cells:
        raise GtsweepError(f"no cell results under '{source}' (expected a sweep output directory with cells/)")
    return [json.loads(p.read_text()) for p in cells]


def frame(summaries: list[dict]) -> pd.DataFrame:
    """:func:`~gtsweep.orchestration.results.summary_table` plus each cell's success per reference count (Table 7)
    and its number of views (pairs for real pairs; summaries from before it was recorded: their rows)."""
    return summary_table(summaries).assign(by_reference_count=[s.get("by_reference_count") for s in summaries],
                                           n_views=[s.get("n_views", s.get("n_rows")) for s in summaries])


def sample_note(part: pd.DataFrame) -> str:
    """What a table was computed on: views (or pairs) per evaluated cell and the transforms, e.g.
    ``27 pairs per cell; transforms: incremental``."""
    ok = part[part["status"] == "ok"] if "status" in part else part
    counts = pd.to_numeric(ok["n_views"], errors="coerce").dropna().astype(int) if "n_views" in ok else pd.Series()
    transforms = sorted(str(t) for t in part["transform"].dropna().unique())
    kind = "pairs" if transforms and set(transforms) <= {"incremental", "absolute"} else "views"
    used = f"transforms: {', '.join(transforms) or 'none'}"
    if counts.empty:  # nothing evaluated, or summaries from before views were counted
        return used
    size = f"{counts.min()}" if counts.min() == counts.max() else f"{counts.min()}–{counts.max()}"
    return f"{size} {kind} per cell; {used}"


def _ok(df: pd.DataFrame, metric: str) -> pd.Series:
    values = pd.to_numeric(df[metric], errors="coerce") if metric in df else pd.Series(math.nan, index=df.index)
    return values.where(df["status"] == "ok")


def _pairing_table(df: pd.DataFrame, transform: str, paper_file: str, name: str, title: str) -> Table | None:
    part = df[(df["transform"] == transform) & df["descriptor"].notna()]
    part = part[part["by_reference_count"].isna()] if "by_reference_count" in part else part
    if part.empty:
        return None
    theirs = paper(paper_file).set_index("detector")
    success = part.assign(value=_ok(part, "pose_success"))
    detectors = _order(success["detector"].unique(), theirs.index)
    descriptors = _order(success["descriptor"].unique(), theirs.columns)
    grid = pd.DataFrame(index=[shown_label(d) for d in detectors], columns=[shown_label(s) for s in descriptors])
    for row in success.groupby(["detector", "descriptor"], sort=False)["value"].mean().reset_index().itertuples():
        p = _lookup(theirs, paper_label(row.detector), paper_label(row.descriptor))
        grid.loc[shown_label(row.detector), shown_label(row.descriptor)] = fmt(row.value, p)
    grid.index.name = "detector"
    return Table(name, f"{title} ({sample_note(part)})", grid.fillna(""))


def _order(names, paper_order) -> list[str]:
    """Methods in the paper's order, the ones it did not have after them."""
    rank = {n: i for i, n in enumerate(paper_order)}
    return sorted(names, key=lambda n: (rank.get(paper_label(n), len(rank)), n))


def _lookup(table: pd.DataFrame, row: str, column: str):
    try:
        return table.loc[row, column]
    except KeyError:
        return None


def _detection(df: pd.DataFrame) -> pd.DataFrame:
    """Detection cells averaged over transforms (equal weight per transform type)."""
    part = df[df["descriptor"].isna() & (df["status"] == "ok")]
    metrics = [m for m in ("repeatability", "ambiguity", "few_keypoints", "n_detected", "t_detect") if m in part]
    return part.groupby(["detector", "selector"])[metrics].mean()


def table_selectors(df: pd.DataFrame) -> Table | None:
    """Survey Table 2: repeatability of every selector-detector pairing, keypoints before selection."""
    detection = _detection(df)
    if detection.empty or detection.index.get_level_values("selector").nunique() < 2:
        return None
    theirs = paper("table2_selector_repeatability.csv").set_index("detector")
    columns = {"none": "rep_no_selection", "nms": "rep_nms", "anms": "rep_anms", "bucketing": "rep_bucketing"}
    detectors = _order(detection.index.get_level_values("detector").unique(), theirs.index)
    out = pd.DataFrame(index=[shown_label(d) for d in detectors])
    for d in detectors:
        p = theirs.loc[paper_label(d)] if paper_label(d) in theirs.index else {}
        counts = detection.loc[d, "n_detected"] if "n_detected" in detection else pd.Series(dtype=float)
        out.loc[shown_label(d), "#KPs before selection"] = fmt(counts.mean(), p.get("kps_before_selection"), 0)
        for selector, column in columns.items():
            value = detection.loc[(d, selector), "repeatability"] if (d, selector) in detection.index else math.nan
            out.loc[shown_label(d), f"Rep. {selector}"] = fmt(value, p.get(column))
    out.index.name = "detector"
    return Table("table2_selectors", f"Survey Table 2: repeatability of selector-detector pairings "
                                     f"({sample_note(df[df['descriptor'].isna()])})", out)


def table_detectors(df: pd.DataFrame) -> Table | None:
    """Survey Table 3: per detector with its best selector, < 100 KPs, repeatability, ambiguity, time."""
    detection = _detection(df)
    detection = detection[detection.index.get_level_values("selector") != "none"]
    if detection.empty:
        return None
    text = paper("table3_text.csv")
    best = detection.reset_index().sort_values("repeatability", ascending=False).groupby("detector").head(1)
    out = []
    for row in best.sort_values("repeatability", ascending=False).itertuples():
        said = {r.metric: r.value for r in text[text["detector"] == paper_label(row.detector)].itertuples()}
        out.append({"detector": shown_label(row.detector), "selector": row.selector.upper(),
                    "< 100 KPs": fmt(row.few_keypoints, said.get("few_keypoints")),
                    "repeatability": fmt(row.repeatability, said.get("repeatability")),
                    "ambiguity": fmt(row.ambiguity, said.get("ambiguity")),
                    "time (s)": fmt(row.t_detect, None, 3)})
    table = pd.DataFrame(out).set_index("detector")
    used = df[df["descriptor"].isna() & (df["status"] == "ok") & (df["selector"] != "none")]
    return Table("table3_detectors", f"Survey Table 3: detectors, best selector ({sample_note(used)})", table)


def table_pairings(df: pd.DataFrame) -> Table | None:
    """Survey Table 6: pairings on synthetic transforms: success, correct matches, precision."""
    part = df[df["transform"].isin(list(TRANSFORMS)) & df["descriptor"].notna() & (df["status"] == "ok")]
    if part.empty:
        return None
    theirs = paper("table6_pairings_synthetic.csv").set_index(["detector", "descriptor"])
    columns = ["pose_success", "n_correct", "precision"]  # a matching sweep has no pose_success: NA
    means = part.groupby(["detector", "descriptor"])[[c for c in columns if c in part]].mean().reindex(columns=columns)
    out = []
    for (det, desc), row in means.sort_values("pose_success", ascending=False).iterrows():
        key = (paper_label(det), paper_label(desc))
        p = theirs.loc[key] if key in theirs.index else {}
        out.append({"detector": shown_label(det), "descriptor": shown_label(desc),
                    "pose success": fmt(row.pose_success, p.get("pose_success")),
                    "#correct matches": fmt(row.n_correct, p.get("correct_matches"), 0),
                    "precision": fmt(row.precision, p.get("precision"))})
    return Table("table6_pairings", f"Survey Table 6: pairings on synthetic transforms ({sample_note(part)})",
                 pd.DataFrame(out).set_index("detector"))


def table_reference_counts(df: pd.DataFrame) -> Table | None:
    """Survey Table 7: success on incremental pairs against the number of reference features."""
    part = df[(df["transform"] == "incremental") & df["by_reference_count"].notna() & (df["status"] == "ok")] \
        if "by_reference_count" in df else df.iloc[0:0]
    if part.empty:
        return None
    theirs = paper("table7_success_vs_reference_features.csv").set_index(["detector", "descriptor"])
    out = []
    for row in part.itertuples():
        key = (paper_label(row.detector), paper_label(row.descriptor))
        p = theirs.loc[key] if key in theirs.index else {}
        record = {"detector": shown_label(row.detector), "descriptor": shown_label(row.descriptor)}
        for count, values in sorted(row.by_reference_count.items(), key=lambda kv: float(kv[0])):
            column = str(int(float(count)))
            record[column] = fmt(values.get("pose_success"), p.get(column))
        out.append(record)
    return Table("table7_reference_features", "Survey Table 7: success against number of reference features "
                 f"({sample_note(part)})", pd.DataFrame(out).set_index("detector"))


def table_cells(summaries: list[dict]) -> Table | None:
    """Every cell with each reported schema metric of its experiment: a new metric needs no other edit here."""
    records, swept = [], swept_variants(summaries)
    for s in summaries:
        experiment, values = schema.experiment_of(s), s.get("metrics") or {}
        record = {**{k: s["methods"].get(k) or "" for k in (*METHODS, *swept)}, "experiment": experiment,
                  "status": s["status"]}
        record.update({m.name: fmt(values.get(m.name), None, m.digits) for m in schema.metrics_of(experiment)
                       if m.reported})
        records.append(record)
    if not records:
        return None
    cells = pd.DataFrame.from_records(records)
    metrics = schema.ordered(c for c in cells.columns if c in schema.METRICS)
    cells = cells[[c for c in cells.columns if c not in metrics] + metrics].fillna("").set_index("detector")
    return Table("cells", "Every cell: the reported metrics of its experiment, aggregated over its views "
                 f"({sample_note(frame(summaries))})", cells)


def build_tables(summaries: list[dict]) -> list[Table]:
    """Every survey table that the cells of ``summaries`` can fill; with several matchers or estimators, each
    table once per (matcher, estimator), named and titled after it."""
    groups = by_variant(summaries)
    if len(groups) == 1:
        return _survey_tables(summaries)
    return [Table(f"{t.name}_{variant_slug(variant)}", f"{t.title}; {variant_label(variant)}", t.cells)
            if variant_slug(variant) else t for variant, part in groups.items() for t in _survey_tables(part)]


def _survey_tables(summaries: list[dict]) -> list[Table]:
    df = frame(summaries)
    if "descriptor" not in df:
        df["descriptor"] = None
    candidates = [
        table_selectors(df), table_detectors(df),
        _pairing_table(df, "incremental", "table4_success_incremental.csv", "table4_incremental",
                       "Survey Table 4: pose success on incremental pairs"),
        _pairing_table(df, "absolute", "table5_success_absolute.csv", "table5_absolute",
                       "Survey Table 5: pose success on absolute pairs"),
        table_pairings(df), table_reference_counts(df),
    ]
    return [t for t in candidates if t is not None]


def write_report(summaries: list[dict], out_dir: str | Path, plots: bool = True) -> tuple[list[Table], list[Path]]:
    """Write every survey table and the per-cell table as .md, .tex and .csv (and the plots) into ``out_dir``;
    returns the survey tables and every file."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tables, files, cells = build_tables(summaries), [], table_cells(summaries)
    for table in tables + ([cells] if cells else []):
        for suffix, text in ((".md", table.markdown()), (".tex", table.latex()), (".csv", table.cells.to_csv())):
            path = out_dir / f"{table.name}{suffix}"
            path.write_text(text + ("\n" if not text.endswith("\n") else ""))
            files.append(path)
    if plots:  # with several matchers or estimators, one folder of plots per (matcher, estimator)
        from gtsweep.report.plots import write_plots

        groups = by_variant(summaries)
        for variant, part in groups.items():
            files += write_plots(part, out_dir / variant_slug(variant) if len(groups) > 1 else out_dir)
    return tables, files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.report", description=__doc__.splitlines()[0])
    parser.add_argument("source", help="a sweep's output directory (it holds cells/ and results.csv), or with "
                                           "--mlflow the id of a sweep's parent run")
    parser.add_argument("--mlflow", action="store_true", help="read the cells from MLflow child runs of SOURCE")
    parser.add_argument("--tracking-uri", help="MLflow store (default: $MLFLOW_TRACKING_URI or ./mlflow.db)")
    parser.add_argument("--out", help="where to write tables and plots (default: <source>/report, or ./report)")
    parser.add_argument("--no-plots", action="store_true", help="tables only")
    args = parser.parse_args(argv)
    out = Path(args.out or ("report" if args.mlflow else Path(args.source) / "report"))
    try:
        if args.mlflow:
            from gtsweep.tracking.sweep import summaries_from_mlflow

            summaries = summaries_from_mlflow(args.source, args.tracking_uri)
        else:
            summaries = load_summaries(args.source)
        tables, files = write_report(summaries, out, not args.no_plots)
    except GtsweepError as e:
        print(f"gtsweep.report: error: {e}", file=sys.stderr)
        return 2
    for table in tables:
        print(table.markdown(), end="\n\n")
    print(f"{len(files)} files in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
