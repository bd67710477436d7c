"""The survey's findings, each stated as a comparison and judged with a paired test on the same images or pairs.

Input: per preset, the frame of its cells (:func:`gtsweep.report.tables.frame`) and the cells' per-view rows.
Each finding compares two entries (or one entry with a bound) and returns a :class:`Finding` with a verdict:

- *holds*: the difference is significant at ``alpha`` in the survey's direction;
- *fails*: it is significant the other way;
- *inconclusive*: the data cannot tell (e.g. 3 pairs out of 54);
- *not testable*: the cells have no per-view rows (the survey's own tables): the point values are shown;
- *not measured*: the preset it needs was not run.

Tests (:mod:`gtsweep.report.samples`, :mod:`gtsweep.evaluation.statistics`): an exact McNemar test for the success
of two pairings on the same pairs; a paired permutation test swapping the two entries within images, with a
bootstrap interval of the difference, for repeatability, ambiguity and success averaged over transforms; a
bootstrap interval over pairings for a difference of Spearman correlations. A finding made of several comparisons
(e.g. one per detector) holds when all hold, fails when any fails, and is inconclusive otherwise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from gtsweep.evaluation import statistics
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.report.samples import compare, estimate
from gtsweep.stages.detect import DETECTORS

SYNTHETIC = tuple(TRANSFORMS)
#: The survey's matcher and pose estimator (section 5: brute force + ratio test 0.7, RANSAC): with several
#: variants in a run, the findings are judged on the cells of this one (never pooled across variants).
SURVEY_VARIANT = {"matcher": "bf_ratio", "estimator": "ransac"}
NOT_MEASURED, NOT_TESTABLE = "not measured", "not testable"
MARGIN = 0.05  # "success stops growing": a gain below 0.05 (the survey's tables print two decimals)


@dataclass
class Finding:
    text: str
    verdict: str
    test: str = ""
    evidence: str = ""


class Data:
    """One preset's evaluated cells and their per-view rows."""

    def __init__(self, frame: pd.DataFrame | None, views, alpha: float):
        ok = frame is not None and len(frame) and "status" in frame
        self.cells = frame[frame["status"] == "ok"] if ok else pd.DataFrame()
        self.views, self.alpha = views, alpha

    def select(self, transforms=None, **methods) -> pd.DataFrame:
        part = self.cells
        if part.empty:
            return part
        if transforms is not None:
            part = part[part["transform"].isin(transforms)]
        for column, names in methods.items():
            part = part[part[column].isin([names] if isinstance(names, str) else list(names))]
        return part

    def value(self, cells, metric, where=None) -> float:
        return estimate(cells, metric, self.views, where)[0] if len(cells) else math.nan


def _judge(data: Data, parts: list[tuple[str, pd.DataFrame, pd.DataFrame, str, str]], where_a=None,
           where_b=None) -> tuple[str, str, str]:
    """Verdict, test and evidence of comparisons ``(label, A, B, metric, claim)`` (claim: greater or less)."""
    verdicts, tests, lines = [], set(), []
    for label, a, b, metric, claim in parts:
        value_a, value_b = data.value(a, metric, where_a), data.value(b, metric, where_b)
        result = compare(a, b, metric, data.views, where_a, where_b) if data.views else None
        if result is None:
            verdicts.append(NOT_TESTABLE)
            lines.append(f"{label}: {value_a:.2f} vs {value_b:.2f}")
            continue
        verdicts.append(_within(result, MARGIN) if claim == "within" else statistics.verdict(result, data.alpha, claim))
        tests.add(result.test)
        interval = f" [{result.low:+.2f}, {result.high:+.2f}]" if math.isfinite(result.low) else ""
        lines.append(f"{label}: {value_a:.2f} vs {value_b:.2f}, diff {result.difference:+.2f}{interval}, "
                     f"p = {result.p_value:.2g}, n = {result.n}")
    return _combine(verdicts), "; ".join(sorted(tests)), "; ".join(lines)


def _within(result: statistics.Comparison, margin: float) -> str:
    """A claim of no (relevant) gain: *holds* when the whole interval of A - B lies below ``margin``, *fails* when
    it lies above, else *inconclusive* (absence of a significant difference alone proves nothing)."""
    if not math.isfinite(result.high):
        return statistics.INCONCLUSIVE
    return statistics.HOLDS if result.high <= margin else statistics.FAILS if result.low > margin else \
        statistics.INCONCLUSIVE


def _combine(verdicts: list[str]) -> str:
    if not verdicts:
        return NOT_MEASURED
    if NOT_TESTABLE in verdicts:
        return NOT_TESTABLE
    if statistics.FAILS in verdicts:
        return statistics.FAILS
    return statistics.HOLDS if all(v == statistics.HOLDS for v in verdicts) else statistics.INCONCLUSIVE


