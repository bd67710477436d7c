"""The optimiser's pose objective takes its matcher and estimator parameters from the matcher and estimator groups,
as a sweep does; the experiment's old keys are refused with their new place."""
from __future__ import annotations

import pytest

from gtsweep.cli import main as gtsweep_main
from gtsweep.experiments.optimize.study_settings import read_settings
from tests.sweep_helpers import compose_config


def test_the_pose_objective_reads_the_matcher_and_estimator_groups():
    survey = read_settings(compose_config(["experiment=optimize"]))
    assert (survey["ratio"], survey["mutual"]) == (0.7, False)
    assert survey["pose"] == {"model": "similarity", "iterations": 2000, "threshold": 3.0,
                              "max_position_error": 30.0, "max_orientation_error": 1.5}
    changed = read_settings(compose_config(["experiment=optimize", "matcher.bf_ratio.params.ratio=0.8",
                                            "estimator.ransac.params.iterations=500"]))
    assert changed["ratio"] == 0.8 and changed["pose"]["iterations"] == 500
    # a trial builds its matcher and estimator from the groups' parameters, as a sweep's pairing task does
    methods = changed["methods"]
    assert list(methods["matchers"]) == ["bf_ratio"] and methods["matchers"]["bf_ratio"]["ratio"] == 0.8
    assert list(methods["estimators"]) == ["ransac"] and methods["estimators"]["ransac"]["iterations"] == 500


def test_the_old_experiment_keys_name_their_new_place(capsys):
    with pytest.raises(SystemExit) as exit_info:
        gtsweep_main(["experiment=optimize", "experiment.ratio=0.8"])
    assert exit_info.value.code == 2
    assert "'experiment.ratio' moved to the matcher group" in capsys.readouterr().err
