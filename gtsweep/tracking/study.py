"""MLflow for parameter optimisation: one run per study, one nested child run per trial, written by the driver.

The study's run is found again by its tags (study name and storage), so a resumed study logs under the same
run; each child carries its trial number as the tag ``gtsweep.trial``, and trials that already have a child are
not logged twice. On (re)start, finished trials without a child (e.g. the process was killed between Optuna's
tell and the MLflow call, or a trial left RUNNING was marked FAIL) are logged first.

As for sweeps (:mod:`gtsweep.tracking.sweep`): the study's run logs the composed config and the data set's
fingerprint as params, each trial what it tried and what identifies it (detector and descriptor as written, seed,
data set, objective), run names are unique in the experiment (``trial-0004 · optimize/<study>``) and metrics other
than the headline ones are grouped under a prefix (:mod:`~gtsweep.tracking.metricnames`).
"""
from __future__ import annotations

import math
import sys
import time
from typing import Mapping

from gtsweep.tracking.metricnames import mlflow_name
from gtsweep.tracking.params import as_written, batches, config_params, dataset_params, parsed_config, written_options
from gtsweep.tracking.store import flatten, git_commit, open_store, tracking_uri
from gtsweep.tracking.tags import child_name, model_development, source_tags, unique_name

STUDY_TAG, STORAGE_TAG, ROLE_TAG, TRIAL_TAG = "gtsweep.study", "gtsweep.storage", "gtsweep.role", "gtsweep.trial"


def safe_storage(storage: str) -> str:
    """The storage URL without a password (it is written to MLflow tags)."""
    try:
        from sqlalchemy.engine import make_url

        return make_url(storage).render_as_string(hide_password=True)
    except Exception:
        return storage


def _ms(moment) -> int | None:
    return int(moment.timestamp() * 1000) if moment is not None else None


