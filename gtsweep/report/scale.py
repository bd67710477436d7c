"""The survey's thresholds in millimetres as well as pixels, for the report (issue 17, item 5).

The survey (section 5) counts keypoints per image (the budget N = 1000, the "< N KPs" threshold of 100 on Micro-GPS'
1288 x 964 views) and judges a pose within 30 px and 1.5 deg (Zhang et al.'s rule on Micro-GPS, where 30 px =
4.8 mm: 6.25 px/mm). A reader of a run at another view size or scale needs the physical meaning of these
numbers: this module reads them from the run's resolved configuration (``<run>/.hydra/config.yaml`` or the parent
MLflow run's ``config.yaml``) and writes the line printed under the tables and in the terminal footer. The scale is
the data set's ``dataset.px_per_mm`` (Micro-GPS' loader: its camera's); where the run does not give one (one's own
data without the key), the line gives pixels only and names the key.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from gtsweep.datasets.floors import MICROGPS_PX_PER_MM  # Zhang et al.: 30 px = 4.8 mm
from gtsweep.evaluation import budget

MICROGPS_VIEW = (1288, 964)
SURVEY_BUDGET, SURVEY_MIN_KEYPOINTS, SURVEY_RADIUS_PX = 1000, 100, 30.0
DETECTION_TABLES = ("table2", "table3")
POSE_TABLES = ("table4", "table5", "table6", "table7")


@dataclass
class Scale:
    """The run's scale and thresholds; ``known``: px/mm is the data set's (else the line gives pixels only)."""

    px_per_mm: float = MICROGPS_PX_PER_MM
    known: bool = False
    view_size: tuple[int, int] | None = None
    budgets: list[int] = field(default_factory=lambda: [SURVEY_BUDGET])
    min_keypoints: int = SURVEY_MIN_KEYPOINTS
    radius_px: float = SURVEY_RADIUS_PX

    def mm(self, px: float) -> float:
        return px / self.px_per_mm

    def _source(self) -> str:
        return f"{self.px_per_mm:g} px/mm, the data set's" if self.known else \
            "pixels only: the data set gives no dataset.px_per_mm"

    def _per_view(self) -> str:
        if self.view_size is None:
            return "per view"
        w, h = self.view_size
        return f"per {w}×{h} px view" + (f" = {self.mm(w):.0f}×{self.mm(h):.0f} mm" if self.known else "")

    def detection(self) -> str:
        n = "/".join(str(b) for b in self.budgets) if self.budgets else "all keypoints (no selection)"
        return f"keypoint budget N = {n} and < N KPs threshold {self.min_keypoints} keypoints {self._per_view()}"

    def pose(self) -> str:
        mm = f" = {self.mm(self.radius_px):.1f} mm" if self.known else ""
        return f"success radius {self.radius_px:g} px{mm}"

    def line(self, detection: bool = True, pose: bool = True) -> str:
        """E.g. ``Scale (6.25 px/mm, the data set's): success radius 30 px = 4.8 mm; keypoint budget N = 1000 and
        < N KPs threshold 100 keypoints per 1288×964 px view = 206×154 mm.``"""
        parts = ([self.pose()] if pose else []) + ([self.detection()] if detection else [])
        return f"Scale ({self._source()}): {'; '.join(parts)}."


def scale_from_config(cfg: Mapping | None) -> Scale:
    """The scale of a resolved run configuration (plain dicts): the data set's ``px_per_mm`` and ``view_size``
    (Micro-GPS' loader: its camera's), the selectors' ``n``, ``experiment.min_keypoints`` and the pose radius."""
    if not cfg:
        return Scale()
    dataset, experiment = cfg.get("dataset") or {}, cfg.get("experiment") or {}
    ppm, view = dataset.get("px_per_mm"), dataset.get("view_size")
    if dataset.get("loader") == "microgps":
        ppm, view = ppm or MICROGPS_PX_PER_MM, view or MICROGPS_VIEW
    known = ppm is not None and math.isfinite(float(ppm)) and float(ppm) > 0
    view = tuple(int(v) for v in view) if view else None
    min_keypoints = int(experiment.get("min_keypoints") or SURVEY_MIN_KEYPOINTS)
    selectors = [node.get("params") or {} for node in (cfg.get("selector") or {}).values()
                 if isinstance(node, Mapping) and (node.get("params") or {}).get("n") is not None]
    if view is not None:  # experiment.budget_per_mpx (off by default) scales n and < N KPs with the view's area
        scaled = [budget.scaled(p, min_keypoints, experiment, (view[1], view[0])) for p in selectors]
        selectors, min_keypoints = [p for p, _ in scaled], (scaled[0][1] if scaled else min_keypoints)
    budgets = sorted({int(p["n"]) for p in selectors}) if "selector" in cfg else [SURVEY_BUDGET]
    radius = _setting(experiment, "max_position_error")
    return Scale(float(ppm) if known else MICROGPS_PX_PER_MM, known, view, budgets, min_keypoints,
                 float(radius or SURVEY_RADIUS_PX))


def _setting(experiment: Mapping, key: str):
    """An experiment setting wherever its kind keeps it: at the top or in one of its sections (a pair experiment's
    success thresholds are ``experiment.pose.*``, localization's at the top)."""
    sections = [experiment, *(v for v in experiment.values() if isinstance(v, Mapping))]
    return next((section[key] for section in sections if section.get(key) is not None), None)


def load_scale(source: str | Path) -> Scale:
    """The scale of a run's output directory, from Hydra's ``.hydra/config.yaml`` (else assumed)."""
    import yaml

    path = Path(source) / ".hydra" / "config.yaml"
    try:
        return scale_from_config(yaml.safe_load(path.read_text()))
    except (OSError, yaml.YAMLError, AttributeError, TypeError, ValueError):
        return Scale()


def annotate(tables, scale: Scale) -> None:
    """Put the scale line under each detection table (budget, < N KPs) and pose table (radius, budget)."""
    for table in tables:
        if table.name.startswith(DETECTION_TABLES):
            table.note = scale.line(pose=False)
        elif table.name.startswith(POSE_TABLES):
            table.note = scale.line()
