"""Survey tables rebuilt from small sweeps: layout (rows, columns, NA cells) and the paper's numbers beside ours."""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from gtsweep.experiments.kinds import run_sweep
from gtsweep.experiments.report_command import main
from gtsweep.report.output import write_report
from gtsweep.report.tables import build_tables, fmt
from sweep_helpers import compose_config, tiny_overrides

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
    assert list(selectors.columns) == ["#KPs before selection (keypoints per view)", "Rep. none (share)",
                                       "Rep. nms (share)", "Rep. anms (share)", "Rep. bucketing (share)"]
    assert selectors.loc["SIFT", "Rep. bucketing (share)"] == "NA (0.77)"  # not run; the paper's value still shown
    detectors = tables["table3_detectors"].cells
    # each detector with the survey's selector (NMS; ANMS only for MSER), whichever scored higher here
    assert set(detectors.index) == {"SIFT", "CenSurE"} and list(detectors["selector"]) == ["NMS", "NMS"]
    assert list(detectors.columns) == ["selector", "< 100 KPs (share of views)", "repeatability (share)",
                                       "ambiguity (matches)", "time (s)"]


def test_pairings_and_reference_count_tables(summaries):
    tables = _tables(summaries)
    assert list(tables["table6_pairings"].cells.columns) == ["descriptor", "pose success (share)",
                                                             "#correct matches (per view)", "precision (share)"]
    assert "pose success (share of pairs)" in tables["table4_incremental"].title
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


def test_fmt_with_interval():
    # ours [low, high] (paper): the ends as they are, not a half-width
    assert fmt(0.85, 0.93, 2, 0.80, 0.90) == "0.85 [0.80, 0.90] (0.93)"
    assert fmt(287.0, 534, 0, 155.0, 419.0) == "287 [155, 419] (534)"
    assert fmt(float("nan"), 0.9, 2, 0.1, 0.2) == "NA (0.90)"
    # a Wilson interval of 10/10 is [0.72, 1.00]: "1.00 ±0.14" would read as values up to 1.14
    assert fmt(1.0, None, 2, 0.7225, 1.0) == "1.00 [0.72, 1.00]"


def _fake_run(directory):
    """Two textures x 10 pairs of incremental pairs, and rotation at two strengths on 2 x 4 images."""
    from report_fakes import fake_cell

    fake_cell(directory, "sift", "sift", "incremental", [1] * 10 + [1] * 5 + [0] * 5, textures=("carpet", "gravel"))
    fake_cell(directory, "akaze", "brief", "incremental", [1] * 20, textures=("carpet", "gravel"))
    fake_cell(directory, "sift", "sift", "rotation", [1, 1] * 4 + [1, 0] * 4, strengths=(0, 90),
              textures=("carpet", "gravel"))
    fake_cell(directory, "akaze", "brief", "rotation", [1, 0] * 8, strengths=(0, 90), textures=("carpet", "gravel"))
    return directory


def test_report_by_texture_with_intervals_values_and_ties(tmp_path, capsys):
    run = _fake_run(tmp_path / "run")
    assert main([str(run), "--by", "texture", "--no-plots"]) == 0
    shown = capsys.readouterr().out
    # SIFT-SIFT 15/20 (Wilson [0.531, 0.888]), AKAZE-BRIEF 20/20 ([0.839, 1]); 5 discordant pairs: McNemar p =
    # 2/32 = 0.0625 >= 0.05, so SIFT-SIFT is tied with the best
    assert "| SIFT |  | 0.75 [0.53, 0.89] (0.84) |" in shown and "| AKAZE | 1.00 [0.84, 1.00] (0.85) |  |" in shown
    assert "best pose_success: AKAZE-BRIEF 1.00; 1 tied with it (SIFT-SIFT)" in shown
    values = pd.read_csv(run / "report" / "table4_incremental_values.csv")
    sift = values[(values["row"] == "SIFT") & (values["column"] == "SIFT")].iloc[0]
    assert sift["ours"] == 0.75 and sift["ci_low"] == pytest.approx(0.531, abs=1e-3) and sift["paper"] == 0.84
    # per texture: carpet has SIFT-SIFT 10/10 (Wilson [0.722, 1]), gravel 5/10 ([0.237, 0.763])
    carpet = (run / "report" / "by_texture" / "carpet" / "table4_incremental.md").read_text()
    gravel = (run / "report" / "by_texture" / "gravel" / "table4_incremental.md").read_text()
    assert "texture carpet" in carpet and "| SIFT |  | 1.00 [0.72, 1.00] (0.84) |" in carpet
    assert "| SIFT |  | 0.50 [0.24, 0.76] (0.84) |" in gravel
    # per transform and strength: AKAZE-BRIEF 8/8 at 0, 0/8 at 90 on rotation (Wilson 8/8: [0.676, 1], 0/8:
    # [0, 0.324])
    strengths = (run / "report" / "synthetic_by_strength.md").read_text()
    assert "| pairing | transform | strength | pose_success (share) |" in strengths
    assert "| AKAZE-BRIEF [nms] | rotation | 0 deg | 1.00 [0.68, 1.00] |" in strengths
    assert "| AKAZE-BRIEF [nms] | rotation | 90 deg | 0.00 [0.00, 0.32] |" in strengths
    # Table 6 with one transform, 8 images x 2 strengths: the interval is over the 8 images, not the 16 views
    # (results.csv's Wilson 8/16 [0.280, 0.720] treats them as independent): every image alike (1 at strength 0,
    # 0 at 90), so the design effect takes its bound, 8 trials, with t(7) = 2.365: Wilson [0.179, 0.821]
    table6 = pd.read_csv(run / "report" / "table6_pairings_values.csv")
    akaze = table6[(table6["row"] == "AKAZE") & (table6["metric"] == "pose_success")].iloc[0]
    assert akaze["ours"] == 0.5 and akaze["ci_low"] == pytest.approx(0.179, abs=1e-3)
    assert (run / "report" / "by_texture" / "gravel" / "synthetic_by_strength.md").exists()


