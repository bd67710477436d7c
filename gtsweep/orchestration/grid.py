"""The grid of a sweep: which cells (detector x selector x descriptor x transform, and for matching and pose the
matcher, and for pose the estimator) to evaluate, from a config.

A composed config brings each method's full parameters (Hydra merged its YAML and the command line onto its
defaults: ``gtsweep.orchestration.schemas``); :meth:`~gtsweep.core.registry.Method.params` checks them strictly (and
fills in the defaults for a config that has only some: a script's, a user's file without its schema), and the method
is built once, so that a parameter it rejects stops the sweep here, in one line. A node with a ``factory`` declares
a new method (:meth:`~gtsweep.core.registry.Registry.declare`); the grid carries these declarations
(:attr:`Grid.declared`) to every process that runs its tasks.
A cell's identity is its methods and their full configuration, hashed; a resumed sweep keeps a finished cell
only when that hash is unchanged. The survey's impossible pairings are marked not applicable here, before any work,
and so is a matcher that cannot match a descriptor's kind (a FLANN index forced to KD-trees on binary descriptors).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.plugins import enable as enable_plugins
from gtsweep.core.registry import Registry
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.stages import device as devices
from gtsweep.stages.applicability import applicability
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.match import MATCHERS, SURVEY_MATCHER
from gtsweep.stages.match import applicability as matcher_applicability
from gtsweep.stages.pose import ESTIMATORS, SURVEY_ESTIMATOR
from gtsweep.stages.select import SELECTORS

#: The experiments on pairs of images (the survey's): each a grid of this module.
PAIR_EXPERIMENTS = ("detection", "matching", "pose")
TRANSFORM_KINDS = ("synthetic", "pairs")
PAIR_TRANSFORMS = ("incremental", "absolute")
#: The registry behind each grid group (the real-pair transforms have no parameters, so no entry).
REGISTRIES: dict[str, Registry] = {"detector": DETECTORS, "selector": SELECTORS, "descriptor": DESCRIPTORS,
                                   "transform": TRANSFORMS, "matcher": MATCHERS, "estimator": ESTIMATORS}
#: The survey's matcher and estimator: a config without these groups (a script's, an older one) uses them.
SURVEY_METHODS = {"matcher": SURVEY_MATCHER, "estimator": SURVEY_ESTIMATOR}
#: Settings that were the experiment's and are now a matcher's or an estimator's parameters (matching and pose).
MOVED = {"ratio": "matcher.bf_ratio.params.ratio", "mutual": "matcher.bf_ratio.params.mutual",
         "pose.model": "estimator.ransac.params.model", "pose.iterations": "estimator.ransac.params.iterations",
         "pose.threshold": "estimator.ransac.params.threshold"}


@dataclass(frozen=True)
class Cell:
    """One grid cell. ``descriptor`` and ``matcher`` are None for the detection experiment, ``estimator`` for
    detection and matching."""

    detector: str
    selector: str
    descriptor: str | None
    transform: str
    na_reason: str | None = None
    matcher: str | None = None
    estimator: str | None = None

    @property
    def key(self) -> str:
        """``detector__selector__descriptor__transform``, then the matcher and the estimator where they are not the
        survey's (``bf_ratio``, ``ransac``): a survey cell keeps its name (its files, its MLflow run)."""
        parts = [self.detector, self.selector, self.descriptor or "-", self.transform]
        others = [m for m in (self.matcher, self.estimator) if m is not None and m not in SURVEY_METHODS.values()]
        return "__".join(parts + others)

    @property
    def methods(self) -> dict:
        """The cell's method names (matcher and estimator only where the experiment has them)."""
        methods = {"detector": self.detector, "selector": self.selector, "descriptor": self.descriptor,
                   "transform": self.transform}
        return {**methods, **{k: v for k, v in (("matcher", self.matcher), ("estimator", self.estimator)) if v}}