class StudyTracker:
    """Opens (or reopens) the study's run and logs trials as children: :meth:`log_trial`, then :meth:`end`."""

    def __init__(self, mlflow_cfg: Mapping, study, target, settings: Mapping, fingerprint: str, config_yaml: str):
        self.uri = tracking_uri(mlflow_cfg)
        self.settings = settings
        self.client, self.experiment_id = open_store(mlflow_cfg)
        model_development(self.client, self.experiment_id)
        self.source = source_tags()
        self.config, self.written = parsed_config(config_yaml), written_options()
        self.identity = self._identity(target, fingerprint)
        storage = safe_storage(settings["storage"])
        query = (f"tags.`{STUDY_TAG}` = '{study.study_name}' and tags.`{STORAGE_TAG}` = '{storage}' "
                 f"and tags.`{ROLE_TAG}` = 'study'")
        found = self.client.search_runs([self.experiment_id], query, max_results=1)
        if found:
            self.parent_id, self.run_name = found[0].info.run_id, found[0].info.run_name
            self.client.update_run(self.parent_id, status="RUNNING")
        else:
            self.parent_id = self._create_parent(study, target, storage, fingerprint, config_yaml)
        children = self.client.search_runs([self.experiment_id], f"tags.mlflow.parentRunId = '{self.parent_id}'",
                                           max_results=50000)
        self.logged = {int(r.data.tags[TRIAL_TAG]) for r in children if TRIAL_TAG in r.data.tags}
        from optuna.trial import TrialState

        for trial in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.FAIL)):
            self.log_trial(trial)

    def _identity(self, target, fingerprint: str) -> dict[str, str]:
        """What a trial's numbers depend on besides its parameters: methods as written, seed, data set, objective."""
        identity = {"detector": as_written(self.written, "detector", target.detector)}
        if target.descriptor:
            identity["descriptor"] = as_written(self.written, "descriptor", target.descriptor)
        if self.config.get("seed") is not None:
            identity["seed"] = str(self.config["seed"])
        return {**identity, "objective": str(self.settings["objective"]),
                **dataset_params(self.config, fingerprint)}

    def _create_parent(self, study, target, storage: str, fingerprint: str, config_yaml: str) -> str:
        tags = {STUDY_TAG: study.study_name, STORAGE_TAG: storage, ROLE_TAG: "study",
                "gtsweep.experiment": "optimize", "gtsweep.objective": self.settings["objective"],
                "gtsweep.detector": target.detector, "gtsweep.tuned_group": target.group,
                "gtsweep.dataset_fingerprint": fingerprint, "gtsweep.git_commit": git_commit(),
                "gtsweep.command": " ".join(["python -m gtsweep", *sys.argv[1:]]), **self.source}
        if target.descriptor:
            tags["gtsweep.descriptor"] = target.descriptor
        self.run_name = unique_name(self.client, self.experiment_id, f"optimize/{study.study_name}")
        run = self.client.create_run(self.experiment_id, run_name=self.run_name, tags=tags)
        keys = ("objective", "min_keypoints", "iou_threshold", "selector", "sampler_seed", "parallel_trials")
        params = {**config_params(self.config, fingerprint), **flatten({"search_space": target.space}),
                  **flatten({"defaults": target.defaults}), **flatten({k: self.settings.get(k) for k in keys})}
        for batch in batches(params):
            self.client.log_batch(run.info.run_id, params=batch)
        self.client.log_text(run.info.run_id, config_yaml, "config.yaml")
        return run.info.run_id

    def log_trial(self, trial) -> None:
        """One child run for a finished trial: its parameters, objective and metrics, state and error."""
        from mlflow.entities import Metric, RunTag

        if trial.number in self.logged:
            return
        state = trial.state.name
        tags = {"mlflow.parentRunId": self.parent_id, TRIAL_TAG: str(trial.number), "gtsweep.state": state,
                **self.source}
        if trial.user_attrs.get("error"):
            tags["gtsweep.reason"] = str(trial.user_attrs["error"])[:5000]
        elif state == "FAIL":
            tags["gtsweep.reason"] = "interrupted (the process stopped while the trial ran)"
        if trial.user_attrs.get("defaults"):
            tags["gtsweep.defaults"] = "true"
        name = child_name(f"trial-{trial.number:04d}", self.run_name)
        run = self.client.create_run(self.experiment_id, run_name=name, start_time=_ms(trial.datetime_start), tags=tags)
        now = int(time.time() * 1000)
        values = dict(trial.user_attrs.get("metrics") or {})
        if trial.value is not None:
            values["objective"] = trial.value
        metrics = [Metric(mlflow_name(k), float(v), now, 0) for k, v in values.items()
                   if isinstance(v, (int, float)) and math.isfinite(v)]
        params = list(batches({**self.identity, **{k: str(v) for k, v in trial.params.items()}})) or [[]]
        for index, batch in enumerate(params):
            self.client.log_batch(run.info.run_id, metrics=metrics if index == 0 else [], params=batch,
                                  tags=[RunTag(k, v) for k, v in tags.items() if k != "mlflow.parentRunId"]
                                  if index == 0 else [])
        self.client.set_terminated(run.info.run_id, "FINISHED" if state == "COMPLETE" else "FAILED",
                                   end_time=_ms(trial.datetime_complete))
        self.logged.add(trial.number)

    def end(self, study, artifacts=(), status: str = "FINISHED") -> None:
        """Log the best trial's numbers and the tuned config on the study's run, and close it."""
        from mlflow.entities import Metric, RunTag
        from optuna.trial import TrialState

        complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        now, step = int(time.time() * 1000), len(complete)
        metrics = [Metric("complete_trials", float(len(complete)), now, step)]
        tags = [RunTag("gtsweep.n_trials", str(self.settings["n_trials"]))]
        if complete:
            best = study.best_trial
            values = {_best(k): v for k, v in (best.user_attrs.get("metrics") or {}).items()}
            values["best_objective"] = best.value
            metrics += [Metric(k, float(v), now, step) for k, v in values.items()
                        if isinstance(v, (int, float)) and math.isfinite(v)]
            tags.append(RunTag("gtsweep.best_trial", str(best.number)))
        self.client.log_batch(self.parent_id, metrics=metrics, tags=tags)
        for path in artifacts:
            self.client.log_artifact(self.parent_id, str(path), "tuned")
        self.client.set_terminated(self.parent_id, status)


def _best(name: str) -> str:
    """The study's run's name for the best trial's metric: ``best_repeatability``, ``ci/best_repeatability_ci_low``."""
    head, sep, tail = mlflow_name(name).rpartition("/")
    return f"{head}{sep}best_{tail}"
