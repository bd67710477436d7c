"""The amendment's tests (docs/statistics_design.md, A2-A6) on synthetic per-view rows: frozen picks tested on old
half 1 plus every new image, restated findings on new images only, and the verdicts their wording allows."""
import pytest

from finding_fakes import Fakes, level
from gtsweep.report.pools import Data
from gtsweep.reproduction import amended
from gtsweep.reproduction.findings import judge

IMAGES = 6 * 100  # 100 images per texture, 6 textures


def _data(fakes: Fakes, alpha=0.05) -> Data:
    return Data(fakes.frame(), fakes.views, alpha)


def _table3(levels: dict[str, float], metric="repeatability", clusters=IMAGES, wood=None):
    fakes = Fakes()
    for seed, (det, mean) in enumerate(sorted(levels.items())):
        fakes.add(det, "rotation", {metric: level(mean, clusters, seed=seed)})
    if wood is not None:  # texture t5 is wood, where the detector ``wood[0]`` has the level ``wood[1]``
        for key, rows in fakes.views.items():
            rows["texture"] = rows["texture"].replace("t5", "wood")
            if key.startswith(f"{wood[0]}__"):
                rows.loc[rows["texture"] == "wood", metric] = wood[1]
    return fakes


def test_frozen_pick_is_tested_on_old_half_one_and_every_new_image():
    fakes = _table3({"sift": 0.84, "akaze": 0.84, "surf": 0.84, "censure": 0.80, "fast": 0.95})
    finding = judge(amended.FINAL[0], _data(fakes, alpha=0.0379))
    assert "vs censure (frozen round-5 pick)" in finding.evidence  # fast is better but not the frozen pick
    assert finding.verdict == "holds"
    assert [p.comparison.n for p in finding.parts] == [8 * 6 + 84 * 6] * 3  # 552 images


@pytest.mark.parametrize("surf, verdict", [(0.84, "holds"), (0.78, "fails")])
def test_restated_finding_3_tests_the_span(surf, verdict):
    fakes = _table3({"sift": 0.84, "akaze": 0.845, "surf": surf, "censure": 0.70})
    finding = judge(amended.RESTATED[1], _data(fakes))
    spans = [p for p in finding.parts if "(span)" in p.label]
    assert len(spans) == 3 and all(p.comparison.n == 84 * 6 for p in finding.parts)
    assert finding.verdict == verdict


def test_restated_finding_5_reads_both_scores_and_akaze_off_wood():
    levels = {"surf": 0.85, "censure": 0.85, "akaze": 0.85, "fast": 0.70, "gftt": 0.72, "agast": 0.74}
    fakes = _table3(levels, wood=("akaze", 0.10))
    ambiguity = _table3({k: 2.0 - v for k, v in levels.items()}, "ambiguity", wood=("akaze", 3.0))
    for key, rows in ambiguity.views.items():
        fakes.views[key]["ambiguity"] = rows["ambiguity"].to_numpy()
    finding = judge(amended.RESTATED[2], _data(fakes))
    assert len(finding.parts) == 6 and finding.verdict == "holds"  # AKAZE's poor wood rows are not read
    akaze = [p for p in finding.parts if p.label.startswith("akaze")]
    assert all(p.comparison.n == 84 * 5 for p in akaze)


@pytest.mark.parametrize("anms, verdict", [(0.73, "holds"), (0.51, "equivalent")])
def test_restated_finding_1_needs_a_gap_for_mser(anms, verdict):
    """The survey's MSER is a gap (ANMS 0.73 vs NMS 0.51): a tie no longer supports it (equivalent)."""
    fakes = Fakes()
    for seed, (det, sel, mean) in enumerate([("mser", "anms", anms), ("mser", "nms", 0.51),
                                             ("mser", "bucketing", 0.50), ("sift", "nms", 0.82),
                                             ("sift", "anms", 0.80), ("sift", "bucketing", 0.77)]):
        fakes.add(det, "rotation", {"repeatability": level(mean, 6 * 23, seed=seed)}, selector=sel)
    finding = judge(amended.RESTATED[0], _data(fakes))
    assert all(p.comparison.n == 7 * 6 for p in finding.parts)  # images 17-23 of every texture
    assert finding.verdict == verdict


def test_picks_of_the_restated_findings_read_half_zero_of_the_rounds_only():
    levels = {"surf": 0.85, "censure": 0.85, "akaze": 0.85, "fast": 0.70, "gftt": 0.72, "agast": 0.74}
    fakes = _table3(levels)
    rows = fakes.views["gftt__nms__none__rotation"]
    later = rows["image"].str[-3:].astype(int) >= 16
    rows.loc[later, "repeatability"] = 0.1  # new images must not move the pick
    picks = amended.picks_restated(_data(fakes), Data(None, {}, 0.05))
    assert picks["median_repeatability"] == "gftt" and picks["censure_or_msd"] is None
