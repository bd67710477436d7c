"""A sweep read back from MLflow: its cells' summaries, per-view rows and configuration (the report's other
source, ``python -m gtsweep.report <parent run> --mlflow``)."""
from __future__ import annotations

from pathlib import Path

from gtsweep.core.errors import BadInput
from gtsweep.tracking.closing import REASON_TAG
from gtsweep.tracking.metricnames import summary_name
from gtsweep.tracking.params import METHOD_TAG
from gtsweep.tracking.store import tracking_uri
from gtsweep.tracking.sweep import CELL_TAG, STATUS_TAG, VIEWS_FILE, VIEWS_TAG, step_scale
from gtsweep.tracking.tags import quiet_mlflow


def summaries_from_mlflow(parent_run_id: str, uri: str | None = None) -> list[dict]:
    """Cell summaries rebuilt from a sweep's MLflow child runs (the report's other source)."""
    from mlflow.tracking import MlflowClient

    from gtsweep.evaluation import schema

    client = MlflowClient(tracking_uri(None) if uri is None else uri)
    try:
        parent = client.get_run(parent_run_id)
    except Exception as e:
        raise BadInput(f"no MLflow run '{parent_run_id}' in '{client.tracking_uri}': {str(e).splitlines()[0]}") \
            from None
    runs = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent_run_id}'",
                              max_results=50000)
    experiment = parent.data.tags.get("gtsweep.experiment")
    summaries = []
    for run in runs:
        params, tags = run.data.params, run.data.tags
        names = {**params, **{k[len(METHOD_TAG):]: v for k, v in tags.items() if k.startswith(METHOD_TAG)}}
        methods = {k: names.get(k) for k in ("detector", "selector", "descriptor", "transform")}
        methods.update({k: names[k] for k in ("matcher", "estimator") if k in names})
        keys = {summary_name(k): k for k in run.data.metrics}  # runs logged with or without metric prefixes
        series = {name: schema.parse_series(name) for name in keys}
        summary = {"key": tags.get(CELL_TAG), "methods": methods, "status": tags.get(STATUS_TAG, "ok"),
                   "reason": tags.get(REASON_TAG), "experiment": experiment,
                   "metrics": {k: run.data.metrics[keys[k]] for k in schema.ordered(keys) if not series[k]}}
        if tags.get(VIEWS_TAG):
            summary["n_views"] = int(tags[VIEWS_TAG])
        for name, (metric, step_key) in ((k, v) for k, v in series.items() if v):
            history = client.get_metric_history(run.info.run_id, keys[name])
            scale = step_scale([m.step for m in history]) if step_key == "strength" else 1
            scale = float(tags.get(f"gtsweep.step_scale.{step_key}", scale))
            steps = summary.setdefault(f"by_{step_key}", {})
            for m in history:
                steps.setdefault(repr(m.step / scale), {})[metric] = m.value
        summaries.append(summary)
    return sorted(summaries, key=lambda s: s["key"] or "")


def config_from_mlflow(parent_run_id: str, uri: str | None = None) -> dict | None:
    """The resolved configuration a sweep logged on its parent run (``config.yaml``), or None without it."""
    import tempfile

    import yaml
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    quiet_mlflow()
    client = MlflowClient(tracking_uri(None) if uri is None else uri)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            return yaml.safe_load(Path(client.download_artifacts(parent_run_id, "config.yaml", tmp)).read_text())
    except (MlflowException, OSError, yaml.YAMLError):  # no such artifact: the report assumes Micro-GPS' scale
        return None


def views_from_mlflow(parent_run_id: str, uri: str | None = None) -> dict:
    """The per-view rows of a sweep's cells (each child run's ``<cell>.csv`` artifact) by cell key, for the
    report's intervals and paired tests; cells without the artifact are left out."""
    import tempfile

    import pandas as pd
    from mlflow.tracking import MlflowClient

    quiet_mlflow()
    client = MlflowClient(tracking_uri(None) if uri is None else uri)
    parent = client.get_run(parent_run_id)
    runs = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent_run_id}'",
                              max_results=50000)
    views = {}
    with tempfile.TemporaryDirectory() as tmp:
        for run in runs:
            key = run.data.tags.get(CELL_TAG)
            logged = {a.path for a in client.list_artifacts(run.info.run_id)} if key else set()
            name = next((n for n in (VIEWS_FILE, f"{key}.csv") if n in logged), None)  # older runs: <cell>.csv
            if name is not None:
                views[key] = pd.read_csv(client.download_artifacts(run.info.run_id, name, tmp))
    return views
