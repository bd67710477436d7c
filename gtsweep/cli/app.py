"""The Hydra task function: one job = one grid, evaluated by :func:`gtsweep.orchestration.sweep.run_sweep`.

Bad input stops with one line and exit code 2; Ctrl-C or SIGTERM stops the workers, marks the MLflow run KILLED
and prints how to resume (:mod:`gtsweep.cli.lifecycle`).
"""
from __future__ import annotations

import json
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
from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import GtsweepError
from gtsweep.core.interrupts import Interrupted
from gtsweep.core.paths import CONF_DIR
from gtsweep.evaluation import schema
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.results import summary_table
from gtsweep.orchestration.sweep import SweepOutcome, run_sweep
from gtsweep.report.tables import Table, write_report

register_resolvers()  # also in processes that only import this module (Hydra's joblib launcher workers)


def hydra_main() -> None:
    """Run the Hydra application on ``sys.argv`` (already checked and expanded by :func:`gtsweep.cli.main`)."""
    _app()


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base=None)
def _app(cfg: DictConfig) -> None:
    output_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        claim(output_dir)
        record = {"key": sweep_key(sys.argv[1:]), "argv": sys.argv[1:]}
        write_atomically(output_dir / SWEEP_RECORD, json.dumps(record))
    except (GtsweepError, OSError) as e:
        fail(e if isinstance(e, GtsweepError) else f"cannot write the output directory {output_dir}: {e}")
    with interruptible():
        if cfg.experiment.name == "optimize":  # parameter optimisation is its own driver
            _optimize(cfg, output_dir)
        else:
            _sweep(cfg, output_dir)


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


def _sweep(cfg: DictConfig, output_dir: Path) -> None:
    tracker = None
    try:
        hooks, on_start = (), None
        if cfg.mlflow.enabled:
            from gtsweep.tracking.sweep import SweepTracker

            tracker = SweepTracker(cfg.mlflow, output_dir, OmegaConf.to_yaml(cfg, resolve=True),
                                   run_name=f"{output_dir.parent.name}/{output_dir.name}")
            hooks = (tracker.log_cell,)
            on_start = lambda grid, fingerprint: tracker.start(grid, fingerprint, library_versions())  # noqa: E731
        outcome = run_sweep(cfg, output_dir, hooks=hooks, on_start=on_start,
                            on_checked=tracker.open if tracker is not None else None)
        tables, files = write_report(outcome.summaries, output_dir / "report", plots=cfg.report.plots)
        if tracker is not None:
            tracker.end(outcome, artifacts=files)
    except GtsweepError as e:
        stop_workers()
        if tracker is not None:
            tracker.abort(str(e))
        fail(e)
    except (Interrupted, Exception) as e:
        if (signal := interruption(e)) is None:
            raise
        stop_workers()
        if tracker is not None:
            tracker.abort(str(signal), status="KILLED")
        kept = len(list((output_dir / "cells").glob("*.json")))
        exit_interrupted(signal, f"{kept} finished cell(s) kept in {output_dir}")
    print(format_outcome(outcome, tables))
    print(f"report: {len(files)} tables and plots in {output_dir / 'report'}")
    if tracker is not None:
        print(f"MLflow: parent run {tracker.parent_id} in {tracker.uri} (make ui, then open http://127.0.0.1:5000)")
    if outcome.failed:
        print(f"gtsweep: {len(outcome.failed)} cell(s) failed: {', '.join(outcome.failed)}", file=sys.stderr)
        sys.exit(1)


def headline_tables(outcome: SweepOutcome) -> dict[str, pd.DataFrame]:
    """Per transform: the experiment's headline metric, detector rows x descriptor (or selector) columns."""
    table = summary_table(outcome.summaries)
    metric = schema.headline(outcome.grid.experiment["name"])
    columns = "selector" if outcome.grid.experiment["name"] == "detection" else "descriptor"
    tables = {}
    for transform, part in table.groupby("transform", sort=False):
        values = part[metric] if metric in part else pd.Series(float("nan"), index=part.index)
        shown = values.map(lambda v: "NA" if pd.isna(v) else f"{v:.2f}").where(part["status"] == "ok", "NA")
        pivot = part.assign(value=shown).pivot_table(index="detector", columns=columns, values="value",
                                                     aggfunc="first", sort=False)
        tables[f"{metric} ({transform})"] = pivot
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
        lines += ["", "cells read 'ours (paper)'; NA = the pairing cannot be evaluated"]
    else:
        for title, pivot in headline_tables(outcome).items():
            lines += ["", title, pivot.to_string()]
    return "\n".join(lines)
