"""The sweep end to end: detection reuse and caching, kill and resume, a two-node Ray cluster, the CLI."""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gtsweep.experiments.kinds import run_sweep
from gtsweep.orchestration import cache
from sweep_helpers import assert_same_cells, cli_env, compose_config, run_cli, tiny_overrides

SERIAL = "runner.backend=serial"


def _count_detections(monkeypatch) -> list:
    calls = []
    original = cache.detect_raw

    def counting(image, mask, detector, *args):
        calls.append((image.tobytes(), None if mask is None else mask.tobytes(), detector, *map(repr, args)))
        return original(image, mask, detector, *args)

    monkeypatch.setattr(cache, "detect_raw", counting)
    return calls


@pytest.mark.slow
def test_detection_is_computed_once_and_cached(tmp_path, monkeypatch):
    calls = _count_detections(monkeypatch)
    grid = ["detector=[akaze,censure]", "descriptor=[brief,latch,orb,sift]", "selector=[nms,none]",
            "transform=[incremental,rotation]", "transform.rotation.strengths=[0,90]", "mlflow.enabled=false"]
    cfg = compose_config(tiny_overrides(tmp_path, SERIAL, *grid))
    first = run_sweep(cfg, tmp_path / "run1")
    # every (image, mask, detector) detected exactly once, however many selectors and descriptors use it
    assert len(calls) == len(set(calls)) > 0 and first.stats.cache_misses == 2 * len(calls)
    assert all(s["status"] == "ok" for s in first.summaries)
    assert len(first.summaries) == 2 * 2 * 4 * 2
    calls.clear()
    second = run_sweep(cfg, tmp_path / "run2")  # same detections, new output directory
    assert calls == [] and second.stats.cache_misses == 0 and second.stats.cache_hits >= first.stats.cache_misses
    assert_same_cells(tmp_path / "run1", tmp_path / "run2")


def test_na_is_only_the_pairing_rule_and_run_time_failures_are_errors(tmp_path, monkeypatch):
    import cv2

    from gtsweep.stages.describe import DESCRIPTORS

    class Rejecting:  # an extractor that OpenCV builds but that fails when it runs, as some parameters do
        def descriptorSize(self):
            return 32

        def compute(self, image, keypoints):
            raise cv2.error("OpenCV(5.0.0) latch.cpp:1: error: (-215:Assertion failed) half_ssd_size in 'compute'")

    latch = DESCRIPTORS.get("latch")
    monkeypatch.setitem(DESCRIPTORS._methods, "latch", dataclasses.replace(latch, create=lambda **p: Rejecting()))
    grid = ["detector=[censure]", "descriptor=[akaze,daisy,brief,latch]", "selector=[nms]",
            "transform=[incremental]", "mlflow.enabled=false"]
    outcome = run_sweep(compose_config(tiny_overrides(tmp_path, SERIAL, *grid)), tmp_path / "run")
    status = {s["methods"]["descriptor"]: (s["status"], s.get("reason") or "") for s in outcome.summaries}
    # NA: the survey's pairing rules; error: OpenCV rejects the method when it runs, with OpenCV's reason
    assert status["akaze"][0] == status["daisy"][0] == "na" and "orientation" in status["daisy"][1]
    assert status["brief"][0] == "ok"
    assert status["latch"][0] == "error" and "(-215:Assertion failed) half_ssd_size" in status["latch"][1]
    assert "\n" not in status["latch"][1]
    assert outcome.failed == [s["key"] for s in outcome.summaries if s["methods"]["descriptor"] == "latch"]
    results = (tmp_path / "run" / "results.csv").read_text()
    assert "only describes AKAZE keypoints" in results


