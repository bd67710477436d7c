"""A selector per detector (``selector_for``), as the survey used ANMS for MSER and NMS for every other detector
(section 4.1): the grid, results.csv, MLflow and the report name the selector each cell used."""
from __future__ import annotations

import mlflow
import pandas as pd
import pytest

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.experiments.pairs.grid import build_grid
from tests.sweep_helpers import compose_config, run_cli, tiny_overrides

PAIR_PRESETS = ("table4_incremental", "table5_absolute", "table6_pairings", "table7_reference_features")


@pytest.mark.parametrize("preset", PAIR_PRESETS)
def test_the_pairing_presets_select_mser_with_anms_and_the_rest_with_nms(preset):
    cfg = compose_config([f"sweeps={preset}", "detector=[tuned/mser,tuned/sift]", "descriptor=[sift,brief]",
                          "pairings=null"])
    grid = build_grid(cfg)
    used = {(c.detector, c.selector) for c in grid.cells}
    assert used == {("mser", "anms"), ("sift", "nms")}
    assert grid.selectors["anms"]["params"] == {"n": 1000, "tolerance": 0.2}  # ANMS's defaults, as conf/selector


def test_a_detector_named_but_not_in_the_grid_is_left_out_and_mistakes_are_one_line():
    cfg = compose_config(["detector=[orb]", "descriptor=[orb]", "selector_for={mser: anms}"])
    assert {c.selector for c in build_grid(cfg).cells} == {"nms"}
    with pytest.raises(UnknownMethod, match="unknown selector 'anmz'"):
        build_grid(compose_config(["detector=[mser]", "descriptor=[orb]", "selector_for={mser: anmz}"]))
    with pytest.raises(BadInput, match="selector_for must map a detector to one selector"):
        build_grid(compose_config(["detector=[mser]", "descriptor=[orb]", "selector_for={mser: [anms, nms]}"]))


def test_a_selector_in_the_group_stays_every_detectors():
    cfg = compose_config(["detector=[mser,orb]", "descriptor=[orb]", "selector=[nms,anms]",
                          "selector_for={mser: anms}"])
    used = {(c.detector, c.selector) for c in build_grid(cfg).cells}
    assert used == {("mser", "anms"), ("orb", "nms"), ("orb", "anms")}


@pytest.mark.slow
def test_results_mlflow_and_report_name_the_selector_each_cell_used(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    result = run_cli(tiny_overrides(tmp_path, "sweeps=table4_incremental", "dataset=synthetic",
                                    "detector=[mser,orb]", "descriptor=[brief]", "runner.backend=serial",
                                    "report.plots=false", f"mlflow.tracking_uri={uri}"), tmp_path)
    assert result.returncode == 0, result.stderr
    (run,) = (tmp_path / "outputs").glob("*/*")
    results = pd.read_csv(run / "results.csv")
    assert dict(zip(results["detector"], results["selector"])) == {"mser": "anms", "orb": "nms"}
    mlflow.set_tracking_uri(uri)
    children = mlflow.search_runs(experiment_names=["gtsweep"], filter_string="params.selector = 'anms'")
    assert list(children["params.detector"]) == ["mser"]
    assert "selector NMS, MSER: ANMS" in (run / "report" / "table4_incremental.md").read_text()
