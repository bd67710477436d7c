"""experiment=optimize: Optuna studies on the optimisation split, every trial an MLflow child run, resume, tuned
configs that load back through Hydra, Ray and in-process trials giving the same numbers, one-line bad input."""
from __future__ import annotations

import math

import mlflow
import optuna
import pytest
import yaml

from gtsweep.cli import overrides as cli
from gtsweep.cli import search
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.paths import CONF_DIR
from gtsweep.experiments.optimize.driver import main
from gtsweep.experiments.optimize.objective import trial_metrics
from gtsweep.experiments.optimize.optuna_study import open_study
from gtsweep.experiments.optimize.search_space import parse_space
from gtsweep.experiments.optimize.study_settings import read_settings
from gtsweep.experiments.optimize.targets import Target, build_targets
from gtsweep.experiments.optimize.tuned_files import tuned_node
from gtsweep.experiments.pairs.grid import build_grid
from sweep_helpers import compose_config, run_cli, tiny_overrides

FAST = ["experiment=optimize", "detector=[fast]", "runner.backend=serial", "experiment.n_startup_trials=2",
        "experiment.transforms.rotation.strengths=[45]", "experiment.transforms.noise.strengths=[20]"]


def overrides(tmp_path, *extra, store="optuna.db", tuned_root=True):
    root = [f"experiment.tuned_root={tmp_path}/tuned"] if tuned_root else []  # else ./tuned, the default
    return tiny_overrides(tmp_path, *FAST, f"experiment.storage=sqlite:///{tmp_path}/{store}", *root,
                          f"mlflow.tracking_uri=sqlite:///{tmp_path}/mlflow.db", *extra)


def optimise(tmp_path, *extra, store="optuna.db", out="out"):
    cfg = compose_config(overrides(tmp_path, *extra, store=store))
    return main(cfg, tmp_path / out)[0]


def runs(tmp_path):
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path}/mlflow.db")
    return mlflow.search_runs(experiment_names=["gtsweep"])


def trial_table(storage: str, name: str):
    study = optuna.load_study(study_name=name, storage=storage)
    return [(t.number, t.params, t.value) for t in study.trials if t.state.name == "COMPLETE"]


@pytest.fixture(scope="module")
def first(tmp_path_factory, existing_store):
    tmp_path = tmp_path_factory.mktemp("optimize")
    existing_store(tmp_path / "mlflow.db", tmp_path)  # migrated once per session: these tests read the study's runs
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(tmp_path)  # MLflow's artifacts go to ./mlruns
        return tmp_path, optimise(tmp_path, "experiment.n_trials=3")  # tuned configs go to <tmp_path>/tuned


@pytest.fixture(autouse=True)
def _in_tmp_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def test_trials_are_nested_mlflow_runs(first):
    tmp_path, summary = first
    frame = runs(tmp_path)
    parents = frame[frame["tags.gtsweep.role"] == "study"]
    assert len(parents) == 1 and parents.iloc[0]["tags.gtsweep.study"] == summary["study"]
    assert parents.iloc[0]["tags.gtsweep.objective"] == "repeatability"
    children = frame[frame["tags.mlflow.parentRunId"] == parents.iloc[0]["run_id"]]
    assert sorted(children["tags.gtsweep.trial"].astype(int)) == [0, 1, 2]
    assert children["params.threshold"].notna().all()
    for metric in ("objective", "score", "repeatability", "few_share", "n_few", "n_keypoints"):
        assert children[f"metrics.{metric}"].notna().all(), metric
    assert (children["metrics.score"] == children["metrics.repeatability"] - children["metrics.n_few"]).all()
    assert children["tags.gtsweep.defaults"].eq("true").sum() == 1  # trial 0 evaluates the defaults
    assert summary["best_value"] == children["metrics.objective"].max()
    # what identifies a trial filters (tracking.params); names are unique in the experiment
    assert (children["params.detector"] == "fast").all() and (children["params.seed"] == "0").all()
    assert (children["params.dataset"] == "synthetic").all() and (children["params.objective"] == "repeatability").all()
    assert frame["tags.mlflow.runName"].is_unique
    assert children["tags.mlflow.runName"].str.endswith(" · optimize/" + summary["study"]).all()
    assert parents.iloc[0]["params.dataset.fingerprint"] == parents.iloc[0]["tags.gtsweep.dataset_fingerprint"]


