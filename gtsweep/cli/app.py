"""The Hydra task function: one job = one experiment, dispatched by its kind (:data:`gtsweep.experiments.kinds.
EXPERIMENTS`): a grid on the sweep skeleton (:func:`gtsweep.orchestration.skeleton.run_sweep`), or a job of its own.

Bad input stops with one line and exit code 2; Ctrl-C or SIGTERM stops the workers, marks the MLflow run KILLED
and prints how to resume (:mod:`gtsweep.cli.lifecycle`). The run's story goes to the job's log (``app.log``).
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from gtsweep.cli.lifecycle import claim, fail, resume_command, stop
from gtsweep.cli.overrides import register_all
from gtsweep.cli.runs import SWEEP_RECORD, command_key
from gtsweep.cli.watchdog import watched
from gtsweep.core.atomic import write_atomically
from gtsweep.core import interrupts
from gtsweep.core.errors import GtsweepError
from gtsweep.core.interrupts import Interrupted, interruptible
from gtsweep.experiments.kinds import EXPERIMENTS, Experiment, ReportOptions, run_sweep
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.progress import Progress
from gtsweep.report.samples import load_views
from gtsweep.report.scale import scale_from_config

log = logging.getLogger(__name__)
register_all()  # also in processes that only import this module (Hydra's joblib launcher workers)


def app(cfg: DictConfig) -> None:
    """The task function Hydra runs for each job (:func:`gtsweep.cli.main`)."""
    hydra_cfg = HydraConfig.get()
    output_dir = Path(hydra_cfg.runtime.output_dir)
    overrides = list(hydra_cfg.overrides.task)
    try:
        experiment = EXPERIMENTS.get(cfg.experiment.name)
        claim(output_dir)
        write_atomically(output_dir / SWEEP_RECORD, json.dumps({"key": job_key(hydra_cfg), "overrides": overrides}))
    except (GtsweepError, OSError) as e:
        fail(e if isinstance(e, GtsweepError) else f"cannot write the output directory {output_dir}: {e}")
    log.info("gtsweep %s in %s", " ".join(overrides), output_dir)
    with interruptible():
        if experiment.job is not None:  # a job of its own (parameter optimisation)
            _job(experiment, cfg, output_dir)
        elif cfg.runner.backend == "ray":
            with watched(output_dir, resume_command()):  # Ray may end this process from its compiled code
                _sweep(experiment, cfg, hydra_cfg, output_dir)
        else:
            _sweep(experiment, cfg, hydra_cfg, output_dir)


def _job(experiment: Experiment, cfg: DictConfig, output_dir: Path) -> None:
    try:
        experiment.job(cfg, output_dir)
    except (Interrupted, Exception) as e:
        stop(e, lambda: "finished trials are kept in the study")


def _sweep(experiment: Experiment, cfg: DictConfig, hydra_cfg, output_dir: Path) -> None:
    tracker = None
    progress = Progress(enabled=cfg.runner.progress)
    try:
        hooks, on_start = (), None
        if cfg.mlflow.enabled:
            from gtsweep.tracking.sweep import SweepTracker

            name, nest_under = parent_run(hydra_cfg, output_dir)
            tracker = SweepTracker(cfg.mlflow, output_dir, OmegaConf.to_yaml(cfg, resolve=True), run_name=name,
                                   nest_under=nest_under)
            hooks = (tracker.log_cell,)
            on_start = lambda grid, fingerprint: tracker.start(grid, fingerprint, library_versions())  # noqa: E731
        outcome = run_sweep(cfg, output_dir, hooks=hooks, on_start=on_start, progress=progress,
                            on_checked=tracker.open if tracker is not None else None, work=experiment.cells)
        progress.phase("report")
        scale = scale_from_config(OmegaConf.to_container(cfg, resolve=True))
        options = ReportOptions(plots=cfg.report.plots, views=lambda: load_views(output_dir), by=cfg.report.by,
                                alpha=cfg.report.alpha, scale=scale)
        tables, files = experiment.report(outcome.summaries, output_dir / "report", options)
        if tracker is not None:
            tracker.end(outcome, artifacts=files)
    except (Interrupted, Exception) as e:  # bad input, Ctrl-C, or a failure anywhere (disk, store, cluster)
        progress.close()
        stop(e, lambda: f"{len(list((output_dir / 'cells').glob('*.json')))} finished cell(s) kept in {output_dir}",
             tracker.abort if tracker is not None else None)
    progress.close()
    summary = [experiment.summary(outcome, tables), scale.line(),
               f"report: {len(files)} tables and plots in {output_dir / 'report'}"]
    if tracker is not None:
        summary.append(tracker.ui_hint())
    log.info("\n".join(summary))
    if hydra_cfg.mode.name != "MULTIRUN":  # the result is out: a late Ctrl-C does not change the exit code
        interrupts.finished()
    print("\n".join(summary))
    if outcome.failed:
        print(f"gtsweep: {len(outcome.failed)} cell(s) failed: {', '.join(outcome.failed)}", file=sys.stderr)
        from hydra.types import RunMode

        if hydra_cfg.mode != RunMode.MULTIRUN:
            sys.exit(1)
        # in a multirun the other jobs still run and are combined; the multirun then exits 1 (gtsweep.cli.multirun)


def job_key(hydra_cfg) -> str:
    """The command a job belongs to (:func:`gtsweep.cli.runs.command_key`): its own, or its multirun's."""
    from hydra.types import RunMode

    from gtsweep.cli.multirun import multirun_record

    if hydra_cfg.mode != RunMode.MULTIRUN:
        return command_key(hydra_cfg.overrides.task)
    return multirun_record(Path(hydra_cfg.sweep.dir)).get("key", "")


def parent_run(hydra_cfg, output_dir: Path) -> tuple[str, str | None]:
    """The name of the sweep's MLflow run (its job's overrides; in a multirun, the swept ones) and the run of the
    multirun it nests under (None for a single run)."""
    from hydra.types import RunMode

    from gtsweep.cli.multirun import multirun_record
    from gtsweep.tracking.tags import overrides_name

    overrides = list(hydra_cfg.overrides.task)
    if hydra_cfg.mode != RunMode.MULTIRUN:
        return overrides_name(overrides, output_dir.name), None
    record = multirun_record(Path(hydra_cfg.sweep.dir))
    swept = [o for o in overrides if o.lstrip("+").split("=")[0] in record.get("swept", [])]
    return overrides_name(swept or overrides, f"job {hydra_cfg.job.num}"), record.get("parent_run_id")
