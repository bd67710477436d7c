"""The survey findings as paired tests on hand-built per-view rows (known verdicts, tied data inconclusive), the
survey's own tables (no per-view rows: not testable, numbers shown) and the REPRODUCTION.md writer on fake runs."""
import pandas as pd
import pytest

from gtsweep.report.samples import load_views
from gtsweep.report.tables import frame, load_summaries, paper
from gtsweep.reproduction.findings import FINDINGS, check_findings
from report_fakes import fake_cell


def _run(directory):
    summaries = load_summaries(directory)
    return frame(summaries), load_views(directory)


def _verdicts(frames, views=None, alpha=0.05):
    return {f.text: f for f in check_findings(frames, views, alpha)}


TABLE4 = "CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)"
TABLE6 = "SIFT is best under severe synthetic transforms (Table 6)"


def test_pairs_finding_holds_fails_and_is_equivalent_on_files(tmp_path):
    """Table 4 from cells written to disk: the best CenSurE pairing and the best other are picked on the even
    pairs and compared on the odd ones (10 of 20), paired t over pairs."""
    fake_cell(tmp_path / "a", "censure", "brief", "incremental", [1] * 20)
    fake_cell(tmp_path / "a", "sift", "sift", "incremental", [1, 0] * 5 + [0, 1] * 5)
    frame_a, views_a = _run(tmp_path / "a")
    found = _verdicts({"table4_incremental": frame_a}, {"table4_incremental": views_a})[TABLE4]
    assert found.verdict == "holds" and "paired t" in found.test
    assert "censure-brief vs sift-sift (both best on half 0): +0.500" in found.evidence and "n = 10" in found.evidence
    fake_cell(tmp_path / "b", "censure", "brief", "incremental", [1, 0] * 5 + [0, 1] * 5)
    fake_cell(tmp_path / "b", "sift", "sift", "incremental", [1] * 20)
    frame_b, views_b = _run(tmp_path / "b")
    assert _verdicts({"table4_incremental": frame_b}, {"table4_incremental": views_b})[TABLE4].verdict == "fails"
    # the same outcomes on the same pairs: a difference of 0, but 10 pairs cannot show it lies within 0.03;
    # on 200 pairs (100 tested) they can: equivalent
    same = [1] * 15 + [0] * 5
    fake_cell(tmp_path / "c", "censure", "brief", "incremental", same)
    fake_cell(tmp_path / "c", "sift", "sift", "incremental", same)
    frame_c, views_c = _run(tmp_path / "c")
    assert _verdicts({"table4_incremental": frame_c}, {"table4_incremental": views_c})[TABLE4].verdict == "undecided"
    fake_cell(tmp_path / "e", "censure", "brief", "incremental", same * 10)
    fake_cell(tmp_path / "e", "sift", "sift", "incremental", same * 10)
    frame_e, views_e = _run(tmp_path / "e")
    assert _verdicts({"table4_incremental": frame_e}, {"table4_incremental": views_e})[TABLE4].verdict == "equivalent"
    # 1 pair of 10 apart: neither a difference nor equivalence within 0.03 can be shown: undecided
    fake_cell(tmp_path / "d", "censure", "brief", "incremental", [1] * 20)
    fake_cell(tmp_path / "d", "sift", "sift", "incremental", [1] * 19 + [0])
    frame_d, views_d = _run(tmp_path / "d")
    close = _verdicts({"table4_incremental": frame_d}, {"table4_incremental": views_d})[TABLE4]
    assert close.verdict == "undecided" and close.to_decide > 10


def test_synthetic_finding_is_a_paired_t_over_images(tmp_path):
    # 16 images x 2 strengths on rotation: SIFT-SIFT succeeds everywhere, AKAZE-BRIEF fails at strength 90 on every
    # image: on the 8 odd images the difference is +0.5 on each: holds
    fake_cell(tmp_path, "sift", "sift", "rotation", [1] * 32, strengths=(0, 90))
    fake_cell(tmp_path, "akaze", "brief", "rotation", [1, 0] * 16, strengths=(0, 90))
    cells, views = _run(tmp_path)
    found = _verdicts({"table6_pairings": cells}, {"table6_pairings": views})[TABLE6]
    assert found.verdict == "holds" and "+0.500" in found.evidence and "n = 8" in found.evidence


NAMES = {"CenSurE": "censure", "HarrisLaplace": "harris_laplace", "LIFT": "lift"}  # LIFT: not our XFeat


def _name(label: str) -> str:
    return NAMES.get(label, label.lower())


