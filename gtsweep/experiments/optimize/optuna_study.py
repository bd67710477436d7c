"""One Optuna study: open (or continue) it, then ask, evaluate on the executor, tell, until ``n_trials`` are
complete.

The driver asks ``parallel_trials`` trials at a time, submits them to the executor, tells each result as it
arrives, and asks the next batch when the batch is done. Before each ask the TPE sampler is re-seeded from
``sampler_seed``, the batch (the number of complete trials when it began) and the trial's place in it, so the same
config and seed give the same trials and numbers, on Ray or in-process alike. Trials left RUNNING by a kill are
marked FAIL and their parameters enqueued (Optuna's ``enqueue_trial``) at their place: the resume asks the
interrupted batch again, retries first, before any new batch, so it gives the trials a clean run gives.
"""
from __future__ import annotations

import hashlib
import tempfile
import warnings
from pathlib import Path
from typing import Mapping

from filelock import FileLock, Timeout

from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.seeds import stable_seed
from gtsweep.experiments.optimize.objective import evaluate
from gtsweep.experiments.optimize.search_space import defaults_in_space
from gtsweep.experiments.optimize.stopping import settled
from gtsweep.experiments.optimize.study_settings import job_transforms
from gtsweep.experiments.optimize.targets import Target

#: The studies this process optimises (their locks are held for the process's life).
_owned: dict[tuple[str, str], FileLock] = {}


def study_lock(storage: str, name: str) -> Path:
    """The lock file of study ``name`` in ``storage``: beside a sqlite database, else in the temporary folder
    (so two runs of one machine exclude each other)."""
    digest = hashlib.sha256(f"{storage}\0{name}".encode()).hexdigest()[:16]
    if storage.startswith("sqlite:///"):
        return Path(storage[len("sqlite:///"):]).with_name(f".optuna-study-{digest}.lock")
    return Path(tempfile.gettempdir()) / f"gtsweep-study-{digest}.lock"


