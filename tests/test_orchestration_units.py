"""Grid building, the keypoint cache, result files and command-line checks (no data set, no Ray)."""
import json

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from gtsweep.cli import main as gtsweep_main
from gtsweep.cli import overrides as cli
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.paths import CONF_DIR, SWEEPS_DIR
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration import resume_pick
from gtsweep.orchestration.cache import KeypointCache, detection_key, image_hash
from gtsweep.orchestration.results import ResultStore, summarize
from sweep_helpers import checked_jobs

PARAMS = {"params": {}}


def _cfg(**over):
    cfg = {"detector": {"akaze": PARAMS, "censure": PARAMS}, "selector": {"nms": {"params": {"n": 10}}},
           "descriptor": {"akaze": PARAMS, "brief": PARAMS},
           "transform": {"incremental": {"kind": "pairs"}, "rotation": {"kind": "synthetic", "strengths": [0, 90]}},
           "experiment": {"name": "pose"}}
    cfg.update(over)
    return cfg


def test_grid_is_the_product_with_na_cells_marked():
    grid = build_grid(_cfg())
    assert len(grid.cells) == 2 * 2 * 2  # detectors x descriptors x transforms (one selector)
    na = {(c.detector, c.descriptor) for c in grid.cells if c.na_reason}
    assert na == {("censure", "akaze")}


def test_detection_experiment_has_no_descriptor_dimension():
    grid = build_grid(_cfg(experiment={"name": "detection"}))
    assert len(grid.cells) == 2 * 2 and all(c.descriptor is None for c in grid.cells)


def test_pairings_restrict_the_product():
    grid = build_grid(_cfg(pairings=[["akaze", "akaze"], ["censure", "brief"]]))
    assert {(c.detector, c.descriptor) for c in grid.cells} == {("akaze", "akaze"), ("censure", "brief")}
    with pytest.raises(BadInput, match="not in the grid"):
        build_grid(_cfg(pairings=[["sift", "sift"]]))


def test_grid_rejects_unknown_methods_and_bad_transforms():
    with pytest.raises(UnknownMethod, match="valid choices"):
        build_grid(_cfg(detector={"siftt": PARAMS}))
    with pytest.raises(BadInput, match="strengths"):
        build_grid(_cfg(transform={"rotation": {"kind": "synthetic", "strengths": ["a"]}}))


def test_cell_hash_changes_with_parameters():
    a, b = build_grid(_cfg()), build_grid(_cfg(selector={"nms": {"params": {"n": 11}}}))
    assert a.cell_hash(a.cells[0], "fp", 0) != b.cell_hash(b.cells[0], "fp", 0)
    assert a.cell_hash(a.cells[0], "fp", 0) == build_grid(_cfg()).cell_hash(a.cells[0], "fp", 0)
    assert a.cell_hash(a.cells[0], "fp", 0) != a.cell_hash(a.cells[0], "fp", 1)


def test_cache_round_trip_and_counts(tmp_path):
    image = np.arange(100, dtype=np.uint8).reshape(10, 10)
    key = detection_key(image, None, "sift", {"params": {}}, "nms", {"params": {"n": 5}})
    assert key != detection_key(image, None, "sift", {"params": {}}, "nms", {"params": {"n": 6}})
    assert key != detection_key(image + 1, None, "sift", {"params": {}}, "nms", {"params": {"n": 5}})
    # the image hashed once keys every detection of it: the same keys as hashing it per key
    hashed = image_hash(image, None)
    assert detection_key(image, None, "sift", {"params": {}}, "nms", {"params": {"n": 5}}, hashed=hashed) == key
    assert detection_key(image, None, "sift", {"params": {}}, "raw", {}, hashed=hashed) == detection_key(
        image, None, "sift", {"params": {}}, "raw", {})
    keypoints = np.random.default_rng(0).random((7, 7))
    first = KeypointCache(tmp_path)
    assert first.get(key) is None and first.misses == 1
    first.put(key, keypoints, 9, 0.5)
    second = KeypointCache(tmp_path)
    found, n, seconds = second.get(key)
    assert second.hits == 1 and n == 9 and seconds == 0.5 and np.array_equal(found, keypoints)
    assert not list(tmp_path.rglob("*.tmp"))


def test_result_store_marks_complete_cells(tmp_path):
    store = ResultStore(tmp_path)
    rows = pd.DataFrame({"image": ["a", "b"], "strength": [0.0, 90.0], "pose_success": [1.0, 0.0]})
    summary = {"key": "k", "hash": "h1", "status": "ok", "methods": {}, **summarize(rows, "pose")}
    assert summary["metrics"]["pose_success"] == 0.5
    assert summary["by_strength"] == {"0.0": {"pose_success": 1.0}, "90.0": {"pose_success": 0.0}}
    store.write_cell("k", summary, rows)
    assert store.complete("k", "h1")["status"] == "ok"
    assert store.complete("k", "h2") is None  # configuration changed: recompute
    assert store.rows("k").equals(rows)


def test_all_is_every_option():
    names = list(cli.compose_config(["detector=all"]).detector)
    assert {"sift", "akaze", "censure", "msd"} <= set(names) and "all" not in names and names == sorted(names)