def test_report_by_texture_is_a_checked_option(tmp_path, capsys):
    from gtsweep.core.errors import GtsweepError
    from gtsweep.orchestration.settings import check_settings

    with pytest.raises(GtsweepError, match="report.by"):
        check_settings({"report": {"by": "image", "alpha": 0.05, "plots": True}})
    with pytest.raises(GtsweepError, match="report.alpha"):
        check_settings({"report": {"by": None, "alpha": 1.5, "plots": True}})
    with pytest.raises(SystemExit):
        main([str(tmp_path), "--alpha", "0"])
    assert "--alpha must be in (0, 1)" in capsys.readouterr().err


@pytest.mark.slow
def test_same_seed_same_intervals_on_serial_and_ray_and_from_mlflow(tmp_path, monkeypatch, capsys):
    """Same seed, bit-identical intervals: serial and Ray (1 CPU) results.csv and report values; the report rebuilt
    from the MLflow child runs (their <m>_ci_* metrics and per-view artifacts) shows the same intervals."""
    from gtsweep.cli.app import library_versions
    from gtsweep.tracking.sweep import SweepTracker

    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    grid = ["detector=[censure]", "descriptor=[brief]", "selector=[nms]", "transform=[incremental,rotation]",
            "transform.rotation.strengths=[0,90]", "mlflow.enabled=false"]
    serial = compose_config(tiny_overrides(tmp_path, "runner.backend=serial", *grid, f"mlflow.tracking_uri={uri}"))
    tracker = SweepTracker(serial.mlflow, tmp_path / "serial", "config: yes", "serial")
    outcome = run_sweep(serial, tmp_path / "serial", hooks=(tracker.log_cell,),
                        on_start=lambda g, fp: tracker.start(g, fp, library_versions()))
    tracker.end(outcome)
    run_sweep(compose_config(tiny_overrides(tmp_path, "runner.backend=ray", "runner.num_cpus=1", *grid)),
              tmp_path / "ray")
    results = {name: pd.read_csv(tmp_path / name / "results.csv") for name in ("serial", "ray")}
    ci = [c for c in results["serial"].columns if "_ci_" in c]
    assert ci and results["serial"][ci].equals(results["ray"][ci])
    for name in ("serial", "ray"):
        assert main([str(tmp_path / name), "--no-plots"]) == 0
    for table in ("table4_incremental_values.csv", "table6_pairings_values.csv"):
        pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "serial" / "report" / table),
                                      pd.read_csv(tmp_path / "ray" / "report" / table), check_exact=True)
    capsys.readouterr()
    assert main([tracker.parent_id, "--mlflow", "--tracking-uri", uri, "--out", str(tmp_path / "from_mlflow"),
                 "--no-plots"]) == 0
    printed = capsys.readouterr()
    assert re.search(r"\d\.\d\d \[\d\.\d\d, \d\.\d\d\]", printed.out)  # ours [low, high]
    assert "Downloading artifacts" not in printed.err  # no progress bar per downloaded file
    for table in ("table4_incremental_values.csv", "table6_pairings_values.csv"):
        ours = pd.read_csv(tmp_path / "from_mlflow" / table)
        theirs = pd.read_csv(tmp_path / "serial" / "report" / table)
        assert np.allclose(ours[["ours", "ci_low", "ci_high"]], theirs[["ours", "ci_low", "ci_high"]], equal_nan=True)


