"""A resumed Optuna study gives the trials a clean run of the same seed gives: a kill -9 leaves trials RUNNING in the
storage (and may leave places of a batch unasked); the resume fails them, enqueues their parameters at their
place and asks the interrupted batch again before any new one."""
from __future__ import annotations

import optuna
import pytest
from optuna.distributions import IntDistribution

from gtsweep.experiments.optimize import optuna_study
from gtsweep.experiments.optimize.optuna_study import open_study, optimise
from gtsweep.experiments.optimize.targets import Target

SETTINGS = {"n_trials": 8, "parallel_trials": 2, "sampler_seed": 0, "n_startup_trials": 3, "enqueue_defaults": True}
TARGET = Target("detector", "fast", "fast", None, {}, {"threshold": 20}, {},
                {"threshold": IntDistribution(3, 60)}, {})


class Killed(Exception):
    """Stands in for kill -9: the process stops; what it had not told stays RUNNING in the storage."""


class FakeExecutor:
    """Evaluates a trial at once (score: a smooth function of the threshold); ``kill_after`` results told in
    all, it stops as a kill -9 would, before telling the next; ``kill_at_submit``: stops when that many trials
    have been submitted (a kill while a batch is being asked)."""

    def __init__(self, kill_after: int | None = None, kill_at_submit: int | None = None):
        self.queue, self.told, self.submitted = [], 0, 0
        self.kill_after, self.kill_at_submit = kill_after, kill_at_submit

    def submit(self, function, shards, job, tag=None):
        self.submitted += 1
        if self.kill_at_submit is not None and self.submitted == self.kill_at_submit:
            raise Killed
        self.queue.append((tag, {"metrics": {"score": -abs(tag.params["threshold"] - 33) / 10}}))

    def results(self):
        while self.queue:
            if self.kill_after is not None and self.told == self.kill_after:
                raise Killed
            self.told += 1
            yield self.queue.pop(0)


@pytest.fixture(autouse=True)
def _no_real_jobs(monkeypatch):
    monkeypatch.setattr(optuna_study, "trial_job", lambda *args: {})


def _completed(study) -> list[int]:
    """The complete trials' thresholds in the order a clean run asks them (batch, place)."""
    trials = sorted(optuna_study.complete_trials(study), key=lambda t: (t.user_attrs["batch"], t.user_attrs["slot"]))
    return [t.params["threshold"] for t in trials]


def _run(tmp_path, name: str, executor) -> optuna.Study:
    study = open_study(f"sqlite:///{tmp_path / 'optuna.db'}", name)
    optimise(study, TARGET, SETTINGS, None, executor, 0, None)
    return study


@pytest.mark.parametrize("kill", [{"kill_after": 3}, {"kill_after": 4}, {"kill_at_submit": 4},
                                  {"kill_at_submit": 6}, {"kill_after": 1}], ids=str)
def test_a_resumed_study_gives_the_clean_runs_trials(tmp_path, kill):
    clean = _completed(_run(tmp_path, "clean", FakeExecutor()))
    assert len(clean) == SETTINGS["n_trials"] and clean[0] == 20  # the defaults first
    with pytest.raises(Killed):
        _run(tmp_path, "killed", FakeExecutor(**kill))
    left = optuna.load_study(study_name="killed", storage=f"sqlite:///{tmp_path / 'optuna.db'}")
    assert left.get_trials(states=(optuna.trial.TrialState.RUNNING,))  # as kill -9 leaves them
    study = open_study(f"sqlite:///{tmp_path / 'optuna.db'}", "killed")
    assert not study.get_trials(states=(optuna.trial.TrialState.RUNNING,))  # failed, and enqueued again
    resumed = _completed(_run(tmp_path, "killed", FakeExecutor()))
    assert resumed == clean