def _best(data: Data, entries: dict[str, pd.DataFrame], metric: str, lowest: bool = False, where=None):
    values = {k: data.value(v, metric, where) for k, v in entries.items() if len(v)}
    values = {k: v for k, v in values.items() if math.isfinite(v)}
    return (min if lowest else max)(values, key=values.get) if values else None


def _pairings(data: Data, transforms) -> dict[str, pd.DataFrame]:
    cells = data.select(transforms)
    if cells.empty or "descriptor" not in cells:
        return {}
    if "by_reference_count" in cells:
        cells = cells[cells["by_reference_count"].isna()]
    return {f"{d}-{s}": group for (d, s), group in cells.dropna(subset=["descriptor"]).groupby(
        ["detector", "descriptor"])}


def _selector_cells(data: Data) -> dict[str, dict[str, pd.DataFrame]]:
    """Detection cells per detector and selector."""
    cells = data.select()
    if cells.empty:
        return {}
    cells = cells[cells["descriptor"].isna()] if "descriptor" in cells else cells
    return {d: {s: c for s, c in group.groupby("selector")} for d, group in cells.groupby("detector")}


def _survey_selector(detector: str, by_selector: dict) -> str:
    """The survey's selector for Table 3: NMS, ANMS for MSER (else whichever was run)."""
    preferred = ("anms", "nms") if detector == "mser" else ("nms",)
    return next((s for s in preferred if s in by_selector), next(iter(by_selector)))


def _keeps_all(cells: pd.DataFrame) -> bool:
    """True when a selector kept every detected keypoint in each of its cells (nothing was selected)."""
    return {"n_detected", "n_kp_test"} <= set(cells) and bool((cells["n_kp_test"] >= cells["n_detected"]).all())


def nms_beats_other_selectors(d: dict[str, Data]):
    """NMS (ANMS for MSER) against the better of the other two selectors, per detector. A selector that, like the
    survey's one, kept every keypoint (e.g. GFTT, which stops at 1000 corners) holds the same keypoints: that is
    no comparison of selection methods, and it is left out."""
    data = d["table2_selectors"]
    parts = []
    for det, sel in _selector_cells(data).items():
        mine = "anms" if det == "mser" else "nms"
        if mine not in sel or len({"nms", "anms", "bucketing"} & set(sel)) < 3:
            continue
        others = {s: c for s, c in sel.items() if s in {"nms", "anms", "bucketing"} - {mine}
                  and not (_keeps_all(c) and _keeps_all(sel[mine]))}
        if not others:
            continue
        rival = _best(data, others, "repeatability")
        parts.append((f"{det} {mine.upper()} vs {rival.upper()}", sel[mine], others[rival], "repeatability",
                      "greater"))
    return data, parts


def selection_hurts_dense_detectors(d):
    data = d["table2_selectors"]
    sel = _selector_cells(data)
    return data, [(f"{det} none vs NMS", sel[det]["none"], sel[det]["nms"], "repeatability", "greater")
                  for det in ("mser", "fast", "agast", "brisk") if {"none", "nms"} <= set(sel.get(det, {}))]


def _table3(d) -> tuple[Data, dict[str, pd.DataFrame]]:
    data = d["table3_detectors"]
    cells = {det: sel[_survey_selector(det, sel)] for det, sel in _selector_cells(data).items() if sel}
    return data, cells


def best_repeatability(d):
    data, cells = _table3(d)
    named = [x for x in ("sift", "akaze", "surf") if x in cells]
    rival = _best(data, {k: v for k, v in cells.items() if k not in named}, "repeatability")
    if len(named) < 3 or rival is None:
        return data, []
    return data, [(f"{x} vs {rival}", cells[x], cells[rival], "repeatability", "greater") for x in named]


def _median_detector(data: Data, cells: dict, metric: str, leave_out=()) -> str | None:
    values = pd.Series({k: data.value(v, metric) for k, v in cells.items() if k not in leave_out}).dropna()
    return None if values.empty else (values - values.median()).abs().idxmin()


def sift_ambiguous(d):
    data, cells = _table3(d)
    median = _median_detector(data, cells, "ambiguity", ("sift",))
    if "sift" not in cells or median is None:
        return data, []
    return data, [(f"sift vs median detector {median}", cells["sift"], cells[median], "ambiguity", "greater")]


def low_ambiguity_detectors(d):
    data, cells = _table3(d)
    named = [x for x in ("surf", "censure", "akaze") if x in cells]
    median = _median_detector(data, cells, "ambiguity", named)
    if not named or median is None or len(cells) < 4:
        return data, []
    return data, [(f"{x} vs median detector {median}", cells[x], cells[median], "ambiguity", "less") for x in named]


