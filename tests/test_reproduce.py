"""The survey-finding checks of the reproduction, on hand-built cells with known verdicts."""
import pandas as pd

from gtsweep.reproduce_findings import check_findings


def _cells(rows):
    return pd.DataFrame([dict(zip(("detector", "selector", "descriptor", "transform", "status", "pose_success",
                                   "repeatability", "by_reference_count"), r)) for r in rows])


def test_findings_by_hand():
    frames = {
        # SIFT-SIFT 1.0 on both transforms beats AKAZE-BRIEF (mean 0.9): holds
        "table6_pairings": _cells([("sift", "nms", "sift", "rotation", "ok", 1.0, None, None),
                                   ("sift", "nms", "sift", "noise", "ok", 1.0, None, None),
                                   ("akaze", "nms", "brief", "rotation", "ok", 0.8, None, None),
                                   ("akaze", "nms", "brief", "noise", "ok", 1.0, None, None)]),
        # CenSurE-ORB 0.80 vs the best pairing 0.90: more than 0.02 behind, does not hold
        "table4_incremental": _cells([("censure", "nms", "orb", "incremental", "ok", 0.8, None, None),
                                      ("sift", "nms", "sift", "incremental", "ok", 0.9, None, None)]),
        # unoriented with BRIEF: mean (0.1 + 0.2) / 2 = 0.15 <= 0.2, holds (SURF descriptor ignored)
        "table5_absolute": _cells([("fast", "nms", "brief", "absolute", "ok", 0.1, None, None),
                                   ("gftt", "nms", "brief", "absolute", "ok", 0.2, None, None),
                                   ("fast", "nms", "surf", "absolute", "ok", 0.9, None, None)]),
        # SIFT: NMS 0.8 beats 0.5 and 0.7; MSER: ANMS 0.7 beats NMS 0.5: holds
        "table2_selectors": _cells([("sift", s, None, "rotation", "ok", None, r, None)
                                    for s, r in (("nms", 0.8), ("anms", 0.5), ("bucketing", 0.7))]
                                   + [("mser", s, None, "rotation", "ok", None, r, None)
                                      for s, r in (("nms", 0.5), ("anms", 0.7), ("bucketing", 0.6))]),
        # success 0.80 at 500 and 0.90 at 1500 features: gain 0.10 > 0.05, does not hold
        "table7_reference_features": _cells([("surf", "nms", "surf", "incremental", "ok", 0.85, None,
                                              {"500.0": {"pose_success": 0.8}, "1500.0": {"pose_success": 0.9}})]),
    }
    verdicts = [v for _, v, _ in check_findings(frames)]
    assert verdicts == ["holds", "does not hold", "holds", "holds", "does not hold"]
    assert [v for _, v, _ in check_findings({})] == ["not measured"] * 5
