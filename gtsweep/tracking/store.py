"""The MLflow store both trackers write to: where it is, its experiment, and how configs become params."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Mapping

from gtsweep.core.errors import BadInput


def tracking_uri(cfg: Mapping | None) -> str:
    """The configured store: ``mlflow.tracking_uri``, else ``$MLFLOW_TRACKING_URI``, else ./mlflow.db (absolute)."""
    uri = (cfg or {}).get("tracking_uri") or os.environ.get("MLFLOW_TRACKING_URI")
    return uri or f"sqlite:///{Path.cwd().resolve() / 'mlflow.db'}"


def experiment_id(client, name: str) -> str:
    """The id of the experiment ``name``, created if missing; an unreachable store or a bad URI is a one-line
    BadInput, before any work."""
    try:
        experiment = client.get_experiment_by_name(name)
        return experiment.experiment_id if experiment else client.create_experiment(name)
    except Exception as e:
        reason = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise BadInput(f"cannot use the MLflow store '{client.tracking_uri}': {reason}") from None


def flatten(value, prefix: str = "") -> dict[str, str]:
    """A nested config as MLflow params: ``{"detector.params.nfeatures": "0", ...}``."""
    if isinstance(value, Mapping):
        out = {}
        for key, inner in value.items():
            out.update(flatten(inner, f"{prefix}.{key}" if prefix else str(key)))
        return out
    return {prefix: json.dumps(value) if isinstance(value, (list, tuple)) else str(value)}


def git_commit() -> str:
    """The commit of the gtsweep checkout, or "unknown"."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5,
                             cwd=Path(__file__).resolve().parent)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"
