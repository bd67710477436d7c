"""The command line's own pieces on Hydra's: near-miss hints, ./tuned serving tuned method files only, malformed
YAML named by file:line, Hydra's flags between overrides (read by Hydra's own parser), settings of options that
are not selected."""
from __future__ import annotations

import pytest

import json
from pathlib import Path

from gtsweep.cli import main as gtsweep_main
from gtsweep.cli import overrides as cli
from gtsweep.cli import search
from gtsweep.core.rundirs import RUN_RECORD, SWEEP_RECORD
from gtsweep.tracking.multirun import multirun_record


def one_line_error(args, capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        gtsweep_main(args)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("args, message", [
    (["detectr=[sift]"], "unknown config key 'detectr'; did you mean 'detector'?"),
    (["runner.num_cpuz=2"], "unknown config key 'runner.num_cpuz'; did you mean 'runner.num_cpus'?"),
    (["transform=[noise]", "transform.rotation.strengths=[0,90]"],
     "transform 'rotation' is not selected (selected: noise)"),
])
def test_a_near_miss_or_an_unselected_option_is_one_line_never_advice_to_add(args, message, capsys):
    err = one_line_error(args, capsys)
    assert message in err and "+" not in err, err


def test_a_hydra_flag_may_stand_between_overrides(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    gtsweep_main(["detector=[orb]", "--cfg", "job", "seed=3"])
    printed = capsys.readouterr().out
    assert "seed: 3" in printed and "orb:" in printed and "sift:" not in printed.split("selector:")[0]
    args = search.hydra_args(["detector=[orb]", "--cfg", "job", "descriptor=[orb]", "-m", "seed=0,1"])
    assert args.overrides == ["detector=[orb]", "descriptor=[orb]", "seed=0,1"] and args.multirun
    assert args.cfg == "job"  # Hydra's own parser read it: gtsweep keeps no table of Hydra's flags


def test_malformed_yaml_in_a_config_dir_is_named_by_file_and_line(tmp_path, capsys):
    (tmp_path / "detector").mkdir()
    broken = tmp_path / "detector" / "broken.yaml"
    broken.write_text("factory: cv2.ORB_create\norientation: true\nparams: {a: [1, 2\n")
    err = one_line_error(["--config-dir", str(tmp_path), "detector=[broken]", "--cfg", "job"], capsys)
    assert f"malformed YAML in {broken}:4" in err


def test_the_working_directorys_tuned_serves_tuned_method_files_only(tmp_path, monkeypatch):
    """Issue 28's planted preset: ./tuned/sweeps/smoke.yaml and ./tuned/detector/planted.yaml do not exist for
    Hydra; ./tuned/detector/tuned/sift.yaml does and wins over the package's."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tuned" / "sweeps").mkdir(parents=True)
    (tmp_path / "tuned" / "detector" / "tuned").mkdir(parents=True)
    (tmp_path / "tuned" / "sweeps" / "smoke.yaml").write_text(
        "# @package _global_\ndefaults:\n  - override /detector: [planted]\n")
    (tmp_path / "tuned" / "detector" / "planted.yaml").write_text(
        "factory: subprocess.Popen\norientation: true\nparams: {args: 'id > PWNED', shell: true}\n")
    (tmp_path / "tuned" / "detector" / "tuned" / "sift.yaml").write_text(
        "# @package detector\nsift:\n  params: {contrastThreshold: 0.031}\n")
    assert "planted" not in search.configs().options("detector")
    cfg = cli.compose_config(["sweeps=smoke"])
    assert "planted" not in cfg.detector and "sift" in cfg.detector
    assert cli.compose_config(["detector=[tuned/sift]"]).detector.sift.params.contrastThreshold == 0.031
    assert not (tmp_path / "PWNED").exists()


def test_a_config_planted_in_the_working_directorys_tuned_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """Issue 28's planted preset is not silently ignored: the command stops before any work and names the file;
    a tuned method file (<group>/tuned/<name>.yaml) alone is fine."""
    from gtsweep.core.searchpath import stray_tuned_files

    monkeypatch.chdir(tmp_path)
    (tmp_path / "tuned" / "detector" / "tuned").mkdir(parents=True)
    (tmp_path / "tuned" / "detector" / "tuned" / "sift.yaml").write_text("# @package detector\nsift: {}\n")
    assert stray_tuned_files("tuned") == []
    (tmp_path / "tuned" / "sweeps").mkdir()
    (tmp_path / "tuned" / "sweeps" / "smoke.yaml").write_text("# @package _global_\n")
    (tmp_path / "tuned" / "detector" / "planted.yaml").write_text("factory: subprocess.Popen\n")
    assert stray_tuned_files("tuned") == ["detector/planted.yaml", "sweeps/smoke.yaml"]
    err = one_line_error(["sweeps=smoke", "runner.backend=serial"], capsys)
    assert err.startswith("gtsweep: error: tuned/detector/planted.yaml is not a tuned method file")
    assert not (tmp_path / "outputs").exists()


def _launched_configs(args, tmp_path, monkeypatch) -> tuple[list, list]:
    """``-m ARGS`` in ``tmp_path`` with a task that runs nothing: (each job's seed, number and directory, each
    composition's overrides)."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra.core.hydra_config import HydraConfig

    import gtsweep.cli.app

    composed, launched = [], []
    compose = ConfigLoaderImpl.load_sweep_config
    monkeypatch.setattr(ConfigLoaderImpl, "load_sweep_config",
                        lambda self, master, job: composed.append(list(job)) or compose(self, master, job))
    def app(cfg):  # leaves what a job that started leaves for resume=true: its record and its run record
        job = Path(HydraConfig.get().runtime.output_dir)
        (job / SWEEP_RECORD).write_text(json.dumps({"key": multirun_record(job.parent)["key"]}))
        (job / RUN_RECORD).write_text("{}")
        launched.append((cfg.seed, HydraConfig.get().job.num, HydraConfig.get().sweep.dir))

    monkeypatch.setattr(gtsweep.cli.app, "app", app)
    monkeypatch.chdir(tmp_path)
    gtsweep_main(["-m", *args, "mlflow.enabled=false", "hydra/hydra_logging=none", "hydra/job_logging=none"])
    return launched, composed


def test_a_multirun_composes_each_job_once_and_again_only_when_resume_moves_its_directory(tmp_path, monkeypatch):
    args = ["detector=[orb]", "descriptor=[orb]", "seed=0,1"]
    launched, composed = _launched_configs(args, tmp_path, monkeypatch)
    seeds = [[o for o in job if o.startswith("seed=")] for job in composed]
    assert seeds == [["seed=0"], ["seed=1"]]  # by the checks; the launcher is handed those
    first = {directory for _, _, directory in launched}
    assert [job[:2] for job in launched] == [(0, 0), (1, 1)] and len(first) == 1
    assert (tmp_path / first.pop()).is_dir()
    launched, composed = _launched_configs([*args, "resume=true"], tmp_path, monkeypatch)
    # resume=true points hydra.sweep.dir at the first run after the checks: each job composed again, with it
    assert [[o for o in job if o.startswith("seed=")] for job in composed] == seeds * 2
    assert {directory for _, _, directory in launched} == {str(sorted((tmp_path / "multirun").glob("*/*"))[0])}
