"""Rebuild the survey's tables from a sweep, with the paper's number beside ours: ``python -m gtsweep.report``.

Each table is built from whatever cells a sweep has (its result files, or its MLflow runs) and printed in the
paper's layout: a cell reads ``ours [low, high] (paper)``, the ends of our 95 % interval (Wilson for a success
rate, a seeded bootstrap over images otherwise; :mod:`gtsweep.report.samples`), which need not be symmetric about
ours; ``NA`` marks a pairing that cannot be evaluated. Every column header (or the title, where the columns are
methods) names its unit. Detection metrics are averaged with equal weight per transform type, as in the survey
(section 5). Below each table: the best entry and those statistically tied with it (a paired test against the best at
``--alpha``). Tables are written as Markdown, LaTeX and CSV (``<table>_values.csv``: the numbers, each interval's
ends and the paper's number in columns), next to the plots of :mod:`gtsweep.report.plots`; ``cells`` lists every
cell with each metric that :mod:`gtsweep.evaluation.schema` marks as reported. ``--by texture`` adds every table
per texture and the synthetic results per transform and strength (:mod:`gtsweep.report.breakdown`).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from gtsweep.core.errors import GtsweepError
from gtsweep.core.paths import PACKAGE_DIR
from gtsweep.evaluation import schema
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.orchestration.results import by_variant, summary_table, swept_variants
from gtsweep.report.labels import paper_label, shown_label, variant_label, variant_slug
from gtsweep.report.pools import survey_selector
from gtsweep.report.samples import Ties, Views, estimate, tied_with_best

PAPER_DIR = PACKAGE_DIR / "data" / "survey"
METHODS = ("detector", "selector", "descriptor", "transform")
ALPHA = 0.05  # significance level of the paired tests (report.alpha)
BY = (None, "texture")  # report.by
KPS_BEFORE = "#KPs before selection (keypoints per view)"


def paper(name: str) -> pd.DataFrame:
    return pd.read_csv(PAPER_DIR / name, keep_default_na=False)


def fmt(ours: float, theirs=None, digits: int = 2, low: float = math.nan, high: float = math.nan) -> str:
    """``ours [low, high] (paper)`` with the same number of digits (the interval's ends as they are: a Wilson
    interval [0.70, 1.00] around 1.00 is not ``1.00 ±0.15``); NA where ours is missing."""
    text = "NA" if _missing(ours) else f"{ours:.{digits}f}"
    if text != "NA" and not (_missing(low) or _missing(high)):
        text += f" {interval(low, high, digits)}"
    if _missing(theirs) or theirs == "":
        return text
    try:
        theirs = f"{float(theirs):.{digits}f}"
    except ValueError:
        theirs = str(theirs)
    return text if text == theirs == "NA" else f"{text} ({theirs})"


def interval(low: float, high: float, digits: int = 2) -> str:
    """``[0.70, 1.00]``: an interval's ends."""
    return f"[{low:.{digits}f}, {high:.{digits}f}]"


def with_unit(name: str, unit: str) -> str:
    """A column header with its unit: ``repeatability (share)``, ``time (s)``."""
    return f"{name} ({unit})"


def _unit(metric: str) -> str:
    """A metric's unit as the schema declares it (``share``: a value in [0, 1])."""
    return schema.METRICS[metric].unit


def _number(value) -> float:
    return math.nan if value is None else float(value)


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


@dataclass
class Table:
    name: str
    title: str
    cells: pd.DataFrame  # strings as shown: "ours [low, high] (paper)"
    values: list[dict] = field(default_factory=list)  # the numbers: row, column, ours, ci_low, ci_high, paper
    ties: Ties | None = None
    note: str = ""  # a line below the table, e.g. the scale in mm (:func:`gtsweep.report.scale.annotate`)

    def markdown(self, note: bool = False) -> str:
        """The table, its title and its ties; ``note``: the line below it too (the table's file has it; a terminal
        printing several tables prints the shared scale line once, after them)."""
        frame = self.cells.reset_index()
        header = [str(c) for c in frame.columns]
        lines = [f"**{self.title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
        if self.ties is not None and self.ties.describe():
            lines += ["", f"*{self.ties.describe()}*"]
        if note and self.note:
            lines += ["", f"*{self.note}*"]
        return "\n".join(lines)

    def show(self, row: str, column: str, cells: pd.DataFrame, metric: str, paper_value=None, digits: int = 2,
             views: Views | None = None, where=None) -> str:
        """The text of one entry made of ``cells`` (value [low, high] (paper)); its numbers go to ``values``."""
        value, low, high = estimate(cells, metric, views, where)
        theirs = None if _missing(paper_value) or paper_value == "" else paper_value
        self.values.append({"row": row, "column": column, "metric": metric, "ours": value, "ci_low": low,
                            "ci_high": high, "paper": theirs})
        return fmt(value, theirs, digits, low, high)

    def latex(self) -> str:
        body = self.cells.reset_index().to_latex(index=False, escape=True)
        return f"% {self.title}\n{body}" + (f"% {self.note}\n" if self.note else "")


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
                                           n_views=[s.get("n_views", s.get("n_rows")) for s in summaries],
                                           key=[s.get("key") for s in summaries])


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