def own_study(storage: str, name: str) -> None:
    """Take study ``name`` for this process: a second identical study started meanwhile stops with one line
    (it would otherwise take the first's live trials for a kill's leftovers and fail them). A killed process's
    lock goes with it, so a resume still finds the study free."""
    if (storage, name) in _owned:
        return
    lock = FileLock(study_lock(storage, name), timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise BadInput(f"the study '{name}' is being optimised by another run right now; wait for it to finish "
                       f"(its trials are shared: this run would then continue it)") from None
    _owned[(storage, name)] = lock


def open_study(storage: str, name: str):
    """Create or load the study, owned by this process (:func:`own_study`); trials left RUNNING by a kill become
    FAIL and their parameters are asked again."""
    import optuna
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    if storage.startswith("sqlite:///"):
        Path(storage[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    own_study(storage, name)
    try:
        rdb = optuna.storages.RDBStorage(storage, engine_kwargs={"connect_args": {"timeout": 60}}
                                         if storage.startswith("sqlite") else None)
        study = optuna.create_study(study_name=name, storage=rdb, direction="maximize", load_if_exists=True)
    except Exception as e:  # bad URL, unreachable database
        raise BadInput(f"cannot open the Optuna storage '{storage}': {str(e).strip().splitlines()[0]}") from None
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study.tell(trial.number, state=TrialState.FAIL)
        if "retry_of" not in trial.user_attrs:  # a trial that was itself retried may have crashed the process
            place = {k: trial.user_attrs[k] for k in SLOT_ATTRS if k in trial.user_attrs}
            study.enqueue_trial(trial.params, user_attrs={"retry_of": trial.number, **place})
    return study


#: Where a trial stands in the sequence a clean run asks: the batch (complete trials when it was asked) and its
#: place in the batch. Its sampler is seeded from both, so a trial's parameters do not depend on how many were asked
#: before it in its process (a resume asks an interrupted batch's missing places as the clean run did).
SLOT_ATTRS = ("batch", "slot")


def batch_places(study, done: int, parallel: int, n_trials: int) -> tuple[int, list[int]]:
    """The batch to ask and its places: a fresh batch at ``done`` complete trials, or the batch a kill interrupted
    (its retries are waiting): its places with a retry, then those the kill left unasked, as the clean run asked
    them (the places of it that completed or failed are not asked again)."""
    from optuna.trial import TrialState

    retries = [t for t in study.get_trials(deepcopy=False, states=(TrialState.WAITING,))
               if "retry_of" in t.user_attrs and "batch" in t.user_attrs]
    if not retries:
        return done, list(range(min(parallel, n_trials - done)))
    batch = retries[0].user_attrs["batch"]
    asked = {t.user_attrs["slot"] for t in study.get_trials(deepcopy=False)
             if t.user_attrs.get("batch") == batch and "slot" in t.user_attrs}
    pending = {t.user_attrs["slot"] for t in retries if t.user_attrs["batch"] == batch}
    unasked = set(range(min(parallel, n_trials - batch))) - asked
    return batch, sorted(pending | unasked)


def complete_trials(study) -> list:
    from optuna.trial import TrialState

    return study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))


def trial_job(target: Target, settings: Mapping, values: Mapping, seed: int, cache_dir: str | None) -> dict:
    """The work of one trial for :func:`gtsweep.experiments.optimize.objective.evaluate`."""
    tuned = {**target.defaults, **values}
    detector_params = tuned if target.group == "detector" else target.detector_params
    return {"objective": settings["objective"], "detector": target.detector, "detector_params": detector_params,
            "descriptor": target.descriptor, "descriptor_params": tuned if target.group == "descriptor" else {},
            "selector": settings["selector"]["name"], "selector_params": dict(settings["selector"].get("params") or {}),
            "transforms": job_transforms(settings), "seed": seed, "cache_dir": cache_dir, "declared": target.declared,
            "settings": {k: settings.get(k) for k in ("min_keypoints", "iou_threshold", "pose", "methods")}}


def optimise(study, target: Target, settings: Mapping, shards, executor, seed: int, cache_dir: str | None,
             on_trial=None) -> dict:
    """Run trials on ``executor`` until ``n_trials`` are complete; returns counts for the summary.

    ``shards``: the executor's handle of the optimisation shards (:func:`gtsweep.orchestration.shards.load_shards`).
    """
    import optuna

    n_trials, parallel = settings["n_trials"], settings["parallel_trials"]
    if settings.get("enqueue_defaults", True) and not study.trials:
        start = defaults_in_space(target.distributions, target.defaults)
        if start is not None:  # the defaults are trial 0: the tuned result is never worse on these images
            study.enqueue_trial(start, user_attrs={"defaults": True})
    new = failed = 0
    last_error = ""
    while (done := len(complete_trials(study))) < n_trials and not settled(
            [t.value for t in complete_trials(study)], settings.get("patience"), settings.get("min_improvement") or 0):
        batch, places = batch_places(study, done, parallel, n_trials)
        for place in places:
            study.sampler = optuna.samplers.TPESampler(seed=stable_seed(settings["sampler_seed"], batch, place),
                                                       n_startup_trials=settings["n_startup_trials"])
            trial = study.ask(target.distributions)  # an enqueued trial first (the defaults, a killed trial's retry)
            for key, value in (("batch", batch), ("slot", place)):
                if key not in trial.user_attrs:  # a retry keeps the place it was enqueued with
                    trial.set_user_attr(key, value)
            executor.submit(evaluate, shards, trial_job(target, settings, trial.params, seed, cache_dir), tag=trial)
        for trial, result in executor.results():
            if "metrics" in result:
                trial.set_user_attr("metrics", result["metrics"])
                frozen = study.tell(trial, result["metrics"]["score"])
                new += 1
            else:
                trial.set_user_attr("error", result["error"])
                frozen = study.tell(trial, state=optuna.trial.TrialState.FAIL)
                failed, last_error = failed + 1, result["error"]
            if on_trial is not None:
                on_trial(frozen)
        if failed > max(n_trials, parallel):
            raise GtsweepError(f"{target.label}: {failed} trials failed; the last: {last_error}")
    return {"new": new, "failed": failed}
