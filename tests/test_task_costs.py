"""The full protocol's cost from measured per-task costs (orchestration/task_costs.py, preset_runs), hand-worked."""
import json

import pandas as pd
import pytest

from gtsweep.reproduction import rounds as preset_runs
from gtsweep.reproduction import task_costs


def _cell(out, descriptor, rows, detector="orb"):
    methods = dict(detector=detector, selector="nms", descriptor=descriptor, transform="incremental",
                   matcher="bf_ratio", estimator="ransac")
    key = f"{detector}__nms__{descriptor}__incremental"
    (out / "cells").mkdir(parents=True, exist_ok=True)
    (out / "cells" / f"{key}.json").write_text(json.dumps({"key": key, "methods": methods}))
    pd.DataFrame(rows).to_csv(out / "cells" / f"{key}.csv", index=False)


def _pairs(out, cpus=2):
    """Two pairs, v0 and v1 (a pair's test image is its view), detected once and described by ORB and SIFT."""
    for descriptor, t_describe in (("orb", 0.5), ("sift", 1.0)):
        _cell(out, descriptor, [dict(view=v, image=v, t_detect=t, t_describe=t_describe, t_match=0.1, t_pose=0.2)
                                for v, t in (("v0", 1.0), ("v1", 2.0))])
    (out / "run.json").write_text(json.dumps({"cluster": {"backend": "ray", "cpus": cpus}}))


def test_work_of_pairs_counts_each_detection_once_and_its_reference(tmp_path):
    _pairs(tmp_path)
    work = task_costs.work_seconds(task_costs.view_rows(tmp_path))
    # detection: test images 1 + 2, reference images (a pair's own, at its test image's cost) 1 + 2;
    # description: 2 views x (0.5 + 1.0); matching 4 x 0.1; pose 4 x 0.2
    assert work == pytest.approx({"detect": 6.0, "describe": 3.0, "match": 0.4, "pose": 0.8})


def test_a_synthetic_reference_is_detected_once_at_its_views_mean_cost(tmp_path):
    _cell(tmp_path, "orb", [dict(view="g/000/rotation/30", image="g/000", t_detect=1.0),
                            dict(view="g/000/rotation/60", image="g/000", t_detect=3.0)])
    rows = task_costs.view_rows(tmp_path)
    assert task_costs.work_seconds(rows)["detect"] == pytest.approx(1.0 + 3.0 + 2.0)
    assert task_costs.work_seconds(rows, skip={("orb", "g/000/rotation/30")})["detect"] == pytest.approx(3.0 + 3.0)


def test_only_the_task_work_scales():
    # 8 s of wall, 10.2 CPU-s of tasks on 2 CPUs (5.1 s): 2.9 s of other costs stay, the work grows 100/6 times
    assert task_costs.scaled_seconds(8.0, 10.2, 2, 100 / 6) == pytest.approx(2.9 + 10.2 * 100 / 6 / 2)
    assert task_costs.scaled_seconds(1.0, 10.0, 2, 2.0) == pytest.approx(10.0)  # work beyond the wall: no rest


def test_full_protocol_estimate_reuses_detections_of_an_earlier_preset_at_the_same_scale(tmp_path):
    four, five = tmp_path / "table4_incremental", tmp_path / "table5_absolute"
    _pairs(four)
    _pairs(five)  # the same views: their detections are in the keypoint cache after Table 4
    runs = [{"preset": p, "output": o, "wall_s": 8.0, "round": 1, "counts": [1, 6, 6]}
            for p, o in (("table5_absolute", five), ("table4_incremental", four))]
    table4 = 2.9 + 10.2 * 100 / 6 / 2
    table5 = (8.0 - 4.2 / 2) + 4.2 * 100 / 6 / 2  # 4.2 CPU-s without the 6 s of detection
    assert preset_runs.full_protocol_estimate(runs, "table4_incremental") == pytest.approx(table4)
    assert preset_runs.full_protocol_estimate(runs, "table5_absolute") == pytest.approx(table5)
    assert preset_runs.full_protocol_estimate(runs) == pytest.approx(table4 + table5)
