"""Grids of any kind: the cell and grid protocol the engine reads (:class:`MethodCell`, :class:`MethodGrid`: a
cell's key, methods, configuration and hash, written once), and the grid groups resolved from a config.

A composed config brings each method's full parameters (Hydra merged its YAML and the command line onto its
defaults: ``gtsweep.orchestration.schemas``); :meth:`~gtsweep.core.registry.Method.params` checks them strictly (and
fills in the defaults for a config that has only some: a script's, a user's file without its schema), and the
method is built once, so that a parameter it rejects stops the sweep here, in one line. A node with a ``factory``
declares a new method (:meth:`~gtsweep.core.registry.Registry.declare`); the grid carries these declarations
(:attr:`MethodGrid.declared`) to every process that runs its tasks. A cell's identity is its methods and their full
configuration, hashed; a resumed sweep keeps a finished cell only when that hash is unchanged. Each kind builds
its own grid from these parts (``gtsweep.experiments.<kind>``).
"""
from __future__ import annotations

from typing import Mapping

from gtsweep.core.config import METHOD_GROUPS, config_hash, plain
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.plugins import enable as enable_plugins
from gtsweep.core.registry import Registry
from gtsweep.evaluation.transforms import TRANSFORMS
from gtsweep.stages.applicability import applicability
from gtsweep.stages.describe import DESCRIPTORS, descriptor_params
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.match import MATCHERS, SURVEY_MATCHER
from gtsweep.stages.pose import ESTIMATORS, SURVEY_ESTIMATOR
from gtsweep.stages.select import SELECTORS

TRANSFORM_KINDS = ("synthetic", "pairs")
PAIR_TRANSFORMS = ("incremental", "absolute")
#: The registry behind each grid group (the real-pair transforms have no parameters, so no entry).
REGISTRIES: dict[str, Registry] = {"detector": DETECTORS, "selector": SELECTORS, "descriptor": DESCRIPTORS,
                                   "transform": TRANSFORMS, "matcher": MATCHERS, "estimator": ESTIMATORS}
#: The survey's matcher and estimator: a config without these groups (a script's, an older one) uses them.
SURVEY_METHODS = {"matcher": SURVEY_MATCHER, "estimator": SURVEY_ESTIMATOR}


#: The grid attribute that holds each group's ``{name: node}``.
GROUP_ATTRIBUTES = {"detector": "detectors", "selector": "selectors", "descriptor": "descriptors",
                    "transform": "transforms", "matcher": "matchers", "estimator": "estimators"}


class MethodCell:
    """What a cell of any kind is to the engine: its methods (one name per grid group it has), its ``key`` (the
    name of its files and MLflow run) and ``na_reason`` (None: it can run). A kind's cell is a frozen dataclass
    with a field per group it has and declares:

    - ``NAMED``: the groups ``methods`` always names (the others only when set);
    - ``KEY``: the groups its key joins, in order (a missing method reads ``-``);
    - ``SURVEY_DEFAULTS``: groups the key names only where the method is not the survey's (:data:`SURVEY_METHODS`:
      a survey cell keeps its name).
    """

    NAMED: tuple[str, ...] = ()
    KEY: tuple[str, ...] = ()
    SURVEY_DEFAULTS: tuple[str, ...] = ()
    na_reason: str | None

    @property
    def methods(self) -> dict:
        return {g: getattr(self, g) for g in METHOD_GROUPS
                if hasattr(self, g) and (g in self.NAMED or getattr(self, g) is not None)}

    @property
    def key(self) -> str:
        parts = [getattr(self, g) for g in self.KEY
                 if g not in self.SURVEY_DEFAULTS or getattr(self, g) not in (None, SURVEY_METHODS.get(g))]
        return "__".join(part or "-" for part in parts)


class MethodGrid:
    """What a grid of any kind is to the engine: ``experiment`` (its settings), ``cells``, and per grid group the
    ``{name: node}`` of its options (attributes named by :data:`GROUP_ATTRIBUTES`; a group the kind lacks is
    absent or empty). A cell's identity is its methods and their full configuration, hashed (:meth:`cell_hash`)."""

    #: The groups whose methods may be declared in YAML (``factory``) and so are declared where tasks run.
    DECLARED_GROUPS: tuple[str, ...] = ("detector", "selector", "descriptor", "transform")
    experiment: dict

    def options(self, group: str) -> dict[str, dict]:
        return getattr(self, GROUP_ATTRIBUTES[group], None) or {}

    @property
    def declared(self) -> dict[str, dict[str, dict]]:
        """The methods declared in YAML, ``{group: {name: node}}``: :func:`declare` them where tasks run."""
        return declared_methods({group: self.options(group) for group in self.DECLARED_GROUPS})

    def cell_config(self, cell: MethodCell, dataset_fingerprint: str, seed: int) -> dict:
        """Everything that determines a cell's numbers: its methods' configuration (a method the kind names but
        has no node for, e.g. a map's transform: ``{}``; a missing one: None), its experiment's settings, the
        data set's fingerprint and the seed."""
        config = {"methods": cell.methods, "experiment": self.experiment, "dataset": dataset_fingerprint,
                  "seed": seed}
        for group, name in cell.methods.items():
            config[group] = self.options(group).get(name, {}) if name is not None else None
        return config

    def cell_hash(self, cell: MethodCell, dataset_fingerprint: str, seed: int) -> str:
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


def pairings_of(cfg: Mapping, grid: MethodGrid) -> list[tuple[str, str]]:
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
