"""Configs are data: a method's ``factory:`` is the exact name of a constructor of OpenCV, gtsweep or a plug-in the user
names on the command line (``plugins``); anything else is one line, exit 2, before the module is imported. (The
attacker's table is tests/test_factory_bypass.py.)"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from gtsweep.core import plugins
from gtsweep.core.errors import BadInput
from gtsweep.core.factories import resolve
from sweep_helpers import cli_env, run_cli, tiny_overrides

#: A module that leaves a mark when imported, and a "detector" factory that leaves another when called.
PLANTED_MODULE = """
from pathlib import Path
from gtsweep.core.plugins import constructor
Path("IMPORTED").write_text("yes")

@constructor
def create(**params):
    Path("CALLED").write_text("yes")
    import cv2
    return cv2.ORB_create(**params)
"""
FAST = ["runner.backend=serial", "mlflow.enabled=false", "report.plots=false", "descriptor=[orb]",
        "transform=[incremental]"]


@pytest.fixture(autouse=True)
def _no_plugins(monkeypatch):
    monkeypatch.delenv(plugins.ENV, raising=False)


def _plant(tmp_path: Path, factory: str, where: str = "tuned/detector/planted.yaml") -> Path:
    (tmp_path / "plugin_dir").mkdir(exist_ok=True)
    (tmp_path / "plugin_dir" / "markmod.py").write_text(PLANTED_MODULE)
    file = tmp_path / where
    file.parent.mkdir(parents=True, exist_ok=True)
    file.write_text(f"factory: {factory}\norientation: true\nparams: {{nfeatures: 200}}\n")
    return file


def _run(tmp_path: Path, *args: str):
    import subprocess
    import sys

    env = {**cli_env(), "PYTHONPATH": f"{cli_env()['PYTHONPATH']}{os.pathsep}{tmp_path / 'plugin_dir'}"}
    return subprocess.run([sys.executable, "-m", "gtsweep", *args], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)


def test_a_factory_outside_the_allow_list_is_refused_before_import(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(_plant(tmp_path, "markmod.create").parent.parent.parent / "plugin_dir"))
    for path in ("markmod.create", "subprocess.Popen", "os.system", "builtins.eval", "cv2x.thing"):
        with pytest.raises(BadInput, match=f"factory '{path}' is refused"):
            resolve(path, "detector 'planted'")
    assert not (tmp_path / "IMPORTED").exists()
    assert resolve("cv2.ORB_create", "detector 'mine'").__name__ == "ORB_create"
    assert resolve("cv2.xfeatures2d.StarDetector_create", "detector 'mine'").__name__ == "StarDetector_create"


def test_plugins_must_be_module_names():
    with pytest.raises(BadInput, match="not a dotted module name"):
        plugins.enable(["os; rm -rf /"])
    with pytest.raises(BadInput, match="must be a list"):
        plugins.enable("mypkg")


def _plant_issue_28(tmp_path: Path) -> None:
    (tmp_path / "tuned/sweeps").mkdir(parents=True)
    (tmp_path / "tuned/sweeps/smoke.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /detector: [planted]\n  - override /descriptor: [orb]\n"
        "  - override /transform: [incremental]\n")
    (tmp_path / "tuned/detector").mkdir(parents=True)
    (tmp_path / "tuned/detector/planted.yaml").write_text(
        "factory: subprocess.Popen\norientation: true\nparams: {args: \"id > PWNED\", shell: true}\n")


def test_the_planted_detector_of_issue_28_named_explicitly_is_one_line(tmp_path):
    _plant_issue_28(tmp_path)
    result = run_cli(["detector=[planted]", "runner.backend=serial"], tmp_path)
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "PWNED").exists()


@pytest.mark.slow
def test_the_command_of_issue_28_runs_no_planted_code(tmp_path):
    """The issue's command: the planted ./tuned files are refused in one line before any work (./tuned serves only
    tuned method files, and were the planted file found, its factory would be refused too)."""
    _plant_issue_28(tmp_path)
    result = run_cli(["sweeps=smoke", "runner.backend=serial", "report.plots=false"], tmp_path)
    assert not (tmp_path / "PWNED").exists()
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "tuned/detector/planted.yaml is not a tuned method file" in result.stderr
    assert not (tmp_path / "outputs").exists()


def test_an_explicit_tuned_file_with_a_foreign_factory_is_refused(tmp_path):
    _plant(tmp_path, "markmod.create", "tuned/detector/tuned/planted.yaml")
    result = _run(tmp_path, "detector=[tuned/planted]", *tiny_overrides(tmp_path, *FAST))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "tuned/detector/tuned/planted.yaml: detector 'planted' is no method of the package" in result.stderr
    assert not (tmp_path / "IMPORTED").exists() and not (tmp_path / "CALLED").exists()


PRESET = "# @package _global_\nplugins: [markmod]\ndefaults:\n  - override /detector: [marked]\n"


def test_a_plugin_named_in_a_config_file_the_user_did_not_pass_is_refused(tmp_path):
    _plant(tmp_path, "markmod.create", "tuned/detector/marked.yaml")
    (tmp_path / "tuned/sweeps").mkdir(parents=True)
    (tmp_path / "tuned/sweeps/planted.yaml").write_text(PRESET)
    result = _run(tmp_path, "sweeps=planted", *tiny_overrides(tmp_path, *FAST))
    assert result.returncode == 2 and not (tmp_path / "IMPORTED").exists(), result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.mark.slow
def test_opencv_factories_and_named_plugins_run(tmp_path):
    configs = tmp_path / "mine"
    _plant(tmp_path, "cv2.ORB_create", "mine/detector/orb_declared.yaml")
    result = _run(tmp_path, "--config-dir", str(configs), "detector=[orb_declared]", *tiny_overrides(tmp_path, *FAST))
    assert result.returncode == 0, result.stderr
    _plant(tmp_path, "markmod.create", "mine/detector/marked.yaml")
    refused = _run(tmp_path, "--config-dir", str(configs), "detector=[marked]", *tiny_overrides(tmp_path, *FAST))
    assert refused.returncode == 2 and not (tmp_path / "IMPORTED").exists(), refused.stderr
    named = _run(tmp_path, "--config-dir", str(configs), "detector=[marked]", "plugins=[markmod]",
                 *tiny_overrides(tmp_path, *FAST))
    assert named.returncode == 0, named.stderr
    assert (tmp_path / "CALLED").exists()
    (tmp_path / "CALLED").unlink()
    (configs / "sweeps").mkdir()
    (configs / "sweeps/marked.yaml").write_text(PRESET)  # a plug-in named in a file, even of the user's config dir
    in_dir = _run(tmp_path, "--config-dir", str(configs), "sweeps=marked", *tiny_overrides(tmp_path, *FAST))
    assert in_dir.returncode == 2 and "plugins are named on the command line only" in in_dir.stderr, in_dir.stderr
    assert not (tmp_path / "CALLED").exists()
