"""The report states the survey's thresholds in mm (issue 17.5), and with several matchers or estimators neither the
findings nor the ties with the best pool cells of different variants (issues 18, 19)."""
import pytest
import yaml

from gtsweep.experiments.report_command import main
from gtsweep.report.samples import load_views
from gtsweep.report.scale import Scale, load_scale, scale_from_config
from gtsweep.report.tables import build_tables, frame, load_summaries
from gtsweep.reproduction.findings import check_findings, survey_variant
from report_fakes import fake_cell

TABLE4 = "CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)"
SURVEY_CONFIG = {"dataset": {"loader": "synthetic", "view_size": [1288, 964], "px_per_mm": 6.25},
                 "selector": {"nms": {"params": {"n": 1000}}, "none": {"params": {}}},
                 "experiment": {"name": "pose", "min_keypoints": 100, "pose": {"max_position_error": 30.0}}}


def test_scale_line_in_mm_hand_worked():
    # 30 px / 6.25 px/mm = 4.8 mm; 1288 / 6.25 = 206.08 mm, 964 / 6.25 = 154.24 mm
    line = scale_from_config(SURVEY_CONFIG).line()
    assert line == ("Scale (6.25 px/mm, the data set's): success radius 30 px = 4.8 mm; keypoint budget N = 1000 "
                    "and < N KPs threshold 100 keypoints per 1288×964 px view = 206×154 mm.")
    # another scale: 12.5 px/mm halves every length; a 640x480 view is 51x38 mm
    half = scale_from_config({**SURVEY_CONFIG, "dataset": {"view_size": [640, 480], "px_per_mm": 12.5}})
    assert "30 px = 2.4 mm" in half.line() and "640×480 px view = 51×38 mm" in half.line()
    # Micro-GPS' loader has no px_per_mm in its config: its camera's scale and view size
    micro = scale_from_config({"dataset": {"loader": "microgps"}})
    assert micro.known and "1288×964 px view = 206×154 mm" in micro.line()
    # nothing recorded (one's own data without dataset.px_per_mm): pixels only, and the line names the key
    assert Scale().line(detection=False) == ("Scale (pixels only: the data set gives no dataset.px_per_mm): success "
                                             "radius 30 px.")
    own = scale_from_config({**SURVEY_CONFIG, "dataset": {"loader": "csv", "px_per_mm": None,
                                                          "view_size": [320, 240]}})
    assert own.line() == ("Scale (pixels only: the data set gives no dataset.px_per_mm): success radius 30 px; "
                          "keypoint "
                          "budget N = 1000 and < N KPs threshold 100 keypoints per 320×240 px view.")
    assert scale_from_config({**SURVEY_CONFIG, "dataset": {"loader": "csv", "px_per_mm": 20}}).line(
        detection=False) == "Scale (20 px/mm, the data set's): success radius 30 px = 1.5 mm."


def _variant_run(directory):
    """Table 4 cells of two variants: on bf_ratio + ransac CenSurE-BRIEF wins 20 to 10 (10 discordant pairs, all
    its: McNemar p = 2/2^10); on flann + magsac SIFT-SIFT wins 20 to 0. Pooled, CenSurE-BRIEF would lose 20/40
    vs 30/40."""
    survey, other = {"matcher": "bf_ratio", "estimator": "ransac"}, {"matcher": "flann", "estimator": "magsac"}
    fake_cell(directory, "censure", "brief", "incremental", [1] * 20, variant=survey)
    fake_cell(directory, "sift", "sift", "incremental", [1] * 10 + [0] * 10, variant=survey)
    fake_cell(directory, "censure", "brief", "incremental", [0] * 20, variant=other)
    fake_cell(directory, "sift", "sift", "incremental", [1] * 20, variant=other)
    (directory / ".hydra").mkdir()
    (directory / ".hydra" / "config.yaml").write_text(yaml.safe_dump(SURVEY_CONFIG))
    return load_summaries(directory), load_views(directory)


def test_findings_are_judged_on_the_survey_variant_not_pooled(tmp_path):
    summaries, views = _variant_run(tmp_path)
    frames = {"table4_incremental": frame(summaries)}
    found = {f.text: f for f in check_findings(frames, {"table4_incremental": views})}[TABLE4]
    assert found.verdict == "holds" and "censure-brief vs sift-sift (both best on half 0): +0.500" in found.evidence
    # the 10 odd pairs of 20: 5 won by CenSurE-BRIEF alone, exact McNemar p = 2/32
    assert "p = 0.062" in found.evidence and "n = 10" in found.evidence
    note = survey_variant(frames)[1]
    assert note == ("Findings judged on the survey's variant (matcher bf_ratio, estimator ransac) only: 2 cell(s) of "
                    "other matchers or estimators left out, never pooled.")
    # without the survey's variant: the first one seen, and the note says the survey's was not run
    other = {"table4_incremental": frames["table4_incremental"].query("matcher == 'flann'")}
    assert "flann" in survey_variant(other)[1] and "was not run" in survey_variant(other)[1]
    assert {f.text: f for f in check_findings(other, {"table4_incremental": views})}[TABLE4].verdict == "fails"
    # one variant, the survey's: no note
    single = {"table4_incremental": frames["table4_incremental"].query("matcher == 'bf_ratio'")}
    assert survey_variant(single)[1] == ""


