"""``cfg.experiment`` of ``experiment=optimize``, checked, and the transforms a trial evaluates."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

from gtsweep.core.config import plain
from gtsweep.core.errors import BadInput
from gtsweep.core.paths import DEFAULT_CACHE_DIR
from gtsweep.optimize.objective import OBJECTIVES

POSE_DATA = ("optimisation", "incremental")


def _int(settings: Mapping, key: str, low: int) -> int:
    value = settings.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise BadInput(f"experiment.{key} must be an integer >= {low}, got {value!r}")
    return value


def read_settings(cfg: Mapping) -> dict:
    """``cfg.experiment`` checked, with the storage made absolute; a mistake raises a one-line BadInput."""
    from gtsweep.evaluation.transforms import TRANSFORMS
    from gtsweep.stages.select import SELECTORS

    s = plain(cfg["experiment"])
    if s.get("objective") not in OBJECTIVES:
        raise BadInput(f"experiment.objective must be one of {', '.join(OBJECTIVES)}, got {s.get('objective')!r}")
    for key, low in (("n_trials", 1), ("parallel_trials", 1), ("min_keypoints", 1), ("sampler_seed", 0),
                     ("n_startup_trials", 0)):
        _int(s, key, low)
    iou = s.get("iou_threshold")
    if isinstance(iou, bool) or not isinstance(iou, (int, float)) or not 0 < iou < 1:
        raise BadInput(f"experiment.iou_threshold must be a number in (0, 1), got {iou!r}")
    selector = s.get("selector") or {}
    if selector.get("name") not in SELECTORS:
        raise BadInput(f"experiment.selector.name must be one of {', '.join(SELECTORS)}, got {selector.get('name')!r}")
    transforms = s.get("transforms")
    if not isinstance(transforms, dict) or not transforms:
        raise BadInput("experiment.transforms must map synthetic transforms to {strengths: [...]}")
    for name, t in transforms.items():
        strengths = (t or {}).get("strengths")
        if name not in TRANSFORMS:
            raise BadInput(f"experiment.transforms.{name}: unknown transform; choices: {', '.join(TRANSFORMS)}")
        if not isinstance(strengths, list) or not strengths or \
                not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in strengths):
            raise BadInput(f"experiment.transforms.{name}.strengths must be a non-empty list of numbers")
    if s.get("pose_data") not in POSE_DATA:
        raise BadInput(f"experiment.pose_data must be one of {', '.join(POSE_DATA)}, got {s.get('pose_data')!r}")
    s["storage"] = s.get("storage") or f"sqlite:///{(Path.cwd() / DEFAULT_CACHE_DIR / 'optuna.db').resolve()}"
    return s


def job_transforms(settings: Mapping) -> dict:
    """The transforms a trial evaluates, in the form :func:`gtsweep.evaluation.views.views` takes."""
    if settings["objective"] == "pose_success" and settings["pose_data"] == "incremental":
        return {"incremental": {"kind": "pairs"}}
    return {name: {"kind": "synthetic", "strengths": list(t["strengths"]), "params": dict(t.get("params") or {})}
            for name, t in settings["transforms"].items()}