def _paper_frames() -> dict[str, pd.DataFrame]:
    """The survey's published numbers as reproduction cells."""
    t2 = paper("table2_selector_repeatability.csv")
    selectors = {"rep_no_selection": "none", "rep_nms": "nms", "rep_anms": "anms", "rep_bucketing": "bucketing"}
    table2 = pd.DataFrame([{"detector": _name(r["detector"]), "selector": s, "transform": "rotation", "status": "ok",
                            "repeatability": float(r[c])} for _, r in t2.iterrows() for c, s in selectors.items()])
    frames = {"table2_selectors": table2}
    for name, csv, transform in (("table4_incremental", "table4_success_incremental.csv", "incremental"),
                                 ("table5_absolute", "table5_success_absolute.csv", "absolute")):
        matrix = paper(csv).set_index("detector")
        frames[name] = pd.DataFrame([{"detector": _name(d), "descriptor": _name(k), "transform": transform,
                                      "status": "ok", "pose_success": float(v)}
                                     for d, row in matrix.iterrows() for k, v in row.items() if v != "NA"])
    t6 = paper("table6_pairings_synthetic.csv")
    frames["table6_pairings"] = pd.DataFrame([{"detector": _name(r["detector"]), "descriptor": _name(r["descriptor"]),
                                               "transform": "rotation", "status": "ok",
                                               "pose_success": float(r["pose_success"]),
                                               "precision": float(r["precision"]),
                                               "n_correct": float(r["correct_matches"])} for _, r in t6.iterrows()])
    t7 = paper("table7_success_vs_reference_features.csv")
    frames["table7_reference_features"] = pd.DataFrame([
        {"detector": _name(r["detector"]), "descriptor": _name(r["descriptor"]), "transform": "incremental",
         "status": "ok", "by_reference_count": {f"{float(c)}": {"pose_success": float(r[c])}
                                                for c in t7.columns[2:]}} for _, r in t7.iterrows()])
    return frames


def test_the_papers_tables_have_no_per_view_rows_so_findings_are_not_testable():
    """The survey's published numbers are means without their images: each paired test is "not testable" and the
    point values are shown (Table 3's full numbers and ambiguity are not published: not measured). The Spearman
    finding needs only one value per pairing, so it is judged (bootstrap over the survey's 25 pairings)."""
    found = _verdicts(_paper_frames())
    assert len(found) == len(FINDINGS)
    for text, f in found.items():
        if "(Table 3)" in text:
            assert f.verdict == "not measured", text
        elif "tracks pose success" in text:
            assert f.verdict in ("holds", "equivalent", "undecided") and "pairings" in f.evidence
        else:
            assert f.verdict == "not testable" and " vs " in f.evidence, (text, f)
    assert "censure-orb vs " in found[TABLE4].evidence  # the paper's best CenSurE pairing against its rival


@pytest.mark.parametrize("text", [h.text for h in FINDINGS])
def test_each_check_tolerates_a_missing_preset(text):
    assert _verdicts({})[text].verdict == "not measured"


def test_document_writer_on_fake_runs(tmp_path):
    """write_document: every finding with its verdict, test and numbers; every table with the entries tied with
    its best (here two of three Table 4 pairings are indistinguishable from the best, one is clearly worse)."""
    from gtsweep.reproduction import command as reproduce

    output = tmp_path / "work" / "table4_incremental"
    fake_cell(output, "censure", "brief", "incremental", [1] * 20)
    fake_cell(output, "censure", "orb", "incremental", [1] * 19 + [0])
    fake_cell(output, "sift", "sift", "incremental", [1] * 8 + [0] * 12)
    measured = {"preset": "table4_incremental", "output": output, "wall_s": 12.4, "peak_mb": 345.6,
                "cache_hit_rate": 0.25, "mlflow_runs": 4, "cells": 3}
    docs = tmp_path / "docs"
    text = reproduce.write_document([measured], "tiny", docs, alpha=0.05).read_text()
    assert "| table4_incremental | 3 | 12 | 346 | 0.25 | 4 |" in text
    row = next(line for line in text.splitlines() if line.startswith(f"| {TABLE4}"))
    assert "| holds | paired t over pairs on half 1, rank claim | ±0.04" in row and "n = 10: holds" in row
    assert "censure-brief vs sift-sift (both best on half 0): +0.600" in row
    assert "| table4_incremental | CenSurE-BRIEF (pose_success 1.00) | 1 of 2 | CenSurE-ORB |" in text
    # Wilson 20/20: [0.839, 1]; 19/20: [0.764, 0.991]; the paper's number beside ours
    assert "| CenSurE | 0.95 [0.76, 0.99] (0.93) | 1.00 [0.84, 1.00] (0.90) |  |" in text
    assert "not measured" in text and (docs / "reproduction" / "table4_incremental.csv").exists()


