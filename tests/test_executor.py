"""The executor both drivers run on: submission order, handles passed between tasks, failures as results, results
not held in memory, the shard builder, honest task statuses, and Ray giving the serial numbers bit for bit."""
from __future__ import annotations

import gc
import operator
import os
import weakref

import numpy as np
import pandas as pd
import pytest

from gtsweep.core.errors import BadInput, GtsweepError, NotApplicable
from gtsweep.evaluation.views import make_shard
from gtsweep.experiments.pairs import tasks
from gtsweep.experiments.pairs.runner import submit
from gtsweep.orchestration.executor import SerialExecutor, make_executor
from gtsweep.orchestration.shards import load_shards
from gtsweep.orchestration.tasks import failure


def test_serial_runs_in_submission_order_when_results_are_read():
    ran = []
    executor = SerialExecutor()
    for i in range(5):
        executor.submit(ran.append, i, tag=i if i % 2 else None)  # untagged tasks run too, in their turn
    assert ran == []  # nothing runs at submit
    assert [tag for tag, _ in executor.results()] == [1, 3]
    assert ran == [0, 1, 2, 3, 4] and not executor.queue


def test_handles_feed_later_tasks_and_tagged_results_come_out():
    executor = SerialExecutor()
    total = executor.submit(operator.add, 1, 2)
    executor.submit(operator.mul, total, 10, tag="product")
    quotient, remainder = executor.submit(divmod, 7, 3, num_returns=2, tag="divmod")  # tagged: the last return
    executor.submit(operator.add, quotient, remainder, tag="sum")
    assert list(executor.results()) == [("product", 30), ("divmod", 1), ("sum", 3)]


def test_a_crashed_task_is_an_error_result_and_so_are_the_tasks_it_feeds():
    executor = SerialExecutor()
    broken = executor.submit(operator.truediv, 1, 0, tag="broken")
    executor.submit(operator.add, broken, 1, tag="fed")
    executor.submit(operator.add, 1, 1, tag="fine")
    results = dict(executor.results())
    assert results["broken"]["error"].startswith("ZeroDivisionError: division by zero (at ")
    assert results["fed"] == results["broken"] and results["fine"] == 2


def test_serial_keeps_a_result_only_while_a_handle_needs_it():
    class Blob:
        pass

    made = []

    def make():
        blob = Blob()
        made.append(weakref.ref(blob))
        return blob

    executor = SerialExecutor()
    for i in range(3):
        blob = executor.submit(make)
        executor.submit(isinstance, blob, Blob, tag=i)
    del blob
    alive = []
    for _tag, result in executor.results():
        gc.collect()
        alive.append(sum(ref() is not None for ref in made))
        assert result is True
    assert alive == [0, 0, 0]  # each blob is gone once the task that needed it has run


def test_backend_is_checked():
    with pytest.raises(BadInput, match="runner.backend must be one of ray, serial, got 'dask'"):
        make_executor({"backend": "dask"})


def test_task_statuses_are_honest():
    assert failure(NotApplicable("needs oriented keypoints")) == {"na": "needs oriented keypoints"}
    assert failure(GtsweepError("detector 'x' is not available: no module")) == \
        {"error": "detector 'x' is not available: no module"}
    try:
        {}["missing"]
    except KeyError as e:
        assert failure(e)["error"].startswith("KeyError: 'missing' (at ")


class _Item:
    def __init__(self, name, image):
        self.id = self.texture = name
        self.load = lambda: image


class _Pair:
    def __init__(self, name, image):
        self.id = self.texture = name
        self.reference = self.test = _Item(name, image)
        self.H = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]


def test_the_driver_keeps_no_copy_of_a_shard_once_it_is_put():
    """With Ray the object store holds the shards' images: the driver's own copies go as each is put."""
    class Store:  # an executor whose put keeps only a token, as Ray's object store keeps the value elsewhere
        def put(self, value):
            return ("ref", len(value["items"]))

    images = [np.zeros((8, 8), np.uint8) for _ in range(3)]
    alive = [weakref.ref(image) for image in images]
    shards = {"synthetic": [{"items": [{"image": image}]} for image in images]}
    del images
    assert submit(Store(), None, shards, [], seed=0, cache_dir=None) == 0
    gc.collect()
    assert shards == {"synthetic": [("ref", 1)] * 3} and [ref() for ref in alive] == [None] * 3


