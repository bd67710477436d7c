"""What the optimiser tunes: one target per detector (``repeatability``) or per [detector, descriptor] pairing
(``pose_success``), with its defaults, search space and study name."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput
from gtsweep.experiments.optimize.search_space import parse_space
from gtsweep.experiments.optimize.study_settings import job_transforms
from gtsweep.orchestration.grid import declared_methods, resolve_group


@dataclass
class Target:
    """What one study tunes: a detector (``group`` "detector") or a descriptor on a detector's keypoints."""

    group: str
    name: str
    detector: str
    descriptor: str | None
    node: dict  # the tuned method's config: params, search_space, ...
    defaults: dict  # the parameters the search starts from
    space: dict  # the declared search space
    distributions: dict
    detector_params: dict
    declared: dict = field(default_factory=dict)  # methods declared in YAML, for the processes that run trials

    @property
    def label(self) -> str:
        return self.name if self.group == "detector" else f"{self.detector}+{self.descriptor}"


def build_targets(cfg: Mapping, settings: Mapping) -> list[Target]:
    """One target per selected detector, or per pairing for the pose objective; search spaces checked."""
    from gtsweep.stages.applicability import applicability
    from gtsweep.stages.describe import descriptor_params
    from gtsweep.stages.detect import DETECTORS

    detectors = resolve_group(cfg, "detector", search_space=True)
    if not detectors:
        raise BadInput("experiment=optimize needs at least one detector, e.g. detector=[sift]")
    if settings["objective"] == "repeatability":
        targets = [_target("detector", name, name, None, detectors[name], detectors[name].get("search_space"),
                           (DETECTORS.get(name).count_param or "",)) for name in detectors]
        return _with_declared(targets, {"detector": detectors})
    descriptors = resolve_group(cfg, "descriptor", search_space=True)
    pairings = plain(cfg.get("pairings"))
    if not descriptors:
        raise BadInput("objective pose_success needs a descriptor, e.g. descriptor=[sift]")
    if pairings is None:
        pairings = [[next(iter(detectors)), next(iter(descriptors))]]
    targets = []
    for pairing in pairings:
        if not isinstance(pairing, list) or len(pairing) != 2 or pairing[0] not in detectors \
                or pairing[1] not in descriptors:
            raise BadInput(f"pairing {pairing!r} must be [detector, descriptor] from detector={list(detectors)} "
                           f"and descriptor={list(descriptors)}")
        detector, descriptor = pairing
        reason = applicability(detector, descriptor)
        if reason:
            raise BadInput(f"pairing [{detector}, {descriptor}] cannot be evaluated: {reason}")
        node = descriptors[descriptor]
        space = node.get("search_space") or (settings.get("descriptor_search_spaces") or {}).get(descriptor)
        target = _target("descriptor", descriptor, detector, descriptor, node, space, (),
                         defaults=descriptor_params(node, detector))
        target.detector_params = dict(detectors[detector].get("params") or {})
        targets.append(target)
    return _with_declared(targets, {"detector": detectors, "descriptor": descriptors})


def _with_declared(targets: list[Target], groups: dict) -> list[Target]:
    declared = declared_methods(groups)
    for target in targets:
        target.declared = declared
    return targets


def _target(group, name, detector, descriptor, node, space, excluded, defaults=None) -> Target:
    defaults = dict(node.get("params") or {}) if defaults is None else defaults
    distributions = parse_space(f"{group}.{name}.search_space", space, defaults, excluded)
    return Target(group, name, detector, descriptor, node, defaults, dict(space), distributions,
                  dict(node.get("params") or {}) if group == "detector" else {})


def study_name(target: Target, settings: Mapping, fingerprint: str, seed: int, several: bool = False) -> str:
    """``experiment.study_name`` (``-<label>`` appended when several studies run), else
    ``<label>-<objective>-<hash>`` with a hash of everything that determines the scores."""
    if settings.get("study_name"):
        return f"{settings['study_name']}-{target.label}" if several else str(settings["study_name"])
    keys = ("objective", "selector", "min_keypoints", "iou_threshold", "sampler_seed")
    what = {**{k: settings.get(k) for k in keys}, "transforms": job_transforms(settings), "dataset": fingerprint,
            "seed": seed, "space": target.space, "defaults": target.defaults, "detector": target.detector,
            "detector_params": target.detector_params, "descriptor": target.descriptor}
    if settings["objective"] == "pose_success":
        what.update(ratio=settings.get("ratio"), pose=settings.get("pose"))
        if settings.get("mutual"):  # only when on, so that earlier studies keep their names
            what["mutual"] = True
    if settings.get("budget_per_mpx") is not None:  # likewise
        what["budget_per_mpx"] = settings["budget_per_mpx"]
    return f"{target.label}-{settings['objective']}-{config_hash(what)[:10]}"