def test_tuned_config_loads_back_through_hydra(first, monkeypatch):
    tmp_path, summary = first
    path = tmp_path / "tuned" / "detector" / "tuned" / "fast.yaml"
    text = path.read_text()
    assert text.startswith("# @package detector\n# Tuned by gtsweep") and str(tmp_path) not in text  # no local path
    assert "(sqlite:///optuna.db), best of 3 complete trials" in text
    assert (tmp_path / "out" / "tuned" / "detector" / "fast.yaml").exists()
    shipped = yaml.safe_load((CONF_DIR / "detector" / "tuned" / "fast.yaml").read_text())["fast"]["params"]
    assert compose_config(["detector=[tuned/fast]"]).detector.fast.params == shipped  # elsewhere: the package's
    monkeypatch.chdir(tmp_path)  # ./tuned is on the search path before the package's configs: ours wins
    cfg = compose_config(tiny_overrides(tmp_path, "experiment=detection", "detector=[tuned/fast,orb]"))
    assert set(cfg.detector) == {"fast", "orb"}
    assert cfg.detector.fast.params.threshold == summary["best_params"]["threshold"] != shipped["threshold"]
    assert cfg.detector.fast.params.type == 2  # untuned defaults are kept
    assert {c.detector for c in build_grid(cfg).cells} == {"fast", "orb"}
    with pytest.raises(UnknownMethod, match="tuned/fast"):  # the CLI's check lists tuned options
        cli.compose_config(["detector=[tuned/siftt]"])


def test_resume_continues_the_study_without_duplicate_runs(first):
    tmp_path, summary = first
    storage = f"sqlite:///{tmp_path}/optuna.db"
    killed = open_study(storage, summary["study"]).ask()  # a trial left RUNNING, as by a kill
    killed_params = {"threshold": 7}
    killed.suggest_int("threshold", 7, 7)
    again = optimise(tmp_path, "experiment.n_trials=5")
    assert again["study"] == summary["study"] and again["new"] == 2
    study = optuna.load_study(study_name=summary["study"], storage=storage)
    states = {t.number: t.state.name for t in study.trials}
    assert states[killed.number] == "FAIL" and list(states.values()).count("COMPLETE") == 5
    retried = [t for t in study.trials if t.user_attrs.get("retry_of") == killed.number]
    assert len(retried) == 1 and retried[0].params == killed_params  # the killed trial's parameters ran again
    frame = runs(tmp_path)
    assert (frame["tags.gtsweep.role"] == "study").sum() == 1
    children = frame[frame["tags.mlflow.parentRunId"].notna()]
    assert children["tags.gtsweep.trial"].is_unique and len(children) == len(study.trials) == 6
    failed = children[children["tags.gtsweep.trial"] == str(killed.number)].iloc[0]
    assert failed["status"] == "FAILED" and failed["tags.gtsweep.reason"].startswith("interrupted")


@pytest.mark.slow
def test_same_seed_same_trials_on_ray_and_in_process(first, tmp_path):
    first_path, summary = first
    ray_run = optimise(tmp_path, "experiment.n_trials=3", "runner.backend=ray", "runner.num_cpus=2",
                       "mlflow.enabled=false", f"dataset.cache_dir={first_path}/data")  # the same data set
    assert ray_run["study"] == summary["study"]  # the name hashes the setup, not the backend
    ours = trial_table(f"sqlite:///{tmp_path}/optuna.db", summary["study"])
    theirs = trial_table(f"sqlite:///{first_path}/optuna.db", summary["study"])[:3]
    assert ours == theirs


