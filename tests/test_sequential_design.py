"""The sequential design's bookkeeping without running sweeps: each look's nominal level is the Pocock-type
spending increment, and a decided finding is frozen (never judged again) while its preset keeps running for the
undecided ones."""
import math

import pandas as pd
import pytest

from gtsweep.evaluation.statistics import Comparison
from gtsweep.evaluation.verdicts import BEATS, Claim
from gtsweep.reproduction import sequential
from gtsweep.reproduction.findings import Hypothesis
from gtsweep.reproduction.sequential import Sequential

CELLS = pd.DataFrame([{"key": "censure__nms__brief__incremental", "detector": "censure", "selector": "nms",
                       "descriptor": "brief", "transform": "incremental", "status": "ok"}])


def _claims(differences):
    """A hypothesis whose k-th look sees the k-th difference (SE 0.01 on 20 pairs): +0.5 holds, 0 is undecided
    (SE 0.01 against a margin of 0.001), -0.5 fails."""
    looks = iter(differences)

    def build(data):
        return [Claim("fake", Comparison("fake", next(looks), math.nan, n=20, se=0.01, df=19), BEATS, 0.001)]
    return build


@pytest.fixture
def no_files(monkeypatch):
    monkeypatch.setattr(sequential, "load_summaries", lambda output: output)
    monkeypatch.setattr(sequential, "frame", lambda summaries: CELLS)
    monkeypatch.setattr(sequential, "load_views", lambda output: {})


def test_each_look_spends_the_pocock_increment_and_a_decided_finding_stays_frozen(no_files):
    early = Hypothesis("decided early", "table4_incremental", "", "", "", "", _claims([0.5, -0.5, -0.5]))
    late = Hypothesis("decided late", "table4_incremental", "", "", "", "", _claims([0.0, 0.0, 0.5]))
    design = Sequential(0.05, [early, late])
    for k, n in enumerate((6, 12, 25)):
        needed = design.update(k, {"table4_incremental": {"round": k + 1, "counts": (1, n, n), "output": None}})
        assert list(needed) == (["table4_incremental"] if k < 2 else [])  # the open finding's preset, until decided
    first, second = design.status
    spent = [0.05 * math.log(1 + (math.e - 1) * t) for t in (0.06, 0.12, 0.25)]
    assert [look[3] for look in first.looks] == ["holds"] and first.finding.verdict == "holds"  # not re-judged
    assert first.nominal == pytest.approx(spent[0]) and first.per_texture == 6
    assert [look[3] for look in second.looks] == ["undecided", "undecided", "holds"]
    assert [look[2] for look in second.looks] == pytest.approx([spent[0], spent[1] - spent[0], spent[2] - spent[1]])
    assert second.spent == pytest.approx(spent[2]) and second.round == 3


def test_a_finding_no_number_of_images_decides_asks_for_no_data_but_is_judged_when_its_preset_runs(no_files):
    """Finding 10's kind (an interval over the methods compared): undecided at every look, it asks for no round
    of its own; while another open finding keeps its preset running it is judged again at each look."""
    def over_methods(data):
        return [Claim("rho", Comparison("bootstrap over pairings", 0.0, math.nan, -1.0, 1.0, n=9), BEATS, 1 / 60,
                      images_narrow=False)]

    methods = Hypothesis("over the methods", "table4_incremental", "", "", "", "", over_methods)
    other = Hypothesis("decided late", "table4_incremental", "", "", "", "", _claims([0.0, 0.5]))
    design = Sequential(0.05, [methods, other])
    needed = design.update(0, {"table4_incremental": {"round": 1, "counts": (1, 6, 6), "output": None}})
    assert list(needed) == ["table4_incremental"]  # for the other finding
    alone, _ = design.status
    assert alone.finding.to_decide == math.inf and not alone.final and not alone.asks_for_data
    needed = design.update(1, {"table4_incremental": {"round": 2, "counts": (2, 12, 12), "output": None}})
    assert needed == {} and [look[3] for look in alone.looks] == ["undecided", "undecided"]
    only = Sequential(0.05, [methods])  # alone: no round after the first
    assert only.update(0, {"table4_incremental": {"round": 1, "counts": (1, 6, 6), "output": None}}) == {}