class _Dataset:
    name = "fake"

    def __init__(self, image):
        self.image = image

    def images(self, split):
        return [_Item(f"{split}{i}", self.image) for i in range(3 if split == "synthetic" else 1)]

    def pairs(self, split):
        return [] if split == "absolute" else [_Pair(f"{split}{i}", self.image) for i in range(2)]


def test_one_shard_builder_for_the_sweep_and_the_optimiser(gravel_small):
    dataset = _Dataset(gravel_small)
    transforms = {"rotation": {"kind": "synthetic", "strengths": [0]}, "incremental": {"kind": "pairs"}}
    sweep = load_shards(dataset, transforms, shard_size=2)
    assert {k: [len(s["items"]) for s in v] for k, v in sweep.items()} == {"incremental": [2], "synthetic": [2, 1]}
    optimiser = load_shards(dataset, {"rotation": transforms["rotation"]}, images="optimisation")
    assert [[item["id"] for item in s["items"]] for s in optimiser["synthetic"]] == [["optimisation0"]]
    with pytest.raises(BadInput, match="no absolute images"):
        load_shards(dataset, {"absolute": {"kind": "pairs"}})


def _graph(executor, image) -> list:
    """A detection task feeding two pairing tasks, on two shards; the results in submission order."""
    transform_cfg = {"kind": "synthetic", "strengths": [0, 30]}
    method = {"detector": "orb", "detector_cfg": {"params": {}}, "selector": "nms",
              "selector_cfg": {"params": {"n": 300}}}
    experiment = {"name": "pose", "iou_threshold": 0.5, "min_keypoints": 100, "ratio": 0.7,
                  "pose": {"model": "similarity", "iterations": 500, "threshold": 3.0, "max_position_error": 30.0,
                           "max_orientation_error": 1.5}}
    tags = []
    for i, crop in enumerate((image[:200, :200], image[20:220, 40:240])):
        shard = executor.put(make_shard("synthetic", [{"id": f"crop{i}", "texture": "gravel", "image": crop}]))
        payload, _ = executor.submit(tasks.detect_shard, shard, "rotation", transform_cfg, method, experiment, 0,
                                     None, num_returns=2, tag=("detect", i))
        tags.append(("detect", i))
        for descriptor in ("brief", "orb"):
            executor.submit(tasks.pair_shard, shard, "rotation", transform_cfg, payload, "orb", descriptor, {},
                            experiment, 0, tag=(descriptor, i))
            tags.append((descriptor, i))
    results = dict(executor.results())
    assert sorted(results) == sorted(tags)
    frames = []
    for tag in tags:
        result = results[tag] if tag[0] == "detect" else results[tag]["by_method"][("bf_ratio", "ransac")]
        rows = pd.DataFrame(result["rows"])
        frames.append(rows[[c for c in rows.columns if not c.startswith("t_")]])
    return frames


@pytest.mark.slow
def test_ray_gives_the_serial_numbers_and_crashes_become_error_results(gravel_small):
    ray = pytest.importorskip("ray")
    serial = _graph(SerialExecutor(), gravel_small)
    executor = make_executor({"backend": "ray", "num_cpus": 2}, retries=0)
    try:
        on_ray = _graph(executor, gravel_small)
        total = executor.submit(operator.add, 1, 2)
        executor.submit(operator.mul, total, 10, tag="product")
        broken = executor.submit(operator.truediv, 1, 0, tag="broken")
        executor.submit(operator.add, broken, 1, tag="fed")
        executor.submit(os._exit, 1, tag="crashed")  # the worker process dies
        results = dict(executor.results())
    finally:
        ray.shutdown()
    for ours, theirs in zip(serial, on_ray, strict=True):
        assert len(ours) > 0
        pd.testing.assert_frame_equal(ours, theirs, check_exact=True)
    assert results["product"] == 30
    assert results["broken"]["error"].startswith("ZeroDivisionError: division by zero")
    assert "error" in results["fed"] and results["crashed"]["error"].startswith("Ray task failed")