@pytest.mark.parametrize("args, message", [
    (["detector=[sift,siftt]"], "unknown detector 'siftt'; valid choices: "),
    (["descriptor=brieff"], "unknown descriptor 'brieff'"),
    (["dataset=nope"], "unknown dataset 'nope'"),
    (["sweeps=table99"], "unknown sweep 'table99'"),
    (["selector.nms.params.n=abc"], "expected an int like the default 1000, got 'abc'"),
    (["seed=x"], "expected an int"),
    (["runner.num_cpuz=2"], "unknown config key 'runner.num_cpuz'"),
    (["detector.sift.params.nfeaturez=3"], "detector 'sift' has no parameter 'nfeaturez'; its parameters: "),
    (["detector=[sift]", "detector.sift.params.contrastThreshol=0.02"], "no parameter 'contrastThreshol'"),
    (["detector=[sift]", "detector.orb.params.nfeatures=5"], "detector 'orb' is not selected"),
    (["descriptor=[beblid]", "descriptor.beblid.per_detector.sift.n_bitz=5"],
     "descriptor 'beblid' has no parameter 'n_bitz'"),
    (["descriptor.beblid.per_detector.sift.n_bits=5"], "descriptor 'beblid' is not selected"),
    (["dataset=[synthetic,csv]"], "dataset takes one option, not a list"),
    (["detector.nope.params.x=3"], "unknown detector 'nope'"),
    (["runner.num_cpus=two"], "override 'runner.num_cpus=two': expected an int, got 'two'"),  # Hydra's type
    (["runner.num_cpus=0"], "runner.num_cpus must be an integer in [1, inf) or null, got 0"),  # gtsweep's range
    (["runner.ray_log_level=loud"], "runner.ray_log_level must be one of debug, info, warning, error"),
    (["--cfg", "job", "runner.dashboard=maybe"], "expected a bool"),
])
def test_bad_overrides_fail_in_one_line(args, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        gtsweep_main(args)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err


def test_good_overrides_pass(tmp_path, monkeypatch):
    jobs = checked_jobs(["detector=all", "selector.nms.params.n=500", "seed=0,1", "transform=[rotation,noise]",
                         "transform.rotation.strengths=[0,90]", "+foo=1"], tmp_path, monkeypatch)
    assert [job[:4] for job in jobs] == [["detector=all", "selector.nms.params.n=500", f"seed={seed}",
                                          "transform=[rotation,noise]"] for seed in (0, 1)]
    jobs = checked_jobs(["detector=glob(s*)"], tmp_path, monkeypatch)
    assert [job[0] for job in jobs] == ["detector=sift", "detector=surf"]
    checked_jobs(["detector=[sift,orb],[sift]", "detector.sift.params.sigma=1.5"], tmp_path, monkeypatch)


def test_resume_finds_the_newest_run_of_the_same_command(tmp_path):
    run = tmp_path / "outputs" / "2026-01-01" / "10-00-00"
    run.mkdir(parents=True)
    (run / resume_pick.SWEEP_RECORD).write_text(json.dumps({"key": resume_pick.command_key(["detector=[sift]"])}))
    (run / "mlflow.json").write_text("{}")  # a run that started (one that never did is passed over)
    assert resume_pick.command_key(["detector=[sift]", "resume=true"]) == resume_pick.command_key(["detector=[sift]"])
    assert resume_pick.earlier_run(resume_pick.command_key(["detector=[sift]"]), False, tmp_path) == run
    assert resume_pick.earlier_run(resume_pick.command_key(["detector=[orb]"]), False, tmp_path) is None
    sweep = tmp_path / "multirun" / "2026-01-01" / "10-00-00"
    (sweep / "0").mkdir(parents=True)  # a multirun's jobs record its command's key
    (sweep / "0" / resume_pick.SWEEP_RECORD).write_text(json.dumps({"key": resume_pick.command_key(["seed=0,1"])}))
    (sweep / "0" / "mlflow.json").write_text("{}")
    assert resume_pick.earlier_run(resume_pick.command_key(["seed=0,1", "resume=true"]), True, tmp_path) == sweep


@pytest.mark.parametrize("preset", sorted(p.stem for p in SWEEPS_DIR.glob("*.yaml")))
def test_every_preset_composes_into_a_grid(preset):
    """Each preset of sweeps/ composes with the committed tuned detector configs and builds a non-empty grid."""
    cfg = cli.compose_config([f"sweeps={preset}"])
    grid = build_grid(cfg)
    assert len(grid.cells) > 0
    tuned = CONF_DIR / "detector" / "tuned"
    for name in cfg.detector:  # every preset runs the committed tuned detectors
        tuned_params = OmegaConf.load(tuned / f"{name}.yaml")[name].params
        assert cfg.detector[name].params == tuned_params, name


def test_hydra_flag_conflicts_fail_in_one_line(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.argv", ["gtsweep"])
    with pytest.raises(SystemExit) as exit_info:
        gtsweep_main(["detector=[orb]", "-m", "--cfg", "job"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gtsweep: error: Only one of") and len(err.splitlines()) == 1, err
