"""The command line's own pieces on Hydra's: near-miss hints, ./tuned serving tuned method files only, malformed
YAML named by file:line, Hydra's flags between overrides, settings of options that are not selected."""
from __future__ import annotations

import pytest

from gtsweep.cli import main as gtsweep_main
from gtsweep.cli import overrides as cli
from gtsweep.cli import search


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
    invocation = search.parse(["detector=[orb]", "--cfg", "job", "descriptor=[orb]", "-m", "seed=0,1"])
    assert invocation.overrides == ("detector=[orb]", "descriptor=[orb]", "seed=0,1") and invocation.multirun
    assert invocation.argv == ["detector=[orb]", "descriptor=[orb]", "seed=0,1", "--cfg", "job", "-m"]


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
    assert "planted" not in cli.options("detector")
    cfg = cli.compose_config(["sweeps=smoke"])
    assert "planted" not in cfg.detector and "sift" in cfg.detector
    assert cli.compose_config(["detector=[tuned/sift]"]).detector.sift.params.contrastThreshold == 0.031
    assert not (tmp_path / "PWNED").exists()


def test_gtsweeps_reading_of_hydras_flags_matches_hydras_parser():
    """gtsweep parses Hydra's command line without Hydra's private parser; this holds the two side by side."""
    from hydra._internal.utils import get_args_parser  # the test may look inside Hydra; the package does not

    def described(parser):
        return {tuple(sorted(a.option_strings)): (a.nargs, a.const, tuple(a.choices or ()), a.default is False)
                for a in parser._actions if a.option_strings}

    theirs, ours = described(get_args_parser()), described(search.hydra_flags())
    theirs[("--version",)] = ours[("--version",)]  # Hydra prints its version; gtsweep only needs to skip the flag
    assert ours == theirs
