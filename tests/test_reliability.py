"""Issue 14, the fast cases: nothing lost, nothing mixed, nothing silently wrong.

Damaged or swapped keypoint cache entries are misses (removed, recomputed, counted); a cache that cannot be written
runs uncached; failed cells are recomputed on resume; an unreachable tracking server or Ray address and an
unwritable output directory are one line and exit 2 before any work; results.csv keeps its column order; a dead
renderer's temporary folder is cleaned up; CSV values are reported as values; files respect the umask.
"""
from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import BadInput
from gtsweep.experiments.kinds import run_sweep
from gtsweep.orchestration import cache
from gtsweep.orchestration.results import ResultStore, summary_table
from sweep_helpers import assert_same_cells, compose_config, run_cli, tiny_overrides

SMALL = ["detector=[orb]", "descriptor=[orb]", "selector=[nms]", "transform=[incremental]", "runner.backend=serial",
         "mlflow.enabled=false", "report.plots=false"]


def _entries(directory: Path) -> list[Path]:
    return sorted(directory.rglob("*.npz"))


# ------------------------------------------------------------------------------------------------ item 4: cache
def _fill(tmp_path: Path):
    """A sweep that fills the cache; returns its config and outcome."""
    cfg = compose_config(tiny_overrides(tmp_path, *SMALL))
    first = run_sweep(cfg, tmp_path / "run0")
    assert first.stats.cache_misses > 0 and _entries(tmp_path / "cache")
    return cfg, first