def test_ties_with_the_best_are_computed_within_each_variant(tmp_path):
    summaries, views = _variant_run(tmp_path)
    tables = {t.name: t for t in build_tables(summaries, views)}
    survey, other = tables["table4_incremental_bf_ratio_ransac"], tables["table4_incremental_flann_magsac"]
    assert survey.ties.best.startswith("CenSurE") and survey.ties.best_value == 1.0 and survey.ties.tied == []
    assert other.ties.best.startswith("SIFT") and other.ties.best_value == 1.0 and other.ties.tied == []
    assert len(survey.ties.tests) == len(other.ties.tests) == 1  # one rival each: the other variant is not in it
    assert all(t.n == 20 for t in [*survey.ties.tests.values(), *other.ties.tests.values()])


def test_report_states_the_scale_under_the_tables_and_in_the_footer(tmp_path, capsys):
    _variant_run(tmp_path)
    assert load_scale(tmp_path).known and not load_scale(tmp_path / "missing").known
    assert main([str(tmp_path), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    line = scale_from_config(SURVEY_CONFIG).line()
    assert printed.count(line) == 1  # the footer, once for both Table 4 variants
    assert printed.rstrip().splitlines()[-2] == line
    for variant in ("bf_ratio_ransac", "flann_magsac"):  # each table's file carries it
        assert line in (tmp_path / "report" / f"table4_incremental_{variant}.md").read_text()


def test_reproduction_document_carries_the_scale_and_the_variant(tmp_path):
    from gtsweep.reproduction import command as reproduce

    output = tmp_path / "work" / "table4_incremental"
    output.mkdir(parents=True)
    _variant_run(output)
    measured = {"preset": "table4_incremental", "output": output, "wall_s": 1.0, "peak_mb": 1.0,
                "cache_hit_rate": 0.5, "mlflow_runs": 5, "cells": 4}
    text = reproduce.write_document([measured], "tiny", tmp_path / "docs").read_text()
    line = scale_from_config(SURVEY_CONFIG).line()
    assert text.count(line) == 3  # the header, and under each variant's Table 4
    assert "Findings judged on the survey's variant (matcher bf_ratio, estimator ransac)" in text
    assert "| table4_incremental_bf_ratio_ransac | CenSurE-BRIEF" in text
    assert "| table4_incremental_flann_magsac | SIFT-SIFT" in text


@pytest.mark.parametrize("bad", ["not: [valid", "- a list"])
def test_unreadable_config_falls_back_to_the_assumed_scale(tmp_path, bad):
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "config.yaml").write_text(bad)
    assert not load_scale(tmp_path).known


def test_budget_per_area_and_no_selection_are_stated():
    # budget_per_mpx 805.4 on a 640x480 view: n = round(805.4 * 0.3072) = 247, < N KPs = round(100 * 247 / 1000) = 25
    cfg = {**SURVEY_CONFIG, "dataset": {"view_size": [640, 480], "px_per_mm": 6.25},
           "experiment": {**SURVEY_CONFIG["experiment"], "budget_per_mpx": 805.4}}
    assert "N = 247 and < N KPs threshold 25 keypoints per 640×480 px view = 102×77 mm" in scale_from_config(cfg).line()
    none = scale_from_config({**SURVEY_CONFIG, "selector": {"none": {"params": {}}}})
    assert "N = all keypoints (no selection)" in none.line()


def test_scale_of_the_composed_survey_and_localization_configs():
    """What the command line hands the report: the resolved config of ``dataset=survey`` (and of localization)."""
    from omegaconf import OmegaConf

    from sweep_helpers import compose_config

    survey = scale_from_config(OmegaConf.to_container(compose_config(["dataset=survey"]), resolve=True))
    assert survey.line() == scale_from_config(SURVEY_CONFIG).line()
    local = OmegaConf.to_container(compose_config(["experiment=localization"]), resolve=True)
    assert "success radius 30 px = 4.8 mm" in scale_from_config(local).line(detection=False)
