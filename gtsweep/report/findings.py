"""The survey's findings, each checked against a reproduction's cells (one frame of cells per preset).

A check returns ``(holds, evidence)``: ``holds`` is None when the preset it needs was not run. Thresholds follow
the survey's wording and its two-decimal rounding (values within 0.005 count as a tie); applied to the paper's
own numbers every check holds (``tests/test_reproduce.py``).
"""
from __future__ import annotations

import math

import pandas as pd

from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.stages.detect import DETECTORS

SYNTHETIC = tuple(TRANSFORMS)  # the synthetic transforms
TIE = 0.005  # the survey prints two decimals


def _ok(df: pd.DataFrame | None) -> pd.DataFrame:
    return df[df["status"] == "ok"] if df is not None and len(df) else pd.DataFrame()


def _success(df: pd.DataFrame | None, transform: str) -> pd.Series:
    """Pose success per (detector, descriptor) on ``transform`` (evaluated cells without reference counts)."""
    part = _ok(df)
    if part.empty:
        return pd.Series(dtype=float)
    part = part[part["transform"] == transform]
    if "by_reference_count" in part:
        part = part[part["by_reference_count"].isna()]
    return part.groupby(["detector", "descriptor"])["pose_success"].mean() if len(part) else pd.Series(dtype=float)


def _detection(df: pd.DataFrame | None, metric: str) -> pd.DataFrame:
    """``metric`` per detector (rows) and selector (columns), equal weight per transform type."""
    part = _ok(df)
    if part.empty or metric not in part:
        return pd.DataFrame()
    return part.groupby(["detector", "selector"])[metric].mean().unstack()


def _best_selector(df: pd.DataFrame | None, metric: str) -> pd.Series:
    """``metric`` per detector with the survey's selector: NMS, ANMS for MSER (else whichever was run)."""
    table = _detection(df, metric)
    if table.empty:
        return pd.Series(dtype=float)
    picks = {d: ("anms" if d == "mser" and "anms" in table else "nms" if "nms" in table else table.columns[0])
             for d in table.index}
    return pd.Series({d: table.loc[d, s] for d, s in picks.items()}).dropna()


def _pair(key) -> str:
    return f"{key[0]}-{key[1]}"


def sift_best_on_synthetic(frames):
    part = _ok(frames.get("table6_pairings"))
    if part.empty:
        return None, ""
    means = part[part["transform"].isin(SYNTHETIC)].groupby(["detector", "descriptor"])["pose_success"].mean()
    if ("sift", "sift") not in means:
        return None, ""
    sift, tied = means[("sift", "sift")], int((means >= means.max() - TIE).sum())
    return bool(sift >= means.max() - TIE), (
        f"SIFT-SIFT {sift:.2f}; best {_pair(means.idxmax())} {means.max():.2f}"
        + (f" ({tied} of {len(means)} pairings tie for best)" if tied > 1 else ""))


def censure_best_incremental(frames):
    success = _success(frames.get("table4_incremental"), "incremental")
    ours = [success.get(("censure", d), math.nan) for d in ("orb", "brief", "latch")]
    if success.empty or all(math.isnan(v) for v in ours):
        return None, ""
    return bool(max(ours) >= success.max() - 0.02), (
        f"CenSurE-ORB/BRIEF/LATCH {', '.join(f'{v:.2f}' for v in ours)}; best {_pair(success.idxmax())} "
        f"{success.max():.2f}")


def unoriented_collapse_absolute(frames):
    success = _success(frames.get("table5_absolute"), "absolute")
    values = [v for (det, desc), v in success.items()
              if det in DETECTORS and not DETECTORS[det].orientation and desc in ("orb", "brief", "latch", "sift")]
    if not values:
        return None, ""
    mean = sum(values) / len(values)
    return mean <= 0.2, f"mean {mean:.2f} over {len(values)} pairings (survey ~0.10)"


