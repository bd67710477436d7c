"""Settings of a multirun side by side (gtsweep.report.settings): per cell each setting's pose success with its
interval, the paired test against the first setting on the same pairs, and which cells move."""
import json

import pandas as pd
from report_fakes import fake_cell

from gtsweep.report.combine import combine


def _job(root, name, setting, censure_sift):
    directory = root / name
    directory.mkdir()
    (directory / "sweep.json").write_text(json.dumps({"overrides": [f"experiment.foreign_scale={setting}",
                                                                    "sweeps=table4_incremental"]}))
    fake_cell(directory, "censure", "sift", "incremental", censure_sift)
    fake_cell(directory, "sift", "sift", "incremental", [1] * 15 + [0] * 5)  # native: the same under both


def test_two_settings_side_by_side_with_paired_tests(tmp_path):
    # CenSurE-SIFT: 18/20 pairs under own, 6/20 under octave0; the 12 discordant pairs all own's (McNemar
    # p = 2 * 0.5^12 = 0.00049): it moves. SIFT-SIFT: identical outcomes, p = 1.
    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    _job(tmp_path, "1", "octave0", [1] * 6 + [0] * 14)
    files = combine(tmp_path, plots=False)
    assert tmp_path / "combined" / "settings.md" in files
    rows = pd.read_csv(tmp_path / "combined" / "settings.csv").set_index(["detector", "descriptor"])
    first, second = "own", "octave0"  # in job order, labelled by the value of the one key they vary
    moved = rows.loc[("censure", "sift")]
    assert moved[first].startswith("0.90 [") and moved[second].startswith("0.30 [")
    assert moved[f"{second} - {first}"] == "-0.60 (p = 0.00049)" and moved[f"moves ({second})"] == "yes"
    assert moved["survey"] == 0.82  # the survey's Table 4: CenSurE-SIFT
    same = rows.loc[("sift", "sift")]
    assert same[f"{second} - {first}"] == "+0.00 (p = 1)" and pd.isna(same[f"moves ({second})"])
    text = (tmp_path / "combined" / "settings.md").read_text()
    # mean |ours - survey| over the two cells (survey: CenSurE-SIFT 0.82, SIFT-SIFT 0.84): octave0
    # (|0.30 - 0.82| + |0.75 - 0.84|) / 2 = 0.305, own (0.08 + 0.09) / 2 = 0.085
    assert text.startswith("**experiment.foreign_scale side by side: pose_success")
    assert "- `own`: mean |ours - survey| 0.085 over 2 cells" in text
    assert "- `octave0`: 1 of 2 cells move; mean |ours - survey| 0.305 over 2 cells" in text


def test_one_setting_writes_no_comparison(tmp_path):
    _job(tmp_path, "0", "own", [1] * 18 + [0] * 2)
    combine(tmp_path, plots=False)
    assert not (tmp_path / "combined" / "settings.md").exists()
