"""The Hydra task function: one job = one grid, evaluated by :func:`gtsweep.orchestration.sweep.run_sweep`.

Bad input stops with one line and exit code 2; Ctrl-C or SIGTERM stops the workers, marks the MLflow run KILLED
and prints how to resume (:mod:`gtsweep.cli.lifecycle`). The run's story goes to the job's log (``app.log``).
"""
from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
import pandas as pd
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from gtsweep.cli.lifecycle import (
    claim,
    exit_interrupted,
    interruptible,
    interruption,
    register_resolvers,
    stop_workers,
)
from gtsweep.cli.overrides import SWEEP_RECORD, fail, sweep_key
from gtsweep.cli.search import PRIMARY, PRIMARY_NAME, keyed_methods
from gtsweep.core.atomic import write_atomically
from gtsweep.core.configs import configs_of_sources, register_help_resolver
from gtsweep.core.errors import GtsweepError
from gtsweep.core.interrupts import Interrupted
from gtsweep.evaluation import schema
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.progress import Progress
from gtsweep.orchestration.results import swept_variants
from gtsweep.orchestration.sweep import SweepOutcome, run_sweep
from gtsweep.report.output import write_report
from gtsweep.report.samples import load_views
from gtsweep.report.scale import scale_from_config
from gtsweep.report.tables import Table, frame, sample_note

log = logging.getLogger(__name__)
register_resolvers()  # also in processes that only import this module (Hydra's joblib launcher workers)


def hydra_main() -> None:
    """Run the Hydra application on ``sys.argv`` (already checked and expanded by :func:`gtsweep.cli.main`)."""
    register_help_resolver()
    _app()


@hydra.main(config_path=PRIMARY, config_name=PRIMARY_NAME, version_base=None)
def _app(cfg: DictConfig) -> None:
    hydra_cfg = HydraConfig.get()
    keyed_methods(cfg, configs_of_sources(hydra_cfg.runtime.config_sources), hydra_cfg.overrides.task)
    output_dir = Path(hydra_cfg.runtime.output_dir)
    try:
        claim(output_dir)
        record = {"key": sweep_key(sys.argv[1:]), "argv": sys.argv[1:], "overrides": list(hydra_cfg.overrides.task)}
        write_atomically(output_dir / SWEEP_RECORD, json.dumps(record))
    except (GtsweepError, OSError) as e:
        fail(e if isinstance(e, GtsweepError) else f"cannot write the output directory {output_dir}: {e}")
    log.info("gtsweep %s in %s", " ".join(sys.argv[1:]), output_dir)
    with interruptible():
        if cfg.experiment.name == "optimize":  # parameter optimisation is its own driver
            _optimize(cfg, output_dir)
        else:
            _sweep(cfg, hydra_cfg, output_dir)


def _optimize(cfg: DictConfig, output_dir: Path) -> None:
    from gtsweep.optimize.driver import main as optimize_main

    try:
        optimize_main(cfg, output_dir)
    except GtsweepError as e:
        stop_workers()
        fail(e)
    except (Interrupted, Exception) as e:
        if (signal := interruption(e)) is None:
            raise
        stop_workers()
        exit_interrupted(signal, "finished trials are kept in the study")


