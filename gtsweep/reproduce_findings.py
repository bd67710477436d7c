"""The survey's findings, each checked against a reproduction's cells (one frame of cells per preset)."""
from __future__ import annotations

import math

import pandas as pd

UNORIENTED = ("censure", "fast", "gftt", "msd", "mser", "harris_laplace", "agast")


def _success(df: pd.DataFrame, transform: str) -> pd.Series:
    """Pose success per (detector, descriptor) on ``transform`` (evaluated cells only)."""
    part = df[(df["transform"] == transform) & (df["status"] == "ok")]
    return part.set_index(["detector", "descriptor"])["pose_success"] if len(part) else pd.Series(dtype=float)


def _verdict(holds: bool | None) -> str:
    return "not measured" if holds is None else ("holds" if holds else "does not hold")


def sift_best_on_synthetic(frames) -> tuple[bool | None, str]:
    df = frames.get("table6_pairings")
    if df is None:
        return None, ""
    synthetic = df[df["transform"].isin(["rotation", "translation", "noise", "gamma"]) & (df["status"] == "ok")]
    means = synthetic.groupby(["detector", "descriptor"])["pose_success"].mean().sort_values(ascending=False)
    if ("sift", "sift") not in means:
        return None, ""
    best = means.index[0]
    return means[("sift", "sift")] >= means.iloc[0] - 1e-9, (
        f"SIFT-SIFT {means[('sift', 'sift')]:.2f}; best {best[0]}-{best[1]} {means.iloc[0]:.2f}")


def censure_best_incremental(frames) -> tuple[bool | None, str]:
    df = frames.get("table4_incremental")
    success = _success(df, "incremental") if df is not None else pd.Series(dtype=float)
    ours = [success.get(("censure", d), math.nan) for d in ("orb", "brief", "latch")]
    if success.empty or all(math.isnan(v) for v in ours):
        return None, ""
    best = success.idxmax()
    return max(ours) >= success.max() - 0.02, (
        f"CenSurE-ORB/BRIEF/LATCH {', '.join(f'{v:.2f}' for v in ours)}; best {best[0]}-{best[1]} "
        f"{success.max():.2f}")


def unoriented_collapse_absolute(frames) -> tuple[bool | None, str]:
    df = frames.get("table5_absolute")
    success = _success(df, "absolute") if df is not None else pd.Series(dtype=float)
    values = [v for (det, desc), v in success.items() if det in UNORIENTED and desc in ("orb", "brief", "latch", "sift")]
    if not values:
        return None, ""
    mean = sum(values) / len(values)
    return mean <= 0.2, f"mean {mean:.2f} over {len(values)} pairings (survey ~0.10)"


def nms_beats_other_selectors(frames) -> tuple[bool | None, str]:
    df = frames.get("table2_selectors")
    if df is None:
        return None, ""
    rep = df[df["status"] == "ok"].groupby(["detector", "selector"])["repeatability"].mean().unstack()
    if not {"nms", "anms", "bucketing"} <= set(rep.columns):
        return None, ""
    nms_best = rep["nms"] >= rep[["anms", "bucketing"]].max(axis=1)
    others = [d for d in rep.index if d != "mser"]
    mser = bool(rep.loc["mser", "anms"] >= rep.loc["mser", ["nms", "bucketing"]].max()) if "mser" in rep.index else None
    holds = bool(nms_best[others].all()) and mser is not False
    exceptions = [d for d in others if not nms_best[d]]
    return holds, f"NMS best for {sum(nms_best[others])}/{len(others)} detectors" + (
        f" (not: {', '.join(exceptions)})" if exceptions else "") + (
        f"; ANMS best for MSER: {mser}" if mser is not None else "")


def success_saturates(frames) -> tuple[bool | None, str]:
    df = frames.get("table7_reference_features")
    if df is None or "by_reference_count" not in df:
        return None, ""
    gains = []
    for row in df[(df["status"] == "ok") & df["by_reference_count"].notna()].itertuples():
        by = {float(k): v.get("pose_success") for k, v in row.by_reference_count.items()}
        if 500.0 in by and max(by) > 500.0:
            gains.append((f"{row.detector}-{row.descriptor}", by[max(by)] - by[500.0]))
    if not gains:
        return None, ""
    worst = max(gains, key=lambda g: g[1])
    return worst[1] <= 0.05, f"largest gain beyond 500 features: {worst[0]} +{worst[1]:.2f}"


FINDINGS = [
    ("SIFT is best under severe synthetic transforms (Table 6)", sift_best_on_synthetic),
    ("CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)", censure_best_incremental),
    ("Unoriented detectors with ORB/BRIEF/LATCH/SIFT collapse to ~10 % on absolute pairs (Table 5)",
     unoriented_collapse_absolute),
    ("NMS beats ANMS and bucketing, except for MSER (Table 2)", nms_beats_other_selectors),
    ("Success stops growing beyond ~300-500 reference features (Table 7)", success_saturates),
]


def check_findings(frames: dict[str, pd.DataFrame]) -> list[tuple[str, str, str]]:
    """``(finding, verdict, evidence)`` for each survey finding."""
    out = []
    for text, check in FINDINGS:
        holds, evidence = check(frames)
        out.append((text, _verdict(holds), evidence))
    return out
