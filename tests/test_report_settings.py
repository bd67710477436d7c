"""Settings of a multirun side by side (gtsweep.report.settings): per cell each setting's pose success with its
interval, the paired test against the first setting on the same pairs, and which cells move."""
import json

import pandas as pd
import pytest

from gtsweep.experiments.kinds import combine_multirun as combine
from report_fakes import fake_cell


def _job(root, name, setting, censure_sift):
    directory = root / name
    directory.mkdir()
    (directory / "sweep.json").write_text(json.dumps({"overrides": [f"experiment.foreign_scale={setting}",
                                                                    "sweeps=table4_incremental"]}))
    fake_cell(directory, "censure", "sift", "incremental", censure_sift)
    fake_cell(directory, "sift", "sift", "incremental", [1] * 15 + [0] * 5)  # native: the same under both


def test_two_settings_side_by_side_with_paired_tests(tmp_path):
    # CenSurE-SIFT: 18/20 pairs under own, 6/20 under octave0; the 12 discordant pairs all own's (McNemar
    # p = 2 * 0.5^12 = 0.00049; Holm over the 2 cells: 2 * 0.00049 = 0.00098): it moves. SIFT-SIFT: identical
    # outcomes, p = 1 (Holm: max(0.00098, 1 * 1) = 1).
    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    _job(tmp_path, "1", "octave0", [1] * 6 + [0] * 14)
    files = combine(tmp_path, plots=False)
    assert tmp_path / "combined" / "settings.md" in files
    rows = pd.read_csv(tmp_path / "combined" / "settings.csv").set_index(["detector", "descriptor"])
    first, second = "own", "octave0"  # in job order, labelled by the value of the one key they vary
    moved = rows.loc[("censure", "sift")]
    assert moved[first].startswith("0.90 [") and moved[second].startswith("0.30 [")
    assert moved[f"{second} - {first}"] == "-0.60 (p = 0.00049, Holm 0.00098)" and moved[f"moves ({second})"] == "yes"
    assert moved["survey"] == 0.82  # the survey's Table 4: CenSurE-SIFT
    same = rows.loc[("sift", "sift")]
    assert same[f"{second} - {first}"] == "+0.00 (p = 1, Holm 1)" and pd.isna(same[f"moves ({second})"])
    text = (tmp_path / "combined" / "settings.md").read_text()
    # mean |ours - survey| over the two cells (survey: CenSurE-SIFT 0.82, SIFT-SIFT 0.84): octave0
    # (|0.30 - 0.82| + |0.75 - 0.84|) / 2 = 0.305, own (0.08 + 0.09) / 2 = 0.085
    assert text.startswith("**experiment.foreign_scale side by side: pose_success")
    assert "- `own`: mean |ours - survey| 0.085 over 2 cells the survey reports (0.085 over the 2" in text
    assert "- `octave0`: 1 of 2 cells move; mean |ours - survey| 0.305 over 2 cells" in text
    assert "Holm-adjusted across the cells" in text


def test_one_setting_writes_no_comparison(tmp_path):
    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    combine(tmp_path, plots=False)
    assert not (tmp_path / "combined" / "settings.md").exists()


def test_a_cell_moves_only_after_holm_across_the_cells(tmp_path):
    # AKAZE-SIFT: 16/20 under own, 10/20 under octave0, the 6 discordant pairs all own's: McNemar p = 2 * 0.5^6 =
    # 0.031 < 0.05, but Holm over the 3 cells (p 0.00049, 0.031, 1) gives 2 * 0.031 = 0.062: it does not move.
    # CenSurE-SIFT (p 0.00049 -> 3 * 0.00049 = 0.0015) still moves.
    for name, setting, censure, akaze in (("0", "own", [1] * 18 + [0] * 2, [1] * 16 + [0] * 4),
                                          ("1", "octave0", [1] * 6 + [0] * 14, [1] * 10 + [0] * 10)):
        _job(tmp_path, name, setting, censure)
        fake_cell(tmp_path / name, "akaze", "sift", "incremental", akaze)
    combine(tmp_path, plots=False)
    rows = pd.read_csv(tmp_path / "combined" / "settings.csv").set_index(["detector", "descriptor"])
    assert rows.loc[("akaze", "sift"), "octave0 - own"] == "-0.30 (p = 0.031, Holm 0.062)"
    assert pd.isna(rows.loc[("akaze", "sift"), "moves (octave0)"])
    assert rows.loc[("censure", "sift"), "octave0 - own"] == "-0.60 (p = 0.00049, Holm 0.0015)"
    assert rows.loc[("censure", "sift"), "moves (octave0)"] == "yes"


