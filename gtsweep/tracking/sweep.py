"""MLflow tracking: one parent run per sweep, one child run per cell, written by the driver alone.

Several processes writing one sqlite store at once corrupt it, so workers return plain rows and only the driver
logs, with ``MlflowClient.log_batch`` (about 4x faster than one call per metric). The default store is
``sqlite:///<cwd>/mlflow.db`` (MLflow 3's default); ``mlflow.tracking_uri`` or ``MLFLOW_TRACKING_URI`` selects a
server. A resumed sweep reuses its parent run and logs only cells that have no child run yet; a cell computed again
with another configuration replaces its old child, which is deleted.

As the UI expects (:mod:`gtsweep.tracking.tags`): the experiment is marked as model development and has a saved
view for comparing pairings (:mod:`~gtsweep.tracking.views`), every run carries MLflow's source, user and
git-commit tags, run names are unique in the experiment (a child's: ``sift·brief·inc · seed=1``), a child run starts
and ends when its cell's tasks ran and holds the cell's per-view rows (``views.csv``) and, with strengths, its
curves as a figure (:mod:`~gtsweep.tracking.figures`); the jobs of a multirun nest under one run. What identifies
a run is logged as params (:mod:`~gtsweep.tracking.params`); metrics other than the headline ones are grouped under
a prefix (:mod:`~gtsweep.tracking.metricnames`).
"""
from __future__ import annotations

import json
import logging
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Mapping

from gtsweep.core import interrupts
from gtsweep.core.rundirs import CELLS, COMBINED, PARENT_RECORD, REPORT, RUN_RECORD
from gtsweep.tracking.closing import REASON_TAG, clear_reason, mark_ended, reopen
from gtsweep.tracking.figures import FIGURE, strength_figure
from gtsweep.tracking.metricnames import SWEEP, mlflow_name
from gtsweep.tracking.params import batches, cell_params, config_params, method_tags, parsed_config, written_options
from gtsweep.tracking.store import experiment_name, git_commit, open_store, tracking_uri
from gtsweep.tracking.tags import (PAIRING_TAG, cell_names, child_name, cluster_tags, model_development, ms,
                                   pairing_label, quiet_mlflow, source_tags, unique_name)
from gtsweep.tracking.views import runs_url, save_pairings_view

CELL_TAG, HASH_TAG, STATUS_TAG = "gtsweep.cell", "gtsweep.hash", "gtsweep.status"
MAX_BATCH = 1000  # metrics per MlflowClient.log_batch call
VIEWS_FILE = "views.csv"  # a child run's per-view rows (one name in every run: MLflow's compare page shows them)


VIEWS_TAG = "gtsweep.n_views"
STALE_TAG = "gtsweep.stale"  # a deleted child whose cell was computed again with another configuration


def step_scale(values) -> int:
    """Metric steps must be integers: strengths are used as they are when integral, else times 100."""
    return 1 if all(float(v).is_integer() for v in values) else 100