def test_rejected_parameter_stops_before_any_result_file(tmp_path):
    from gtsweep.core.errors import BadInput

    grid = ["detector=[censure]", "descriptor=[latch]", "transform=[incremental]", "mlflow.enabled=false",
            "descriptor.latch.params.bytes=3"]
    with pytest.raises(BadInput, match=r"descriptor 'latch' rejects bytes=3: \(-5:Bad argument\) descriptorSize"):
        run_sweep(compose_config(tiny_overrides(tmp_path, SERIAL, *grid)), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_unavailable_method_stops_before_any_result_file(tmp_path, monkeypatch):
    from gtsweep.core.errors import GtsweepError
    from gtsweep.stages.describe import DESCRIPTORS

    def not_installed(**params):
        raise ImportError("No module named 'nonfree_sift'")

    missing = dataclasses.replace(DESCRIPTORS.get("sift"), create=not_installed)
    monkeypatch.setitem(DESCRIPTORS._methods, "sift", missing)
    grid = ["detector=[censure]", "descriptor=[brief,sift]", "transform=[incremental]", "mlflow.enabled=false"]
    with pytest.raises(GtsweepError, match="descriptor 'sift' is not available: No module named 'nonfree_sift'"):
        run_sweep(compose_config(tiny_overrides(tmp_path, SERIAL, *grid)), tmp_path / "run")
    assert not (tmp_path / "run").exists()


_CLUSTER_RUN = """
import sys
import ray
from ray.cluster_utils import Cluster
from sweep_helpers import compose_config, tiny_overrides
from gtsweep.experiments.kinds import run_sweep
from pathlib import Path

tmp, grid = Path(sys.argv[1]), sys.argv[2:]
cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
cluster.add_node(num_cpus=1)
try:
    cfg = compose_config(tiny_overrides(tmp, "runner.backend=ray", f"runner.address={cluster.address}",
                                        f"cache.dir={tmp}/cache-cluster", *grid))
    outcome = run_sweep(cfg, tmp / "cluster")
    print(len({n["NodeID"] for n in ray.nodes() if n["Alive"]}), outcome.stats.cache_misses)
finally:
    ray.shutdown()
    cluster.shutdown()
"""


@pytest.mark.slow
@pytest.mark.xdist_group("real_ray_heads")  # with test_cluster's: one real head at a time
def test_ray_two_node_cluster_gives_the_same_numbers_as_serial(tmp_path):
    pytest.importorskip("ray")
    grid = ["detector=[akaze,sift]", "descriptor=[brief,sift]", "selector=[nms]", "transform=[absolute]",
            "mlflow.enabled=false"]
    serial = run_sweep(compose_config(tiny_overrides(tmp_path, SERIAL, *grid)), tmp_path / "serial")
    # in a process of its own: Ray 2.60 cannot join a cluster in a process that has run Ray before
    # Ray's test cluster starts its nodes without token authentication, where `ray start` enables it whenever
    # ~/.ray/auth_token exists (every local Ray start writes one): its mode said explicitly, as its users say it
    env = {**cli_env(), "PYTHONPATH": os.pathsep.join([cli_env()["PYTHONPATH"], str(Path(__file__).parent)]),
           "RAY_AUTH_MODE": "disabled"}
    done = subprocess.run([sys.executable, "-c", _CLUSTER_RUN, str(tmp_path), *grid], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    nodes, misses = map(int, done.stdout.split()[-2:])
    assert nodes == 2 and misses == serial.stats.cache_misses
    assert_same_cells(tmp_path / "serial", tmp_path / "cluster")


def test_joining_another_cluster_after_ray_ran_is_one_line(monkeypatch):
    ray = pytest.importorskip("ray")
    from gtsweep.core.errors import BadInput
    from gtsweep.orchestration.executor import connect

    monkeypatch.setattr(ray, "is_initialized", lambda: True)
    context = type("Context", (), {"gcs_address": "127.0.0.1:6379"})()
    monkeypatch.setattr(ray, "get_runtime_context", lambda: context)
    connect({"address": "local"})  # the Ray already running serves
    with pytest.raises(BadInput, match="already ran Ray .* run the sweep in a new process"):
        connect({"address": "10.0.0.9:6379"})


@pytest.mark.slow
def test_killed_sweep_resumes_to_the_same_numbers(tmp_path):
    grid = ["detector=[akaze,censure,orb,sift]", "descriptor=[brief,latch,sift]", "selector=[nms]",
            "transform=[incremental]", "mlflow.enabled=false", "runner.num_cpus=1"]
    args = tiny_overrides(tmp_path, *grid)
    # the uninterrupted reference in this process, serially (no second Ray start; Ray and serial agree bit for bit)
    reference = [a for a in tiny_overrides(tmp_path, SERIAL, *grid) if not a.startswith("cache.dir=")]
    run_sweep(compose_config([*reference, f"cache.dir={tmp_path}/cache0"]), tmp_path / "uninterrupted")
    victim = subprocess.Popen([sys.executable, "-m", "gtsweep", *args, f"cache.dir={tmp_path}/cache1"],
                              cwd=tmp_path, env=cli_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    deadline = time.time() + 240
    cells = []
    while time.time() < deadline and victim.poll() is None:
        cells = list(tmp_path.glob("outputs/*/*/cells/*.json"))
        if cells:  # kill at the first cell: a loaded machine can write the others in one burst
            break
        time.sleep(0.05)
    assert victim.poll() is None, "the sweep finished before it could be killed: make the grid larger"
    os.killpg(victim.pid, signal.SIGKILL)
    victim.wait()
    killed_dir = cells[0].parent.parent
    partial = len(list((killed_dir / "cells").glob("*.json")))
    assert 1 <= partial < 12
    resumed = run_cli([*args, f"cache.dir={tmp_path}/cache1", "resume=true"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    record = json.loads((killed_dir / "run.json").read_text())
    assert record["resumed_cells"] == partial
    assert_same_cells(tmp_path / "uninterrupted", killed_dir)


def test_cli_bad_input_is_one_line(tmp_path):
    result = run_cli(["detector=[sift,surff]"], tmp_path)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "unknown detector 'surff'" in result.stderr
    assert not (tmp_path / "outputs").exists()


@pytest.mark.slow
def test_glob_splits_jobs_and_outer_sweeps_work(tmp_path):
    grid = ["descriptor=[brief]", "selector=[nms]", "transform=[incremental]", "mlflow.enabled=false",
            "runner.backend=serial", "report.plots=false", "dataset.textures=[gravel]"]  # one texture: the jobs count
    result = run_cli(["-m", *tiny_overrides(tmp_path, *grid), "detector=glob(a*,exclude=aliked*)", "seed=0,1",
                      f"hydra.sweep.dir={tmp_path}/multi"], tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    jobs = sorted(p.parent.name for p in (tmp_path / "multi").glob("*/results.csv"))
    assert jobs == ["0", "1", "2", "3"]  # {agast, akaze} x {seed 0, 1}, one Hydra job each
    detectors = {(tmp_path / "multi" / j / "results.csv").read_text().splitlines()[1].split(",")[0] for j in jobs}
    assert detectors == {"agast", "akaze"}


@pytest.mark.slow
def test_corrupt_image_stops_before_any_result_file(tmp_path, existing_store):
    import dataset_fixtures as fx

    existing_store(tmp_path / "mlflow.db", tmp_path)  # made once per session: this test is about the data set
    database = fx.microgps(tmp_path / "data")
    image = database.parent / database.read_text().splitlines()[4]
    image.write_bytes(b"garbage")
    args = ["dataset=microgps", f"dataset.root={tmp_path / 'data'}", "dataset.n_incremental=100",
            "dataset.n_absolute=1", "dataset.absolute_min_gap=4", "dataset.n_synthetic=0", "dataset.n_optimisation=0",
            "detector=[censure]", "descriptor=[brief,akaze]", "transform=[incremental]", "runner.backend=serial",
            f"mlflow.tracking_uri=sqlite:///{tmp_path}/mlflow.db", f"cache.dir={tmp_path}/cache"]
    result = run_cli(args, tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(image) in lines[0] and "cannot read image" in lines[0], result.stderr
    assert not list(tmp_path.glob("outputs/*/*/cells")) and not list(tmp_path.glob("outputs/*/*/results.csv"))
    skipped = run_cli([*args, "dataset.skip_bad=true"], tmp_path)
    assert skipped.returncode == 0, skipped.stderr[-1500:]
    assert "1 bad item(s) skipped" in skipped.stdout


def test_the_xfeat_column_runs_the_network_once_per_image_with_the_same_results(tmp_path, monkeypatch):
    """A pairing table's XFeat column over two detectors: with the cache on, each image's dense map is computed
    once (by the first detector's task) and read by the other's; the results equal a run without the cache."""
    from gtsweep.stages import xfeat

    calls = []
    network = xfeat.run_network
    monkeypatch.setattr(xfeat, "run_network", lambda *a, **k: calls.append(1) or network(*a, **k))
    grid = [SERIAL, "detector=[fast,censure]", "descriptor=[xfeat]", "selector=[nms]", "transform=[incremental]",
            "mlflow.enabled=false"]
    run_sweep(compose_config(tiny_overrides(tmp_path / "a", *grid)), tmp_path / "a" / "run")
    images = 2 * 2 * 2  # 2 textures x 2 incremental pairs x 2 images
    assert len(calls) == images and len(list((tmp_path / "a" / "cache" / "dense").rglob("*.npz"))) == images
    del calls[:]
    run_sweep(compose_config(tiny_overrides(tmp_path / "b", *grid, "cache.enabled=false")), tmp_path / "b" / "run")
    assert len(calls) == 2 * images  # once per image and detector
    assert_same_cells(tmp_path / "a" / "run", tmp_path / "b" / "run")