def censure_best_incremental(d):
    data = d["table4_incremental"]
    entries = _pairings(data, ["incremental"])
    mine = {k: v for k, v in entries.items() if k in ("censure-orb", "censure-brief", "censure-latch")}
    best, rival = _best(data, mine, "pose_success"), _best(data, {k: v for k, v in entries.items()
                                                                  if not k.startswith("censure-")}, "pose_success")
    if best is None or rival is None:
        return data, []
    return data, [(f"{best} vs {rival}", mine[best], entries[rival], "pose_success", "greater")]


def _oriented(name: str) -> bool | None:
    return DETECTORS[name].orientation if name in DETECTORS else None


def oriented_detectors_win_absolute(d):
    data = d["table5_absolute"]
    entries = _pairings(data, ["absolute"])
    best = {}
    for det in {k.split("-")[0] for k in entries}:
        mine = {k: v for k, v in entries.items() if k.split("-")[0] == det}
        top = _best(data, mine, "pose_success")
        best[det] = mine[top] if top else None
    oriented = [v for k, v in best.items() if v is not None and _oriented(k)]
    unoriented = [v for k, v in best.items() if v is not None and _oriented(k) is False]
    if not oriented or not unoriented:
        return data, []
    return data, [("best pairing per detector, oriented vs unoriented", pd.concat(oriented),
                   pd.concat(unoriented), "pose_success", "greater")]


def unoriented_collapse_absolute(d):
    """Unoriented detectors with ORB/BRIEF/LATCH/SIFT vs the same detectors' other pairings on absolute pairs."""
    data = d["table5_absolute"]
    entries = _pairings(data, ["absolute"])
    plain = ("orb", "brief", "latch", "sift")
    named = [v for k, v in entries.items() if _oriented(k.split("-")[0]) is False and k.split("-")[1] in plain]
    oriented = [v for k, v in entries.items() if _oriented(k.split("-")[0]) and k.split("-")[1] in plain]
    if not named or not oriented:
        return data, []
    return data, [("unoriented vs oriented detectors with ORB/BRIEF/LATCH/SIFT", pd.concat(named),
                   pd.concat(oriented), "pose_success", "less")]


def sift_best_on_synthetic(d):
    data = d["table6_pairings"]
    entries = _pairings(data, SYNTHETIC)
    rival = _best(data, {k: v for k, v in entries.items() if k != "sift-sift"}, "pose_success")
    if "sift-sift" not in entries or rival is None:
        return data, []
    return data, [(f"sift-sift vs {rival}", entries["sift-sift"], entries[rival], "pose_success", "greater")]


def precision_tracks_success(d):
    """Spearman over pairings: rho(precision, success) - rho(correct matches, success) > 0."""
    data = d["table6_pairings"]
    entries = _pairings(data, SYNTHETIC)
    if len(entries) < 3:
        return data, None
    values = pd.DataFrame({k: {m: data.value(v, m) for m in ("pose_success", "precision", "n_correct")}
                           for k, v in entries.items()}).T
    result = statistics.correlation_difference(values["precision"], values["n_correct"], values["pose_success"],
                                               confidence=1 - data.alpha)
    return data, result


def _by_count(d):
    data = d["table7_reference_features"]
    cells = data.select(["incremental"])
    if cells.empty or "by_reference_count" not in cells:
        return data, cells, []
    cells = cells[cells["by_reference_count"].notna()]
    counts = sorted({float(c) for r in cells["by_reference_count"] for c in r})
    return data, cells, counts


def _at(cells: pd.DataFrame, count: float) -> pd.DataFrame:
    """Cells with the success at ``count`` reference features as their value (for the point estimate)."""
    return cells.assign(pose_success=[next((v.get("pose_success") for k, v in r.items() if float(k) == count),
                                           math.nan) for r in cells["by_reference_count"]])


def few_references_fail(d):
    data, cells, counts = _by_count(d)
    if not {100.0, 1000.0} <= set(counts):
        return data, [], None, None
    return (data, [("100 vs 1000 reference features", _at(cells, 100.0), _at(cells, 1000.0), "pose_success",
                    "less")], {"reference_count": 100.0}, {"reference_count": 1000.0})


def success_saturates(d):
    """For the best half of the pairings, success at the largest count vs at 500: the gain's interval lies below
    :data:`MARGIN`."""
    data, cells, counts = _by_count(d)
    if 500.0 not in counts or max(counts) <= 500.0:
        return data, [], None, None
    top = max(counts)
    at_top = _at(cells, top)
    best = at_top[at_top["pose_success"] >= at_top["pose_success"].median()]
    return (data, [(f"{top:.0f} vs 500 features, best half", best, _at(cells.loc[best.index], 500.0),
                    "pose_success", "within")], {"reference_count": top}, {"reference_count": 500.0})