@dataclass
class Grid:
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

    @property
    def declared(self) -> dict[str, dict[str, dict]]:
        """The methods declared in YAML, ``{group: {name: node}}``: :func:`declare` them where tasks run."""
        groups = {"detector": self.detectors, "selector": self.selectors, "descriptor": self.descriptors,
                  "transform": self.transforms}
        return declared_methods(groups)

    def matcher_params(self, name: str) -> dict:
        return dict(self.matchers[name].get("params") or {})

    def estimator_params(self, name: str) -> dict:
        return dict(self.estimators[name].get("params") or {})

    def cell_config(self, cell: Cell, dataset_fingerprint: str, seed: int) -> dict:
        """Everything that determines a cell's numbers (a matcher's and an estimator's config where it has them)."""
        config = {
            "methods": cell.methods,
            "detector": self.detectors[cell.detector],
            "selector": self.selectors[cell.selector],
            "descriptor": self.descriptors.get(cell.descriptor) if cell.descriptor else None,
            "transform": self.transforms[cell.transform],
            "experiment": self.experiment,
            "dataset": dataset_fingerprint,
            "seed": seed,
        }
        if cell.matcher is not None:
            config["matcher"] = self.matchers[cell.matcher]
        if cell.estimator is not None:
            config["estimator"] = self.estimators[cell.estimator]
        config.update(self.device_entry(cell))
        return config

    def device_entry(self, cell: Cell) -> dict:
        """``{"device": ...}`` when one of the cell's methods computes on a device other than the CPU, else
        nothing (a CPU run's cell hashes are the ones it had before ``runner.device`` existed)."""
        groups = (("detector", cell.detector), ("descriptor", cell.descriptor), ("matcher", cell.matcher))
        return {"device": self.device} if any(devices.key_entry(g, n, self.device) for g, n in groups) else {}

    def torch_methods(self) -> bool:
        """Whether any method of the grid runs on torch (only then does ``runner.device=auto`` look for CUDA)."""
        groups = {"detector": self.detectors, "descriptor": self.descriptors, "matcher": self.matchers}
        return any(devices.moves(group, name) for group, names in groups.items() for name in names)

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
    enable_plugins(cfg.get("plugins"))  # configs are data: factories only from allowed modules
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
        settings["params"] = method.check(settings.get("params"))  # a script's partial params: defaults filled in
        for params in _variants(cfg, group, settings)[1:]:  # a descriptor's per-detector ones
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


def selectors_of(cfg: Mapping, grid) -> dict[str, list[str]]:
    """The selectors each detector of ``grid`` runs with: the grid's selectors, or the one ``selector_for`` names
    for it (``selector_for: {mser: anms}``: MSER with ANMS, every other detector with the selector group; the
    survey, section 4.1, kept NMS for all detectors but MSER). A selector named there and not in the selector group
    is added to ``grid.selectors`` with its default parameters; a detector named there and not in the grid is
    ignored (a preset's choice for a detector the command line left out)."""
    pinned = plain(cfg.get("selector_for")) or {}
    if not isinstance(pinned, dict) or not all(isinstance(v, str) for v in pinned.values()):
        raise BadInput(f"selector_for must map a detector to one selector, e.g. {{mser: anms}}; got {pinned!r}")
    for detector, selector in pinned.items():
        DETECTORS.get(detector)  # an unknown name: one line with the choices
        if selector not in grid.selectors:
            grid.selectors[selector] = resolve_group({"selector": {selector: {"params": {}}}}, "selector")[selector]
    return {d: [pinned[d]] if d in pinned else [s for s in grid.selectors if s not in _only_pinned(pinned, cfg)]
            for d in grid.detectors}


def _only_pinned(pinned: dict, cfg: Mapping) -> set[str]:
    """Selectors that are in the grid only because ``selector_for`` names them (not in the selector group)."""
    return set(pinned.values()) - set(plain(cfg.get("selector")) or {})


def with_survey_method(cfg: Mapping, group: str) -> Mapping:
    """``cfg``, with the survey's method for ``group`` when it has no such group at all."""
    if cfg.get(group) is not None:
        return cfg
    return {**cfg, group: {SURVEY_METHODS[group]: {"params": {}}}}


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


def matcher_na_line(cells) -> str | None:
    """One line for the ``cells`` that are NA because their matcher cannot match their descriptor (known from the
    grid alone: written NA, nothing computed for them), by matcher; None when there is none."""
    by_matcher: dict[str, dict] = {}
    for cell in cells:
        matcher, descriptor = getattr(cell, "matcher", None), getattr(cell, "descriptor", None)
        if cell.na_reason and matcher and descriptor and applicability(cell.detector, descriptor) is None:
            found = by_matcher.setdefault(matcher, {"descriptors": {}, "cells": 0})
            found["descriptors"].setdefault(descriptor, cell.na_reason.removesuffix(f", not {descriptor}"))
            found["cells"] += 1
    return "; ".join(f"matcher {matcher} cannot match descriptor {', '.join(found['descriptors'])} "
                     f"({next(iter(found['descriptors'].values()))}): {found['cells']} cell(s) NA, not computed"
                     for matcher, found in by_matcher.items()) or None


def pairings_of(cfg: Mapping, grid: Grid) -> list[tuple[str, str]]:
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