def _evaluated(df: pd.DataFrame) -> pd.DataFrame:
    return df[df["status"] == "ok"]


def _pair_label(detector: str, descriptor: str) -> str:
    return f"{shown_label(detector)}-{shown_label(descriptor)}"


def _pairing_table(df: pd.DataFrame, transform: str, paper_file: str, name: str, title: str,
                   views: Views | None = None, alpha: float = ALPHA) -> Table | None:
    part = df[(df["transform"] == transform) & df["descriptor"].notna()]
    part = part[part["by_reference_count"].isna()] if "by_reference_count" in part else part
    if part.empty:
        return None
    theirs = paper(paper_file).set_index("detector")
    detectors = paper_order(part["detector"].unique(), theirs.index)
    descriptors = paper_order(part["descriptor"].unique(), theirs.columns)
    grid = pd.DataFrame(index=[shown_label(d) for d in detectors], columns=[shown_label(s) for s in descriptors])
    table = Table(name, f"{title} ({sample_note(part)})", grid)
    entries = {}
    for (det, desc), cells in part.groupby(["detector", "descriptor"], sort=False):
        p = _lookup(theirs, paper_label(det), paper_label(desc))
        ok = _evaluated(cells)
        grid.loc[shown_label(det), shown_label(desc)] = table.show(shown_label(det), shown_label(desc), ok,
                                                                    "pose_success", p, views=views) \
            if len(ok) else fmt(math.nan, p)
        if len(ok):
            entries[_pair_label(det, desc)] = ok
    grid.index.name = "detector"
    table.cells = grid.fillna("")
    table.ties = tied_with_best(entries, "pose_success", views, alpha)
    return table


def paper_order(names, order) -> list[str]:
    """Methods in the paper's ``order`` (of its labels), the ones it did not have after them."""
    rank = {n: i for i, n in enumerate(order)}
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


def _detection_cells(df: pd.DataFrame, detector: str, selector: str) -> pd.DataFrame:
    return df[df["descriptor"].isna() & (df["status"] == "ok") & (df["detector"] == detector)
              & (df["selector"] == selector)]


def table_selectors(df: pd.DataFrame, views: Views | None = None, alpha: float = ALPHA) -> Table | None:
    """Survey Table 2: repeatability of every selector-detector pairing, keypoints before selection."""
    detection = _detection(df)
    if detection.empty or detection.index.get_level_values("selector").nunique() < 2:
        return None
    theirs = paper("table2_selector_repeatability.csv").set_index("detector")
    columns = {"none": "rep_no_selection", "nms": "rep_nms", "anms": "rep_anms", "bucketing": "rep_bucketing"}
    detectors = paper_order(detection.index.get_level_values("detector").unique(), theirs.index)
    out = pd.DataFrame(index=[shown_label(d) for d in detectors])
    table = Table("table2_selectors", f"Survey Table 2: repeatability of selector-detector pairings "
                                      f"({sample_note(df[df['descriptor'].isna()])})", out)
    entries = {}
    for d in detectors:
        p = theirs.loc[paper_label(d)] if paper_label(d) in theirs.index else {}
        counts = detection.loc[d, "n_detected"] if "n_detected" in detection else pd.Series(dtype=float)
        out.loc[shown_label(d), KPS_BEFORE] = fmt(counts.mean(), p.get("kps_before_selection"), 0)
        for selector, column in columns.items():
            cells, header = _detection_cells(df, d, selector), with_unit(f"Rep. {selector}", _unit("repeatability"))
            out.loc[shown_label(d), header] = table.show(
                shown_label(d), header, cells, "repeatability", p.get(column), views=views) \
                if len(cells) else fmt(math.nan, p.get(column))
            if len(cells):
                entries[f"{shown_label(d)} {selector.upper()}"] = cells
    out.index.name = "detector"
    table.ties = tied_with_best(entries, "repeatability", views, alpha)
    return table


