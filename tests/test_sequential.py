"""The sequential reproduction end to end on a tiny data set with two cheap findings: round 1 runs both presets,
the finding decided there is frozen, round 2 runs only the cell the undecided one reads, at a larger count, and
evaluates only its new pairs (the first ones' rows are kept from round 1)."""
import math

import pytest

from gtsweep.evaluation.statistics import Comparison
from gtsweep.evaluation.verdicts import BEATS, Claim
from gtsweep.report.pools import cells_where, pairings
from gtsweep.report.samples import matrices
from gtsweep.reproduction.findings import Hypothesis
from gtsweep.reproduction.rounds import run_rounds
from gtsweep.reproduction.sequential import Sequential

TINY = ["dataset.textures=[gravel,wood]", "dataset.view_size=[320,240]", "runner.backend=serial",
        "detector=[censure]", "descriptor=[brief,orb]", "selector=[nms]"]


def _clusters(data, kind):
    cells = next(iter(pairings(data, [kind]).values()))
    return len(matrices(cells, "pose_success", data.views)[0])


def equal_at_once(data):
    """A difference of exactly 0: equivalent within any margin at the first look."""
    return [Claim(f"zero on {_clusters(data, 'absolute')} pairs", Comparison("fake", 0.0, 1.0, 0.0, 0.0, n=4,
                                                                             se=0.0, df=3), BEATS, 0.1)]


def clear_with_six_pairs(data):
    """+0.5, with an SE that is large below 6 pairs and small from 6 on: undecided, then holds."""
    n = _clusters(data, "incremental")
    return [Claim(f"+0.5 on {n} pairs", Comparison("fake", 0.5, math.nan, n=n, se=0.5 if n < 6 else 0.01, df=n - 1),
                 BEATS, 0.1)]


FAKE = [Hypothesis("equal at once", "table5_absolute", "", "", "", "0.1", equal_at_once),
        Hypothesis("clear with six pairs", "table4_incremental", "", "", "", "0.1", clear_with_six_pairs,
                   cells_where(descriptors=["brief"]))]


@pytest.mark.slow
def test_rounds_run_only_the_presets_of_undecided_findings(tmp_path, existing_store):
    existing_store(tmp_path / "mlflow.db", tmp_path / "round1")  # run_rounds' store, made once per session
    rounds = ((1, 2, 2), (1, 3, 3))  # 2 textures: 4 pairs, then 6
    sequential = Sequential(0.05, FAKE, information=lambda preset, counts: counts[1] / 3)
    runs = run_rounds(["table4_incremental", "table5_absolute"], sequential.update, tmp_path, rounds=rounds,
                      extra=TINY, log=lambda m: None)
    assert [(r["round"], r["preset"]) for r in runs] == [(1, "table4_incremental"), (1, "table5_absolute"),
                                                          (2, "table4_incremental")]
    first, second = sequential.status
    assert first.finding.verdict == "equivalent" and first.round == 1 and len(first.looks) == 1
    assert [look[3] for look in second.looks] == ["undecided", "holds"] and second.per_texture == 3
    # alpha spent: ln(1 + (e - 1) 2/3) of alpha at the first look, the rest at the second
    assert second.looks[0][2] == pytest.approx(0.05 * math.log(1 + (math.e - 1) * 2 / 3))
    assert second.spent == pytest.approx(0.05)
    # round 1: 2 cells x 2 textures x 2 pairs evaluated; round 2: only censure-brief (the cell the open finding
    # reads), only its new pair per texture, the rows of the first 2 kept
    assert [r["cells"] for r in runs] == [2, 2, 1] and runs[2]["extra_cells"] == 0
    assert (runs[0]["items_evaluated"], runs[0]["items_reused"]) == (8, 0)
    assert (runs[2]["items_evaluated"], runs[2]["items_reused"]) == (2, 4)
    assert len(list((tmp_path / "round2" / "table4_incremental" / "cells").glob("*.json"))) == 2  # orb carried
    # the document: each finding with the round, count per texture and level of its verdict; compute spent
    from gtsweep.reproduction.command import write_document

    text = write_document(runs, "decide", tmp_path / "docs", 0.05, sequential).read_text()
    assert "| equal at once | equivalent | round 1, 2, " in text
    assert "| clear with six pairs | holds | round 2, 3, " in text
    assert "newest round: table4_incremental 3, table5_absolute 2" in text and "Compute spent" in text
    assert "| table4_incremental | 3: 1 cells; 2: 1 cells |" in text  # each cell at the count it last reached
    assert "| round | preset | cells |" in text and "| 2 | table4_incremental | 1 |" in text
    spent = sum(r["wall_s"] for r in runs if r["preset"] == "table4_incremental") / 60
    assert f"| clear with six pairs | holds | round 2, 3, {second.nominal:.2g} | {spent:.1f} / " in text
