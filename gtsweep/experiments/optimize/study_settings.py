"""``cfg.experiment`` of ``experiment=optimize``, checked, and the transforms a trial evaluates; the pose objective's
matcher and estimator parameters come from the matcher and estimator groups, as in a sweep."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gtsweep.core.config import plain
from gtsweep.core.errors import BadInput
from gtsweep.core.paths import DEFAULT_CACHE_DIR
from gtsweep.core.ranges import Choice, ListOf, Range
from gtsweep.experiments.optimize.objective import OBJECTIVES

POSE_DATA = ("optimisation", "incremental")


#: The optimiser's settings with their allowed values (``experiment.*``), checked before any trial.
SETTINGS = {
    "objective": Choice(OBJECTIVES),
    "n_trials": Range(1, None, integer=True),
    "patience": Range(1, None, integer=True, optional=True),  # optimize/stopping.py
    "min_improvement": Range(0, None, optional=True),
    "parallel_trials": Range(1, None, integer=True),
    "min_keypoints": Range(1, None, integer=True),
    "budget_per_mpx": Range(0, None, low_open=True, optional=True),
    "sampler_seed": Range(0, None, integer=True),
    "n_startup_trials": Range(0, None, integer=True),
    "iou_threshold": Range(0, 1, low_open=True, high_open=True),
    "pose_data": Choice(POSE_DATA),
}


def read_settings(cfg: Mapping) -> dict:
    """``cfg.experiment`` checked, with the storage made absolute; a mistake raises a one-line BadInput."""
    from gtsweep.evaluation.transforms import TRANSFORMS
    from gtsweep.stages.select import SELECTORS

    s = plain(cfg["experiment"])
    for key, rule in SETTINGS.items():
        rule.check(f"experiment.{key}", s.get(key))
    selector = s.get("selector") or {}
    Choice(tuple(SELECTORS)).check("experiment.selector.name", selector.get("name"))
    transforms = s.get("transforms")
    if not isinstance(transforms, dict) or not transforms:
        raise BadInput("experiment.transforms must map synthetic transforms to {strengths: [...]}")
    for name, t in transforms.items():
        strengths = (t or {}).get("strengths")
        if name not in TRANSFORMS:
            raise BadInput(f"experiment.transforms.{name}: unknown transform; choices: {', '.join(TRANSFORMS)}")
        ListOf(TRANSFORMS.get(name).strength).check(f"experiment.transforms.{name}.strengths", strengths)
    s["storage"] = s.get("storage") or f"sqlite:///{(Path.cwd() / DEFAULT_CACHE_DIR / 'optuna.db').resolve()}"
    return {**s, **survey_method_settings(cfg, s.get("pose") or {})}


def survey_method_settings(cfg: Mapping, judging: Mapping) -> dict:
    """The pose objective's matcher and estimator, the survey's (``bf_ratio``, ``ransac``), with the parameters of
    the matcher and estimator groups (``matcher.bf_ratio.params.ratio=0.8``), as the sweep takes them: ``methods``
    (``{"matchers": {name: params}, "estimators": {name: params}}``, what a trial builds), ``pose`` (``judging``'s
    success thresholds), and for the study's name ``ratio``, ``mutual`` and the estimator's model, iterations and
    threshold in ``pose``."""
    from gtsweep.stages.match import MATCHERS, SURVEY_MATCHER
    from gtsweep.stages.pose import ESTIMATORS, SURVEY_ESTIMATOR

    def params(group: str, name: str, registry) -> dict:
        node = (plain(cfg.get(group)) or {}).get(name) or {}
        return registry.get(name).params(node.get("params"))

    matcher = params("matcher", SURVEY_MATCHER, MATCHERS)
    estimator = params("estimator", SURVEY_ESTIMATOR, ESTIMATORS)
    pose = {k: estimator[k] for k in ("model", "iterations", "threshold")}
    return {"ratio": matcher["ratio"], "mutual": matcher["mutual"], "pose": {**pose, **judging},
            "methods": {"matchers": {SURVEY_MATCHER: matcher}, "estimators": {SURVEY_ESTIMATOR: estimator}}}


def job_transforms(settings: Mapping) -> dict:
    """The transforms a trial evaluates, in the form :func:`gtsweep.evaluation.views.views` takes."""
    if settings["objective"] == "pose_success" and settings["pose_data"] == "incremental":
        return {"incremental": {"kind": "pairs"}}
    return {name: {"kind": "synthetic", "strengths": list(t["strengths"]), "params": dict(t.get("params") or {})}
            for name, t in settings["transforms"].items()}