def test_document_is_rebuilt_from_a_finished_reproduction(tmp_path):
    """--document-only: REPRODUCTION.md from saved measurements and cells, with paper numbers, findings and notes."""
    import json

    from gtsweep.experiments.kinds import run_sweep
    from gtsweep.reproduction import command as reproduce
    from sweep_helpers import compose_config, tiny_overrides

    work, docs = tmp_path / "work", tmp_path / "docs"
    output = work / "table4_incremental"
    grid = ["runner.backend=serial", "mlflow.enabled=false", "detector=[censure]", "descriptor=[brief]",
            "selector=[nms]", "transform=[incremental]"]
    run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), output)
    with pytest.raises(SystemExit, match="no reproduction with a finished run"):
        reproduce.main(["--document-only", "--work", str(work), "--docs", str(docs)])
    measured = {"preset": "table4_incremental", "output": str(output), "wall_s": 12.4, "peak_mb": 345.6,
                "cache_hit_rate": 0.25, "mlflow_runs": 2, "cells": 1}
    (work / "measurements.json").write_text(json.dumps({"size": "tiny", "presets": [measured]}))
    docs.mkdir()
    (docs / "reproduction_notes.md").write_text("## Why\n\nHand-written explanation.")
    assert reproduce.main(["--document-only", "--work", str(work), "--docs", str(docs), "--alpha", "0.1"]) == 0
    text = (docs / "REPRODUCTION.md").read_text()
    assert "alpha = 0.1" in text and "--alpha 0.1" in text
    assert "| table4_incremental | 1 | 12 | 346 | 0.25 | 2 |" in text
    assert "| all | 1 | 12 | 346 | | 2 |" in text
    assert "| CenSurE |" in text and "(0.90)" in text  # CenSurE-BRIEF beside the paper's 0.90
    assert "CenSurE with ORB/BRIEF/LATCH is best on incremental pairs (Table 4)" in text
    assert text.index("Hand-written explanation.") < text.index("## The tables") < text.index("| CenSurE |")
    assert (docs / "reproduction" / "table4_incremental.csv").exists()
    assert "Interim document" not in text


def test_an_unfinished_reproduction_gives_an_interim_document(tmp_path):
    """--document-only on a reproduction still running (only progress.json): the rounds finished so far, marked
    as interim, each finding judged at its last look and marked still open below its full count."""
    import json

    from gtsweep.reproduction import command as reproduce

    work, docs = tmp_path / "work", tmp_path / "docs"
    output = work / "round1" / "table4_incremental"
    timed = lambda i: {"t_detect": 0.5, "t_describe": 0.25, "t_match": 0.125, "t_pose": 0.125}  # noqa: E731
    fake_cell(output, "censure", "orb", "incremental", [1] * 9 + [0] * 3, extra=timed)
    fake_cell(output, "sift", "sift", "incremental", [1] * 6 + [0] * 6, extra=timed)
    measured = {"preset": "table4_incremental", "output": str(output), "wall_s": 60.0, "peak_mb": 100.0,
                "cache_hit_rate": 0.0, "mlflow_runs": 3, "cells": 2, "round": 1, "counts": [1, 6, 6],
                "items_evaluated": 24, "items_reused": 0, "extra_cells": 0}
    plan = {"size": "decide", "presets": ["table4_incremental"], "alpha": 0.05, "tuned": "x"}
    (work / "progress.json").write_text(json.dumps({"plan": plan, "finished": {"round1/table4_incremental": measured},
                                                    "attempts": {}}))
    assert reproduce.main(["--document-only", "--work", str(work), "--docs", str(docs)]) == 0
    text = (docs / "REPRODUCTION.md").read_text()
    assert "**Interim document: this reproduction is not finished.**" in text
    assert "| 1 | table4_incremental | 2 | 60 | 100 | 0.00 | 3 | 24 (0) |" in text
    row = next(line for line in text.splitlines() if line.startswith(f"| {TABLE4}"))
    assert "(still open: the next round adds data)" in row and "| round 1, 6, " in row
    (work / "progress.json").write_text("{not json")
    with pytest.raises(SystemExit, match="cannot read the reproduction's record"):
        reproduce.main(["--document-only", "--work", str(work), "--docs", str(docs)])


def test_selectors_that_both_keep_every_keypoint_are_not_compared(tmp_path):
    # GFTT stops at 1000 corners: NMS and ANMS keep all 1000 (the same keypoints), bucketing keeps 600 and repeats
    # worse by 0.1 on every one of 6 images; the finding compares NMS with bucketing only
    def rows(kept, repeatability):
        return lambda i: {"n_detected": 1000.0, "n_kp_test": kept, "repeatability": repeatability}

    textures = ("gravel", "wood", "tiles", "carpet", "concrete", "grass")
    for selector, kept, rep in (("nms", 1000.0, 0.6), ("anms", 1000.0, 0.6), ("bucketing", 600.0, 0.5)):
        fake_cell(tmp_path, "gftt", None, "rotation", [0] * 6, selector=selector, textures=textures,
                  extra=rows(kept, rep))
    cells, views = _run(tmp_path)
    found = _verdicts({"table2_selectors": cells}, {"table2_selectors": views})[
        "NMS beats ANMS and bucketing, except for MSER (Table 2)"]
    assert "gftt NMS vs BUCKETING" in found.evidence and "ANMS" not in found.evidence
    assert found.verdict == "holds" and "+0.100" in found.evidence and "n = 6" in found.evidence