@pytest.mark.parametrize("damage", ["truncated", "empty", "bit-flipped", "swapped"])
def test_a_damaged_cache_entry_is_a_miss_removed_recomputed_and_counted(tmp_path, damage):
    cfg, first = _fill(tmp_path)
    entries = [e for e in _entries(tmp_path / "cache") if not e.stem.startswith("raw-")]  # selected detections
    victim = entries[0]
    data = victim.read_bytes()
    if damage == "truncated":
        victim.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        victim.write_bytes(b"")
    elif damage == "bit-flipped":  # inside the compressed keypoints
        flipped = bytearray(data)
        flipped[len(data) // 2] ^= 0x10
        victim.write_bytes(bytes(flipped))
    else:  # a valid entry of another detection copied over this one
        victim.write_bytes(entries[1].read_bytes())
    second = run_sweep(cfg, tmp_path / "run1")
    assert second.stats.cache_corrupt == 1 and second.stats.cache_misses == 1
    assert_same_cells(tmp_path / "run0", tmp_path / "run1")
    record = json.loads((tmp_path / "run1" / "run.json").read_text())
    assert record["cache_corrupt"] == 1
    with np.load(victim) as entry:  # rewritten whole, for the key it is filed under
        assert str(entry["key"]) == victim.stem
    third = run_sweep(cfg, tmp_path / "run2")
    assert third.stats.cache_corrupt == 0 and third.stats.cache_misses == 0


def test_an_entry_that_loads_but_fails_its_checksum_is_a_miss(tmp_path):
    store = cache.KeypointCache(tmp_path)
    key = "ab" * 32
    store.put(key, np.arange(14, dtype=np.float32).reshape(2, 7), 2, 0.5)
    path = _entries(tmp_path)[0]
    with np.load(path) as entry:
        fields = dict(entry)
    fields["keypoints"] = fields["keypoints"] + 1  # silently changed numbers, a well-formed file
    with open(path, "wb") as f:
        np.savez(f, **fields)
    fresh = cache.KeypointCache(tmp_path)
    assert fresh.get(key) is None and fresh.corrupt == 1 and fresh.misses == 1 and not path.exists()


def test_an_unwritable_cache_runs_uncached_with_one_warning(tmp_path, capsys):
    if os.geteuid() == 0:  # root writes anywhere: a place no one can create a folder in
        directory = Path("/proc/gtsweep-cache")
    else:
        directory = tmp_path / "readonly"
        directory.mkdir()
        directory.chmod(0o555)
    cfg = compose_config(tiny_overrides(tmp_path, *SMALL, f"cache.dir={directory}"))
    outcome = run_sweep(cfg, tmp_path / "run")
    assert [s["status"] for s in outcome.summaries] == ["ok"]
    warnings = [line for line in capsys.readouterr().err.splitlines() if "keypoint cache" in line]
    assert len(warnings) == 1 and "without a keypoint cache" in warnings[0], warnings
    assert json.loads((tmp_path / "run" / "run.json").read_text())["cache"].startswith("off")


def _full_disk(monkeypatch) -> list:
    """Every cache write fails as on a full disk; the paths tried."""
    calls = []

    def broken(path, content):
        calls.append(path)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(cache, "write_atomically", broken)
    return calls


def test_a_failed_write_turns_the_cache_off_for_the_rest_of_the_task(tmp_path, monkeypatch):
    keypoints = np.zeros((3, 7), np.float32)
    store = cache.KeypointCache(tmp_path / "c")
    calls = _full_disk(monkeypatch)
    store.put("ab" * 32, keypoints, 3, 0.1)
    store.put("cd" * 32, keypoints, 3, 0.1)
    assert len(calls) == 1 and store.write_errors == 1
    assert store.get("cd" * 32)[1] == 3  # still served from memory


def test_failed_cells_are_recomputed_on_resume(tmp_path):
    store = ResultStore(tmp_path)
    summary = {"key": "a", "methods": {}, "hash": "h", "experiment": "pose", "status": "error", "reason": "boom"}
    store.write_cell("a", summary, None)
    assert store.complete("a", "h") is None
    store.write_cell("a", {**summary, "status": "na", "reason": "rule"}, None)
    assert store.complete("a", "h")["status"] == "na"


@pytest.mark.slow
def test_a_failed_cell_is_computed_again_and_logged_once(tmp_path, monkeypatch, existing_store):
    """Resume recomputes a cell that ended in error; MLflow keeps one child per cell, the new one."""
    import dataclasses

    from gtsweep.orchestration.cache import library_versions
    from gtsweep.stages.describe import DESCRIPTORS
    from gtsweep.tracking.sweep import SweepTracker

    uri = existing_store(tmp_path / "m.db", tmp_path)  # the store as an earlier sweep left it

    def sweep():
        cfg = compose_config(tiny_overrides(tmp_path, *SMALL[:-2], f"mlflow.tracking_uri={uri}"))
        tracker = SweepTracker(cfg.mlflow, tmp_path / "run", "config: yes", "run")
        outcome = run_sweep(cfg, tmp_path / "run", hooks=(tracker.log_cell,), on_checked=tracker.open,
                            on_start=lambda grid, fp: tracker.start(grid, fp, library_versions()))
        tracker.end(outcome)
        children = tracker.client.search_runs([tracker.experiment_id],
                                              f"tags.mlflow.parentRunId = '{tracker.parent_id}'")
        return outcome, [c.data.tags["gtsweep.status"] for c in children]

    orb = DESCRIPTORS.get("orb")
    with monkeypatch.context() as patch:  # OpenCV failing at run time: the cell ends in error
        patch.setitem(DESCRIPTORS._methods, "orb", dataclasses.replace(orb, create=lambda **p: None))
        failed, logged = sweep()
    assert [s["status"] for s in failed.summaries] == ["error"] and logged == ["error"]
    again, logged = sweep()
    assert again.resumed == 0 and [s["status"] for s in again.summaries] == ["ok"] and logged == ["ok"]


# ------------------------------------------------------------------------------- item 2: one directory per run
def test_runs_started_in_the_same_second_get_their_own_directory(tmp_path, monkeypatch):
    from gtsweep.core.rundirs import new_dir

    monkeypatch.chdir(tmp_path)
    assert [new_dir("outputs/day/10-00-00") for _ in range(3)] == \
        ["outputs/day/10-00-00", "outputs/day/10-00-00-2", "outputs/day/10-00-00-3"]


def test_a_directory_in_use_stops_a_second_run_with_one_line(tmp_path):
    import fcntl

    busy = tmp_path / "busy"
    busy.mkdir()
    with open(busy / ".gtsweep.lock", "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # as a running sweep holds it
        result = run_cli([*SMALL, f"hydra.run.dir={busy}"], tmp_path, timeout=60)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "another gtsweep run is writing to" in lines[0], lines
    assert sorted(p.name for p in busy.iterdir()) == [".gtsweep.lock"]  # nothing of the run written


# ------------------------------------------------------------------------------- item 6: unreachable services
def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_tracking_server_is_one_line_in_seconds(tmp_path):
    from gtsweep.tracking.store import open_store

    start = time.perf_counter()
    with pytest.raises(BadInput, match="cannot reach the MLflow tracking server"):
        open_store({"tracking_uri": f"http://127.0.0.1:{_closed_port()}", "timeout_s": 2}, "gtsweep")
    assert time.perf_counter() - start < 5


def test_silent_tracking_server_times_out(tmp_path):
    """A server that accepts the connection but never answers costs ``mlflow.timeout_s``, not minutes."""
    from gtsweep.tracking.store import open_store

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        start = time.perf_counter()
        with pytest.raises(BadInput, match="cannot reach"):
            open_store({"tracking_uri": f"http://127.0.0.1:{server.getsockname()[1]}", "timeout_s": 1}, "gtsweep")
        assert time.perf_counter() - start < 4


def test_unreachable_ray_address_is_one_line_in_seconds():
    from gtsweep.orchestration.executor import check_address

    start = time.perf_counter()
    with pytest.raises(BadInput, match=r"cannot reach the Ray cluster at '127\.0\.0\.1:\d+'"):
        check_address({"address": f"127.0.0.1:{_closed_port()}", "connect_timeout_s": 2})
    assert time.perf_counter() - start < 5
    check_address({"address": "local"})  # nothing to reach


def _stops_at_once(tmp_path, override: str, what: str) -> None:
    start = time.perf_counter()
    result = run_cli([*tiny_overrides(tmp_path, *SMALL[:-2]), "report.plots=false", *override.split()], tmp_path,
                     timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and what in lines[0], result.stderr[-2000:]
    assert time.perf_counter() - start < 30
    assert not list(tmp_path.glob("outputs/*/*/cells")) and not (tmp_path / "data").exists()  # no work done


@pytest.mark.slow
def test_cli_unreachable_tracking_server_stops_before_any_work(tmp_path):
    _stops_at_once(tmp_path, f"mlflow.tracking_uri=http://127.0.0.1:{_closed_port()} mlflow.timeout_s=2",
                   "cannot reach the MLflow tracking server")


@pytest.mark.slow
def test_cli_unreachable_ray_address_stops_before_the_parent_run(tmp_path):
    import mlflow

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    _stops_at_once(tmp_path, f"runner.backend=ray runner.address=127.0.0.1:{_closed_port()} mlflow.enabled=true "
                             f"mlflow.tracking_uri={uri}", "cannot reach the Ray cluster")
    if (tmp_path / "mlflow.db").exists():
        assert len(mlflow.MlflowClient(uri).search_runs(["0"])) == 0


# ----------------------------------------------------------------------------- item 7: unwritable output dir
@pytest.mark.parametrize("flag", ["", "-m"])
def test_unwritable_output_directory_is_one_line(tmp_path, flag):
    key = "hydra.sweep.dir" if flag else "hydra.run.dir"
    result = run_cli([*([flag] if flag else []), *SMALL, f"{key}=/proc/forbidden/run"], tmp_path, timeout=60)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr[-2000:]
    assert lines[0].startswith("gtsweep: error: cannot write the output directory /proc/forbidden/run")


# ------------------------------------------------------------------------------------------- item 8: smaller
def test_results_columns_keep_their_order_after_a_resume():
    fresh = {"methods": {"detector": "orb", "selector": "nms", "descriptor": "orb", "transform": "incremental"},
             "status": "ok", "metrics": {"pose_success": 1.0, "repeatability": 0.5}}
    reloaded = json.loads(json.dumps(fresh, sort_keys=True))  # as a kept cell's JSON comes back
    na = {"methods": {"descriptor": "sift", "detector": "akaze", "selector": "nms", "transform": "absolute"},
          "status": "na", "reason": "rule"}
    for order in ([fresh, na], [reloaded, na], [na, reloaded]):
        columns = list(summary_table(order).columns)
        assert columns[:6] == ["detector", "selector", "descriptor", "transform", "status", "reason"]
        assert columns.index("repeatability") < columns.index("pose_success")  # the schema's order


def test_leftovers_of_a_killed_renderer_are_removed(tmp_path):
    from gtsweep.datasets import synthetic

    code = ("import sys, time\n"
            "from gtsweep.datasets import synthetic\n"
            "synthetic.render_texture = lambda *a: time.sleep(60)\n"
            "synthetic.load({'cache_dir': sys.argv[1], 'textures': ['gravel'], 'view_size': [64, 48]})\n")
    child = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], env={**os.environ})
    datasets = tmp_path / "datasets"
    deadline = time.time() + 60
    while time.time() < deadline and not (datasets.exists() and any(datasets.glob(".synthetic-*"))):
        time.sleep(0.1)
    child.kill()
    child.wait()
    assert len(list(datasets.glob(".synthetic-*"))) == 1  # what a killed renderer leaves
    options = {"cache_dir": str(tmp_path), "textures": ["gravel"], "view_size": [64, 48], "n_optimisation": 1,
               "n_synthetic": 1, "n_incremental": 1, "n_absolute": 1}
    synthetic.load(options)
    assert list(datasets.glob(".synthetic-*")) == [] and len(list(datasets.glob("synthetic-*"))) == 1


def test_a_bad_value_in_the_first_csv_row_is_a_bad_value(tmp_path):
    import dataset_fixtures as fx
    from gtsweep.datasets import load_dataset

    file = fx.csv_poses(tmp_path)
    lines = file.read_text().splitlines()
    cells = lines[1].split(",")
    cells[1] = "12x"  # no header: the first row is data with one bad value
    file.write_text("\n".join([",".join(cells), *lines[2:]]) + "\n")
    with pytest.raises(BadInput, match=f"{file}:1: x, y, theta, scale must be finite numbers"):
        load_dataset({"loader": "csv", "root": str(file)})
    file.write_text("\n".join(["image,x,y,angle", *lines[1:]]) + "\n")  # a real header with a typo
    with pytest.raises(BadInput, match=f"{file}:1: header must start with image,x,y,theta"):
        load_dataset({"loader": "csv", "root": str(file)})


def test_files_we_write_respect_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_atomically(tmp_path / "a.json", "{}")
        store = cache.KeypointCache(tmp_path / "cache")
        store.put("ab" * 32, np.zeros((1, 7), np.float32), 1, 0.0)
        os.umask(0o027)
        write_atomically(tmp_path / "b.json", "{}")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.json").stat().st_mode) == 0o644
    assert stat.S_IMODE(_entries(tmp_path / "cache")[0].stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "b.json").stat().st_mode) == 0o640


