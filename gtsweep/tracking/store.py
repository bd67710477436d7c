"""The MLflow store both trackers write to: where it is, its experiment, and how configs become params.

:func:`open_store` is the one way in. A fresh sqlite store is created and migrated by whichever process first
takes an exclusive lock on ``<db>.lock``: two sweeps (or the parallel jobs of Hydra's joblib launcher) started
at once in a new directory would otherwise both run MLflow's migrations and could break the file for good. An
``http(s)`` server must answer within ``mlflow.timeout_s``; MLflow's own retries then stay short too.
"""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import urllib.error
import urllib.request
from pathlib import Path
from typing import Iterator, Mapping

from gtsweep.core.errors import BadInput
from gtsweep.orchestration.settings import default

#: MLflow's own HTTP retries (default 7, with exponential backoff: minutes); the user's environment wins.
HTTP_RETRIES = "2"


def tracking_uri(cfg: Mapping | None) -> str:
    """The configured store: ``mlflow.tracking_uri``, else ``$MLFLOW_TRACKING_URI``, else ./mlflow.db (absolute)."""
    uri = (cfg or {}).get("tracking_uri") or os.environ.get("MLFLOW_TRACKING_URI")
    return uri or f"sqlite:///{Path.cwd().resolve() / 'mlflow.db'}"


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI, else None."""
    return Path(uri[len("sqlite:///"):]) if uri.startswith("sqlite:///") else None


@contextlib.contextmanager
def store_lock(uri: str) -> Iterator[None]:
    """Hold an exclusive lock on ``<db>.lock`` beside a sqlite store (other stores: no lock)."""
    path = sqlite_path(uri)
    if path is None or path.name in ("", ":memory:"):
        yield
        return
    from filelock import FileLock

    if not path.parent.is_dir():  # never created for the user: a typo in the URI would leave folders behind
        raise BadInput(f"cannot use the MLflow store '{uri}': the folder {path.parent} does not exist")
    try:
        lock = FileLock(path.with_name(path.name + ".lock"))
        lock.acquire()
    except OSError as e:
        raise BadInput(f"cannot use the MLflow store '{uri}': {e.strerror or e}") from None
    try:
        yield
    finally:
        lock.release()


def probe(uri: str, timeout: float) -> None:
    """An ``http(s)`` tracking server must answer (any HTTP status) within ``timeout`` seconds."""
    if not uri.startswith(("http://", "https://")):
        return
    try:
        urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout).close()
    except urllib.error.HTTPError:
        return  # it answered
    except (OSError, ValueError) as e:
        reason = getattr(e, "reason", None) or e
        reason = getattr(reason, "strerror", None) or str(reason) or type(e).__name__
        raise BadInput(f"cannot reach the MLflow tracking server '{uri}' within {timeout:g} s "
                       f"(mlflow.timeout_s): {reason}") from None
    os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", HTTP_RETRIES)


def experiment_name(cfg: Mapping | None) -> str:
    """The MLflow experiment of the ``mlflow`` settings ``cfg``."""
    return (cfg or {}).get("experiment") or default("mlflow.experiment")


def open_store(cfg: Mapping | None, name: str | None = None):
    """``(client, experiment id)`` of the configured store (:func:`tracking_uri`) and experiment ``name`` (by
    default :func:`experiment_name`).

    Checked before any work: a server that does not answer within ``mlflow.timeout_s`` or a store
    that cannot be opened is a one-line BadInput. Creation and migration of a sqlite store, and the experiment's
    get-or-create, run under :func:`store_lock`.
    """
    from mlflow.tracking import MlflowClient

    uri = tracking_uri(cfg)
    probe(uri, (cfg or {}).get("timeout_s", default("mlflow.timeout_s")))  # its range: check_settings
    with store_lock(uri):
        try:
            client = MlflowClient(uri)
        except Exception as e:
            reason = (str(e).strip().splitlines() or [type(e).__name__])[0]
            raise BadInput(f"cannot use the MLflow store '{uri}': {reason}") from None
        return client, experiment_id(client, name or experiment_name(cfg))


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