def _sweep(cfg: DictConfig, hydra_cfg, output_dir: Path) -> None:
    tracker = None
    run, report, summarize = run_sweep, write_report, format_outcome
    if cfg.experiment.name == "localization":  # issue 19: a map per floor, queries against it
        from gtsweep.orchestration.localization import run_localization
        from gtsweep.report.localization import format_localization, write_localization_report

        run, report, summarize = run_localization, write_localization_report, format_localization
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
        outcome = run(cfg, output_dir, hooks=hooks, on_start=on_start, progress=progress,
                            on_checked=tracker.open if tracker is not None else None)
        progress.phase("report")
        scale = scale_from_config(OmegaConf.to_container(cfg, resolve=True))
        if report is write_report:
            tables, files = write_report(outcome.summaries, output_dir / "report", plots=cfg.report.plots,
                                         views=load_views(output_dir), by=cfg.report.by, alpha=cfg.report.alpha,
                                         scale=scale)
        else:
            tables, files = report(outcome.summaries, output_dir / "report", plots=cfg.report.plots)
        if tracker is not None:
            tracker.end(outcome, artifacts=files)
    except GtsweepError as e:
        progress.close()
        stop_workers()
        if tracker is not None:
            tracker.abort(str(e))
        fail(e)
    except (Interrupted, Exception) as e:
        if (signal := interruption(e)) is None:
            raise
        progress.close()
        stop_workers()
        if tracker is not None:
            tracker.abort(str(signal), status="KILLED")
        kept = len(list((output_dir / "cells").glob("*.json")))
        exit_interrupted(signal, f"{kept} finished cell(s) kept in {output_dir}")
    progress.close()
    summary = [summarize(outcome, tables), scale.line(),
               f"report: {len(files)} tables and plots in {output_dir / 'report'}"]
    if tracker is not None:
        summary.append(tracker.ui_hint())
    log.info("\n".join(summary))
    print("\n".join(summary))
    if outcome.failed:
        print(f"gtsweep: {len(outcome.failed)} cell(s) failed: {', '.join(outcome.failed)}", file=sys.stderr)
        sys.exit(1)


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


def headline_tables(outcome: SweepOutcome) -> dict[str, pd.DataFrame]:
    """Per transform: the experiment's headline metric, detector rows x descriptor (or selector) columns; the
    descriptor columns split by matcher and estimator when the grid has several."""
    table = frame(outcome.summaries)
    metric = schema.headline(outcome.grid.experiment["name"])
    columns = ["selector"] if outcome.grid.experiment["name"] == "detection" else \
        ["descriptor", *swept_variants(outcome.summaries)]
    tables = {}
    for transform, part in table.groupby("transform", sort=False):
        values = part[metric] if metric in part else pd.Series(float("nan"), index=part.index)
        shown = values.map(lambda v: "NA" if pd.isna(v) else f"{v:.2f}").where(part["status"] == "ok", "NA")
        pivot = part.assign(value=shown).pivot_table(index="detector", columns=columns, values="value",
                                                     aggfunc="first", sort=False)
        tables[f"{metric} ({sample_note(part)})"] = pivot
    return tables


def format_outcome(outcome: SweepOutcome, tables: list[Table] = ()) -> str:
    """Totals, then the survey's tables that the sweep fills (else the headline metric per transform)."""
    statuses = pd.Series([s["status"] for s in outcome.summaries])
    lines = [
        f"gtsweep: {len(outcome.summaries)} cells ({(statuses == 'ok').sum()} evaluated, "
        f"{(statuses == 'na').sum()} not applicable, {(statuses == 'error').sum()} failed, "
        f"{outcome.resumed} kept from an earlier run) in {outcome.seconds:.1f} s",
        f"keypoint cache: {outcome.stats.cache_hits} hits, {outcome.stats.cache_misses} misses "
        f"(= detector calls)" + (f", {outcome.stats.cache_corrupt} damaged entries replaced"
                                 if outcome.stats.cache_corrupt else ""),
        f"results: {outcome.table}",
    ]
    if outcome.skipped_items:
        lines.append(f"data set: {len(outcome.skipped_items)} bad item(s) skipped (dataset.skip_bad=true); "
                     f"listed in {outcome.output_dir / 'run.json'}")
    if tables:
        for table in tables:
            lines += ["", table.markdown()]
        lines += ["", "cells read 'ours [95 % interval] (paper)'; NA = not applicable"]
    else:
        for title, pivot in headline_tables(outcome).items():
            lines += ["", title, pivot.to_string()]
    return "\n".join(lines)