FINDINGS = [
    ("NMS beats ANMS and bucketing, except for MSER (Table 2)", nms_beats_other_selectors),
    ("MSER, FAST, AGAST and BRISK repeat better without selection (Table 2)", selection_hurts_dense_detectors),
    ("SIFT, AKAZE and SURF have the best repeatability (Table 3)", best_repeatability),
    ("SIFT's ambiguity is large, about 1.5 (Table 3)", sift_ambiguous),
    ("SURF, CenSurE and AKAZE have among the lowest ambiguity (Table 3)", low_ambiguity_detectors),
    ("CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)", censure_best_incremental),
    ("Unoriented detectors with ORB/BRIEF/LATCH/SIFT collapse on absolute pairs (Table 5)",
     unoriented_collapse_absolute),
    ("Detectors with orientation outperform the others on absolute pairs (Table 5)", oriented_detectors_win_absolute),
    ("SIFT is best under severe synthetic transforms (Table 6)", sift_best_on_synthetic),
    ("Precision, not the number of correct matches, tracks pose success (Table 6)", precision_tracks_success),
    ("Success stops growing beyond ~300-500 reference features for the best pairings (Table 7)", success_saturates),
    ("Success is low with 100 or fewer reference features (Table 7)", few_references_fail),
]


def check(text: str, finding, frames: dict, views: dict, alpha: float) -> Finding:
    """One finding on the presets' cells (``frames``) and per-view rows (``views``), by preset."""
    data = {name: Data(frames.get(name), views.get(name), alpha) for name in
            ("table2_selectors", "table3_detectors", "table4_incremental", "table5_absolute", "table6_pairings",
             "table7_reference_features")}
    out = finding(data)
    if finding is precision_tracks_success:
        source, result = out
        if result is None:
            return Finding(text, NOT_MEASURED)
        if not math.isfinite(result.difference):
            return Finding(text, statistics.INCONCLUSIVE, result.test,
                           f"undefined: a quantity ties across all {result.n} pairings")
        return Finding(text, statistics.verdict(result, alpha), result.test,
                       f"rho(precision, success) - rho(correct matches, success) = {result.difference:+.2f}, "
                       f"{1 - alpha:.0%} CI [{result.low:+.2f}, {result.high:+.2f}], {result.n} pairings")
    source, parts, *where = out if len(out) == 4 else (*out, None, None)
    if not parts:
        return Finding(text, NOT_MEASURED)
    verdict, test, evidence = _judge(source, parts, *where)
    return Finding(text, verdict, test, evidence)


def survey_variant(frames: dict[str, pd.DataFrame]) -> tuple[dict[str, pd.DataFrame], str]:
    """``frames`` reduced to one (matcher, estimator) variant, and a sentence saying which, so that no finding
    pools cells that differ only in matcher or estimator: the survey's (:data:`SURVEY_VARIANT`) where a run has
    it, else the first one seen. Cells without the column (detection) are kept. The sentence is empty when every
    frame has only the survey's variant (or none)."""
    chosen, left_out, shown = {}, 0, {}
    for name, df in frames.items():
        if df is None or not len(df):
            chosen[name] = df
            continue
        keep = pd.Series(True, index=df.index)
        for column, survey in SURVEY_VARIANT.items():
            if column not in df or df[column].dropna().empty:
                continue
            values = list(dict.fromkeys(df[column].dropna()))
            value = survey if survey in values else values[0]
            keep &= df[column].isna() | (df[column] == value)
            shown.setdefault(column, set()).add(value)
        chosen[name], left_out = df[keep], left_out + int((~keep).sum())
    if all(v == {SURVEY_VARIANT[k]} for k, v in shown.items()) and not left_out:
        return chosen, ""
    names = ", ".join(f"{k} {'/'.join(sorted(map(str, v)))}" for k, v in shown.items())
    survey = all(v == {SURVEY_VARIANT[k]} for k, v in shown.items())
    which = f"the survey's variant ({names})" if survey else \
        f"{names} (the survey's bf_ratio + ransac was not run)"
    dropped = f": {left_out} cell(s) of other matchers or estimators left out, never pooled" if left_out else ""
    return chosen, f"Findings judged on {which} only{dropped}."


def check_findings(frames: dict[str, pd.DataFrame], views: dict | None = None, alpha: float = 0.05) -> list[Finding]:
    """Every survey finding on a reproduction: ``frames`` and ``views`` by preset name; with several matchers or
    estimators, on the survey's variant only (:func:`survey_variant`)."""
    frames = survey_variant(frames)[0]
    return [check(text, finding, frames, views or {}, alpha) for text, finding in FINDINGS]