def _listening_addresses(pid: int) -> set[str]:
    """Hex local addresses (as in /proc/net/tcp*) of the TCP sockets that ``pid`` and its descendants listen on."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").glob("[0-9]*/stat"):
        try:
            children.setdefault(int(entry.read_text().rsplit(")", 1)[1].split()[1]), []).append(int(entry.parent.name))
        except (OSError, ValueError):
            continue
    pids, todo, inodes = [], [pid], set()
    while todo:
        pids.append(todo.pop())
        todo += children.get(pids[-1], [])
    for p in pids:
        try:
            inodes |= {os.readlink(fd)[8:-1] for fd in Path(f"/proc/{p}/fd").iterdir()
                       if os.readlink(fd).startswith("socket:[")}
        except OSError:
            continue
    found = set()
    for table in ("tcp", "tcp6"):
        for line in Path(f"/proc/net/{table}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == "0A" and fields[9] in inodes:  # 0A: LISTEN
                found.add(fields[1].rsplit(":", 1)[0])
    return found


@pytest.mark.slow
def test_embedded_ray_listens_on_loopback_only():
    import ray

    from gtsweep.orchestration.executor import connect

    if ray.is_initialized():
        ray.shutdown()
    connect({"address": "local", "num_cpus": 1})
    try:
        ray.get(ray.remote(lambda: 1).remote())  # a worker too
        addresses = _listening_addresses(os.getpid())
    finally:
        ray.shutdown()
    loopback = {"0100007F", "0000000000000000FFFF00000100007F", "00000000000000000000000001000000"}
    assert addresses and addresses <= loopback, addresses  # 127.0.0.1, ::ffff:127.0.0.1, ::1


def test_an_atomic_write_that_fails_keeps_the_old_file_and_leaves_no_temporary_file(tmp_path):
    target = tmp_path / "deep" / "er" / "a.json"
    write_atomically(target, "old")  # the missing folders are made

    def failing(f):
        f.write(b"half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="a.json"):
        write_atomically(target, failing)
    assert target.read_text() == "old" and [p.name for p in target.parent.iterdir()] == ["a.json"]


def test_a_dense_map_that_cannot_be_written_is_still_returned_and_writing_stops(tmp_path, monkeypatch):
    maps = cache.DenseMapCache(tmp_path / "c")
    calls = _full_disk(monkeypatch)
    value = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert maps.get_or_compute("ab" * 20, lambda: value).tobytes() == value.tobytes()
    assert maps.get_or_compute("cd" * 20, lambda: value * 2).tobytes() == (value * 2).tobytes()
    assert len(calls) == 1 and maps.write_errors == 1 and maps.misses == 2


def test_dense_descriptor_maps_are_counted_in_run_json_and_a_failed_write_warns_once(tmp_path, capsys):
    """XFeat's dense maps (<cache.dir>/dense/): the first detector's tasks compute them, the second's read them,
    a second sweep on the same cache computes none; run.json counts each. A dense folder that cannot be written
    gives one warning line and the same results."""
    grid = ["detector=[orb,fast]", "descriptor=[xfeat]", "selector=[nms]", "transform=[incremental]",
            "runner.backend=serial", "mlflow.enabled=false", "report.plots=false"]
    run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "first")
    record = json.loads((tmp_path / "first" / "run.json").read_text())
    views = record["dense_map_misses"]  # one network run per distinct image
    assert views > 0 and record["dense_map_hits"] == views and record["dense_map_write_errors"] == 0
    again = json.loads((run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "again").output_dir
                        / "run.json").read_text())
    assert (again["dense_map_misses"], again["dense_map_hits"]) == (0, 2 * views)
    blocked = tmp_path / "blocked"
    blocked.mkdir()
    (blocked / "dense").write_text("not a folder")
    capsys.readouterr()
    run_sweep(compose_config(tiny_overrides(tmp_path, *grid, f"cache.dir={blocked}")), tmp_path / "b")
    warnings = [line for line in capsys.readouterr().err.splitlines()
                if line.startswith("gtsweep: warning:") and "dense descriptor maps" in line]
    assert len(warnings) == 1, warnings
    record = json.loads((tmp_path / "b" / "run.json").read_text())
    assert record["dense_map_write_errors"] > 0 and record["dense_map_hits"] == 0
    assert_same_cells(tmp_path / "first", tmp_path / "b")


def test_entries_are_stored_as_float32_where_that_is_exact(tmp_path):
    store = cache.KeypointCache(tmp_path)
    exact = np.array([[10.5, 20.25, 31.0, -1.0, 0.0078125, 16712191.0, -1.0]])  # float32 values, SIFT's packed octave
    inexact = np.array([[0.1, 2.0, 3.0, -1.0, 1.0, 0.0, -1.0]])  # 0.1 is not a float32
    store.put("ab" * 32, exact, 5, 0.5)
    store.put("cd" * 32, inexact, 5, 0.5)
    dtypes = {}
    for path in _entries(tmp_path):
        with np.load(path) as entry:
            dtypes[path.stem] = entry["keypoints"].dtype
    assert dtypes == {"ab" * 32: np.float32, "cd" * 32: np.float64}
    fresh = cache.KeypointCache(tmp_path)
    for key, array in (("ab" * 32, exact), ("cd" * 32, inexact)):
        found = fresh.get(key)[0]
        assert found.dtype == np.float64 and np.array_equal(found, array)  # the same numbers back


@pytest.mark.parametrize("selectors, raw_entries", [("[nms]", False), ("[nms,anms]", True)])
def test_the_raw_detection_is_stored_only_when_two_selectors_share_it(tmp_path, selectors, raw_entries):
    grid = ["detector=[orb]", "descriptor=[orb]", f"selector={selectors}", "transform=[incremental]",
            "runner.backend=serial", "mlflow.enabled=false"]
    outcome = run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "run")
    assert {s["status"] for s in outcome.summaries} == {"ok"}
    names = [p.name for p in _entries(tmp_path / "cache")]
    assert any(n.startswith(f"{cache.RAW}-") for n in names) == raw_entries
    assert sum(not n.startswith(f"{cache.RAW}-") for n in names) == outcome.stats.cache_misses  # every selection
    again = run_sweep(compose_config(tiny_overrides(tmp_path, *grid)), tmp_path / "run2")
    assert again.stats.cache_misses == 0  # the selected keypoints are what a later run reads