def oriented_detectors_win_absolute(frames):
    """Every detector's best pairing: those with orientation beat those without (Table 5)."""
    success = _success(frames.get("table5_absolute"), "absolute")
    best = success.groupby(level=0).max() if len(success) else success
    oriented = [d for d in best.index if d in DETECTORS and DETECTORS[d].orientation]
    unoriented = [d for d in best.index if d in DETECTORS and not DETECTORS[d].orientation]
    if not oriented or not unoriented:
        return None, ""
    mean_o, mean_u = best[oriented].mean(), best[unoriented].mean()
    return bool(mean_o > mean_u), (f"mean best pairing: oriented {mean_o:.2f}, unoriented {mean_u:.2f}; "
                                   f"best unoriented {best[unoriented].idxmax()} {best[unoriented].max():.2f}")


def nms_beats_other_selectors(frames):
    rep = _detection(frames.get("table2_selectors"), "repeatability")
    if rep.empty or not {"nms", "anms", "bucketing"} <= set(rep.columns):
        return None, ""
    nms_best = rep["nms"] >= rep[["anms", "bucketing"]].max(axis=1) - TIE
    others = [d for d in rep.index if d != "mser"]
    mser = bool(rep.loc["mser", "anms"] >= rep.loc["mser", ["nms", "bucketing"]].max() - TIE) \
        if "mser" in rep.index else None
    exceptions = [d for d in others if not nms_best[d]]
    return (not exceptions and mser is not False), f"NMS best for {len(others) - len(exceptions)}/{len(others)} " \
        f"detectors" + (f" (not: {', '.join(exceptions)})" if exceptions else "") + (
            f"; ANMS best for MSER: {mser}" if mser is not None else "")


def selection_hurts_dense_detectors(frames):
    """MSER, FAST, AGAST and BRISK repeat better without selection than with NMS (Table 2)."""
    rep = _detection(frames.get("table2_selectors"), "repeatability")
    if rep.empty or not {"none", "nms"} <= set(rep.columns):
        return None, ""
    dense = [d for d in ("mser", "fast", "agast", "brisk") if d in rep.index]
    if not dense:
        return None, ""
    better = [d for d in dense if rep.loc[d, "none"] > rep.loc[d, "nms"] + TIE]
    return len(better) == len(dense), ", ".join(f"{d} {rep.loc[d, 'none']:.2f} vs NMS {rep.loc[d, 'nms']:.2f}"
                                                for d in dense)


def best_repeatability(frames):
    """SIFT, AKAZE and SURF have the best repeatability (Table 3)."""
    rep = _best_selector(frames.get("table3_detectors"), "repeatability")
    if len(rep) < 4 or not {"sift", "akaze", "surf"} <= set(rep.index):
        return None, ""
    top = rep.sort_values(ascending=False)
    third = top.iloc[2]
    holds = all(rep[d] >= third - TIE for d in ("sift", "akaze", "surf"))
    return holds, "top: " + ", ".join(f"{d} {v:.2f}" for d, v in top.iloc[:4].items())


def sift_ambiguous(frames):
    """SIFT's ambiguity is large, about 1.5: several orientations at one location (Table 3)."""
    amb = _best_selector(frames.get("table3_detectors"), "ambiguity")
    if "sift" not in amb or len(amb) < 2:
        return None, ""
    return bool(amb["sift"] >= 1.3 and amb["sift"] > amb.median()), (
        f"SIFT {amb['sift']:.2f}; median detector {amb.median():.2f}; largest {amb.idxmax()} {amb.max():.2f}")


def low_ambiguity_detectors(frames):
    """SURF, CenSurE and AKAZE have among the best (lowest) ambiguity scores (Table 3)."""
    amb = _best_selector(frames.get("table3_detectors"), "ambiguity")
    named = [d for d in ("surf", "censure", "akaze") if d in amb]
    if not named or len(amb) < 4:
        return None, ""
    median = amb.median()
    return all(amb[d] <= median + TIE for d in named), (
        ", ".join(f"{d} {amb[d]:.2f}" for d in named) + f"; median detector {median:.2f}")


