"""A tuned file's header states the study, why it stopped, the defaults' and the best trial's scores; the
reproduction's parameter table is read back from it (no study database needed)."""
from types import SimpleNamespace

from gtsweep.experiments.optimize.targets import Target
from gtsweep.experiments.optimize.tuned_files import defaults_trial, stop_reason, tuned_header, write_tuned
from gtsweep.report.tuning import read_header, tuning_table

SETTINGS = {"objective": "repeatability", "min_keypoints": 100, "storage": "sqlite:///.gtsweep_cache/optuna.db",
            "n_trials": 200, "patience": 20, "min_improvement": 0.005,
            "selector": {"name": "anms", "params": {"n": 1000}}}


def _trial(number, score, repeatability, few, defaults=False):
    metrics = {"repeatability": repeatability, "n_few": few, "n_views": 144}
    attrs = {"metrics": metrics, **({"defaults": True} if defaults else {})}
    return SimpleNamespace(number=number, value=score, user_attrs=attrs)


def _target():
    node = {"params": {"delta": 5, "min_area": 60}, "search_space": {"delta": {"type": "int", "low": 1, "high": 10}}}
    return Target("detector", "mser", "mser", None, node, dict(node["params"]), node["search_space"], {}, {})


def test_the_header_round_trips_into_the_parameter_table(tmp_path):
    trials = [_trial(0, -2.49, 0.51, 3, defaults=True), _trial(1, 0.4, 0.4, 0), _trial(7, 0.6012, 0.6012, 0)]
    assert defaults_trial(trials) is trials[0]
    header = tuned_header(_target(), SETTINGS, "mser-repeatability-abc", trials[2], 28, "9e16", trials[0])
    path = write_tuned(tmp_path / "mser.yaml", _target(), {"delta": 2}, header)
    row = read_header(path)
    assert row == {"detector": "mser", "trials": 28, "best_trial": 7, "tuned_repeatability": 0.6012,
                   "tuned_few": 0, "views": 144, "min_keypoints": 100, "defaults_repeatability": 0.51,
                   "defaults_few": 3, "stop": "no gain > 0.005 in the last 20 trials", "selector": "anms",
                   "fingerprint": "9e16", "values": {"delta": 2}}
    table = tuning_table(tmp_path).splitlines()
    assert table[0].startswith("| detector | trials | stopped | selector | views < 100 KPs (defaults → tuned) of views")
    assert table[2] == ("| mser | 28 | no gain > 0.005 in the last 20 trials | anms | 3 → 0 of 144 | 0.51 → 0.60 "
                        "| delta=2 |")


def test_a_study_that_ran_out_of_trials_says_so():
    assert stop_reason(200, SETTINGS) == "stopped: n_trials = 200 reached (patience 20)"
    assert stop_reason(30, {**SETTINGS, "n_trials": 30, "patience": None}) == "stopped: n_trials = 30 reached"
    assert stop_reason(41, SETTINGS) == "stopped: no gain > 0.005 in the last 20 trials"


def test_an_older_header_gives_what_it_states(tmp_path):
    (tmp_path / "sift.yaml").write_text(
        "# @package detector\n# Tuned by gtsweep experiment=optimize on 2026-11-21 08:26:32: study 'x'\n"
        "# (sqlite:///.gtsweep_cache/optuna.db), best of 10 complete trials: trial 4,\n"
        "# objective repeatability: score 0.7234 = repeatability 0.7234 - 0 of 216 views with < 100 keypoints.\n"
        "# Data set fingerprint 47746f8e4d9c3386.\n"
        "sift:\n  params:\n    contrastThreshold: 0.0138\n  search_space:\n"
        "    contrastThreshold: {type: float, low: 0.005, high: 0.1}\n")
    expected = "| sift | 10 | ? | ? | 0 of 216 | 0.72 | contrastThreshold=0.0138 |"
    assert tuning_table(tmp_path).splitlines()[2] == expected
