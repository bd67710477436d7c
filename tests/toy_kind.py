"""A toy experiment kind from outside the package, as a plug-in writes one: keypoints per image of each detector
and selector, each image counted at two scales. Its entry (:data:`ENTRY`) is all it registers: typed settings, its
rows (its own metric, headline, step and curves), its cells on the sweep skeleton, its report and its summary."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import pandas as pd

from gtsweep.core.config import plain
from gtsweep.core.ranges import Choice, Range
from gtsweep.evaluation.schema import Metric, Rows
from gtsweep.experiments.kinds import Experiment
from gtsweep.experiments.pairs.cells import load_pairs
from gtsweep.orchestration.grid import MethodCell, MethodGrid, resolve_group
from gtsweep.orchestration.skeleton import CellWork
from gtsweep.orchestration.tasks import RunStats
from gtsweep.stages.detect import detect

NAME = "toy_count"
METRIC = "n_toy_keypoints"
#: Each image is counted at these scales (the step: the cell's figure is its largest scale's).
SCALE = "toy_scale"
YAML = f"""defaults:
  - /schema/experiment/{NAME}@_here_
  - _self_
name: {NAME}
min_size: 8         # images (at a scale) smaller than this on a side are not counted
half_scale: true    # also count each image at half its size
"""


@dataclass(frozen=True)
class ToyCell(MethodCell):
    NAMED = ("detector", "selector", "transform")
    KEY = ("detector", "selector")

    detector: str
    selector: str
    na_reason: str | None = None

    transform = "image"


@dataclass
class ToyGrid(MethodGrid):
    experiment: dict
    detectors: dict
    selectors: dict
    cells: list[ToyCell] = field(default_factory=list)
    transforms: dict = field(default_factory=dict)


def build_grid(cfg) -> ToyGrid:
    grid = ToyGrid(plain(cfg["experiment"]), resolve_group(cfg, "detector"), resolve_group(cfg, "selector"))
    grid.cells = [ToyCell(d, s) for d in grid.detectors for s in grid.selectors]
    return grid


def _count(image, cell: ToyCell, grid: ToyGrid) -> float:
    return float(len(detect(image, cell.detector, **grid.detectors[cell.detector]["params"])))


def evaluate(grid: ToyGrid, data, cells, runner_cfg, seed, cache_dir, finish, on_started) -> RunStats:
    on_started()
    scales = [0.5, 1.0] if grid.experiment["half_scale"] else [1.0]
    for cell in cells:
        rows = []
        for i, sample in enumerate(data.dataset.images("synthetic")):
            image = sample.load()
            for scale in scales:
                scaled = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
                if min(scaled.shape) >= grid.experiment["min_size"]:
                    rows.append({"view": i, "image": sample.id, "texture": sample.texture, "transform": "image",
                                 "strength": 0.0, SCALE: scale, METRIC: _count(scaled, cell, grid)})
        finish(cell, {"rows": pd.DataFrame(rows)})
    return RunStats()


def report(summaries, out_dir: Path, options):
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "toy_counts.md"
    path.write_text("\n".join(f"{s['methods']['detector']}: {s['metrics'][METRIC]:.1f}" for s in summaries) + "\n")
    return [], [path]


ENTRY = Experiment(
    NAME, "keypoints per image",
    settings={"min_size": Range(1, None, integer=True), "half_scale": Choice((True, False))},
    rows=Rows((Metric(METRIC, "keypoints", "keypoints the detector finds per image"),), METRIC,
              curves=(METRIC,), meta=(SCALE,), step=SCALE),
    cells=CellWork(build_grid, load_pairs, evaluate),
    report=report,
    summary=lambda outcome, tables: f"toy: {len(outcome.summaries)} cells")