def test_a_job_with_failed_cells_fails_the_multirun_after_combining(tmp_path, capsys):
    """A failed cell (e.g. passthrough's MSD octaves out of SIFT's pyramid) does not stop the other jobs: the
    multirun combines every job, then names the failed cells in one line and exits 1."""
    from omegaconf import OmegaConf

    from gtsweep.cli.multirun import MultirunReport, failed_cells
    from gtsweep.orchestration.results import ResultStore

    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    _job(tmp_path, "1", "passthrough", [1] * 6 + [0] * 14)
    error = {"key": "msd__nms__sift__incremental", "status": "error", "experiment": "pose", "reason": "octaves",
             "methods": {"detector": "msd", "selector": "nms", "descriptor": "sift", "transform": "incremental"}}
    ResultStore(tmp_path / "1").write_cell(error["key"], error, None)
    assert failed_cells(tmp_path) == ["1/msd__nms__sift__incremental"]
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}, "mlflow": {"enabled": False},
                               "report": {"plots": False, "by": None, "alpha": 0.05}})
    with pytest.raises(SystemExit) as stop:
        MultirunReport().on_multirun_end(config)
    assert stop.value.code == 1 and (tmp_path / "combined" / "settings.md").exists()
    out, err = capsys.readouterr()
    assert "multirun: jobs combined in" in out
    assert err.strip() == "gtsweep: multirun: 1 cell(s) failed: 1/msd__nms__sift__incremental"


@pytest.mark.slow
def test_a_multirun_whose_job_fails_a_cell_still_combines_and_exits_1(tmp_path):
    """The real case: passthrough reads MSD's level indices as SIFT octaves outside SIFT's pyramid, so that cell
    fails in its job; the other job runs, the settings are combined, and the multirun exits 1 naming the cell."""
    from sweep_helpers import run_cli

    done = run_cli(["-m", "experiment.foreign_scale=own,passthrough", "detector=[msd]", "descriptor=[sift]",
                    "transform=[incremental]", "selector=[nms]", "dataset.textures=[gravel,wood]",
                    "dataset.view_size=[320,240]", "dataset.n_incremental=1", "dataset.n_absolute=1",
                    "dataset.n_synthetic=1", "dataset.n_optimisation=1", "runner.backend=serial",
                    "mlflow.enabled=false", "runner.progress=false", f"hydra.sweep.dir={tmp_path}/multi"], tmp_path)
    assert done.returncode == 1, done.stderr[-2000:]
    assert "gtsweep: multirun: 1 cell(s) failed: 1/msd__nms__sift__incremental" in done.stderr
    assert "Traceback" not in done.stderr and "raised" not in done.stderr
    text = (tmp_path / "multi" / "combined" / "settings.md").read_text()
    assert "| MSD | SIFT | incremental | 0.83 |" in text and "- `passthrough`: no cell with a value" in text


def test_failed_cells_end_the_multirun_in_1_even_when_combining_breaks(tmp_path, monkeypatch, capsys):
    """Hydra turns a callback's exception into a warning: a combine step that breaks must not turn a multirun
    with failed cells into exit 0."""
    from omegaconf import OmegaConf

    from gtsweep.cli.multirun import MultirunReport
    from gtsweep.experiments import kinds
    from gtsweep.orchestration.results import ResultStore

    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    error = {"key": "msd__nms__sift__incremental", "status": "error", "experiment": "pose", "reason": "octaves",
             "methods": {"detector": "msd", "selector": "nms", "descriptor": "sift", "transform": "incremental"}}
    ResultStore(tmp_path / "0").write_cell(error["key"], error, None)

    def broken(*args, **kwargs):
        raise KeyError("pose_success")

    monkeypatch.setattr(kinds, "combine_multirun", broken)
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}, "mlflow": {"enabled": False},
                               "report": {"plots": False, "by": None, "alpha": 0.05}})
    with pytest.raises(SystemExit) as stop:
        MultirunReport().on_multirun_end(config)
    assert stop.value.code == 1
    assert capsys.readouterr().err.strip() == "gtsweep: multirun: 1 cell(s) failed: 0/msd__nms__sift__incremental"


def test_the_multiruns_mlflow_run_is_marked_failed_with_the_failed_cells(tmp_path, existing_store):
    from mlflow.tracking import MlflowClient

    from gtsweep.tracking.sweep import close_multirun, open_multirun

    cfg = {"tracking_uri": existing_store(tmp_path / "m.db", tmp_path), "experiment": "gtsweep"}
    run_id = open_multirun(cfg, "multirun experiment.foreign_scale=own,passthrough", tmp_path)
    close_multirun(cfg, run_id, [], "1 cell(s) failed: 1/msd__nms__sift__incremental")
    run = MlflowClient(cfg["tracking_uri"]).get_run(run_id)
    assert run.info.status == "FAILED"
    assert run.data.tags["gtsweep.reason"] == "1 cell(s) failed: 1/msd__nms__sift__incremental"
    other = open_multirun(cfg, "multirun seed=0,1", tmp_path)
    close_multirun(cfg, other)
    assert MlflowClient(cfg["tracking_uri"]).get_run(other).info.status == "FINISHED"
