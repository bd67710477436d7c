"""How methods are named in tables and plots: the survey's labels (``SIFT``, ``CenSurE``), and the survey's method
that one of ours stands in for."""
from __future__ import annotations

from gtsweep.evaluation.transforms import STRENGTH_AXIS  # noqa: F401 (the plots' axes; declared with the transforms)
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.match import MATCHERS
from gtsweep.stages.pose import ESTIMATORS

#: The strength of each synthetic transform, with its unit (survey section 3), for axes and table cells.
STRENGTH_UNIT = {"rotation": "deg", "translation": "IoU", "noise": "sigma, gray levels", "gamma": "gamma"}

#: Our learned feature is compared with the survey's learned one.
PAPER_NAME = {"xfeat": "LIFT"}


def label(name: str) -> str:
    spec = DETECTORS.get(name, None) or DESCRIPTORS.get(name, None) or MATCHERS.get(name, None) \
        or ESTIMATORS.get(name, None)
    return spec.label if spec else name


def variant_label(variant: tuple) -> str:
    """``matcher FLANN, estimator MAGSAC++`` for a :func:`~gtsweep.orchestration.results.by_variant` key."""
    return ", ".join(f"{column} {label(name)}" for column, name in variant if name)


def variant_slug(variant: tuple) -> str:
    """``flann_magsac``: a variant's part of a file name ("" for cells without a matcher and an estimator)."""
    return "_".join(str(name) for _, name in variant if name)


def strength_label(transform: str, strength: float) -> str:
    """``90 deg``, ``0.5 IoU``, ``gamma 2``: a strength with its unit."""
    unit = STRENGTH_UNIT.get(transform, "")
    if unit == "gamma":
        return f"gamma {strength:g}"
    return f"{strength:g} {unit}".strip()


def paper_label(name: str) -> str:
    return PAPER_NAME.get(name, label(name))


def shown_label(name: str) -> str:
    return f"{label(name)} (vs {PAPER_NAME[name]})" if name in PAPER_NAME else label(name)


