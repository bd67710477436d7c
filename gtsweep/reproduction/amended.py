"""The findings as the amendment of 2026-11-27 tests them (``docs/statistics_design.md``, sections A2-A6).

- :data:`FINAL`: findings 3, 4 and 9 at their one remaining look, the rivals frozen at their round-5 picks
  (:data:`~gtsweep.reproduction.design.FROZEN`) and tested on old half 1 plus every new image (A2, A3).
- :data:`RESTATED`: findings 1, 3, 5 and 6 restated from the survey's words (A5), judged once at alpha 0.05 on
  data collected after the amendment only; their picks are made on half 0 of the rounds' images.
- :data:`EXTENSION`: findings 1 and 2 as they are, on Table 2's fresh images (A6).

Every builder takes a :class:`~gtsweep.report.pools.Data` of all the preset's rows and chooses its rows with a
test set (:func:`~gtsweep.report.samples.in_half` with a callable): nothing here reads a row the amendment does not
name.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from gtsweep.evaluation.verdicts import AMONG, BEATS, WITHIN, Claim
from gtsweep.report.pools import best, detection_cells, keeps_all, median_entry, pairings, table3
from gtsweep.report.samples import against
from gtsweep.reproduction.design import FROZEN
from gtsweep.reproduction.findings import (AMBIGUITY_MARGIN, FINDINGS, REPEATABILITY_MARGIN, SUCCESS_MARGIN, SYNTHETIC,
                                           pair_claim)
from gtsweep.reproduction.state import item_numbers

#: Images (Tables 2, 3, 6) or pairs (Table 4) per texture that rounds 1-5 evaluated for the picks: a number at or
#: above it is new data.
ROUNDS_SYNTHETIC, ROUNDS_INCREMENTAL = 16, 25
#: Table 2's fresh images (A6): numbers 16 to 22 of every texture (images 17-23, counted from 1).
EXTENSION_IMAGES = (16, 23)
#: The span "with 83% to 84%" allows: two values printed 0.83 and 0.84 differ by up to 0.02 before rounding.
SPAN_MARGIN = 0.02
NON_WOOD = "wood"


def _numbers(rows) -> np.ndarray:
    return item_numbers(rows["image"]).to_numpy()


def old_half(half: int, first: int):
    """Half ``half`` of the images numbered below ``first`` (the rounds' images)."""
    return lambda rows, halves: (halves == half) & (_numbers(rows) < first)


def old_half1_and_new(first: int):
    """The amended test set: half 1 of the images below ``first`` and every image from ``first`` on (A2)."""
    return lambda rows, halves: ((halves == 1) & (_numbers(rows) < first)) | (_numbers(rows) >= first)


def numbered(low: int, high: int | None = None, skip_texture: str | None = None):
    """Images numbered ``low`` to ``high`` - 1 (``high`` None: every later one), optionally without a texture."""
    def chosen(rows, halves):
        numbers = _numbers(rows)
        keep = (numbers >= low) & (numbers < (high if high is not None else np.inf))
        return keep & (rows["texture"].astype(str).to_numpy() != skip_texture) if skip_texture else keep
    return chosen


# --- findings 3, 4, 9 at their final look (frozen picks) ---------------------------------------------------------

def _named_vs_frozen(data, test) -> tuple[dict, list[str], list]:
    """SIFT, AKAZE and SURF each against the frozen best other detector (CenSurE) on the images ``test`` selects:
    (Table 3's cells, the named detectors, the comparisons; none without every cell)."""
    cells, rival = table3(data), FROZEN["best_repeatability"]
    named = [x for x in ("sift", "akaze", "surf") if x in cells]
    if len(named) < 3 or rival not in cells:
        return cells, named, []
    return cells, named, [pair_claim(data, f"{x} vs {rival} (frozen round-5 pick)", AMONG, REPEATABILITY_MARGIN,
                                     cells[x], cells[rival], "repeatability", half=test) for x in named]


def best_repeatability_final(data):
    return _named_vs_frozen(data, old_half1_and_new(ROUNDS_SYNTHETIC))[2]


def sift_ambiguous_final(data):
    cells, median = table3(data), FROZEN["sift_ambiguous"]
    if "sift" not in cells or median not in cells:
        return []
    large = pair_claim(data, f"sift vs median detector {median} (frozen round-5 pick)", BEATS, AMBIGUITY_MARGIN,
                       cells["sift"], cells[median], "ambiguity", half=old_half1_and_new(ROUNDS_SYNTHETIC))
    about = against(cells["sift"], "ambiguity", data.views, 1.5, confidence=1 - 2 * data.alpha)
    return [large, Claim("sift ambiguity - 1.5", about, WITHIN, AMBIGUITY_MARGIN)]


def sift_best_on_synthetic_final(data):
    entries, rival = pairings(data, SYNTHETIC), FROZEN["sift_best_on_synthetic"]
    if "sift-sift" not in entries or rival not in entries:
        return []
    return [pair_claim(data, f"sift-sift vs {rival} (frozen round-5 pick)", AMONG, SUCCESS_MARGIN, entries["sift-sift"],
                       entries[rival], "pose_success", half=old_half1_and_new(ROUNDS_SYNTHETIC))]


# --- restated findings (new data only) ---------------------------------------------------------------------------

def selectors_restated(data):
    """1': MSER's ANMS beats NMS and bucketing; every other detector's NMS ranks with the best (extension images)."""
    test, parts = numbered(*EXTENSION_IMAGES), []
    for det, sel in detection_cells(data).items():
        mine, kind = ("anms", BEATS) if det == "mser" else ("nms", AMONG)
        for rival in sorted({"nms", "anms", "bucketing"} - {mine}):
            if mine in sel and rival in sel and not (keeps_all(sel[rival]) and keeps_all(sel[mine])):
                parts.append(pair_claim(data, f"{det} {mine.upper()} vs {rival.upper()}", kind, REPEATABILITY_MARGIN,
                                        sel[mine], sel[rival], "repeatability", half=test))
    return parts


def best_repeatability_restated(data):
    """3': each named detector ranks with the frozen best other, and the three lie within one printed step."""
    test = numbered(ROUNDS_SYNTHETIC)
    cells, named, best_part = _named_vs_frozen(data, test)
    if not best_part:
        return []
    span = [pair_claim(data, f"{a} vs {b} (span)", WITHIN, SPAN_MARGIN, cells[a], cells[b], "repeatability",
                       half=test) for i, a in enumerate(named) for b in named[i + 1:]]
    return best_part + span


#: Finding 5's named detectors; its restated form compares each with the median of the others.
LOW_AMBIGUITY = ("surf", "censure", "akaze")


def _median_other(data, cells: dict, metric: str) -> str | None:
    """The detector nearest the median of those finding 5 does not name, on half 0 of the rounds' images."""
    return median_entry(data, cells, metric, LOW_AMBIGUITY, half=old_half(0, ROUNDS_SYNTHETIC))


def _incremental_picks(data) -> tuple[dict, dict, str | None, str | None]:
    """Finding 6''s entries: every incremental pairing, the six of CenSurE and MSD with ORB, BRIEF and LATCH, and
    the best of those six and the best other, both picked on half 0 of the rounds' pairs."""
    entries = pairings(data, ["incremental"])
    mine = {k: v for k, v in entries.items() if k.split("-")[0] in ("censure", "msd")
            and k.split("-")[1] in ("orb", "brief", "latch")}
    pick = old_half(0, ROUNDS_INCREMENTAL)
    others = {k: v for k, v in entries.items() if k not in mine}
    return entries, mine, best(data, mine, "pose_success", half=pick), best(data, others, "pose_success", half=pick)


def low_ambiguity_restated(data):
    """5': SURF, CenSurE and AKAZE (non-wood) beat the median other detector in repeatability and ambiguity."""
    cells = table3(data)
    named = [x for x in LOW_AMBIGUITY if x in cells]
    parts = []
    for metric, sign, margin in (("repeatability", 1, REPEATABILITY_MARGIN), ("ambiguity", -1, AMBIGUITY_MARGIN)):
        median = _median_other(data, cells, metric)
        if median is None:
            return []
        for x in named:
            test = numbered(ROUNDS_SYNTHETIC, skip_texture=NON_WOOD if x == "akaze" else None)
            where = " (non-wood)" if x == "akaze" else ""
            parts.append(pair_claim(data, f"{x}{where} {metric} vs median other {median} (on half 0)", BEATS, margin,
                                    cells[x], cells[median], metric, sign=sign, half=test))
    return parts


def censure_or_msd_best_restated(data):
    """6': the best of CenSurE and MSD with ORB, BRIEF, LATCH vs the best other pairing (picked on half 0)."""
    entries, mine, top, rival = _incremental_picks(data)
    if top is None or rival is None:
        return []
    return [pair_claim(data, f"{top} vs {rival} (both best on half 0)", AMONG, SUCCESS_MARGIN, mine[top],
                       entries[rival], "pose_success", half=numbered(ROUNDS_INCREMENTAL))]


def picks_restated(data_table3, data_table4) -> dict[str, str | None]:
    """The restated findings' picks (half 0 of the rounds' images): which cells their new data needs."""
    cells = table3(data_table3)
    found = {f"median_{m}": _median_other(data_table3, cells, m) for m in ("repeatability", "ambiguity")}
    _, _, found["censure_or_msd"], found["other_incremental"] = _incremental_picks(data_table4)
    return found


_BY_BUILD = {h.build.__name__: h for h in FINDINGS}
FINAL = [replace(_BY_BUILD["best_repeatability"], build=best_repeatability_final,
                 comparison="each named detector vs CenSurE (frozen round-5 pick)",
                 test="paired t over images (old half 1 + new), rank claim"),
         replace(_BY_BUILD["sift_ambiguous"], build=sift_ambiguous_final,
                 comparison="SIFT vs AGAST (frozen round-5 median); SIFT vs 1.5",
                 test="paired t over images (old half 1 + new), superiority; t test, TOST vs 1.5 (all images)"),
         replace(_BY_BUILD["sift_best_on_synthetic"], build=sift_best_on_synthetic_final,
                 comparison="SIFT-SIFT vs SURF-BRISK (frozen round-5 pick)",
                 test="paired t over images (old half 1 + new), rank claim")]
RESTATED = [
    replace(_BY_BUILD["nms_beats_other_selectors"], text="1' MSER alone is best with ANMS, NMS for the others "
            "(Table 2, restated)", build=selectors_restated,
            comparison="MSER: ANMS vs NMS and bucketing (superiority); others: NMS vs each other selector (rank)",
            test="paired t over images (images 17-23), superiority / rank claim"),
    replace(_BY_BUILD["best_repeatability"], text="3' SIFT, AKAZE and SURF have the best repeatability, within one "
            "printed step of each other (Table 3, restated)", build=best_repeatability_restated,
            comparison="each named vs CenSurE (frozen); each pair of named detectors",
            test="paired t over new images, rank claim; TOST within ±0.02 (span)",
            margin=f"±{REPEATABILITY_MARGIN} (two decimals); span ±{SPAN_MARGIN} (\"83% to 84%\", before rounding)"),
    replace(_BY_BUILD["low_ambiguity_detectors"], text="5' SURF, CenSurE and AKAZE (non-wood) are in the better half "
            "of repeatability and ambiguity (Table 3, restated)", build=low_ambiguity_restated,
            comparison="each named detector vs the median other detector (picked on half 0), per score",
            test="paired t over new images (AKAZE: non-wood textures), superiority",
            margin=f"±{REPEATABILITY_MARGIN} repeatability; ±{AMBIGUITY_MARGIN} ambiguity (\"1.5\": one decimal)"),
    replace(_BY_BUILD["censure_best_incremental"], text="6' CenSurE or MSD with ORB/BRIEF/LATCH is best on "
            "incremental pairs (Table 4, restated)", build=censure_or_msd_best_restated,
            comparison="best CenSurE/MSD-ORB/BRIEF/LATCH vs best other pairing (both picked on half 0)",
            test="paired t over new pairs (26-100), rank claim"),
]
EXTENSION = [replace(h, text=f"{h.text}, extension on 7 fresh images per texture") for h in FINDINGS[:2]]
