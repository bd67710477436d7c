"""The grid of a pair experiment (detection, matching, pose: the survey's): which cells (detector x selector x
descriptor x transform, and for matching and pose the matcher, and for pose the estimator) to evaluate, from a
config. The survey's impossible pairings are marked not applicable here, before any work, and so is a matcher that
cannot match a descriptor's kind (a FLANN index forced to KD-trees on binary descriptors).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gtsweep.core.config import METHOD_GROUPS, plain
from gtsweep.core.errors import BadInput
from gtsweep.orchestration.grid import (MethodCell, MethodGrid, pairings_of, resolve_group, selectors_of,
                                        with_survey_method)
from gtsweep.stages import device as devices
from gtsweep.stages.applicability import applicability
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.match import applicability as matcher_applicability

#: The experiments on pairs of images (the survey's): each a grid of this module.
PAIR_EXPERIMENTS = ("detection", "matching", "pose")
#: Settings that were the experiment's and are now a matcher's or an estimator's parameters (matching and pose).
MOVED = {"ratio": "matcher.bf_ratio.params.ratio", "mutual": "matcher.bf_ratio.params.mutual",
         "pose.model": "estimator.ransac.params.model", "pose.iterations": "estimator.ransac.params.iterations",
         "pose.threshold": "estimator.ransac.params.threshold"}


@dataclass(frozen=True)
class Cell(MethodCell):
    """One grid cell. ``descriptor`` and ``matcher`` are None for the detection experiment, ``estimator`` for
    detection and matching. Its key is ``detector__selector__descriptor__transform``, then the matcher and the
    estimator where they are not the survey's (``bf_ratio``, ``ransac``): a survey cell keeps its name (its files,
    its MLflow run)."""

    NAMED = ("detector", "selector", "descriptor", "transform")
    KEY = METHOD_GROUPS
    SURVEY_DEFAULTS = ("matcher", "estimator")

    detector: str
    selector: str
    descriptor: str | None
    transform: str
    na_reason: str | None = None
    matcher: str | None = None
    estimator: str | None = None


@dataclass
class Grid(MethodGrid):
    """Cells plus the configuration of every method they use."""

    experiment: dict
    detectors: dict[str, dict]
    selectors: dict[str, dict]
    descriptors: dict[str, dict]
    transforms: dict[str, dict]
    cells: list[Cell] = field(default_factory=list)
    matchers: dict[str, dict] = field(default_factory=dict)
    estimators: dict[str, dict] = field(default_factory=dict)
    #: Where the torch methods compute (``runner.device`` resolved: cpu or cuda; :mod:`gtsweep.stages.device`).
    device: str = "cpu"

    def matcher_params(self, name: str) -> dict:
        return dict(self.matchers[name].get("params") or {})

    def estimator_params(self, name: str) -> dict:
        return dict(self.estimators[name].get("params") or {})

    def cell_config(self, cell: Cell, dataset_fingerprint: str, seed: int) -> dict:
        """:meth:`MethodGrid.cell_config`, with the device where a method computes on one other than the CPU."""
        return {**super().cell_config(cell, dataset_fingerprint, seed), **self.device_entry(cell)}

    def device_entry(self, cell: Cell) -> dict:
        """``{"device": ...}`` when one of the cell's methods computes on a device other than the CPU, else
        nothing (a CPU run's cell hashes are the ones it had before ``runner.device`` existed)."""
        groups = (("detector", cell.detector), ("descriptor", cell.descriptor), ("matcher", cell.matcher))
        return {"device": self.device} if any(devices.key_entry(g, n, self.device) for g, n in groups) else {}

    def torch_methods(self) -> bool:
        """Whether any method of the grid runs on torch (only then does ``runner.device=auto`` look for CUDA)."""
        groups = {"detector": self.detectors, "descriptor": self.descriptors, "matcher": self.matchers}
        return any(devices.moves(group, name) for group, names in groups.items() for name in names)


def build_grid(cfg: Mapping) -> Grid:
    """The cells of the sweep described by ``cfg`` (the composed Hydra config, its run settings checked where it
    was composed)."""
    experiment = plain(cfg.get("experiment")) or {}
    if experiment.get("name") not in PAIR_EXPERIMENTS:
        raise BadInput(f"experiment must be one of {', '.join(PAIR_EXPERIMENTS)}, got {experiment.get('name')!r}")
    name = experiment["name"]
    if name != "detection":
        _check_moved(experiment)
    grid = Grid(
        experiment=experiment,
        detectors=resolve_group(cfg, "detector"),
        selectors=resolve_group(cfg, "selector"),
        descriptors=resolve_group(cfg, "descriptor") if name != "detection" else {},
        transforms=resolve_group(cfg, "transform"),
        matchers=resolve_group(with_survey_method(cfg, "matcher"), "matcher") if name != "detection" else {},
        estimators=resolve_group(with_survey_method(cfg, "estimator"), "estimator") if name == "pose" else {},
    )
    grid.device = devices.resolve((plain(cfg.get("runner")) or {}).get("device"), grid.torch_methods())
    pairings = pairings_of(cfg, grid)
    selected = selectors_of(cfg, grid)
    combinations = [(m, e) for m in grid.matchers for e in (grid.estimators or [None])]
    for transform in grid.transforms:
        for selector in grid.selectors:
            if name == "detection":
                grid.cells += [Cell(d, selector, None, transform) for d in grid.detectors if selector in selected[d]]
                continue
            for detector, descriptor in pairings:
                if selector not in selected[detector]:
                    continue
                reason = applicability(detector, descriptor)
                grid.cells += [Cell(detector, selector, descriptor, transform,
                                    reason or _matcher_na(grid, matcher, descriptor), matcher, estimator)
                               for matcher, estimator in combinations]
    return grid


def _check_moved(experiment: dict) -> None:
    """A setting that moved to a matcher's or an estimator's parameters is one line naming its new place."""
    for old, new in MOVED.items():
        head, _, tail = old.partition(".")
        node = experiment.get(head)
        if (head in experiment and not tail) or (tail and isinstance(node, dict) and tail in node):
            raise BadInput(f"experiment.{old} moved to the {new.split('.')[0]} group: set {new} instead "
                           f"(conf/{new.split('.')[0]}/{new.split('.')[1]}.yaml)")


def _matcher_na(grid: Grid, matcher: str, descriptor: str) -> str | None:
    """Why ``matcher`` (with the grid's params) cannot match ``descriptor``'s vectors, else None."""
    built = MATCHERS.get(matcher).build(grid.matcher_params(matcher))
    return matcher_applicability(built, DESCRIPTORS.get(descriptor).norm, descriptor)
