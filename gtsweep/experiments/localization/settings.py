"""The settings of ``experiment=localization`` (``experiment.*``) with their allowed values: typed in Hydra's
ConfigStore by the experiment registry, their ranges checked before any work."""
from __future__ import annotations

from gtsweep.core.ranges import Choice, Range
from gtsweep.stages.scales import FOREIGN_SCALES

SETTINGS = {
    "foreign_scale": Choice(FOREIGN_SCALES, optional=True),
    "voting": Choice((True, False)),
    "vote_cell": Range(0, None, low_open=True),
    "map_dedupe": Choice((True, False)),
    "min_inliers": Range(2, None, integer=True),
    "min_inlier_ratio": Range(0, 1),
    "max_position_error": Range(0, None, low_open=True),
    "max_orientation_error": Range(0, 180, low_open=True),
}
