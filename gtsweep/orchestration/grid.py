"""The grid of a sweep: which cells (detector x selector x descriptor x transform) to evaluate, from a config.

A cell's identity is its methods and their full configuration, hashed; a resumed sweep keeps a finished cell only
when that hash is unchanged. The survey's impossible pairings are marked not applicable here, before any work.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.stages.describe import DESCRIPTORS, applicability
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.select import SELECTORS

EXPERIMENTS = ("detection", "matching", "pose")
TRANSFORM_KINDS = ("synthetic", "pairs")


@dataclass(frozen=True)
class Cell:
    """One grid cell. ``descriptor`` is None for the detection experiment."""

    detector: str
    selector: str
    descriptor: str | None
    transform: str
    na_reason: str | None = None

    @property
    def key(self) -> str:
        parts = [self.detector, self.selector, self.descriptor or "-", self.transform]
        return "__".join(parts)

    @property
    def methods(self) -> dict:
        return {"detector": self.detector, "selector": self.selector, "descriptor": self.descriptor,
                "transform": self.transform}


@dataclass
class Grid:
    """Cells plus the configuration of every method they use."""

    experiment: dict
    detectors: dict[str, dict]
    selectors: dict[str, dict]
    descriptors: dict[str, dict]
    transforms: dict[str, dict]
    cells: list[Cell] = field(default_factory=list)

    def cell_config(self, cell: Cell, dataset_fingerprint: str, seed: int) -> dict:
        """Everything that determines a cell's numbers."""
        return {
            "methods": cell.methods,
            "detector": self.detectors[cell.detector],
            "selector": self.selectors[cell.selector],
            "descriptor": self.descriptors.get(cell.descriptor) if cell.descriptor else None,
            "transform": self.transforms[cell.transform],
            "experiment": self.experiment,
            "dataset": dataset_fingerprint,
            "seed": seed,
        }

    def cell_hash(self, cell: Cell, dataset_fingerprint: str, seed: int) -> str:
        return config_hash(self.cell_config(cell, dataset_fingerprint, seed))


# replaced by the registry helper
def resolve_group(cfg: Mapping, group: str) -> dict[str, dict]:
    """``{name: config}`` of a method group as composed (search spaces included)."""
    return dict(plain(cfg.get(group)) or {})


#: Keys of a method config that do not change its results (the optimiser's search space).
NOT_RESULTS = ("search_space",)


def _group(cfg: Mapping, name: str, registry: Mapping) -> dict[str, dict]:
    """The options of a grid group as ``{name: config}``, without keys that do not change results."""
    node = plain(cfg.get(name))
    if not isinstance(node, dict) or not node:
        raise BadInput(f"the grid needs at least one {name}; choices: {', '.join(sorted(registry))}")
    for option, settings in node.items():
        if option not in registry:
            raise UnknownMethod(name, option, registry)
        if not isinstance(settings, dict):
            raise BadInput(f"{name}.{option} must be a mapping with 'params', got {settings!r}")
    return {option: {k: v for k, v in node[option].items() if k not in NOT_RESULTS} for option in sorted(node)}


def _transforms(cfg: Mapping) -> dict[str, dict]:
    from gtsweep.evaluation.transforms import TRANSFORMS

    node = plain(cfg.get("transform")) or {}
    if not node:
        raise BadInput("the grid needs at least one transform; choices: "
                       f"{', '.join(sorted([*TRANSFORMS, 'incremental', 'absolute']))}")
    for name, settings in node.items():
        kind = (settings or {}).get("kind")
        if kind not in TRANSFORM_KINDS:
            raise BadInput(f"transform.{name}.kind must be one of {', '.join(TRANSFORM_KINDS)}, got {kind!r}")
        if kind == "synthetic":
            if name not in TRANSFORMS:
                raise UnknownMethod("transform", name, [*TRANSFORMS, "incremental", "absolute"])
            strengths = settings.get("strengths")
            if not isinstance(strengths, list) or not strengths:
                raise BadInput(f"transform.{name}.strengths must be a non-empty list of numbers")
            if not all(isinstance(s, (int, float)) and not isinstance(s, bool) for s in strengths):
                raise BadInput(f"transform.{name}.strengths must be numbers, got {strengths}")
        elif name not in ("incremental", "absolute"):
            raise BadInput(f"transform '{name}' of kind 'pairs' must be named incremental or absolute")
    return dict(sorted(node.items()))


def build_grid(cfg: Mapping) -> Grid:
    """The cells of the sweep described by ``cfg`` (the composed Hydra config)."""
    experiment = plain(cfg.get("experiment")) or {}
    if experiment.get("name") not in EXPERIMENTS:
        raise BadInput(f"experiment must be one of {', '.join(EXPERIMENTS)}, got {experiment.get('name')!r}")
    grid = Grid(
        experiment=experiment,
        detectors=_group(cfg, "detector", DETECTORS),
        selectors=_group(cfg, "selector", SELECTORS),
        descriptors=_group(cfg, "descriptor", DESCRIPTORS) if experiment["name"] != "detection" else {},
        transforms=_transforms(cfg),
    )
    pairings = _pairings(cfg, grid)
    for transform in grid.transforms:
        for selector in grid.selectors:
            if experiment["name"] == "detection":
                grid.cells += [Cell(d, selector, None, transform) for d in grid.detectors]
                continue
            for detector, descriptor in pairings:
                grid.cells.append(Cell(detector, selector, descriptor, transform, applicability(detector, descriptor)))
    return grid


def _pairings(cfg: Mapping, grid: Grid) -> list[tuple[str, str]]:
    wanted = plain(cfg.get("pairings"))
    if wanted is None:
        return [(d, s) for d in grid.detectors for s in grid.descriptors]
    if not isinstance(wanted, list) or not all(isinstance(p, list) and len(p) == 2 for p in wanted):
        raise BadInput("pairings must be a list of [detector, descriptor] pairs")
    for detector, descriptor in wanted:
        if detector not in grid.detectors:
            raise BadInput(f"pairing [{detector}, {descriptor}]: detector '{detector}' is not in the grid "
                           f"(detector={list(grid.detectors)})")
        if descriptor not in grid.descriptors:
            raise BadInput(f"pairing [{detector}, {descriptor}]: descriptor '{descriptor}' is not in the grid "
                           f"(descriptor={list(grid.descriptors)})")
    return [tuple(p) for p in wanted]
