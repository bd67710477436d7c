"""The reproduction's design as declared in ``docs/statistics_design.md``, and the work it asks for.

The amendment of 2026-11-27 (its section of that page) fixes the rest of the run before its data: frozen picks,
one final look per open finding, restated findings, the Table 2 extension and the rows each test reads. Its
digest (:func:`design_digest`) enters the run's plan: no chunk of work starts under another design.

The work is a list of :class:`Unit` s, each one preset's cells on a window of image or pair numbers (per texture).
The rebuild of rounds 1-5 (lost with the machine that ran them; every row is seeded by its view's id, so it can be
computed again and must come out equal) takes each cell to the count it reached in round 5, as the round-5
document recorded it (``docs/reproduction/reference/round5_cell_counts/``, kept apart from the generated
``docs/reproduction/*__cell_counts.csv``, which a new document rewrites), in windows that end at the rounds'
counts.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import PROJECT_DIR
from gtsweep.reproduction.rounds import KIND

DESIGN_PAGE = PROJECT_DIR / "docs" / "statistics_design.md"
AMENDMENT = "## Amendment of 2026-11-27"
RECORDS = PROJECT_DIR / "docs" / "reproduction" / "reference" / "round5_cell_counts"
#: The rivals, medians and "best others" frozen at their round-5 picks on half 0 (amendment, A2).
FROZEN = {"best_repeatability": "censure", "sift_ambiguous": "agast", "sift_best_on_synthetic": "surf-brisk"}
#: The splits, in the order of a round's counts (:data:`~gtsweep.reproduction.rounds.ROUNDS`).
SPLITS = ("synthetic", "incremental", "absolute")
#: The rebuild's order: the open findings' presets first (amendment; issue: "start with the open findings' cells").
REBUILD_ORDER = ("table3_detectors", "table6_pairings", "table2_selectors", "table4_incremental",
                 "table5_absolute", "table7_reference_features")
#: Windows of a rebuild end at these counts per texture (every round's count, and chunks of about half an hour).
REBUILD_BOUNDS = {"table2_selectors": (1,), "table3_detectors": (1, 4, 8, 12, 16), "table6_pairings": (4, 8, 12, 16),
                  "table4_incremental": (12, 25), "table5_absolute": (6, 12, 25, 50),
                  "table7_reference_features": (12, 25)}


def split_of(preset: str) -> str:
    """Which split a preset's images or pairs come from (its findings' clusters: :data:`rounds.KIND`)."""
    return SPLITS[KIND[preset]]


def amendment_text(page: Path = DESIGN_PAGE) -> str:
    """The amendment's section of the design page (to the next section of the same level, or the end)."""
    text = Path(page).read_text()
    if AMENDMENT not in text:
        raise BadInput(f"{page}: no section '{AMENDMENT}'")
    section = text[text.index(AMENDMENT):]
    end = section.find("\n## ", len(AMENDMENT))
    return section if end < 0 else section[:end + 1]


def design_digest(page: Path = DESIGN_PAGE) -> str:
    """The digest of the amended design as declared (its section's text, trailing spaces ignored)."""
    text = "\n".join(line.rstrip() for line in amendment_text(page).strip().splitlines())
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Unit:
    """One chunk of work: ``preset``'s ``cells`` (None: all of them) on image or pair numbers ``start`` to
    ``stop`` - 1 of every texture. ``kind``: "rebuild" (rounds 1-5 again) or a new-data part of the amendment."""

    kind: str
    preset: str
    start: int
    stop: int
    cells: tuple[str, ...] | None = None

    @property
    def name(self) -> str:
        which = "all" if self.cells is None else f"{len(self.cells)}cells"
        return f"{self.kind}/{self.preset}/{self.start}-{self.stop}/{which}"

    @property
    def split(self) -> str:
        return split_of(self.preset)

    def overrides(self) -> list[str]:
        """The data set's counts and window: only this unit's images or pairs are rendered and evaluated."""
        counts = {"synthetic": 0, "incremental": 0, "absolute": 0, self.split: self.stop}
        window = [f"dataset.skip_first={{{self.split}:{self.start}}}"] if self.start else []
        return ["dataset=survey", *(f"dataset.n_{k}={v}" for k, v in counts.items()), *window]