@pytest.mark.slow
def test_pose_success_tunes_descriptor_params(tmp_path):
    summary = optimise(tmp_path, "experiment.objective=pose_success", "detector=[orb]", "descriptor=[brief]",
                       "experiment.n_trials=2", "experiment.transforms={rotation:{strengths:[30]}}")
    assert summary["target"] == "orb+brief" and summary["group"] == "descriptor"
    assert 0 <= summary["metrics"]["pose_success"] <= 1 and "precision" in summary["metrics"]
    written = yaml.safe_load((tmp_path / "tuned" / "descriptor" / "tuned" / "brief.yaml").read_text())
    assert written["brief"]["params"]["bytes"] == summary["best_params"]["bytes"]
    assert written["brief"]["params"]["use_orientation"] is True


@pytest.mark.slow
def test_cli_runs_a_study_and_reports_bad_spaces_in_one_line(tmp_path):
    done = run_cli(overrides(tmp_path, "experiment.n_trials=2", "mlflow.enabled=false", tuned_root=False),
                   cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "best: trial" in done.stdout and (tmp_path / "tuned/detector/tuned/fast.yaml").exists()  # ./tuned
    bad = run_cli(overrides(tmp_path, "detector.fast.search_space.threshold.low=100"), cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert "detector.fast.search_space.threshold: low must be below high" in bad.stderr


@pytest.mark.parametrize("space, message", [
    (None, "search_space is missing"),
    ({"threshold": {"type": "float", "low": 1.0, "high": 9.0}}, "is an int"),
    ({"threshold": {"type": "int", "low": 0, "high": 9, "log": True}}, "needs low > 0"),
    ({"thresh": {"type": "int", "low": 1, "high": 9}}, "no such parameter"),
    ({"threshold": {"type": "between", "low": 1, "high": 9}}, "type must be one of"),
    ({"threshold": {"type": "int", "low": 1, "high": 9, "lo": 2}}, "unknown key"),
    ({"nonmaxSuppression": {"type": "categorical", "choices": []}}, "non-empty list"),
    ({"maxCorners": {"type": "int", "low": 10, "high": 90}}, "fixed to the survey's N"),
])
def test_bad_search_space_is_one_line(space, message):
    defaults = {"threshold": 10, "nonmaxSuppression": True, "maxCorners": 1000}
    with pytest.raises(BadInput, match=message) as caught:
        parse_space("detector.x.search_space", space, defaults, excluded=("maxCorners",))
    assert "\n" not in str(caught.value)


def test_detector_without_space_stops_before_any_work(tmp_path):
    cfg = compose_config(overrides(tmp_path, "~detector.fast.search_space"))
    with pytest.raises(BadInput, match="detector.fast.search_space is missing"):
        main(cfg, tmp_path / "out")
    assert not (tmp_path / "optuna.db").exists()


def test_every_detector_declares_a_valid_space(tmp_path):
    cfg = compose_config(tiny_overrides(tmp_path, "experiment=optimize", "detector=all"))
    targets = build_targets(cfg, read_settings(cfg))
    assert len(targets) == len(search.configs().options("detector"))
    assert all(1 <= len(t.distributions) <= 3 for t in targets)


def test_score_is_lexicographic():
    rows = {"rotation": [{"repeatability": 0.9, "few_keypoints": 1.0, "n_keypoints": 50.0},
                         {"repeatability": 0.9, "few_keypoints": 0.0, "n_keypoints": 500.0}],
            "noise": [{"repeatability": 0.5, "few_keypoints": 0.0, "n_keypoints": 400.0}]}
    metrics = trial_metrics(rows, "repeatability")
    assert math.isclose(metrics["repeatability"], 0.7) and metrics["n_few"] == 1 and metrics["few_share"] == 1 / 3
    assert math.isclose(metrics["score"], 0.7 - 1)  # any view below N outweighs any repeatability gain


def test_tuned_descriptor_is_not_overridden_per_detector():
    node = {"params": {"scale_factor": 5.0, "n_bits": 100}, "per_detector": {"sift": {"scale_factor": 6.75}}}
    target = Target("descriptor", "beblid", "sift", "beblid", node, {}, {}, {}, {})
    tuned = tuned_node(target, {"scale_factor": 3.0})
    assert tuned["params"]["scale_factor"] == 3.0 and tuned["per_detector"]["sift"] == {}
    assert node["per_detector"]["sift"] == {"scale_factor": 6.75}