def precision_tracks_success(frames):
    """Across pairings, precision follows pose success more closely than the number of correct matches (Table 6)."""
    part = _ok(frames.get("table6_pairings"))
    if part.empty or "n_correct" not in part:
        return None, ""
    means = part[part["transform"].isin(SYNTHETIC)].groupby(["detector", "descriptor"])[
        ["pose_success", "precision", "n_correct"]].mean()
    if len(means) < 3:
        return None, ""
    rho = means.corr(method="spearman")["pose_success"]
    return bool(rho["precision"] > rho["n_correct"]), (
        f"Spearman with success: precision {rho['precision']:.2f}, correct matches {rho['n_correct']:.2f}")


def _by_count(frames) -> pd.DataFrame:
    """Pose success per pairing (rows) and reference feature count (columns), Table 7."""
    part = _ok(frames.get("table7_reference_features"))
    if part.empty or "by_reference_count" not in part:
        return pd.DataFrame()
    rows = {(r.detector, r.descriptor): {float(k): v.get("pose_success") for k, v in r.by_reference_count.items()}
            for r in part[part["by_reference_count"].notna()].itertuples()}
    return pd.DataFrame.from_dict(rows, orient="index").sort_index(axis=1)


def success_saturates(frames):
    """For the best half of the pairings, success grows by at most 0.05 beyond 500 reference features."""
    table = _by_count(frames)
    if table.empty or 500.0 not in table or table.columns.max() <= 500.0:
        return None, ""
    top = table.columns.max()
    best = table[table[top] >= table[top].median()]
    gains = best[top] - best[500.0]
    worst = gains.idxmax()
    return bool(gains.max() <= 0.05 + TIE), f"largest gain from 500 to {top:.0f} features: {_pair(worst)} " \
        f"+{gains.max():.2f}"


def few_references_fail(frames):
    """With 100 reference features success is clearly lower than with 1000 (N = 100 for < N KPs, Table 7)."""
    table = _by_count(frames)
    if table.empty or not {100.0, 1000.0} <= set(table.columns):
        return None, ""
    at_100, at_1000 = table[100.0].mean(), table[1000.0].mean()
    return bool(at_100 < at_1000 - 0.1), f"mean success {at_100:.2f} at 100, {at_1000:.2f} at 1000 features"


FINDINGS = [
    ("NMS beats ANMS and bucketing, except for MSER (Table 2)", nms_beats_other_selectors),
    ("MSER, FAST, AGAST and BRISK repeat better without selection (Table 2)", selection_hurts_dense_detectors),
    ("SIFT, AKAZE and SURF have the best repeatability (Table 3)", best_repeatability),
    ("SIFT's ambiguity is large, about 1.5 (Table 3)", sift_ambiguous),
    ("SURF, CenSurE and AKAZE have among the lowest ambiguity (Table 3)", low_ambiguity_detectors),
    ("CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)", censure_best_incremental),
    ("Unoriented detectors with ORB/BRIEF/LATCH/SIFT collapse to ~10 % on absolute pairs (Table 5)",
     unoriented_collapse_absolute),
    ("Detectors with orientation outperform the others on absolute pairs (Table 5)", oriented_detectors_win_absolute),
    ("SIFT is best under severe synthetic transforms (Table 6)", sift_best_on_synthetic),
    ("Precision, not the number of correct matches, tracks pose success (Table 6)", precision_tracks_success),
    ("Success stops growing beyond ~300-500 reference features for the best pairings (Table 7)", success_saturates),
    ("Success is low with 100 or fewer reference features (Table 7)", few_references_fail),
]


def check_findings(frames: dict[str, pd.DataFrame]) -> list[tuple[str, str, str]]:
    """``(finding, verdict, evidence)`` for each survey finding."""
    out = []
    for text, check in FINDINGS:
        holds, evidence = check(frames)
        out.append((text, "not measured" if holds is None else ("holds" if holds else "does not hold"), evidence))
    return out
