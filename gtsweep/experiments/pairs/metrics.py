"""The rows of the pair experiments, each extending the one before it: detection (survey 4.1), matching (4.2) and
pose (4.3). Their metrics are the evaluation's (:data:`gtsweep.evaluation.schema.EVALUATED`); a summary written
before cells recorded their kind is recognised by its methods and metrics."""
from __future__ import annotations

from typing import Mapping

from gtsweep.evaluation.schema import Rows

DETECTION_METRICS = ("repeatability", "ambiguity", "few_keypoints", "n_detected", "n_kp_test", "n_kp_ref",
                     "n_test_valid", "n_ref_valid", "n_repeated", "t_detect")
MATCHING_METRICS = DETECTION_METRICS + ("n_described_ref", "n_described_test", "n_matches", "n_correct", "precision",
                                        "precision_per_view", "t_describe", "t_match")
POSE_METRICS = MATCHING_METRICS + ("pose_success", "position_error", "orientation_error", "n_inliers", "t_pose")
POSE_HEADLINE = "pose_success"


def _described(summary: Mapping) -> bool:
    return bool((summary.get("methods") or {}).get("descriptor"))


def _posed(summary: Mapping) -> bool:
    return POSE_HEADLINE in (summary.get("metrics") or {})


DETECTION = Rows(DETECTION_METRICS, "repeatability", curves=("repeatability",),
                 recognizes=lambda summary: not _described(summary))
MATCHING = Rows(MATCHING_METRICS, "precision", curves=("precision",),
                recognizes=lambda summary: _described(summary) and not _posed(summary))
POSE = Rows(POSE_METRICS, POSE_HEADLINE, curves=(POSE_HEADLINE, "precision"),
            recognizes=lambda summary: _described(summary) and _posed(summary))
