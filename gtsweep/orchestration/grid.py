"""The grid of a sweep: which cells (detector x selector x descriptor x transform) to evaluate, from a config.

Each method's YAML params are merged onto its registry defaults (the full effective parameters, as results and
MLflow record them) and the method is built once, so that a parameter it rejects stops the sweep here, in one
line. A node with a ``factory`` declares a new method (:meth:`~gtsweep.core.registry.Registry.declare`); the
grid carries these declarations (:attr:`Grid.declared`) to every process that runs its tasks.
A cell's identity is its methods and their full configuration, hashed; a resumed sweep keeps a finished cell
only when that hash is unchanged. The survey's impossible pairings are marked not applicable here, before any work.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.registry import Registry
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.orchestration.settings import check_settings
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.pairing import applicability
from gtsweep.stages.select import SELECTORS

EXPERIMENTS = ("detection", "matching", "pose")
TRANSFORM_KINDS = ("synthetic", "pairs")
PAIR_TRANSFORMS = ("incremental", "absolute")
#: The registry behind each grid group (the real-pair transforms have no parameters, so no entry).
REGISTRIES: dict[str, Registry] = {"detector": DETECTORS, "selector": SELECTORS, "descriptor": DESCRIPTORS,
                                   "transform": TRANSFORMS}


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

    @property
    def declared(self) -> dict[str, dict[str, dict]]:
        """The methods declared in YAML, ``{group: {name: node}}``: :func:`declare` them where tasks run."""
        groups = {"detector": self.detectors, "selector": self.selectors, "descriptor": self.descriptors,
                  "transform": self.transforms}
        return declared_methods(groups)

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


#: Keys of a method config that do not change its results (the optimiser's search space).
NOT_RESULTS = ("search_space",)


def declared_methods(groups: Mapping[str, Mapping[str, dict]]) -> dict[str, dict[str, dict]]:
    """``{group: {name: node}}`` of the nodes that declare a method (they have a ``factory``)."""
    return {group: {name: node for name, node in nodes.items() if "factory" in node}
            for group, nodes in groups.items() if any("factory" in node for node in nodes.values())}


def declare(declared: Mapping[str, Mapping[str, dict]]) -> None:
    """Register the declared methods in this process's registries (a Ray worker's too)."""
    for group, nodes in declared.items():
        for name, node in nodes.items():
            REGISTRIES[group].declare(name, node)


def resolve_group(cfg: Mapping, group: str, search_space: bool = False) -> dict[str, dict]:
    """The options of grid group ``group`` as ``{name: node}``, sorted, without keys that do not change results
    (the optimiser asks for the ``search_space`` too).

    A node's ``params`` are its YAML params merged strictly onto the method's registry defaults, and the method is
    built once with them (pre-flight); a descriptor once per detector of ``cfg`` with that detector's
    ``per_detector`` params. An unknown method or parameter, or one the method rejects, is a one-line BadInput.
    """
    registry = REGISTRIES[group]
    node = plain(cfg.get(group))
    if not isinstance(node, dict) or not node:
        choices = [*registry, *PAIR_TRANSFORMS] if group == "transform" else list(registry)
        raise BadInput(f"the grid needs at least one {group}; choices: {', '.join(sorted(choices))}")
    resolved = {}
    for name in sorted(node):
        settings = node[name]
        if not isinstance(settings, dict):
            raise BadInput(f"{group}.{name} must be a mapping with 'params', got {settings!r}")
        settings = {k: v for k, v in settings.items() if search_space or k not in NOT_RESULTS}
        if "factory" in settings:
            registry.declare(name, {k: v for k, v in settings.items() if k != "search_space"})
        if group == "transform":
            _check_transform(name, settings)
            if settings["kind"] == "pairs":
                resolved[name] = settings
                continue
        method = registry.get(name)
        settings["params"] = method.params(settings.get("params"))
        for params in _variants(cfg, group, settings):
            method.check(params)
        resolved[name] = settings
    return resolved


def _variants(cfg: Mapping, group: str, settings: dict) -> list[dict]:
    """The parameter sets a method runs with: a descriptor's differ per detector (``per_detector``)."""
    if group != "descriptor":
        return [settings["params"]]
    per_detector = settings.get("per_detector") or {}
    for detector in per_detector:
        DETECTORS.get(detector)
    detectors = sorted({*per_detector, *(plain(cfg.get("detector")) or {})})
    variants = [settings["params"], *(descriptor_params(settings, d) for d in detectors)]
    return list({config_hash(params): params for params in variants}.values())


def _check_transform(name: str, settings: dict) -> None:
    kind = settings.get("kind")
    if kind not in TRANSFORM_KINDS:
        raise BadInput(f"transform.{name}.kind must be one of {', '.join(TRANSFORM_KINDS)}, got {kind!r}")
    if kind == "pairs":
        if name not in PAIR_TRANSFORMS:
            raise BadInput(f"transform '{name}' of kind 'pairs' must be named incremental or absolute")
        return
    if name not in TRANSFORMS:
        raise UnknownMethod("transform", name, [*TRANSFORMS, *PAIR_TRANSFORMS])
    strengths = settings.get("strengths")
    if not isinstance(strengths, list) or not strengths:
        raise BadInput(f"transform.{name}.strengths must be a non-empty list of numbers")
    spec = TRANSFORMS.get(name)
    for strength in strengths:
        spec.check_strength(f"transform.{name}.strengths: {strength!r}; each strength", strength)


def build_grid(cfg: Mapping) -> Grid:
    """The cells of the sweep described by ``cfg`` (the composed Hydra config); every setting checked first."""
    check_settings(cfg)
    experiment = plain(cfg.get("experiment")) or {}
    if experiment.get("name") not in EXPERIMENTS:
        raise BadInput(f"experiment must be one of {', '.join(EXPERIMENTS)}, got {experiment.get('name')!r}")
    grid = Grid(
        experiment=experiment,
        detectors=resolve_group(cfg, "detector"),
        selectors=resolve_group(cfg, "selector"),
        descriptors=resolve_group(cfg, "descriptor") if experiment["name"] != "detection" else {},
        transforms=resolve_group(cfg, "transform"),
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