def table_detectors(df: pd.DataFrame, views: Views | None = None, alpha: float = ALPHA) -> Table | None:
    """Survey Table 3: per detector with the survey's selector (NMS; ANMS for MSER, 4.1: "For all other detectors,
    we use NMS"; else the one that ran), < 100 KPs, repeatability, ambiguity, time. Not the best selector by this
    table's own numbers: that choice would read the results, and would weigh cells of different counts (the
    sequential reproduction runs the other selectors only in its first round)."""
    detection = _detection(df)
    detection = detection[detection.index.get_level_values("selector") != "none"].reset_index()
    if detection.empty:
        return None
    text = paper("table3_text.csv")
    ran = detection.groupby("detector")["selector"].agg(lambda s: dict.fromkeys(s))
    chosen = detection[detection["selector"] == detection["detector"].map(lambda d: survey_selector(d, ran[d]))]
    table = Table("table3_detectors", "", pd.DataFrame())
    out, entries = [], {}
    for row in chosen.sort_values("repeatability", ascending=False).itertuples():
        said = {r.metric: r.value for r in text[text["detector"] == paper_label(row.detector)].itertuples()}
        cells, shown = _detection_cells(df, row.detector, row.selector), shown_label(row.detector)
        entries[shown] = cells
        record = {"detector": shown, "selector": row.selector.upper()}
        for column, metric in (("< 100 KPs", "few_keypoints"), ("repeatability", "repeatability"),
                               ("ambiguity", "ambiguity")):
            column = with_unit(column, "share of views" if metric == "few_keypoints" else _unit(metric))
            record[column] = table.show(shown, column, cells, metric, said.get(metric), views=views)
        record[with_unit("time", _unit("t_detect"))] = fmt(row.t_detect, None, 3)
        out.append(record)
    table.title = f"Survey Table 3: detectors, the survey's selector ({sample_note(pd.concat(entries.values()))})"
    table.cells = pd.DataFrame(out).set_index("detector")
    table.ties = tied_with_best(entries, "repeatability", views, alpha)
    return table


def table_pairings(df: pd.DataFrame, views: Views | None = None, alpha: float = ALPHA) -> Table | None:
    """Survey Table 6: pairings on synthetic transforms: success, correct matches, precision (pooled)."""
    part = df[df["transform"].isin(list(TRANSFORMS)) & df["descriptor"].notna() & (df["status"] == "ok")]
    if part.empty:
        return None
    theirs = paper("table6_pairings_synthetic.csv").set_index(["detector", "descriptor"])
    table = Table("table6_pairings", f"Survey Table 6: pairings on synthetic transforms ({sample_note(part)})",
                  pd.DataFrame())
    success = part.assign(value=_ok(part, "pose_success")).groupby(["detector", "descriptor"])["value"].mean()
    out, entries = [], {}
    for det, desc in success.sort_values(ascending=False).index:
        key = (paper_label(det), paper_label(desc))
        p = theirs.loc[key] if key in theirs.index else {}
        cells, row = part[(part["detector"] == det) & (part["descriptor"] == desc)], shown_label(det)
        entries[_pair_label(det, desc)] = cells
        record = {"detector": row, "descriptor": shown_label(desc)}
        for column, metric, said, digits in (("pose success", "pose_success", p.get("pose_success"), 2),
                                             ("#correct matches", "n_correct", p.get("correct_matches"), 0),
                                             ("precision", "precision", p.get("precision"), 2)):
            column = with_unit(column, "per view" if metric == "n_correct" else _unit(metric))
            record[column] = table.show(row, column, cells, metric, said, digits, views)
        out.append(record)
    table.cells = pd.DataFrame(out).set_index("detector")
    table.ties = tied_with_best(entries, "pose_success", views, alpha)
    return table


