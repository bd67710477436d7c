"""The Hydra task function: one job = one experiment, dispatched by its kind (:data:`gtsweep.experiments.kinds.
EXPERIMENTS`): a grid on the sweep skeleton (:func:`gtsweep.orchestration.skeleton.run_sweep`), or a job of its own;
its end in one line (:mod:`gtsweep.cli.lifecycle`), its story in the job's log (``app.log``)."""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from gtsweep.cli.lifecycle import fail, resume_command, stop
from gtsweep.cli.overrides import register_all
from gtsweep.core import interrupts
from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import GtsweepError
from gtsweep.core.interrupts import Interrupted, interruptible
from gtsweep.core.rundirs import REPORT, SWEEP_RECORD, claim
from gtsweep.experiments.kinds import EXPERIMENTS, Experiment, ReportOptions, run_sweep
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.resume_pick import command_key, kept_cells
from gtsweep.report.samples import load_views
from gtsweep.report.scale import scale_from_config
from gtsweep.tracking.multirun import job_run, multirun_record
from gtsweep.tracking.watchdog import watched

log = logging.getLogger(__name__)
register_all()  # also in processes that only import this module (Hydra's joblib launcher workers)


def app(cfg: DictConfig) -> None:
    """The task function Hydra runs for each job (:func:`gtsweep.cli.main`)."""
    hydra_cfg = HydraConfig.get()
    output_dir = Path(hydra_cfg.runtime.output_dir)
    overrides = list(hydra_cfg.overrides.task)
    sweep_dir = Path(hydra_cfg.sweep.dir) if hydra_cfg.mode == RunMode.MULTIRUN else None
    try:
        key = multirun_record(sweep_dir).get("key", "") if sweep_dir else command_key(overrides)  # its multirun's
        experiment = EXPERIMENTS.get(cfg.experiment.name)
        claim(output_dir)
        write_atomically(output_dir / SWEEP_RECORD, json.dumps({"key": key, "overrides": overrides}))
    except (GtsweepError, OSError) as e:
        fail(e if isinstance(e, GtsweepError) else f"cannot write the output directory {output_dir}: {e}")
    log.info("gtsweep %s in %s", " ".join(overrides), output_dir)
    with interruptible():
        if experiment.job is not None:  # a job of its own (parameter optimisation)
            _job(experiment, cfg, output_dir)
        elif cfg.runner.backend == "ray":
            with watched(output_dir, resume_command()):  # Ray may end this process from its compiled code
                _sweep(experiment, cfg, hydra_cfg, output_dir, sweep_dir)
        else:
            _sweep(experiment, cfg, hydra_cfg, output_dir, sweep_dir)


def _job(experiment: Experiment, cfg: DictConfig, output_dir: Path) -> None:
    try:
        experiment.job(cfg, output_dir)
    except (Interrupted, Exception) as e:
        stop(e, lambda: "finished trials are kept in the study")


def _sweep(experiment: Experiment, cfg: DictConfig, hydra_cfg, output_dir: Path, sweep_dir: Path | None) -> None:
    tracker = None
    progress = Progress(enabled=cfg.runner.progress)
    try:
        hooks, on_start = (), None
        if cfg.mlflow.enabled:
            from gtsweep.tracking.sweep import SweepTracker

            job = hydra_cfg.job.num if sweep_dir else None  # a single run has no job number
            name, nest_under = job_run(hydra_cfg.overrides.task, output_dir, sweep_dir, job)
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
        tables, files = experiment.report(outcome.summaries, output_dir / REPORT, options)
        if tracker is not None:
            tracker.end(outcome, artifacts=files)
    except (Interrupted, Exception) as e:  # bad input, Ctrl-C, or a failure anywhere (disk, store, cluster)
        progress.close()
        stop(e, lambda: kept_cells(output_dir), tracker.abort if tracker is not None else None)
    progress.close()
    summary = [experiment.summary(outcome, tables), scale.line(),
               f"report: {len(files)} tables and plots in {output_dir / REPORT}"]
    if tracker is not None:
        summary.append(tracker.ui_hint())
    log.info("\n".join(summary))
    if sweep_dir is None:  # the result is out: a late Ctrl-C does not change the exit code
        interrupts.finished()
    print("\n".join(summary))
    if outcome.failed:
        print(f"gtsweep: {len(outcome.failed)} cell(s) failed: {', '.join(outcome.failed)}", file=sys.stderr)
        if sweep_dir is None:  # in a multirun the other jobs still run; the multirun then exits 1 (cli.multirun)
            sys.exit(1)
