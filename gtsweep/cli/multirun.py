"""``-m``: one MLflow run that holds the jobs' runs (opened by the sweeper once every job is checked), and at the
end one combined table and report across the jobs (:mod:`gtsweep.report.combine`), by the Hydra callback
``hydra.callbacks.multirun`` of conf/config.yaml."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from hydra.experimental.callback import Callback

MULTIRUN_RECORD = "multirun.json"


def multirun_record(sweep_dir: Path) -> dict:
    """What the callback recorded for the jobs: the swept keys and the MLflow run they nest under."""
    path = Path(sweep_dir) / MULTIRUN_RECORD
    return json.loads(path.read_text()) if path.exists() else {}


def swept_keys(overrides) -> list[str]:
    """The keys a multirun sweeps over (``seed=0,1``; ``detector=glob(a*)``)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return [o.key_or_group for o in OverridesParser.create().parse_overrides(list(overrides)) if o.is_sweep_override()]


def open_multirun_run(config) -> None:
    """Record the swept keys and open the multirun's MLflow run (once its jobs are checked: the sweeper)."""
    from gtsweep.tracking.tags import overrides_name

    sweep_dir = Path(config.hydra.sweep.dir)
    overrides = list(config.hydra.overrides.task)
    record = {**multirun_record(sweep_dir), "swept": swept_keys(overrides)}
    if config.mlflow.enabled:
        from gtsweep.tracking.sweep import open_multirun

        swept = [o for o in overrides if o.lstrip("+").split("=")[0] in record["swept"]]
        record["parent_run_id"] = open_multirun(config.mlflow, "multirun " + overrides_name(swept, ""),
                                                sweep_dir, record.get("parent_run_id"))
    (sweep_dir / MULTIRUN_RECORD).write_text(json.dumps(record))


class MultirunReport(Callback):
    """Combines the jobs' results after them and closes the multirun's MLflow run."""

    def on_multirun_end(self, config, **kwargs) -> None:
        from gtsweep.core.errors import GtsweepError
        from gtsweep.experiments.kinds import combine_multirun

        sweep_dir = Path(config.hydra.sweep.dir)
        failed = failed_cells(sweep_dir)
        reason = f"{len(failed)} cell(s) failed: {', '.join(failed)}" if failed else ""
        try:  # Hydra turns a callback's exception into a warning: failed cells must still end the multirun in 1
            try:
                files = combine_multirun(sweep_dir, plots=config.report.plots, by=config.report.by,
                                alpha=config.report.alpha)
            except GtsweepError as e:
                print(f"gtsweep: multirun: nothing combined ({e})")
                files = []
            else:
                print(f"multirun: jobs combined in {sweep_dir / 'combined'} (summary.md: mean ± std over the seeds)")
            record = multirun_record(sweep_dir)
            if record.get("parent_run_id"):
                from gtsweep.tracking.sweep import close_multirun

                close_multirun(config.mlflow, record["parent_run_id"],
                               [f for f in files if f.parent == sweep_dir / "combined"], reason)
        finally:
            if failed:
                print(f"gtsweep: multirun: {reason}", file=sys.stderr)
                sys.exit(1)


def failed_cells(sweep_dir: Path) -> list[str]:
    """The cells of a multirun's jobs that ended in error, as ``<job>/<cell>`` (a job with failed cells lets the
    other jobs run; the multirun as a whole then fails)."""
    failed = []
    for cell in sorted(Path(sweep_dir).glob("*/cells/*.json")):
        try:
            status = json.loads(cell.read_text()).get("status")
        except (OSError, ValueError):
            continue
        if status == "error":
            failed.append(f"{cell.parent.parent.name}/{cell.stem}")
    return failed
