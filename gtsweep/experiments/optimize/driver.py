"""``experiment=optimize``: tune method parameters on the optimisation split, as the survey did (section 5).

One Optuna study per selected detector (objective ``repeatability``) or per ``[detector, descriptor]`` pairing
(objective ``pose_success``): :mod:`~gtsweep.experiments.optimize.targets`. Trials run on the sweep's executor (Ray
tasks, or in-process with ``runner.backend=serial``): :mod:`~gtsweep.experiments.optimize.optuna_study`. The study
lives in an RDB storage (sqlite by default): rerunning the same command continues it. Every trial is an MLflow child
run of the study's run (:mod:`gtsweep.tracking.study`). The best parameters are written as
``./tuned/<group>/tuned/<name>.yaml`` in the working directory (``experiment.tuned_root``), a config file Hydra
selects with ``detector=[tuned/<name>]`` (``./tuned`` is on the search path before the package's own tuned configs;
:mod:`~gtsweep.experiments.optimize.tuned_files`).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from gtsweep.core.config import plain
from gtsweep.core.interrupts import Interrupted
from gtsweep.core.paths import DEFAULT_TUNED_ROOT
from gtsweep.experiments.optimize.optuna_study import complete_trials, open_study, optimise
from gtsweep.experiments.optimize.study_settings import job_transforms, read_settings
from gtsweep.experiments.optimize.targets import build_targets, study_name
from gtsweep.experiments.optimize.tuned_files import (defaults_trial, describe_best, format_summary, tuned_header,
                                                      write_tuned)
from gtsweep.orchestration.cache import cache_directory
from gtsweep.orchestration.executor import backend, check_address, make_executor
from gtsweep.orchestration.shards import load_shards


def main(cfg, output_dir: str | Path) -> list[dict]:
    """Optimise every target of ``cfg``; print a summary per study; return the summaries."""
    from gtsweep.datasets import load_dataset
    from gtsweep.tracking.store import open_store

    output_dir = Path(output_dir)
    settings = read_settings(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    if backend(runner_cfg) == "ray":
        check_address(runner_cfg)
    targets = build_targets(cfg, settings)
    mlflow_cfg = plain(cfg.get("mlflow")) or {}
    if mlflow_cfg.get("enabled", True):  # the tracking store reachable (and created) before any work
        open_store(mlflow_cfg, mlflow_cfg.get("experiment") or "gtsweep")
    dataset = load_dataset(cfg["dataset"])
    shards = load_shards(dataset, job_transforms(settings), images="optimisation")  # a trial is one task
    executor = make_executor(runner_cfg, retries=0)  # a trial that kills its worker fails; the study goes on
    run = _Studies(cfg, settings, executor.put(shards), executor, int(cfg.get("seed", 0)), cache_directory(cfg),
                   dataset.fingerprint(), mlflow_cfg, output_dir, several=len(targets) > 1)  # shards put once
    summaries = [run.study(target) for target in targets]
    (output_dir / "optimize.json").write_text(json.dumps(summaries, indent=1, default=str))
    return summaries


@dataclass
class _Studies:
    """What every study of one ``experiment=optimize`` job shares: its settings, the optimisation shards (put to
    the executor once), the seed, caches, data set fingerprint and MLflow settings."""

    cfg: object
    settings: dict
    shards: object
    executor: object
    seed: int
    cache_dir: str | None
    fingerprint: str
    mlflow_cfg: dict
    output_dir: Path
    several: bool

    def study(self, target) -> dict:
        """Run (or continue) the study of ``target``, write its tuned config; its summary, also printed."""
        from omegaconf import OmegaConf

        from gtsweep.tracking.study import StudyTracker

        start, settings = time.perf_counter(), self.settings
        name = study_name(target, settings, self.fingerprint, self.seed, several=self.several)
        study = open_study(settings["storage"], name)
        tracker = None
        if self.mlflow_cfg.get("enabled", True):
            tracker = StudyTracker(self.mlflow_cfg, study, target, settings, self.fingerprint,
                                   OmegaConf.to_yaml(self.cfg, resolve=True))
        try:
            counts = optimise(study, target, settings, self.shards, self.executor, self.seed, self.cache_dir,
                              on_trial=tracker.log_trial if tracker else None)
            best = study.best_trial
        except BaseException as e:
            if tracker is not None:
                killed = isinstance(e, Interrupted) or isinstance(e.__cause__, Interrupted)  # Ray: SystemError
                tracker.end(study, [], status="KILLED" if killed else "FAILED")
            raise
        complete = len(complete_trials(study))
        header = tuned_header(target, settings, name, best, complete, self.fingerprint,
                              defaults_trial(complete_trials(study)))
        root = Path(settings.get("tuned_root") or DEFAULT_TUNED_ROOT).resolve()
        path = write_tuned(root / target.group / "tuned" / f"{target.name}.yaml", target, best.params, header)
        copy = write_tuned(self.output_dir / "tuned" / target.group / f"{target.name}.yaml", target, best.params,
                           header)
        if tracker is not None:
            tracker.end(study, [copy])
        summary = {"target": target.label, "group": target.group, "study": name, "storage": settings["storage"],
                   "best_trial": best.number, "best_value": best.value, "best_params": best.params,
                   "best": describe_best(best, settings), "metrics": best.user_attrs.get("metrics", {}),
                   "complete": complete, "new": counts["new"], "failed": counts["failed"],
                   "tuned_config": str(path), "mlflow_run": tracker.parent_id if tracker else None,
                   "seconds": time.perf_counter() - start}
        print(format_summary(summary, settings))
        return summary
