"""Resume on a grown data set (gtsweep/orchestration/view_reuse.py): a sweep at n images and pairs per texture, then
at 2n in the same directory, evaluates only the n new ones per cell; the first n rows are the n-run's; the result
equals a run at 2n from scratch, bit for bit; anything that changes the numbers (a cell's configuration, the seed,
an image's bytes) stops the reuse."""
import json
from collections import Counter

import cv2
import pandas as pd
import pytest

import gtsweep.evaluation.evaluate as evaluate
from gtsweep.datasets import load_dataset
from gtsweep.experiments.kinds import run_sweep
from sweep_helpers import assert_same_cells, compose_config, tiny_overrides

BASE = ["runner.backend=serial", "mlflow.enabled=false", "detector=[orb]", "descriptor=[brief]", "selector=[nms]",
        "transform=[rotation,incremental]", "transform.rotation.strengths=[0,45]", "experiment=pose",
        "runner.shard_size=3"]  # shards of 3 cut n = 2 and n = 4 per texture differently


def _counts(n: int) -> list[str]:
    return [f"dataset.n_synthetic={n}", f"dataset.n_incremental={n}", "dataset.n_absolute=1"]


@pytest.fixture
def evaluated(monkeypatch):
    """Every view the evaluation computes, per (transform, experiment stage): detection and pairing."""
    seen = Counter()
    original = evaluate.views

    def counting(shard, transform, transform_cfg, seed):
        for meta, view in original(shard, transform, transform_cfg, seed):
            seen[transform, meta["image"]] += 1
            yield meta, view

    monkeypatch.setattr(evaluate, "views", counting)
    return seen


def _sweep(tmp_path, out, n, *extra):
    outcome = run_sweep(compose_config(tiny_overrides(tmp_path, *BASE, *_counts(n), *extra)), tmp_path / out)
    return json.loads((tmp_path / out / "run.json").read_text()), outcome


def test_a_grown_data_set_evaluates_only_its_new_images_and_equals_a_run_from_scratch(tmp_path, evaluated):
    small, _ = _sweep(tmp_path, "grow", 2)
    first = {p.stem: pd.read_csv(p) for p in (tmp_path / "grow" / "cells").glob("*.csv")}
    assert small["items_evaluated"] == 2 * 2 * 2 and small["items_reused"] == 0  # 2 cells x 2 textures x 2
    before = set(evaluated)
    evaluated.clear()
    grown, outcome = _sweep(tmp_path, "grow", 4)
    # 2 cells x 2 textures x 2 new images or pairs; the old ones' rows kept
    assert grown["items_evaluated"] == 8 and grown["items_reused"] == 8 and outcome.resumed == 0
    images = {image for _, image in evaluated}
    assert len(images) == 8 and not images & {image for _, image in before}
    # each new view computed once for detection and once for the pairing: 2 strengths x 4 new images + 4 new pairs
    assert sum(evaluated.values()) == 2 * (2 * 4 + 4)
    for key, rows in first.items():  # the n-run's rows, verbatim (their timings too), first in each cell
        grown_rows = pd.read_csv(tmp_path / "grow" / "cells" / f"{key}.csv")
        kept = grown_rows[grown_rows["image"].isin(set(rows["image"]))].reset_index(drop=True)
        pd.testing.assert_frame_equal(kept, rows, check_exact=True)
        assert len(grown_rows) == 2 * len(rows)
    evaluated.clear()
    scratch, _ = _sweep(tmp_path, "scratch", 4)
    assert scratch["items_evaluated"] == 16 and sum(evaluated.values()) == 2 * (2 * 8 + 8)
    assert_same_cells(tmp_path / "grow", tmp_path / "scratch")  # rows: every number but the timings
    for key in first:
        ours, theirs = (json.loads((tmp_path / d / "cells" / f"{key}.json").read_text()) for d in ("grow", "scratch"))
        assert ours["hash"] == theirs["hash"] and ours["n_images"] == theirs["n_images"] == 8
        same = {m: v for m, v in ours["metrics"].items() if not m.startswith("t_")}
        assert same == {m: v for m, v in theirs["metrics"].items() if not m.startswith("t_")}
    # the same count again: every cell complete, kept whole (the resume as before)
    _, again = _sweep(tmp_path, "grow", 4)
    assert again.resumed == 2


def test_a_changed_configuration_seed_or_image_is_evaluated_again(tmp_path):
    _sweep(tmp_path, "run", 2)
    record, _ = _sweep(tmp_path, "run", 2, "seed=1")
    assert record["items_reused"] == 0 and record["items_evaluated"] == 8
    record, _ = _sweep(tmp_path, "run", 2, "seed=1", "selector.nms.params.n=300")
    assert record["items_reused"] == 0
    # one image of the grown data set differs from the image of the same id before: only it is evaluated again
    cfg = compose_config(tiny_overrides(tmp_path, *BASE, *_counts(3), "seed=1", "selector.nms.params.n=300"))
    dataset = load_dataset(cfg["dataset"])
    changed = dataset.images("synthetic")[0]
    cv2.imwrite(changed.path, 255 - changed.load())
    record, _ = _sweep(tmp_path, "run", 3, "seed=1", "selector.nms.params.n=300")
    # rotation: 4 kept, the changed one and 2 new evaluated; incremental: 4 kept, 2 new
    assert record["items_reused"] == 3 + 4 and record["items_evaluated"] == 3 + 2
