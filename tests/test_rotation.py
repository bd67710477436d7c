"""report/rotation.py: pose success per 15-degree bin of the pair's rotation, from the cells' per-view rows."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from gtsweep.evaluation.transforms import rotation_matrix
from gtsweep.evaluation.views import rotation_deg
from gtsweep.report.rotation import PAIRS_ROW, bin_labels, rotation_table, write_rotation


def summary(key, detector, matcher="bf_ratio", transform="absolute", experiment="pose"):
    return {"key": key, "experiment": experiment, "status": "ok",
            "methods": {"detector": detector, "descriptor": detector, "selector": "nms", "transform": transform,
                        "matcher": matcher, "estimator": "ransac"}}


def test_rotation_of_a_homography_is_its_angle_magnitude():
    for angle in (0.0, 14.0, 90.0, 179.0, -120.0):
        H = rotation_matrix(angle, (964, 1288)) * 2.0  # scaled: the angle does not depend on it
        assert math.isclose(rotation_deg(H), abs(angle), abs_tol=1e-9)


def test_table_bins_pose_success_by_rotation(tmp_path):
    # SIFT succeeds on 3 of 4 pairs; ALIKED only on the pair near 0 degrees. Expected means per bin, by hand:
    # 0-15: SIFT 1, ALIKED 1; 90-105: SIFT (1 + 0) / 2, ALIKED 0; 165-180 (180 itself included): SIFT 1, ALIKED 0.
    rotation = [5.0, 92.0, 104.9, 180.0]
    views = {"sift": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 1.0, 0.0, 1.0]}),
             "aliked": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 0.0, 0.0, 0.0]}),
             "incr": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 1.0, 1.0, 1.0]})}
    summaries = [summary("sift", "sift"), summary("aliked", "aliked_n16rot", matcher="lightglue"),
                 summary("incr", "sift", transform="incremental")]
    table = rotation_table(summaries, views)
    assert list(table.cells.columns) == bin_labels() and len(bin_labels()) == 12
    assert list(table.cells.index) == ["SIFT + SIFT", "ALIKED-n16rot + ALIKED-n16rot, LightGlue", PAIRS_ROW]
    row = table.cells.loc["SIFT + SIFT"]
    assert (row["0-15"], row["90-105"], row["165-180"], row["15-30"]) == ("1.00", "0.50", "1.00", "")
    aliked = table.cells.loc["ALIKED-n16rot + ALIKED-n16rot, LightGlue"]
    assert (aliked["0-15"], aliked["90-105"], aliked["165-180"]) == ("1.00", "0.00", "0.00")
    assert table.cells.loc[PAIRS_ROW, "90-105"] == "2" and table.cells.loc[PAIRS_ROW, "30-45"] == "0"
    files = write_rotation(summaries, views, tmp_path)
    assert {p.name for p in files} >= {"rotation_absolute.md", "rotation_absolute.png", "rotation_absolute.csv"}


def test_no_table_without_absolute_pose_cells(tmp_path):
    views = {"incr": pd.DataFrame({"rotation": [3.0], "pose_success": [1.0]}),
             "match": pd.DataFrame({"rotation": [120.0], "precision": [0.5]})}
    summaries = [summary("incr", "sift", transform="incremental"),
                 summary("match", "sift", experiment="matching")]
    assert rotation_table(summaries, views) is None
    assert write_rotation(summaries, views, tmp_path) == [] and not any(tmp_path.iterdir())
    assert np.isnan(rotation_deg(np.full((3, 3), np.nan)))