def table_reference_counts(df: pd.DataFrame, views: Views | None = None, alpha: float = ALPHA) -> Table | None:
    """Survey Table 7: success on incremental pairs against the number of reference features."""
    part = df[(df["transform"] == "incremental") & df["by_reference_count"].notna() & (df["status"] == "ok")] \
        if "by_reference_count" in df else df.iloc[0:0]
    if part.empty:
        return None
    theirs = paper("table7_success_vs_reference_features.csv").set_index(["detector", "descriptor"])
    table = Table("table7_reference_features", "Survey Table 7: pose success (share of pairs) against the number "
                  f"of reference features (columns: reference features per image; {sample_note(part)})",
                  pd.DataFrame())
    out, entries, top = [], {}, None
    for index, row in part.iterrows():
        key = (paper_label(row.detector), paper_label(row.descriptor))
        p = theirs.loc[key] if key in theirs.index else {}
        record = {"detector": shown_label(row.detector), "descriptor": shown_label(row.descriptor)}
        for count, values in sorted(row.by_reference_count.items(), key=lambda kv: float(kv[0])):
            column, top = str(int(float(count))), max(top or 0.0, float(count))
            cells = part.loc[[index]].assign(pose_success=values.get("pose_success"))
            record[column] = table.show(record["detector"], column, cells, "pose_success", p.get(column), 2, views,
                                        {"reference_count": float(count)})
        entries[_pair_label(row.detector, row.descriptor)] = cells  # at its largest count
        out.append(record)
    table.cells = pd.DataFrame(out).set_index("detector")
    table.ties = tied_with_best(entries, "pose_success", views, alpha, where={"reference_count": top})
    return table


def table_cells(summaries: list[dict]) -> Table | None:
    """Every cell with each reported schema metric of its experiment, headed ``<metric> (<unit>)`` (the cell's
    interval ``[low, high]`` where the schema gives one): a new metric needs no other edit here."""
    records, swept = [], swept_variants(summaries)
    for s in summaries:
        experiment, values = schema.experiment_of(s), s.get("metrics") or {}
        record = {**{k: s["methods"].get(k) or "" for k in (*METHODS, *swept)}, "experiment": experiment,
                  "status": s["status"]}
        record.update({m.name: fmt(values.get(m.name), None, m.digits, _number(values.get(f"{m.name}_ci_low")),
                                   _number(values.get(f"{m.name}_ci_high")))
                       for m in schema.metrics_of(experiment) if m.reported})
        records.append(record)
    if not records:
        return None
    cells = pd.DataFrame.from_records(records)
    metrics = schema.ordered(c for c in cells.columns if c in schema.METRICS)
    cells = cells[[c for c in cells.columns if c not in metrics] + metrics].fillna("").set_index("detector")
    cells = cells.rename(columns={m: with_unit(m, _unit(m)) for m in metrics})
    return Table("cells", "Every cell: the reported metrics of its experiment (unit in each header), aggregated "
                 f"over its views, [95 % interval] where there is one ({sample_note(frame(summaries))})", cells)


def build_tables(summaries: list[dict], views: Views | None = None, alpha: float = ALPHA) -> list[Table]:
    """Every survey table that the cells of ``summaries`` can fill; ``views``: the cells' per-view rows (for the
    intervals and the ties with the best), ``alpha``: the significance level of the paired tests. With several
    matchers or estimators, each table once per (matcher, estimator), named and titled after it."""
    groups = by_variant(summaries)
    if len(groups) == 1:
        return _survey_tables(summaries, views, alpha)
    return [Table(f"{t.name}_{variant_slug(variant)}", f"{t.title}; {variant_label(variant)}", t.cells, t.values,
                  t.ties)
            if variant_slug(variant) else t for variant, part in groups.items()
            for t in _survey_tables(part, views, alpha)]


def _survey_tables(summaries: list[dict], views: Views | None, alpha: float) -> list[Table]:
    df = frame(summaries)
    if "descriptor" not in df:
        df["descriptor"] = None
    candidates = [
        table_selectors(df, views, alpha), table_detectors(df, views, alpha),
        _pairing_table(df, "incremental", "table4_success_incremental.csv", "table4_incremental",
                       "Survey Table 4: pose success (share of pairs) on incremental pairs", views, alpha),
        _pairing_table(df, "absolute", "table5_success_absolute.csv", "table5_absolute",
                       "Survey Table 5: pose success (share of pairs) on absolute pairs", views, alpha),
        table_pairings(df, views, alpha), table_reference_counts(df, views, alpha),
    ]
    return [t for t in candidates if t is not None]


def write_tables(tables: list[Table], out_dir: str | Path) -> list[Path]:
    """Each table as .md, .tex and .csv (as shown) and ``<name>_values.csv`` (the numbers) in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for table in tables:
        texts = [(".md", table.markdown(note=True)), (".tex", table.latex()), (".csv", table.cells.to_csv())]
        if table.values:
            texts.append(("_values.csv", pd.DataFrame(table.values).to_csv(index=False)))
        for suffix, text in texts:
            path = out_dir / f"{table.name}{suffix}"
            path.write_text(text + ("\n" if not text.endswith("\n") else ""))
            files.append(path)
    return files