def test_multirun_report_takes_intervals_from_every_repeats_views(tmp_path):
    """Two repeats (seeds) of a sweep: each repeat is a stratum, images are matched across; Table 6 averages two
    transforms, and its interval comes from resampling images, not from averaging the cells' intervals."""
    import json

    from gtsweep.experiments.kinds import combine_multirun as combine
    from report_fakes import fake_cell

    for job, sift in (("0", [1] * 15 + [0] * 5), ("1", [1] * 10 + [0] * 10)):
        directory = tmp_path / job
        directory.mkdir()
        (directory / "sweep.json").write_text(json.dumps({"overrides": [f"seed={job}"]}))
        fake_cell(directory, "sift", "sift", "incremental", sift)
        fake_cell(directory, "akaze", "brief", "incremental", [1] * 20)
        fake_cell(directory, "sift", "sift", "rotation", [1, 1] * 4 + [1, 0] * 4, strengths=(0, 90))
        fake_cell(directory, "sift", "sift", "noise", [1, 0] * 8, strengths=(0, 90))
    combine(tmp_path, plots=False)
    report = tmp_path / "combined" / "report"
    table4 = (report / "table4_incremental.md").read_text()
    # SIFT-SIFT: (15 + 10) / 40 = 0.62; AKAZE-BRIEF 40/40 over 20 pairs x 2 repeats: every pair alike, so the
    # design effect takes its bound, one trial per pair, with t(19) = 2.093 (20/20: [0.82, 1.00]); the 5 + 10
    # discordant pairs are all AKAZE's: not tied
    assert "| AKAZE | 1.00 [0.82, 1.00] (0.85) |  |" in table4 and "| SIFT |  | 0.62 [" in table4
    assert "none tied with it" in table4
    values = pd.read_csv(report / "table6_pairings_values.csv")
    success = values[values["metric"] == "pose_success"].iloc[0]
    # rotation 12/16 = 0.75, noise 8/16 = 0.5: the mean over transforms 0.625; averaging the cells' Wilson
    # intervals would give [0.393, 0.809]
    assert success["ours"] == pytest.approx(0.625)
    assert success["ci_low"] < 0.625 < success["ci_high"] and success["ci_low"] != pytest.approx(0.393, abs=0.01)


@pytest.mark.slow
def test_plots_per_texture_with_interval_bands(tmp_path):
    run = _fake_run(tmp_path / "run")
    assert main([str(run), "--by", "texture"]) == 0
    for folder in (run / "report", run / "report" / "by_texture" / "gravel"):
        assert {"pose_success_vs_rotation.png", "success_heatmap_incremental.png"} <= {p.name for p in
                                                                                       folder.glob("*.png")}
    from gtsweep.report.plots import _band
    from gtsweep.report.samples import load_views
    from gtsweep.report.tables import load_summaries

    cell = next(s for s in load_summaries(run) if s["key"] == "akaze__nms__brief__rotation")
    # AKAZE-BRIEF on rotation: 8/8 at 0 (Wilson [0.676, 1]), 0/8 at 90 ([0, 0.324])
    lows, highs = _band(cell, "strength", "pose_success", [0.0, 90.0], load_views(run))
    assert lows == pytest.approx([0.676, 0.0], abs=1e-3) and highs == pytest.approx([1.0, 0.324], abs=1e-3)


def test_heatmap_cells_show_value_interval_and_na_and_curves_count_views_per_point(tmp_path, monkeypatch):
    from gtsweep.report import plots
    from gtsweep.report.samples import load_views
    from gtsweep.report.tables import load_summaries

    run = _fake_run(tmp_path / "run")
    summaries, views = load_summaries(run), load_views(run)
    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    plots.plot_success_heatmaps(summaries, tmp_path)
    (figure,) = figures
    ax = figure.axes[0]
    texts = {t.get_text() for t in ax.texts}
    # AKAZE-BRIEF 20/20 (Wilson [0.839, 1]), SIFT-SIFT 15/20 ([0.531, 0.888]); AKAZE-SIFT, SIFT-BRIEF not run
    assert texts == {"1.00\n[0.84, 1.00]", "0.75\n[0.53, 0.89]", "NA"}
    assert ax.get_title() == "Pose success, incremental pairs\n20 pairs per cell; [95 % interval]; NA: not applicable"
    width, height = figure.get_size_inches()  # sized to its 2 x 2 cells
    assert width == pytest.approx(2.6 + 2 * 1.25) and height == pytest.approx(1.9 + 2 * 0.62)
    # rotation: 8 images, each at 0 and 90 deg: 16 views per cell, 8 behind each point (rows or, without, counts)
    rotation = [s for s in summaries if s["methods"]["transform"] == "rotation"]
    assert plots._views(rotation) == "16"
    assert plots._per_point(rotation, "strength", views) == plots._per_point(rotation, "strength", None) == "8"
