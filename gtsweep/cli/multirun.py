"""The end of ``-m``: one combined table and report across the jobs (:mod:`gtsweep.report.combine`) and the
multirun's MLflow run closed, by the Hydra callback ``hydra.callbacks.multirun`` of conf/config.yaml."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from hydra.experimental.callback import Callback

from gtsweep.core.rundirs import CELLS, COMBINED
from gtsweep.tracking.multirun import multirun_record


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
                print(f"multirun: jobs combined in {sweep_dir / COMBINED} (summary.md: mean ± std over the seeds)")
            record = multirun_record(sweep_dir)
            if record.get("parent_run_id"):
                from gtsweep.tracking.sweep import close_multirun

                close_multirun(config.mlflow, record["parent_run_id"],
                               [f for f in files if f.parent == sweep_dir / COMBINED], reason)
        finally:
            if failed:
                print(f"gtsweep: multirun: {reason}", file=sys.stderr)
                sys.exit(1)


def failed_cells(sweep_dir: Path) -> list[str]:
    """The cells of a multirun's jobs that ended in error, as ``<job>/<cell>`` (a job with failed cells lets the
    other jobs run; the multirun as a whole then fails)."""
    failed = []
    for cell in sorted(Path(sweep_dir).glob(f"*/{CELLS}/*.json")):
        try:
            status = json.loads(cell.read_text()).get("status")
        except (OSError, ValueError):
            continue
        if status == "error":
            failed.append(f"{cell.parent.parent.name}/{cell.stem}")
    return failed
