"""The entries and pools the survey's findings compare, by the survey's own definitions.

- :data:`ORIENTED`, :data:`UNORIENTED`: the survey's list "Detectors that provide orientation information (SIFT,
  SURF, AKAZE, ORB, BRISK, and LIFT)" (5.2) against the other detectors of its Tables 4-5 (AGAST, CenSurE, FAST,
  GFTT, HarrisLaplace, MSD, MSER). LIFT's stand-in here, XFeat, gives no orientation, while the survey counted
  LIFT as oriented: it belongs to neither pool (either way would change the survey's definition). Detectors the
  survey did not evaluate (Harris, KAZE) are in neither.
- a detector's selector in Tables 3-7 is the survey's: ANMS for MSER, NMS for the rest ("For all other detectors,
  we use NMS in the following", 4.1).
- a "best" entry picked from the data is picked on one half of the images (``half``, see
  :func:`~gtsweep.report.samples.half_of`); the finding tests it on the other half.
"""
from __future__ import annotations

import math

import pandas as pd

from gtsweep.report.samples import estimate, textures_of

ORIENTED = frozenset({"sift", "surf", "akaze", "orb", "brisk"})
UNORIENTED = frozenset({"agast", "censure", "fast", "gftt", "harris_laplace", "msd", "mser"})
#: "ORB, BRIEF, LATCH, SIFT, and LIFT descriptors rely on available orientation information" (5.2); LIFT's
#: descriptor has no counterpart here.
PLAIN_DESCRIPTORS = ("orb", "brief", "latch", "sift")


class Data:
    """One preset's evaluated cells, their per-view rows and the significance level."""

    def __init__(self, frame: pd.DataFrame | None, views, alpha: float):
        ok = frame is not None and len(frame) and "status" in frame
        self.cells = frame[frame["status"] == "ok"] if ok else pd.DataFrame()
        self.views, self.alpha = views, alpha
        self.textures = textures_of(views)  # the data set's: an image's half is the same in every entry

    def select(self, transforms=None, **methods) -> pd.DataFrame:
        part = self.cells
        if part.empty:
            return part
        if transforms is not None:
            part = part[part["transform"].isin(transforms)]
        for column, names in methods.items():
            part = part[part[column].isin([names] if isinstance(names, str) else list(names))]
        return part

    def value(self, cells, metric, where=None, half=None) -> float:
        return estimate(cells, metric, self.views, where, half, textures=self.textures)[0] if len(cells) \
            else math.nan


def best(data: Data, entries: dict[str, pd.DataFrame], metric: str, lowest: bool = False, half=None):
    """The label of the entry with the highest (``lowest``: lowest) value on ``half`` of the images."""
    values = {k: data.value(v, metric, half=half if data.views else None) for k, v in entries.items() if len(v)}
    values = {k: v for k, v in values.items() if math.isfinite(v)}
    return (min if lowest else max)(values, key=values.get) if values else None


def median_entry(data: Data, cells: dict, metric: str, leave_out=(), half=None) -> str | None:
    """The entry nearest the median of the others on ``half`` of the images."""
    values = pd.Series({k: data.value(v, metric, half=half if data.views else None) for k, v in cells.items()
                        if k not in leave_out}, dtype=float).dropna()
    return None if values.empty else (values - values.median()).abs().idxmin()


def pairings(data: Data, transforms) -> dict[str, pd.DataFrame]:
    """Pose cells per ``detector-descriptor`` on ``transforms`` (Table 7's by-count cells left out)."""
    cells = data.select(transforms)
    if cells.empty or "descriptor" not in cells:
        return {}
    if "by_reference_count" in cells:
        cells = cells[cells["by_reference_count"].isna()]
    return {f"{d}-{s}": group for (d, s), group in cells.dropna(subset=["descriptor"]).groupby(
        ["detector", "descriptor"])}


def detection_cells(data: Data) -> dict[str, dict[str, pd.DataFrame]]:
    """Detection cells per detector and selector."""
    cells = data.select()
    if cells.empty:
        return {}
    cells = cells[cells["descriptor"].isna()] if "descriptor" in cells else cells
    return {d: {s: c for s, c in group.groupby("selector")} for d, group in cells.groupby("detector")}


def survey_selector(detector: str, by_selector: dict) -> str:
    """The survey's selector: NMS, ANMS for MSER (else whichever was run)."""
    preferred = ("anms", "nms") if detector == "mser" else ("nms",)
    return next((s for s in preferred if s in by_selector), next(iter(by_selector)))


def keeps_all(cells: pd.DataFrame) -> bool:
    """True when a selector kept every detected keypoint in each of its cells (nothing was selected)."""
    return {"n_detected", "n_kp_test"} <= set(cells) and bool((cells["n_kp_test"] >= cells["n_detected"]).all())


def table3(data: Data) -> dict[str, pd.DataFrame]:
    """Table 3's entries: each detector with the survey's selector."""
    return {det: sel[survey_selector(det, sel)] for det, sel in detection_cells(data).items() if sel}


def by_count(data: Data) -> tuple[pd.DataFrame, list[float]]:
    """Table 7's cells (success by reference feature count) and the counts they hold."""
    cells = data.select(["incremental"])
    if cells.empty or "by_reference_count" not in cells:
        return pd.DataFrame(), []
    cells = cells[cells["by_reference_count"].notna()]
    return cells, sorted({float(c) for r in cells["by_reference_count"] for c in r})


def cells_where(transforms=None, detectors=None, descriptors=None, selectors=None, pose: bool | None = None):
    """What a finding needs of its preset's cells: a function of the preset's cells (a frame with the method
    columns) giving the rows it reads, every candidate a rival or "best" may be picked from included.
    ``selectors``: names, or ``"survey"`` for each detector's survey selector (:func:`survey_selector`) among
    those the preset ran; ``pose``: pose cells only (True), detection cells only (False)."""

    def needs(cells: pd.DataFrame) -> pd.Series:
        keep = pd.Series(True, index=cells.index)
        described = cells["descriptor"].notna() if "descriptor" in cells else pd.Series(False, index=cells.index)
        if pose is not None:
            keep &= described if pose else ~described
        for column, names in (("transform", transforms), ("detector", detectors), ("descriptor", descriptors)):
            if names is not None:
                keep &= cells[column].isin(list(names)) if column in cells else False
        if selectors is not None:
            named = [s for s in selectors if s != "survey"]
            ran = cells.groupby("detector")["selector"].agg(lambda s: dict.fromkeys(s))
            own = cells["detector"].map(lambda d: survey_selector(d, ran[d]))
            keep &= cells["selector"].isin(named) | (("survey" in selectors) & (cells["selector"] == own))
        return keep

    return needs


#: A finding that reads every cell of its preset.
EVERY_CELL = cells_where()