class SweepTracker:
    """Logs a sweep to MLflow. Use :meth:`start`, then :meth:`log_cell` per cell (a sweep hook), then :meth:`end`."""

    def __init__(self, cfg: Mapping | None, output_dir: str | Path, config_yaml: str, run_name: str,
                 nest_under: str | None = None):
        import mlflow
        from mlflow.tracking import MlflowClient

        quiet_mlflow()
        # a store error (locked, full) is the sweep's one line (gtsweep.cli.lifecycle), not MLflow's traceback
        logging.getLogger("mlflow.store.db.utils").setLevel(logging.CRITICAL)
        self.cfg = cfg
        self.uri = tracking_uri(cfg)
        self.experiment_name = experiment_name(cfg)
        self.output_dir = Path(output_dir)
        self.config_yaml = config_yaml
        self.run_name, self.nest_under = run_name, nest_under  # nest_under: a multirun's run
        mlflow.set_tracking_uri(self.uri)
        self.client: MlflowClient | None = None
        self.experiment_id: str | None = None
        self.parent_id: str | None = None
        self.logged: set[tuple[str, str]] = set()  # (cell key, config hash) already logged under the parent
        self.children: dict[str, dict[str, str]] = {}  # cell key -> config hash -> its child run (on resume)

    def open(self) -> None:
        """Reach the store and its experiment (before any work: a sweep hook ``on_checked``)."""
        if self.client is None:
            self.client, self.experiment_id = open_store(self.cfg, self.experiment_name)

    def start(self, grid, dataset_fingerprint: str, versions: Mapping) -> None:
        """Create (or, on resume, reopen) the parent run."""
        self.open()
        model_development(self.client, self.experiment_id)
        save_pairings_view(self.client, self.experiment_id, CELL_TAG)
        self.names = cell_names(grid.cells, several_selectors=len(grid.selectors) > 1)
        self.source = source_tags()
        self.config, self.fingerprint, self.written = parsed_config(self.config_yaml), dataset_fingerprint, \
            written_options()
        self.output_dir.mkdir(parents=True, exist_ok=True)
        self.sweep_name = self.client.get_run(self.nest_under).info.run_name if self.nest_under else None
        record = self.output_dir / PARENT_RECORD
        if record.exists():
            self.parent_id = json.loads(record.read_text())["parent_run_id"]
            reopen(self.client, self.parent_id)
            self.run_name = self.client.get_run(self.parent_id).info.run_name
            self.logged = self._logged_children(self.experiment_id)
        else:
            tags = {"gtsweep.command": " ".join(["python -m gtsweep", *sys.argv[1:]]),
                    "gtsweep.git_commit": git_commit(),
                    "gtsweep.dataset_fingerprint": dataset_fingerprint, "gtsweep.output_dir": str(self.output_dir),
                    "gtsweep.experiment": grid.experiment["name"], **self.source,
                    **{f"gtsweep.version.{k}": str(v) for k, v in versions.items()}}
            if self.nest_under:
                tags["mlflow.parentRunId"] = self.nest_under
            self.run_name = unique_name(self.client, self.experiment_id, self.run_name)
            run = self.client.create_run(self.experiment_id, run_name=self.run_name, tags=tags)
            self.parent_id = run.info.run_id
            for params in batches(config_params(self.config, dataset_fingerprint)):
                self.client.log_batch(self.parent_id, params=params)
            self.client.log_text(self.parent_id, self.config_yaml, "config.yaml")
            record.write_text(json.dumps({"parent_run_id": self.parent_id, "tracking_uri": self.uri}))
        self.grid = grid

    def _logged_children(self, experiment_id: str) -> set[tuple[str, str]]:
        """(cell, hash) of the child runs already complete under the parent (a resumed sweep logs no duplicates).

        A child counts only when it ended (FINISHED or FAILED) with its status tag and, for an evaluated cell, its
        metrics: a child that a kill left RUNNING or half-logged is deleted, and the cell, complete on disk, is
        logged again by the resume. A cell that failed is computed again on resume: its old child is deleted too.
        """
        runs = self.client.search_runs([experiment_id], f"tags.mlflow.parentRunId = '{self.parent_id}'",
                                       max_results=50000)
        complete = set()
        for run in sorted(runs, key=lambda r: r.info.start_time or 0):
            tags = run.data.tags
            key = (tags.get(CELL_TAG), tags.get(HASH_TAG))
            if key in complete or not child_complete(run) or tags.get(STATUS_TAG) == "error":
                self.client.delete_run(run.info.run_id)
            else:
                complete.add(key)
                self.children.setdefault(key[0], {})[key[1]] = run.info.run_id
        return complete

    def _drop_stale(self, cell_key: str, cell_hash: str) -> None:
        """Delete the children of ``cell_key`` logged with another configuration (a parameter changed before the
        resume, so the cell was computed again): tagged :data:`STALE_TAG` with why, then deleted, so that
        MLflow's searches, the saved view and ``--mlflow`` reports see the cell's current run only."""
        for old_hash, run_id in list(self.children.get(cell_key, {}).items()):
            if old_hash != cell_hash:
                self.client.set_tag(run_id, STALE_TAG, f"computed again with another configuration ({cell_hash})")
                self.client.delete_run(run_id)
                del self.children[cell_key][old_hash]
                self.logged.discard((cell_key, old_hash))

    def log_cell(self, cell, summary: Mapping, rows=None) -> None:
        """One child run: what identifies the cell (methods as written, seed, data set, method configurations), its
        schema metrics, steps per strength and their figure, NA reason, its per-view rows; it starts and ends when
        the cell's tasks ran."""
        with interrupts.deferred():  # Ctrl-C waits until the child run is whole
            self._drop_stale(cell.key, summary.get("hash"))
            if (cell.key, summary.get("hash")) not in self.logged:
                self._log_child(cell, summary)

    def _log_child(self, cell, summary: Mapping) -> None:
        from mlflow.entities import Metric, RunTag

        from gtsweep.evaluation import schema

        params = cell_params(cell, self.grid.cell_config(cell, "", 0), self.config, self.fingerprint, self.written)
        cell_name = self.names.get(cell.key, cell.key)
        pairing = pairing_label(cell_name, self.sweep_name or self.run_name, self.run_name if self.sweep_name else "")
        tags = {"mlflow.parentRunId": self.parent_id, CELL_TAG: cell.key, HASH_TAG: summary.get("hash", ""),
                STATUS_TAG: summary["status"], PAIRING_TAG: pairing, **method_tags(cell), **self.source}
        if summary.get("reason"):
            tags[REASON_TAG] = str(summary["reason"])[:5000]
        if summary.get("n_views") is not None:  # views (or pairs) per cell: the report's table titles say it
            tags[VIEWS_TAG] = str(summary["n_views"])
        name = child_name(cell_name, self.run_name)
        run = self.client.create_run(self.experiment_id, run_name=name, tags=tags,
                                     start_time=ms(summary.get("started")))
        now = ms(summary.get("ended")) or int(time.time() * 1000)
        # undefined values (e.g. ambiguity when no keypoint repeats) are logged as NaN: every metric is present
        values = summary.get("metrics") or {}
        metrics = [Metric(mlflow_name(key), _number(values[key]), now, 0) for key in schema.ordered(values)]
        metrics += self._step_metrics(summary, now)
        for step_key in schema.STEP_KEYS:
            if summary.get(f"by_{step_key}"):
                tags[f"gtsweep.step_scale.{step_key}"] = str(step_scale([float(v) for v in summary[f"by_{step_key}"]]))
        tags = [RunTag(k, v) for k, v in tags.items() if k != "mlflow.parentRunId"]
        try:
            self._log_batches(run.info.run_id, list(batches(params)), metrics, tags)
            self._log_files(run.info.run_id, cell, summary, name)
        except BaseException as e:  # a full artifact store, a locked store: the child is not left RUNNING
            mark_ended(self.client, run.info.run_id, f"logging the cell failed: {type(e).__name__}: "
                                                     f"{(str(e).strip().splitlines() or [''])[0][:300]}", "FAILED")
            raise
        self.client.set_terminated(run.info.run_id, "FINISHED" if summary["status"] != "error" else "FAILED",
                                   end_time=ms(summary.get("ended")))
        self.logged.add((cell.key, summary.get("hash")))

    def _log_batches(self, run_id: str, params: list, metrics: list, tags: list) -> None:
        """MLflow takes at most 1000 metrics and 100 params per call."""
        for index in range(max(len(params), math.ceil(len(metrics) / MAX_BATCH), 1)):
            self.client.log_batch(run_id, metrics=metrics[index * MAX_BATCH:(index + 1) * MAX_BATCH],
                                  params=params[index] if index < len(params) else [], tags=tags if index == 0 else [])

    def _log_files(self, run_id: str, cell, summary: Mapping, name: str) -> None:
        """The cell's per-view rows as ``views.csv`` and, with strengths, its curves as a figure."""
        per_view = self.output_dir / CELLS / f"{cell.key}.csv"
        if per_view.exists():
            with tempfile.TemporaryDirectory() as tmp:
                self.client.log_artifact(run_id, str(shutil.copyfile(per_view, Path(tmp) / VIEWS_FILE)))
        figure = strength_figure({"methods": cell.methods, **summary}, self.grid.experiment["name"], name)
        if figure is not None:
            self.client.log_figure(run_id, figure, FIGURE)

    @staticmethod
    def _step_metrics(summary: Mapping, now: int) -> list:
        """``<metric>_vs_<step key>`` series of the schema's step keys; steps are the value x :func:`step_scale`.
        Logged only as a series of several steps: a single point would read as the cell's value in the UI,
        where the cell's aggregate over every view is the metric without suffix."""
        from mlflow.entities import Metric

        from gtsweep.evaluation import schema

        metrics = []
        for step_key in schema.STEP_KEYS:
            by_step = summary.get(f"by_{step_key}") or {}
            if len(by_step) < 2:
                continue
            scale = step_scale([float(v) for v in by_step])
            for value, values in by_step.items():
                step = int(round(float(value) * scale))
                metrics += [Metric(mlflow_name(schema.series_name(name, step_key)), float(values[name]), now, step)
                            for name in schema.ordered(values) if _finite(values[name])]
        return metrics

    def abort(self, reason: str, status: str = "FAILED") -> str:
        """Close the parent run as FAILED (the sweep stopped on bad input or a failure) or KILLED (interrupted),
        with why. Never raises: the store itself may be what failed; then the returned note says the parent is
        left open for the resume to close ("" when it was closed)."""
        if self.parent_id is None:
            return ""
        return mark_ended(self.client, self.parent_id, reason, status)

    def end(self, outcome, artifacts: list[Path] = ()) -> None:
        """Log the sweep's totals and files on the parent run and close it."""
        from mlflow.entities import Metric, RunTag

        now = int(time.time() * 1000)
        record = self.output_dir / RUN_RECORD  # written by the sweep; its cluster (serial, or Ray's) becomes tags
        tags = cluster_tags(json.loads(record.read_text())) if record.exists() else {}
        totals = {"cells": len(outcome.summaries), "cache_hits": outcome.stats.cache_hits,
                  "cache_misses": outcome.stats.cache_misses, "dense_map_hits": outcome.stats.dense_hits,
                  "dense_map_misses": outcome.stats.dense_misses, "wall_time_s": outcome.seconds,
                  "resumed_cells": outcome.resumed}
        self.client.log_batch(self.parent_id, metrics=[Metric(SWEEP + k, float(v), now, 0) for k, v in totals.items()],
                              tags=[RunTag(k, v) for k, v in tags.items()])
        if outcome.table is not None and Path(outcome.table).exists():
            self.client.log_artifact(self.parent_id, str(outcome.table))
        for path in artifacts:  # the report: survey tables and plots
            if Path(path).exists():
                self.client.log_artifact(self.parent_id, str(path), REPORT)
        if not outcome.failed:
            clear_reason(self.client, self.parent_id)
        self.client.set_terminated(self.parent_id, "FAILED" if outcome.failed else "FINISHED")

    def ui_hint(self) -> str:
        """How to look at the runs: the ``mlflow ui`` command for the store actually used, or its address."""
        if self.uri.startswith(("http://", "https://")):
            return f"MLflow: parent run {self.parent_id}, open {runs_url(self.uri, self.experiment_id)}"
        return (f"MLflow: parent run {self.parent_id}; to browse: mlflow ui --backend-store-uri {self.uri} "
                f"--host 127.0.0.1 --port 5000, then open {runs_url('http://127.0.0.1:5000', self.experiment_id)}")


