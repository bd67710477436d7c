"""The pair experiments (detection, matching, pose) on the sweep skeleton (:data:`PAIRS`): their data (a data set of
images and pairs), and their evaluation as a graph of detection and pairing tasks
(:mod:`gtsweep.experiments.pairs.runner`); a cell keeps the rows of the images or pairs it already evaluated on a
smaller data set (:mod:`gtsweep.orchestration.view_reuse`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.datasets import load_dataset
from gtsweep.experiments.pairs.grid import Grid, build_grid
from gtsweep.experiments.pairs.runner import plan, run
from gtsweep.orchestration.shards import load_shards
from gtsweep.orchestration.skeleton import CellWork
from gtsweep.orchestration.tasks import RunStats
from gtsweep.orchestration.view_reuse import ViewReuse

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PairData:
    """A data set of images and pairs (:func:`gtsweep.datasets.load_dataset`) as the skeleton reads it."""

    dataset: object
    fingerprint: str

    @property
    def name(self) -> str:
        return self.dataset.name

    @property
    def skipped(self) -> list[str]:
        return list(getattr(self.dataset, "skipped", []))


def load_pairs(cfg: Mapping, grid: Grid) -> PairData:
    dataset = load_dataset(cfg["dataset"])
    for kind in [name for name, transform in grid.transforms.items() if transform.get("kind") == "pairs"]:
        if not dataset.pairs(kind):  # a data set too small for the pair rules: one line before any work
            why = dataset.empty_kinds.get(kind, f"dataset.n_{kind}?")
            raise BadInput(f"data set '{dataset.name}' has no {kind} pairs: {why}")
    if cfg["dataset"].get("pose_check") and dataset.pairs("incremental"):
        check_the_poses(dataset)
    return PairData(dataset, dataset.fingerprint())


def check_the_poses(dataset) -> None:
    """Before any work: poses that disagree with the images stop the sweep in one line (which convention would
    fit); poses that agree are said in the log."""
    from gtsweep.datasets.posecheck import check_poses

    found = check_poses(dataset)
    log.info("%s", found.line())
    if not found.consistent:
        raise BadInput(f"{found.line()}; or dataset.pose_check=false to run anyway")


def evaluate_pairs(grid: Grid, data: PairData, cells: list, runner_cfg: dict, seed: int, cache_dir, finish,
                    on_started) -> RunStats:
    # Load (and so check) every image the cells read before the first result file is written: bad data stops the
    # run clean.
    transforms = {name: grid.transforms[name] for name in sorted({cell.transform for cell in cells})}
    shards = load_shards(data.dataset, transforms, int(runner_cfg["shard_size"]))
    jobs = plan(grid, {kind: len(s) for kind, s in shards.items()}, {cell.key for cell in cells})
    return run(grid, shards, jobs, runner_cfg, seed, cache_dir, finish, on_started=on_started)


#: The pair experiments (detection, matching, pose): detector x selector (x descriptor x matcher x estimator) x
#: transform on images and image pairs.
PAIRS = CellWork(build_grid, load_pairs, evaluate_pairs,
                 reuse=lambda store, grid, data, seed: ViewReuse(store, grid, data.dataset, seed,
                                                                 lambda part: PairData(part, data.fingerprint)))
