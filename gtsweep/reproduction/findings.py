"""The survey's twelve findings, each a pre-stated hypothesis judged on the same images or pairs.

Every finding (:data:`FINDINGS`) states, before any result is read: the survey's claim, the comparison, the
statistic, the test, the margin with its source in the survey, and the kind of claim, which fixes the verdicts it
can give (:mod:`gtsweep.evaluation.verdicts`: *holds*, *fails*, *equivalent* within the margin, *undecided*).
docs/statistics_design.md lists each choice and its source. Besides:

- *not testable*: the cells have no per-view rows (the survey's own tables): the point values are shown;
- *not measured*: the preset it needs was not run.

Tests (:mod:`gtsweep.report.samples`): paired t tests over images (cluster-robust; every view of an image or
pair stays together), t tests of one entry against the survey's number, a design-effect Wilson interval for a
rate against a band, a bootstrap over pairings for a difference of Spearman correlations. A rival or "best"
picked from the data is picked on one half of the images (:func:`~gtsweep.report.samples.half_of`) and tested on
the other. Holm's correction runs across the comparisons of one finding.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import pandas as pd

from gtsweep.evaluation import statistics, verdicts
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.evaluation.verdicts import ABOVE, AMONG, BEATS, BELOW, WITHIN, Claim
from gtsweep.orchestration.grid import SURVEY_METHODS
from gtsweep.report.pools import (EVERY_CELL, ORIENTED, PLAIN_DESCRIPTORS, UNORIENTED, Data, best, by_count,
                                  cells_where, detection_cells, keeps_all, median_entry, pairings, survey_selector,
                                  table3)
from gtsweep.report.samples import against, compare, rate_within

NOT_MEASURED, NOT_TESTABLE = "not measured", "not testable"
SYNTHETIC = tuple(TRANSFORMS)
#: Margins, each from the survey's wording or numbers (docs/statistics_design.md):
REPEATABILITY_MARGIN = 0.01  # Tables 2-3 print two decimals and bold equal values as tied; "83 % to 84 %" best
AMBIGUITY_MARGIN = 0.05  # "about 1.5": ambiguity stated to one decimal, half a unit either way
SUCCESS_MARGIN = 0.04  # "perform similarly well" (0.90 vs 0.93), "close to their best" (0.89 vs 0.92): gaps of 0.03
#: as printed to two decimals, up to 0.04 before rounding; the survey's own "similar" cases lie inside the margin
COLLAPSE_BAND = (0.075, 0.175)  # "drops to about 10% to 15%": numbers in steps of 5 %, half a step either way
RHO_MARGIN = 12 / (9 * (9 ** 2 - 1))  # one adjacent rank swap among Table 6's 9 pairings changes rho by 1/60


@dataclass(frozen=True)
class Hypothesis:
    """A finding as fixed before the data: what the survey says and how it is tested."""

    text: str
    preset: str
    claim: str  # the survey's sentence
    comparison: str
    test: str
    margin: str  # the margin and its source
    build: object  # Data -> list of Claim (or point-value strings when not testable)
    #: the preset's cells it reads, every candidate of a rival or "best" picked from the data included (a frame
    #: of the preset's cells -> a mask; :func:`~gtsweep.report.pools.cells_where`): a round of ``--size decide``
    #: runs only the cells of the findings still undecided
    needs: object = EVERY_CELL


@dataclass
class Finding:
    text: str
    verdict: str
    test: str = ""
    evidence: str = ""
    margin: str = ""
    correction: str = ""
    n: int = 0  # clusters (images or pairs) the finding draws on: both halves where a rival is picked on one
    to_decide: float = math.nan  # clusters (counted as n is) that would decide it at the observed effect
    parts: list = field(default_factory=list)


def _oriented(c: statistics.Comparison, sign: int) -> statistics.Comparison:
    if sign > 0:
        return c
    return replace(c, difference=-c.difference, low=-c.high, high=-c.low, centre=-c.centre, p_greater=c.p_less,
                   p_less=c.p_greater)


def pair_claim(data: Data, label, kind, margin, a, b, metric, sign=1, where_a=None, where_b=None, half=None):
    """A paired comparison of entries A and B as a :class:`Claim` (oriented by ``sign``), or a string with the
    point values when there are no per-view rows."""
    result = compare(a, b, metric, data.views, where_a, where_b, half, 1 - 2 * data.alpha, data.textures) \
        if data.views else None
    if result is None:
        return f"{label}: {data.value(a, metric, where_a):.2f} vs {data.value(b, metric, where_b or where_a):.2f}"
    return Claim(label, _oriented(result, sign), kind, margin, 0.5 if half in (0, 1) else 1.0)


def nms_beats_other_selectors(data: Data):
    """NMS (ANMS for MSER) ranks first among the three selectors, ties within the margin allowed (the survey
    bolds ties). Two selectors that both keep every keypoint hold the same keypoints: no comparison."""
    parts = []
    for det, sel in detection_cells(data).items():
        mine = "anms" if det == "mser" else "nms"
        if mine not in sel:
            continue
        for rival in sorted({"nms", "anms", "bucketing"} - {mine}):
            if rival in sel and not (keeps_all(sel[rival]) and keeps_all(sel[mine])):
                parts.append(pair_claim(data, f"{det} {mine.upper()} vs {rival.upper()}", AMONG, REPEATABILITY_MARGIN,
                                        sel[mine], sel[rival], "repeatability"))
    return parts


def selection_hurts_dense_detectors(data: Data):
    sel = detection_cells(data)
    return [pair_claim(data, f"{det} none vs {survey_selector(det, sel[det]).upper()}", BEATS, REPEATABILITY_MARGIN,
                       sel[det]["none"], sel[det][survey_selector(det, sel[det])], "repeatability")
            for det in ("mser", "fast", "agast", "brisk")
            if "none" in sel.get(det, {}) and survey_selector(det, sel[det]) != "none"]


def best_repeatability(data: Data):
    cells = table3(data)
    named = [x for x in ("sift", "akaze", "surf") if x in cells]
    rival = best(data, {k: v for k, v in cells.items() if k not in named}, "repeatability", half=0)
    if len(named) < 3 or rival is None:
        return []
    return [pair_claim(data, f"{x} vs {rival} (best other on half 0)", AMONG, REPEATABILITY_MARGIN, cells[x],
                       cells[rival], "repeatability", half=1) for x in named]


def sift_ambiguous(data: Data):
    cells = table3(data)
    median = median_entry(data, cells, "ambiguity", ("sift",), half=0)
    if "sift" not in cells or median is None:
        return []
    large = pair_claim(data, f"sift vs median detector {median} (on half 0)", BEATS, AMBIGUITY_MARGIN, cells["sift"],
                       cells[median], "ambiguity", half=1)
    about = against(cells["sift"], "ambiguity", data.views, 1.5, confidence=1 - 2 * data.alpha) \
        if data.views else None
    about = Claim("sift ambiguity - 1.5", about, WITHIN, AMBIGUITY_MARGIN) if about is not None else \
        f"sift ambiguity {data.value(cells['sift'], 'ambiguity'):.2f} vs 1.5"
    return [large, about]


def low_ambiguity_detectors(data: Data):
    cells = table3(data)
    named = [x for x in ("surf", "censure", "akaze") if x in cells]
    rival = best(data, {k: v for k, v in cells.items() if k not in named}, "ambiguity", lowest=True, half=0)
    if not named or rival is None:
        return []
    return [pair_claim(data, f"{x} vs lowest other {rival} (on half 0)", AMONG, AMBIGUITY_MARGIN, cells[x],
                       cells[rival], "ambiguity", sign=-1, half=1) for x in named]


def censure_best_incremental(data: Data):
    entries = pairings(data, ["incremental"])
    mine = {k: v for k, v in entries.items() if k in ("censure-orb", "censure-brief", "censure-latch")}
    top = best(data, mine, "pose_success", half=0)
    rival = best(data, {k: v for k, v in entries.items() if not k.startswith("censure-")}, "pose_success", half=0)
    if top is None or rival is None:
        return []
    return [pair_claim(data, f"{top} vs {rival} (both best on half 0)", AMONG, SUCCESS_MARGIN, mine[top],
                       entries[rival], "pose_success", half=1)]


def _plain(entries: dict, pool) -> list[pd.DataFrame]:
    return [v for k, v in entries.items() if k.split("-")[0] in pool and k.split("-")[1] in PLAIN_DESCRIPTORS]


def unoriented_collapse_absolute(data: Data):
    """Unoriented detectors with ORB/BRIEF/LATCH/SIFT: success about 10 % to 15 % (pooled)."""
    named = _plain(pairings(data, ["absolute"]), UNORIENTED)
    if not named:
        return []
    cells = pd.concat(named)
    result = rate_within(cells, "pose_success", data.views, COLLAPSE_BAND, 1 - 2 * data.alpha) \
        if data.views else None
    if result is None:
        return [f"unoriented detectors with ORB/BRIEF/LATCH/SIFT: {data.value(cells, 'pose_success'):.2f} vs "
                f"{COLLAPSE_BAND[0]:.3f}-{COLLAPSE_BAND[1]:.3f}"]
    return [Claim("unoriented detectors with ORB/BRIEF/LATCH/SIFT - centre of [0.075, 0.175]", result, WITHIN,
                 (COLLAPSE_BAND[1] - COLLAPSE_BAND[0]) / 2)]


def oriented_detectors_win_absolute(data: Data):
    entries = pairings(data, ["absolute"])
    chosen = {}
    for det in {k.split("-")[0] for k in entries}:
        mine = {k: v for k, v in entries.items() if k.split("-")[0] == det}
        top = best(data, mine, "pose_success", half=0)
        if top is not None:
            chosen[det] = mine[top]
    oriented = [v for k, v in chosen.items() if k in ORIENTED]
    unoriented = [v for k, v in chosen.items() if k in UNORIENTED]
    if not oriented or not unoriented:
        return []
    return [pair_claim(data, "best pairing per detector (on half 0), oriented vs unoriented", BEATS, SUCCESS_MARGIN,
                       pd.concat(oriented), pd.concat(unoriented), "pose_success", half=1)]


def sift_best_on_synthetic(data: Data):
    entries = pairings(data, SYNTHETIC)
    rival = best(data, {k: v for k, v in entries.items() if k != "sift-sift"}, "pose_success", half=0)
    if "sift-sift" not in entries or rival is None:
        return []
    return [pair_claim(data, f"sift-sift vs {rival} (best other on half 0)", AMONG, SUCCESS_MARGIN,
                       entries["sift-sift"], entries[rival], "pose_success", half=1)]


def precision_tracks_success(data: Data):
    """Spearman over pairings: rho(precision, success) - rho(correct matches, success) > 0."""
    entries = pairings(data, SYNTHETIC)
    if len(entries) < 3:
        return []
    values = pd.DataFrame({k: {m: data.value(v, m) for m in ("pose_success", "precision", "n_correct")}
                           for k, v in entries.items()}).T
    result = statistics.correlation_difference(values["precision"], values["n_correct"], values["pose_success"],
                                               confidence=1 - 2 * data.alpha)
    return [Claim(f"rho(precision, success) - rho(correct matches, success), {len(values)} pairings", result, BEATS,
                 RHO_MARGIN, images_narrow=False)]


#: The pairings the survey names as "close to their best performance at 300 features already" (5.2).
SATURATING = ("censure-orb", "censure-latch", "sift-sift")


def success_saturates(data: Data):
    """CenSurE-ORB, CenSurE-LATCH, SIFT-SIFT: success at the largest count minus at 300 stays below the margin."""
    cells, counts = by_count(data)
    if 300.0 not in counts or max(counts) <= 300.0:
        return []
    top = max(counts)
    return [pair_claim(data, f"{name} {top:.0f} vs 300 features", BELOW, SUCCESS_MARGIN, group, group, "pose_success",
                       where_a={"reference_count": top}, where_b={"reference_count": 300.0})
            for name, group in _by_pairing(cells) if name in SATURATING]


def few_references_fail(data: Data):
    """Per Table 7 pairing: success at 1000 reference features minus at 100 exceeds the margin ("low": not
    similar)."""
    cells, counts = by_count(data)
    if not {100.0, 1000.0} <= set(counts):
        return []
    return [pair_claim(data, f"{name} 1000 vs 100 features", ABOVE, SUCCESS_MARGIN, group, group, "pose_success",
                       where_a={"reference_count": 1000.0}, where_b={"reference_count": 100.0})
            for name, group in _by_pairing(cells)]


def _by_pairing(cells: pd.DataFrame):
    return [(f"{d}-{s}", g) for (d, s), g in cells.groupby(["detector", "descriptor"])] if len(cells) else []


#: Table 3's findings pick their rival (best, median, lowest) among every detector with its survey selector.
_TABLE3 = cells_where(selectors=("survey",), pose=False)
_REP = f"±{REPEATABILITY_MARGIN} (tables' two decimals; ties bolded)"
_SUC = f"±{SUCCESS_MARGIN} (\"similarly well\": 0.90 vs 0.93, two decimals)"
FINDINGS = [
    Hypothesis("NMS beats ANMS and bucketing, except for MSER (Table 2)", "table2_selectors",
               "\"We find MSER to be the only detector that performs best with ANMS. For all other detectors, we "
               "use NMS\" (4.1)", "per detector, its selector (ANMS for MSER) vs each other selector",
               "paired t over images, rank claim (ties within the margin support it)", _REP,
               nms_beats_other_selectors, cells_where(pose=False)),
    Hypothesis("MSER, FAST, AGAST and BRISK repeat better without selection (Table 2)", "table2_selectors",
               "\"Together with FAST, AGAST, and BRISK, MSER has significantly better repeatability without "
               "selection\" (4.1)", "per detector, no selection vs its survey selector",
               "paired t over images, superiority", _REP, selection_hurts_dense_detectors,
               cells_where(detectors=("mser", "fast", "agast", "brisk"), selectors=("none", "survey"), pose=False)),
    Hypothesis("SIFT, AKAZE and SURF have the best repeatability (Table 3)", "table3_detectors",
               "\"SIFT, AKAZE, and SURF have with 83% to 84% the best repeatability\" (4.1)",
               "each named detector vs the best other detector (picked on half 0)",
               "paired t over images on half 1, rank claim", _REP, best_repeatability,
               _TABLE3),
    Hypothesis("SIFT's ambiguity is large, about 1.5 (Table 3)", "table3_detectors",
               "\"SIFT has a large ambiguity score of 1.5\" (4.1)",
               "SIFT vs the median other detector (picked on half 0); SIFT vs 1.5",
               "paired t over images (half 1), superiority; t test, TOST vs 1.5",
               f"±{AMBIGUITY_MARGIN} (\"1.5\": one decimal)", sift_ambiguous, _TABLE3),
    Hypothesis("SURF, CenSurE and AKAZE have among the lowest ambiguity (Table 3)", "table3_detectors",
               "\"They have among the best repeatability, and ambiguity scores\" (4.1)",
               "each named detector vs the lowest other detector (picked on half 0)",
               "paired t over images on half 1, rank claim (ambiguity >= 1: ties at the floor support it)",
               f"±{AMBIGUITY_MARGIN} (ambiguity stated to one decimal)", low_ambiguity_detectors, _TABLE3),
    Hypothesis("CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)", "table4_incremental",
               "\"The best performance for incremental localization of 93% ... ORB on CenSurE or MSD keypoints. "
               "BRIEF and LATCH perform similarly well with 90%\" (5.2)",
               "best CenSurE-ORB/BRIEF/LATCH vs best other pairing (both picked on half 0)",
               "paired t over pairs on half 1, rank claim", _SUC, censure_best_incremental,
               cells_where(transforms=["incremental"], pose=True)),
    Hypothesis("Unoriented detectors with ORB/BRIEF/LATCH/SIFT collapse on absolute pairs (Table 5)",
               "table5_absolute", "\"In these cases pose estimation success rate drops to about 10% to 15%\" (5.2)",
               "success of unoriented detectors with ORB/BRIEF/LATCH/SIFT, pooled, vs the band 0.10-0.15",
               "design-effect Wilson interval (1 - 2 alpha) inside / outside the band",
               "[0.075, 0.175] (\"about\": half a 5 % step)", unoriented_collapse_absolute,
               cells_where(transforms=["absolute"], detectors=UNORIENTED, descriptors=PLAIN_DESCRIPTORS, pose=True)),
    Hypothesis("Detectors with orientation outperform the others on absolute pairs (Table 5)", "table5_absolute",
               "\"Detectors that provide orientation information (SIFT, SURF, AKAZE, ORB, BRISK, and LIFT) "
               "outperform the other detectors\" (5.2)",
               "best pairing per detector (picked on half 0), oriented pool vs unoriented pool",
               "paired t over pairs on half 1, superiority", _SUC, oriented_detectors_win_absolute,
               cells_where(transforms=["absolute"], detectors=ORIENTED | UNORIENTED, pose=True)),
    Hypothesis("SIFT is best under severe synthetic transforms (Table 6)", "table6_pairings",
               "\"SIFT outperforms the other feature extraction pipelines\"; \"other pairings ... perform "
               "similarly well\" (5.2, 6)", "SIFT-SIFT vs the best other pairing (picked on half 0)",
               "paired t over images on half 1, rank claim", _SUC, sift_best_on_synthetic,
               cells_where(transforms=SYNTHETIC, pose=True)),
    Hypothesis("Precision, not the number of correct matches, tracks pose success (Table 6)", "table6_pairings",
               "\"We find precision to correlate with the pose estimation success rate, while this relation is "
               "not that clear for the number of correct matches\" (5.2)",
               "rho(precision, success) - rho(correct matches, success) over pairings",
               "bootstrap interval over pairings (1 - 2 alpha), superiority",
               "±1/60 (one adjacent rank swap among the survey's 9 pairings)", precision_tracks_success,
               cells_where(transforms=SYNTHETIC, pose=True)),
    Hypothesis("CenSurE-ORB, CenSurE-LATCH and SIFT-SIFT are close to their best at 300 reference features "
               "(Table 7)", "table7_reference_features",
               "\"pairings like CenSurE-ORB, CenSurE-LATCH, and SIFT-SIFT reach values close to their best "
               "performance at 300 features already\" (5.2)",
               "per named pairing, success at the largest count minus at 300", "paired t over pairs, below the margin",
               f"{SUCCESS_MARGIN} (\"close to their best\": 0.92 vs 0.89, 0.89 vs 0.86, 0.84 vs 0.82, two decimals)",
               success_saturates, cells_where(transforms=["incremental"], detectors=("censure", "sift"),
                                              descriptors=("orb", "latch", "sift"), pose=True)),
    Hypothesis("Success is low with 100 or fewer reference features (Table 7)", "table7_reference_features",
               "\"localization performance is low for 100 or less reference keypoints\" (5.2)",
               "per pairing, success at 1000 minus at 100 reference features",
               "paired t over pairs, above the margin (\"low\": not similar to 1000)",
               f"{SUCCESS_MARGIN} (\"similarly well\": 0.90 vs 0.93, two decimals)", few_references_fail,
               cells_where(transforms=["incremental"], pose=True)),
]


def judge(hypothesis: Hypothesis, data: Data) -> Finding:
    """One finding on one preset's data."""
    base = Finding(hypothesis.text, NOT_MEASURED, hypothesis.test, margin=hypothesis.margin)
    if data.cells.empty:
        return base
    parts = hypothesis.build(data)
    if not parts:
        return base
    points = [p for p in parts if isinstance(p, str)]
    if points:
        return replace(base, verdict=NOT_TESTABLE, evidence="; ".join(points))
    result = verdicts.decide(parts, data.alpha)
    lines = []
    for test, verdict, adjusted in zip(result.tests, result.parts(), result.adjusted_fail):
        c = test.comparison
        p = f", p = {c.p_value:.2g}" if math.isfinite(c.p_value) else ""
        p += f", p(fail, Holm) = {adjusted:.2g}" if len(parts) > 1 else ""
        lines.append(f"{test.label}: {c.difference:+.3f} [{c.low:+.3f}, {c.high:+.3f}]{p}, n = {c.n}: {verdict}")
    need = [verdicts.images_to_decide(t, data.alpha) for t, v in zip(parts, result.parts())
            if v == verdicts.UNDECIDED]
    # the largest finite need; infinity when only comparisons no number of images decides are open
    finite = [x for x in need if math.isfinite(x)]
    to_decide = max(finite) if finite else (math.inf if math.inf in need else math.nan)
    return replace(base, verdict=result.verdict, evidence="; ".join(lines),
                   n=min(round(t.comparison.n / t.share) for t in parts),
                   correction=f"Holm over {len(parts)}" if len(parts) > 1 else "none (one comparison)",
                   to_decide=to_decide if result.verdict == verdicts.UNDECIDED else math.nan,
                   parts=list(parts))


