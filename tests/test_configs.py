"""Configs found the way Hydra finds them: a user's --config-dir wins over the package's configs, methods can be
declared in YAML alone, Hydra's flags stand anywhere on the command line, and the package lists its packages."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

from gtsweep.cli import overrides as cli
from gtsweep.cli import search
from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.paths import CONF_DIR, PACKAGE_DIR, PROJECT_DIR
from gtsweep.experiments.kinds import run_sweep
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration.grid import REGISTRIES
from gtsweep.stages.detect import DETECTORS
from sweep_helpers import checked_jobs, cli_env, compose_config, tiny_overrides

MY_STAR = """\
# detector/my_star.yaml: OpenCV's CenSurE with a smaller border
factory: cv2.xfeatures2d.StarDetector_create
orientation: false
params: {maxSize: 22}
"""


@pytest.fixture(autouse=True)
def _declarations_stay_in_the_test(monkeypatch):
    """Methods declared here are registered process-wide: each test works on copies of the registries."""
    for registry in REGISTRIES.values():
        monkeypatch.setattr(registry, "_methods", dict(registry._methods))
        monkeypatch.setattr(registry, "_declared", dict(registry._declared))


@pytest.fixture
def user_conf(tmp_path) -> Path:
    conf = tmp_path / "myconf"
    (conf / "detector").mkdir(parents=True)
    (conf / "detector" / "my_star.yaml").write_text(MY_STAR)
    (conf / "detector" / "sift.yaml").write_text("sift:\n  params: {contrastThreshold: 0.02}\n")
    return conf


def test_a_detector_declared_in_yaml_sweeps_beside_a_package_detector(user_conf, tmp_path):
    overrides = tiny_overrides(tmp_path, "detector=[my_star,orb,sift]", "descriptor=[brief]", "transform=[incremental]",
                               "runner.backend=serial", "detector.my_star.params.maxSize=30")
    cfg = compose_config(overrides, config_dir=str(user_conf))
    assert set(cfg.detector) == {"my_star", "orb", "sift"}  # the declaration keyed by its option name
    assert cfg.detector.my_star.params.maxSize == 30  # a command-line override wins over the file
    assert cfg.detector.sift.params == {"contrastThreshold": 0.02}  # the user's sift.yaml, not the package's
    outcome = run_sweep(cfg, tmp_path / "run")
    assert {s["key"]: s["status"] for s in outcome.summaries} == {
        "my_star__nms__brief__incremental": "ok", "orb__nms__brief__incremental": "ok",
        "sift__nms__brief__incremental": "ok"}
    star = DETECTORS.get("my_star")
    assert star.create is __import__("cv2").xfeatures2d.StarDetector_create and star.response  # family default
    assert build_grid(cfg).detectors["sift"]["params"]["contrastThreshold"] == 0.02


def test_user_configs_are_valid_choices(user_conf, tmp_path, monkeypatch):
    cfg = compose_config(["detector=all"], config_dir=str(user_conf))  # every option on the search path
    assert "my_star" in cfg.detector and "sift" in cfg.detector and "all" not in cfg.detector
    # Hydra's own glob lists its main directory only: gtsweep's sweeper globs over the search path
    jobs = checked_jobs(["--config-dir", str(user_conf), "detector=glob(my_*)"], tmp_path, monkeypatch)
    assert [job[0] for job in jobs] == ["detector=my_star"]
    with pytest.raises(SystemExit) as exit_info:
        checked_jobs(["detector=glob(zz*)"], tmp_path, monkeypatch)
    assert exit_info.value.code == 2
    with pytest.raises(UnknownMethod, match=r"unknown detector 'my_starr'; valid choices: .*my_star"):
        compose_config(["detector=[my_starr]"], config_dir=str(user_conf))
    with pytest.raises(BadInput, match="detector 'my_star' has no parameter 'size'; its parameters: maxSize"):
        compose_config(["detector=[my_star]", "detector.my_star.params.size=3"], config_dir=str(user_conf))
    cfg = compose_config(["detector=[sift,my_star]", "detector.my_star.params.maxSize=3"], config_dir=str(user_conf))
    assert cfg.detector.my_star.params.maxSize == 3  # declared in YAML: keyed by its name when Hydra loads it
    with pytest.raises(BadInput, match="detector 'my_star' is not selected"):
        compose_config(["detector=[sift]", "detector.my_star.params.maxSize=3"], config_dir=str(user_conf))
    with pytest.raises(UnknownMethod):  # without the user's directory it does not exist
        compose_config(["detector=[my_star]"])


@pytest.mark.parametrize("node, message", [
    ({"factory": "cv2.NoSuchDetector_create", "orientation": False},
     "factory 'cv2.NoSuchDetector_create' is refused (cv2 has no "
        "constructor 'NoSuchDetector_create')"),
    ({"factory": "nomodule.create", "orientation": False}, "factory 'nomodule.create' is refused"),
    ({"factory": "cv2.ORB_create", "orientation": False, "colour": True}, "unknown key 'colour'; its capabilities: "
                                                                          "orientation, response"),
    ({"factory": "cv2.ORB_create"}, "declared in YAML, it needs orientation"),
    ({"factory": "cv2.ORB_create", "orientation": "yes"}, "orientation must be true or false"),
    ({"factory": "cv2.ORB_create", "orientation": True, "params": {"nfeatures": "x"}},
     "rejects its default parameters {'nfeatures': 'x'}"),
])
def test_bad_declarations_fail_in_one_line(node, message):
    cfg = {"detector": {"my_bad": {"params": {}, **node}}, "selector": {"nms": {"params": {}}},
           "descriptor": {"brief": {"params": {}}}, "transform": {"incremental": {"kind": "pairs"}},
           "experiment": {"name": "pose"}}
    with pytest.raises(BadInput) as info:
        build_grid(cfg)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_declaration_never_replaces_a_method_of_the_code():
    with pytest.raises(BadInput, match="detector 'sift' is built in"):
        DETECTORS.declare("sift", {"factory": "cv2.ORB_create", "orientation": True})


def test_descriptors_declared_in_yaml_need_a_known_norm():
    from gtsweep.stages.describe import DESCRIPTORS

    with pytest.raises(BadInput, match="norm must be hamming"):
        DESCRIPTORS.declare("my_desc", {"factory": "cv2.ORB_create", "norm": "cosine"})
    method = DESCRIPTORS.declare("my_orb", {"factory": "cv2.ORB_create", "norm": "hamming",
                                            "excluded_detectors": {"sift": "scales"}})
    assert method.norm == "hamming" and method.excluded_detectors == {"sift": "scales"}


def test_hydras_own_parser_reads_the_command_line():
    args = search.hydra_args(["--cfg", "job", "detector=all", "-m", "seed=1", "--config-dir", "x"])
    assert args.overrides == ["detector=all", "seed=1"] and args.cfg == "job" and args.multirun
    assert args.config_dir == "x"
    args = search.hydra_args(["detector=[sift]", "--info", "searchpath"])
    assert args.overrides == ["detector=[sift]"] and args.info == "searchpath" and not args.multirun


def test_a_users_searchpath_keeps_gtsweeps_entries(user_conf):
    args = search.hydra_args([f"hydra.searchpath=[file://{user_conf}]"])
    assert args.overrides == [f"hydra.searchpath=[file://{user_conf},tuned://tuned,pkg://gtsweep.conf,every://all]"]
    assert search.search_path(args) == (
        search.PRIMARY, f"file://{user_conf}", "tuned://tuned", "pkg://gtsweep.conf", "every://all")
    assert "my_star" in search.configs([f"hydra.searchpath=[file://{user_conf}]"]).options("detector")
    cfg = compose_config([f"hydra.searchpath=[file://{user_conf}]", "detector=[my_star,orb]"])
    assert set(cfg.detector) == {"my_star", "orb"}


@pytest.mark.slow
def test_help_lists_the_groups_on_the_search_path(user_conf, tmp_path):
    def help_of(*args):
        done = subprocess.run([sys.executable, "-m", *args, "--help"], cwd=tmp_path, env=cli_env(),
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        return done.stdout

    text = help_of("gtsweep", "--config-dir", str(user_conf))
    detectors = re.search(r"^detector: (.*)$", text, re.M).group(1).split(", ")
    assert "my_star" in detectors and "sift" in detectors
    assert re.search(r"^sweeps: .*smoke", text, re.M) and "hydra/" not in text.split("== Config ==")[0]
    assert re.search(r"^dataset: .*synthetic", help_of("gtsweep.datasets"), re.M)


def test_shell_completion_installs():
    done = subprocess.run([sys.executable, "-m", "gtsweep", "-sc", "install=bash"], env=cli_env(),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "complete" in done.stdout, done.stderr


def test_pyproject_ships_every_package_and_the_configs():
    setuptools = tomllib.loads((PROJECT_DIR / "pyproject.toml").read_text())["tool"]["setuptools"]
    # every folder, code or data only (setuptools warns "Package would be ignored" about an unlisted data folder)
    def folders(root, name):
        return {".".join((name, *d.relative_to(root).parts)) for d in [root, *root.rglob("*")]
                if d.is_dir() and d.name != "__pycache__"}

    packages = folders(PACKAGE_DIR, "gtsweep") | folders(CONF_DIR, "gtsweep.conf")
    plugins = folders(PROJECT_DIR / "hydra_plugins", "hydra_plugins") - {"hydra_plugins"}  # a namespace package
    assert packages | plugins | {"gtsweep.conf.sweeps"} == set(setuptools["packages"])
    assert setuptools["package-dir"] == {"gtsweep.conf": "conf", "gtsweep.conf.sweeps": "sweeps"}
    assert CONF_DIR == PROJECT_DIR / "conf" and (CONF_DIR / "__init__.py").exists()


def test_every_package_method_config_composes_onto_its_schema():
    """A method of the code has its defaults in the ConfigStore (orchestration.schemas); its YAML lists that schema
    first, so that Hydra merges the file and the command line onto the defaults once. (A tuned file holds every
    parameter; experiment=optimize writes the same line into it, so that its values are typed too.)"""
    import yaml

    for group, registry in REGISTRIES.items():
        for path in (CONF_DIR / group).glob("*.yaml"):
            if path.stem in registry:
                defaults = yaml.safe_load(path.read_text())["defaults"]
                assert defaults == [f"/schema/{group}/{path.stem}@_here_", "_self_"], path


def test_hydra_types_the_parameters_and_settings(tmp_path):
    cfg = cli.compose_config(["detector=[orb]", "detector.orb.params.scaleFactor=2", "runner.shard_size=3"])
    assert cfg.detector.orb.params.scaleFactor == 2.0 and isinstance(cfg.detector.orb.params.scaleFactor, float)
    assert cfg.runner.shard_size == 3
    assert cfg.detector.orb.params.nfeatures == DETECTORS.get("orb").defaults["nfeatures"]
    with pytest.raises(BadInput, match=r"override 'detector.orb.params.nfeatures=1.5': expected an int like the "
                                       r"default \d+, got '1.5'"):
        cli.compose_config(["detector=[orb]", "detector.orb.params.nfeatures=1.5"])
    with pytest.raises(BadInput, match="override 'runner.shard_size=many': expected an int"):
        cli.compose_config(["runner.shard_size=many"])
    with pytest.raises(BadInput, match=r"runner.shard_size must be an integer in \[1, inf\), got 0"):  # its range
        cli.compose_config(["runner.shard_size=0"])


def test_a_users_config_without_the_schema_keeps_the_defaults_but_names_what_it_misses(user_conf):
    cfg = compose_config(["detector=[sift]"], config_dir=str(user_conf))
    assert dict(cfg.detector.sift.params) == {"contrastThreshold": 0.02}
    assert build_grid(cfg).detectors["sift"]["params"] == {**DETECTORS.get("sift").defaults, "contrastThreshold": 0.02}
    with pytest.raises(BadInput, match="detector 'sift': its config does not compose onto its defaults, so 'sigma' "
                                       "cannot be set; list /schema/detector/sift@_here_ first in its defaults"):
        cli.compose_config(["detector=[sift]", "detector.sift.params.sigma=1.5"], config_dir=str(user_conf))


def test_a_descriptors_per_detector_entries_are_its_yamls_and_a_new_one_is_appended():
    with pytest.raises(BadInput, match=r"descriptor 'teblid' has no per_detector entry 'akaze' \(its entries: kaze, "
                                       r"orb, sift, surf\); a new one is appended: \+descriptor.teblid"):
        cli.compose_config(["descriptor=[teblid]", "descriptor.teblid.per_detector.akaze.scale_factor=6.0"])
    cfg = cli.compose_config(["detector=[akaze]", "descriptor=[teblid]",
                              "+descriptor.teblid.per_detector.akaze.scale_factor=6.0"])
    assert cfg.descriptor.teblid.per_detector.akaze.scale_factor == 6.0