def child_complete(run) -> bool:
    """A child run that ended with what its cell needs: FINISHED (FAILED for a failed cell; a child whose logging
    failed is FAILED with another status tag), its status tag, and metrics when the cell was evaluated (an NA or
    failed cell has none)."""
    status = run.data.tags.get(STATUS_TAG)
    ended = run.info.status == ("FAILED" if status == "error" else "FINISHED")
    return ended and status is not None and (status != "ok" or bool(run.data.metrics))


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def _number(value) -> float:
    """A metric value for MLflow: None (NaN after a JSON round trip) becomes NaN."""
    return math.nan if value is None else float(value)


def open_multirun(cfg: Mapping | None, name: str, sweep_dir: Path, previous: str | None = None) -> str:
    """The MLflow run that holds the jobs' runs of a multirun (``previous``, reopened on resume, else new)."""
    quiet_mlflow()
    client, experiment = open_store(cfg)  # locked first use
    if previous is not None:
        reopen(client, previous)
        return previous
    model_development(client, experiment)
    tags = {"gtsweep.command": " ".join(["python -m gtsweep", *sys.argv[1:]]), "gtsweep.role": "multirun",
            "gtsweep.output_dir": str(sweep_dir), **source_tags()}
    return client.create_run(experiment, run_name=unique_name(client, experiment, name), tags=tags).info.run_id


def close_multirun(cfg: Mapping | None, run_id: str, artifacts: list[Path] = (), failed: str = "") -> None:
    """Attach the combined table and report to the multirun's run and close it: FINISHED, or FAILED with
    ``failed`` as the reason (e.g. the cells that failed in its jobs)."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri(cfg))
    for path in artifacts:
        client.log_artifact(run_id, str(path), COMBINED)
    if failed:
        mark_ended(client, run_id, failed, "FAILED")
    else:
        clear_reason(client, run_id)
        client.set_terminated(run_id, "FINISHED")
