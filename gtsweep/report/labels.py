"""How methods are named in tables and plots: the survey's labels (``SIFT``, ``CenSurE``), and the survey's method
that one of ours stands in for."""
from __future__ import annotations

from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import DETECTORS

#: Our learned feature is compared with the survey's learned one.
PAPER_NAME = {"xfeat": "LIFT"}


def label(name: str) -> str:
    spec = DETECTORS.get(name, None) or DESCRIPTORS.get(name, None)
    return spec.label if spec else name


def paper_label(name: str) -> str:
    return PAPER_NAME.get(name, label(name))


def shown_label(name: str) -> str:
    return f"{label(name)} (vs {PAPER_NAME[name]})" if name in PAPER_NAME else label(name)


