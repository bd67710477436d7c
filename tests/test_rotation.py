"""report/rotation.py: pose success per 15-degree bin of the pair's rotation, from the cells' per-view rows."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from gtsweep.evaluation.transforms import rotation_matrix
from gtsweep.evaluation.views import rotation_deg
from gtsweep.report.rotation import PAIRS_ROW, bin_labels, plot_curves, rotation_table, write_rotation


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


def test_plot_data_counts_bands_and_coinciding_curves():
    # SIFT and ORB: the same outcome on every pair (one curve, both names); ALIKED: only the first pair.
    # Pairs per bin: 0-15: 2, 90-105: 2, 165-180: 1, every other bin none.
    rotation = [5.0, 10.0, 92.0, 104.9, 180.0]
    views = {"sift": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 1.0, 1.0, 0.0, 1.0]}),
             "orb": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 1.0, 1.0, 0.0, 1.0]}),
             "aliked": pd.DataFrame({"rotation": rotation, "pose_success": [1.0, 0.0, 0.0, 0.0, 0.0]})}
    table = rotation_table([summary("sift", "sift"), summary("orb", "orb"), summary("aliked", "aliked_n16")], views)
    curves, pairs = plot_curves(table)
    assert pairs.to_dict() == {**dict.fromkeys(bin_labels(), 0), "0-15": 2, "90-105": 2, "165-180": 1}
    shared = "2 cells, same outcome:\nSIFT + SIFT\nORB + ORB"
    assert list(dict.fromkeys(curves["curve"])) == [shared, "ALIKED-n16 + ALIKED-n16"]
    # Wilson 95 % (z = 1.959964): 2/2 -> [0.342380, 1]; 1/2 -> [0.094531, 0.905469]; 1/1 -> [0.206549, 1];
    # 0/2 -> [0, 0.657620]; 0/1 -> [0, 0.793451]. The two curves sit 2 degrees either side of the bin's centre.
    by_bin = curves.set_index(["curve", "bin"])
    expected = {(shared, "0-15"): (6.5, 1.0, 0.342380, 1.0), (shared, "90-105"): (96.5, 0.5, 0.094531, 0.905469),
                (shared, "165-180"): (171.5, 1.0, 0.206549, 1.0),
                ("ALIKED-n16 + ALIKED-n16", "0-15"): (8.5, 0.5, 0.094531, 0.905469),
                ("ALIKED-n16 + ALIKED-n16", "90-105"): (98.5, 0.0, 0.0, 0.657620),
                ("ALIKED-n16 + ALIKED-n16", "165-180"): (173.5, 0.0, 0.0, 0.793451)}
    for key, numbers in expected.items():
        assert np.allclose(by_bin.loc[key, ["x", "rate", "ci_low", "ci_high"]].to_numpy(float), numbers,
                           atol=5e-7), key
    empty = by_bin.loc[("ALIKED-n16 + ALIKED-n16", "30-45")]
    assert empty["x"] == 38.5 and np.isnan(empty[["rate", "ci_low", "ci_high"]].to_numpy(float)).all()
    entry = next(v for v in table.values if v["row"] == "ORB + ORB" and v["column"] == "90-105")
    assert entry["pairs"] == 2 and entry["ours"] == 0.5 and round(entry["ci_low"], 6) == 0.094531


def test_a_large_grid_draws_its_best_outcomes_and_names_a_few_cells_of_a_shared_one():
    # Ten detectors with distinct outcomes (k of 10 pairs found, k = 0..9) and five that share the outcome 9 of 10.
    rotation = np.linspace(1.0, 179.0, 10)
    views, summaries = {}, []
    for k in range(10):
        views[f"d{k}"] = pd.DataFrame({"rotation": rotation, "pose_success": (np.arange(10) < k).astype(float)})
        summaries.append(summary(f"d{k}", f"d{k}"))
    for k in range(5):
        views[f"s{k}"] = views["d9"]
        summaries.append(summary(f"s{k}", f"s{k}"))
    table = rotation_table(summaries, views)
    curves, _ = plot_curves(table, most=3)
    names = list(dict.fromkeys(curves["curve"]))
    assert len(names) == 3
    assert names[0].startswith("6 cells, same outcome:\n") and names[0].endswith("\nand 3 more")
    assert names[0].count("\n") == 4  # the header line, three cells, "and 3 more"
    assert names[0].split("\n")[1:4] == ["d9 + d9", "s0 + s0", "s1 + s1"]
    assert names[1:] == ["d8 + d8", "d7 + d7"]