def reached_counts(preset: str, records: Path = RECORDS) -> dict[str, float]:
    """Per cell, the count per texture it reached in round 5 (NaN: a cell without rows, not applicable)."""
    table = pd.read_csv(Path(records) / f"{preset}__cell_counts.csv")
    return dict(zip(table["cell"], table["per_texture"].astype(float)))


def rebuild_units(records: Path = RECORDS) -> list[Unit]:
    """The rebuild of rounds 1-5: per preset, windows ending at :data:`REBUILD_BOUNDS`, each with the cells whose
    reached count goes beyond the window's start (the first window: every cell, not-applicable ones included)."""
    units = []
    for preset in REBUILD_ORDER:
        reached = reached_counts(preset, records)
        start = 0
        for stop in REBUILD_BOUNDS[preset]:
            cells = tuple(sorted(k for k, n in reached.items() if math.isfinite(n) and n > start))
            if not cells:
                break
            units.append(Unit("rebuild", preset, start, stop, None if start == 0 else cells))
            start = stop
    return units


#: The amendment's new data (A6, A7): per part, its preset and the windows of its chunks (numbers per texture).
NEW_WINDOWS = {
    "extension": ("table2_selectors", (16, 18, 20, 23)),
    "round6": ("table3_detectors", (16, 28, 40, 52, 64, 76, 88, 100)),
    "round6-pairings": ("table6_pairings", (16, 37, 58, 79, 100)),
    "restated": ("table4_incremental", (25, 100)),
}
#: Finding 2's detectors, evaluated without selection in the extension (A6).
DENSE = ("mser", "fast", "agast", "brisk")


def _survey_selector(detector: str) -> str:
    return "anms" if detector == "mser" else "nms"


def new_cells(part: str, records: dict[str, dict], picks: dict[str, str | None]) -> tuple[str, ...]:
    """The cells of a part of the new data (A7), by the state's records of the preset's cells (``{key: record}``),
    given the restated findings' picks (:func:`gtsweep.reproduction.amended.picks_restated`)."""
    def keys(match) -> tuple[str, ...]:
        return tuple(sorted(k for k, r in records.items() if r["status"] == "ok" and match(r["methods"])))

    if part == "extension":
        return keys(lambda m: m["selector"] in ("nms", "anms", "bucketing") or m["detector"] in DENSE)
    if part == "round6":
        detectors = {"sift", "akaze", "surf", "censure", FROZEN["sift_ambiguous"], FROZEN["best_repeatability"],
                     picks["median_repeatability"], picks["median_ambiguity"]}
        return keys(lambda m: m["detector"] in detectors and m["selector"] == _survey_selector(m["detector"]))
    if part == "round6-pairings":
        wanted = {("sift", "sift"), tuple(FROZEN["sift_best_on_synthetic"].split("-"))}
        return keys(lambda m: (m["detector"], m.get("descriptor")) in wanted)
    wanted = {tuple(picks[k].split("-")) for k in ("censure_or_msd", "other_incremental")}
    return keys(lambda m: (m["detector"], m.get("descriptor")) in wanted)


def new_units(records: dict[str, dict[str, dict]], picks: dict[str, str | None]) -> list[Unit]:
    """Every chunk of the amendment's new data; ``records``: per preset, the state's cell records."""
    units = []
    for part, (preset, bounds) in NEW_WINDOWS.items():
        if preset not in records:
            raise BadInput(f"the state holds no {preset} cells: rebuild it before the new data")
        cells = new_cells(part, records[preset], picks)
        units += [Unit(part, preset, a, b, cells) for a, b in zip(bounds, bounds[1:])]
    return units
