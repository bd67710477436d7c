"""The settings of the pair experiments (``experiment.*``) with their allowed values, each extending the one before
it; typed in Hydra's ConfigStore by the experiment registry, their ranges checked before any work."""
from __future__ import annotations

from gtsweep.core.ranges import Choice, ListOf, Range
from gtsweep.stages.scales import FOREIGN_SCALES

_COUNT = Range(1, None, integer=True)
_POSITIVE = Range(0, None, low_open=True)

DETECTION = {
    "iou_threshold": Range(0, 1, low_open=True, high_open=True),
    "min_keypoints": _COUNT,
    "budget_per_mpx": Range(0, None, low_open=True, optional=True),
}
MATCHING = {**DETECTION, "foreign_scale": Choice(FOREIGN_SCALES, optional=True)}
POSE = {
    **MATCHING,
    "pose.max_position_error": _POSITIVE,
    "pose.max_orientation_error": Range(0, 180, low_open=True),
    "reference_counts": ListOf(_COUNT, optional=True),
    "test_count": Range(1, None, integer=True, optional=True),
}
