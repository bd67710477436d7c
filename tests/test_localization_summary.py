"""A localization cell's headline counts each query once, at its floor's largest map (issue 19), and
``python -m gtsweep.report <parent> --mlflow`` rebuilds a localization run's report from its MLflow child runs."""
from __future__ import annotations

import math

import pandas as pd
import pytest

from gtsweep.orchestration.results import summarize

NAN = math.nan


def _rows() -> pd.DataFrame:
    """Floor a: queries q1, q2 in the map and f3 from a foreign floor, against maps of 1 and 4 images; floor b (a
    smaller real map): q4 against its only map of 2 images. q1 and q2 fail on the 1-image map and succeed on the
    4-image map; f3 is rejected by the 1-image map and (wrongly) accepted by the 4-image map; q4 fails."""
    rows = [  # query, texture, in_map, map_images, localized, success, t_query
        ("q1", "a", 1, 1, 0, 0, 0.1), ("q2", "a", 1, 1, 0, 0, 0.1), ("f3", "a", 0, 1, 0, NAN, 0.1),
        ("q1", "a", 1, 4, 1, 1, 0.3), ("q2", "a", 1, 4, 1, 1, 0.3), ("f3", "a", 0, 4, 1, NAN, 0.3),
        ("q4", "b", 1, 2, 0, 0, 0.2),
    ]
    frame = pd.DataFrame(rows, columns=["query", "texture", "in_map", "map_images", "localized",
                                        "localization_success", "t_query"])
    return frame.assign(false_localization=frame["localized"].where(frame["in_map"] == 0))


def test_headline_is_the_largest_map_of_each_floor_each_query_once():
    summary = summarize(_rows(), "localization")
    m = summary["metrics"]
    # headline rows: a at 4 images (q1 1, q2 1, f3 accepted) and b at 2 images (q4 0): success 2/3, not the
    # pooled 2/5 of all rows; false localization 1/1, not 1/2; time per query (0.3 + 0.3 + 0.3 + 0.2) / 4
    assert m["localization_success"] == pytest.approx(2 / 3)
    assert m["false_localization"] == 1.0
    assert m["localized"] == pytest.approx(3 / 4)
    assert m["t_query"] == pytest.approx(0.275)
    # Wilson 95 % of 2 of 3 by hand: centre (2/3 + z^2/6) / (1 + z^2/3) = 0.5731, half-width
    # z sqrt(2/27 + z^2/36) / (1 + z^2/3) = 0.3654 (z = 1.96): [0.2077, 0.9385]
    assert m["localization_success_ci_low"] == pytest.approx(0.2077, abs=2e-4)
    assert m["localization_success_ci_high"] == pytest.approx(0.9385, abs=2e-4)
    assert summary["n_views"] == 4 and summary["n_rows"] == 7
    # each map size keeps its own values (all rows of that size)
    by_size = summary["by_map_images"]
    assert by_size["1.0"]["localization_success"] == 0.0 and by_size["1.0"]["false_localization"] == 0.0
    assert by_size["4.0"]["localization_success"] == 1.0 and by_size["4.0"]["false_localization"] == 1.0
    assert by_size["2.0"]["localization_success"] == 0.0


def test_other_experiments_still_aggregate_every_row():
    rows = pd.DataFrame({"view": ["a", "b", "c"], "pose_success": [1.0, 0.0, 0.0], "strength": [0.0, 90.0, 90.0]})
    assert summarize(rows, "pose")["metrics"]["pose_success"] == pytest.approx(1 / 3)


@pytest.mark.slow
def test_report_of_a_localization_run_rebuilt_from_mlflow(tmp_path, monkeypatch, capsys):
    """Child runs logged as a localization run logs them; ``--mlflow`` writes the localization tables."""
    from gtsweep.experiments.localization.cells import LocCell, LocGrid
    from gtsweep.experiments.report_command import main
    from gtsweep.tracking.sweep import SweepTracker

    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cells = [LocCell("sift", "nms", "sift", "flann", "ransac"), LocCell("akaze", "nms", "sift", "flann", "ransac",
                                                                        "the SIFT descriptor needs ...")]
    grid = LocGrid({"name": "localization"}, {"sift": {"params": {}}, "akaze": {"params": {}}}, {"nms": {"params": {}}},
                   {"sift": {"params": {}}}, {"flann": {"params": {}}}, {"ransac": {"params": {}}}, cells)
    config = "dataset:\n  loader: synthetic\n  px_per_mm: 12.5\nexperiment:\n  max_position_error: 30.0\n"
    tracker = SweepTracker({"tracking_uri": uri}, tmp_path / "run", config, "loc")
    tracker.start(grid, "fp", {})
    rows = _rows()
    ok = {"key": cells[0].key, "hash": "h", "status": "ok", "experiment": "localization",
          "methods": cells[0].methods, **summarize(rows.assign(map_bytes=rows["map_images"] * 1e6), "localization")}
    tracker.log_cell(cells[0], ok)
    tracker.log_cell(cells[1], {"key": cells[1].key, "hash": "h", "status": "na", "experiment": "localization",
                                "methods": cells[1].methods, "reason": "not applicable"})
    from gtsweep.tracking.readback import summaries_from_mlflow

    rebuilt = {s["key"]: s for s in summaries_from_mlflow(tracker.parent_id, uri)}
    assert rebuilt[cells[0].key]["n_views"] == 4 and "n_views" not in rebuilt[cells[1].key]
    assert rebuilt[cells[0].key]["metrics"]["localization_success"] == pytest.approx(2 / 3)
    assert main([tracker.parent_id, "--mlflow", "--tracking-uri", uri, "--out", str(tmp_path / "rep"),
                 "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert "| sift/sift | flann | ransac | 67 % [21 %, 94 %] | 100 % |" in printed
    assert "| akaze/sift | flann | ransac | NA |" in printed
    assert "| sift / sift / flann / ransac | 0 %, 100 ms | 0 %, 200 ms | 100 %, 300 ms |" in printed
    assert "| 4.00 |" in printed  # MB of the largest map
    assert "success radius 30 px = 2.4 mm" in printed and "12.5 px/mm, the data set's" in printed
    assert (tmp_path / "rep" / "localization_cells.md").exists()
    assert not (tmp_path / "rep" / "table4_incremental.md").exists()
