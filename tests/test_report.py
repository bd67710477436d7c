"""Survey tables rebuilt from small sweeps: layout (rows, columns, NA cells) and the paper's numbers beside ours."""
from __future__ import annotations

import pytest
from sweep_helpers import compose_config, tiny_overrides

from gtsweep.orchestration.sweep import run_sweep
from gtsweep.report.output import main, write_report
from gtsweep.report.tables import build_tables, fmt

SERIAL = ["runner.backend=serial", "mlflow.enabled=false"]


@pytest.fixture(scope="module")
def summaries(tmp_path_factory):
    """Cells of three small sweeps: detection with selectors, pose on pairs, pose on synthetic + Table 7."""
    tmp = tmp_path_factory.mktemp("report")
    runs = [
        ["experiment=detection", "detector=[censure,sift]", "selector=[none,nms,anms]", "transform=[rotation]",
         "transform.rotation.strengths=[0,90]"],
        ["detector=[akaze,censure]", "descriptor=[akaze,brief,daisy]", "selector=[nms]",
         "transform=[incremental,absolute]"],
        ["sweeps=table7_reference_features", "detector=[censure]", "descriptor=[brief]", "pairings=[[censure,brief]]",
         "experiment.reference_counts=[10,100]"],
        ["detector=[akaze]", "descriptor=[brief]", "selector=[nms]", "transform=[gamma]",
         "transform.gamma.strengths=[0.5,2.0]"],
    ]
    out = []
    for i, grid in enumerate(runs):
        out += run_sweep(compose_config(tiny_overrides(tmp, *SERIAL, *grid)), tmp / f"run{i}").summaries
    return out


def _tables(summaries):
    return {t.name: t for t in build_tables(summaries)}


def test_every_table_is_built(summaries):
    assert set(_tables(summaries)) == {"table2_selectors", "table3_detectors", "table4_incremental",
                                       "table5_absolute", "table6_pairings", "table7_reference_features"}


def test_pose_tables_have_paper_layout_and_na_cells(summaries):
    table = _tables(summaries)["table4_incremental"].cells
    assert list(table.index) == ["CenSurE", "AKAZE"]  # the paper's row order
    assert list(table.columns) == ["BRIEF", "AKAZE", "DAISY"]
    assert table.loc["CenSurE", "AKAZE"] == "NA" and table.loc["CenSurE", "DAISY"] == "NA"
    assert table.loc["AKAZE", "AKAZE"].endswith("(0.84)")  # the paper's number beside ours
    assert _tables(summaries)["table5_absolute"].cells.loc["AKAZE", "BRIEF"].endswith("(0.99)")


def test_selector_and_detector_tables(summaries):
    tables = _tables(summaries)
    selectors = tables["table2_selectors"].cells
    assert list(selectors.index) == ["SIFT", "CenSurE"]
    assert list(selectors.columns) == ["#KPs before selection", "Rep. none", "Rep. nms", "Rep. anms",
                                       "Rep. bucketing"]
    assert selectors.loc["SIFT", "Rep. bucketing"] == "NA (0.77)"  # not run here; the paper's value still shown
    detectors = tables["table3_detectors"].cells
    assert set(detectors.index) == {"SIFT", "CenSurE"} and set(detectors["selector"]) <= {"NMS", "ANMS"}


def test_pairings_and_reference_count_tables(summaries):
    tables = _tables(summaries)
    assert list(tables["table6_pairings"].cells.columns) == ["descriptor", "pose success", "#correct matches",
                                                             "precision"]
    table7 = tables["table7_reference_features"].cells
    assert list(table7.columns) == ["descriptor", "10", "100"]
    assert table7.loc["CenSurE", "10"].endswith("(0.00)") and table7.loc["CenSurE", "100"].endswith("(0.73)")


def test_report_files_and_command(summaries, tmp_path, capsys):
    tables, files = write_report(summaries, tmp_path / "report")
    names = {f.name for f in files}
    assert {"table4_incremental.md", "table4_incremental.tex", "table4_incremental.csv"} <= names
    assert {"success_heatmap_incremental.png", "success_vs_reference_features.png",
            "pose_success_vs_gamma.png"} <= names
    assert main([str(tmp_path / "missing")]) == 2
    assert "no cell results" in capsys.readouterr().err


def test_fmt():
    assert fmt(0.931, 0.9) == "0.93 (0.90)" and fmt(float("nan"), "NA") == "NA" and fmt(551.2, 551, 0) == "551 (551)"
    assert fmt(0.5) == "0.50" and fmt(None, 0.3) == "NA (0.30)"