def check(hypothesis: Hypothesis, frames: dict, views: dict, alpha: float) -> Finding:
    return judge(hypothesis, Data(frames.get(hypothesis.preset), views.get(hypothesis.preset), alpha))


def survey_variant(frames: dict[str, pd.DataFrame]) -> tuple[dict[str, pd.DataFrame], str]:
    """``frames`` reduced to one (matcher, estimator) variant, and a sentence saying which, so that no finding pools
    cells that differ only in matcher or estimator: the survey's
    (:data:`~gtsweep.orchestration.grid.SURVEY_METHODS`) where a run has it, else the first one seen. Cells without
    the column (detection) are kept. The sentence is empty when every frame has only the survey's variant (or
    none)."""
    chosen, left_out, shown = {}, 0, {}
    for name, df in frames.items():
        if df is None or not len(df):
            chosen[name] = df
            continue
        keep = pd.Series(True, index=df.index)
        for column, survey in SURVEY_METHODS.items():
            if column not in df or df[column].dropna().empty:
                continue
            values = list(dict.fromkeys(df[column].dropna()))
            value = survey if survey in values else values[0]
            keep &= df[column].isna() | (df[column] == value)
            shown.setdefault(column, set()).add(value)
        chosen[name], left_out = df[keep], left_out + int((~keep).sum())
    if all(v == {SURVEY_METHODS[k]} for k, v in shown.items()) and not left_out:
        return chosen, ""
    names = ", ".join(f"{k} {'/'.join(sorted(map(str, v)))}" for k, v in shown.items())
    survey = all(v == {SURVEY_METHODS[k]} for k, v in shown.items())
    which = f"the survey's variant ({names})" if survey else \
        f"{names} (the survey's bf_ratio + ransac was not run)"
    dropped = f": {left_out} cell(s) of other matchers or estimators left out, never pooled" if left_out else ""
    return chosen, f"Findings judged on {which} only{dropped}."


def check_findings(frames: dict[str, pd.DataFrame], views: dict | None = None, alpha: float = 0.05) -> list[Finding]:
    """Every survey finding on a reproduction: ``frames`` and ``views`` by preset name; with several matchers or
    estimators, on the survey's variant only (:func:`survey_variant`)."""
    frames = survey_variant(frames)[0]
    return [check(h, frames, views or {}, alpha) for h in FINDINGS]
