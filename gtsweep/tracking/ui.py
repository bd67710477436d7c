"""``make ui``: ``python -m gtsweep.tracking.ui [--port 5000] [--backend-store-uri URI]``.

Prints the address of gtsweep's experiment in MLflow's model-training view, with the "gtsweep: pairings" view
(:mod:`gtsweep.tracking.views`), then becomes ``mlflow ui`` on 127.0.0.1 for the store (default: ./mlflow.db,
as a sweep's). Opening MLflow's own start page instead lands in its GenAI layout.
"""
from __future__ import annotations

import argparse
import os
import sys

from gtsweep.tracking.store import sqlite_path, tracking_uri
from gtsweep.tracking.tags import quiet_mlflow
from gtsweep.tracking.views import TRAINING_VIEW, runs_url


def address(uri: str, experiment: str, base: str) -> str:
    """Where to point the browser: the experiment's runs in the training view, or the experiment list in that view
    while the store has no such experiment (or no file yet)."""
    path = sqlite_path(uri)
    if path is None or path.exists():
        from mlflow.tracking import MlflowClient

        found = MlflowClient(uri).get_experiment_by_name(experiment)
        if found is not None:
            return runs_url(base, found.experiment_id)
    return f"{base}/#/experiments?{TRAINING_VIEW}"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.tracking.ui", description=__doc__.splitlines()[0])
    parser.add_argument("--backend-store-uri", help="MLflow store (default: $MLFLOW_TRACKING_URI or ./mlflow.db)")
    parser.add_argument("--experiment", default="gtsweep", help="MLflow experiment to open (mlflow.experiment)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=5000)
    args = parser.parse_args(argv)
    quiet_mlflow()
    uri = args.backend_store_uri or tracking_uri(None)
    print(f"gtsweep: MLflow UI of {uri}; open {address(uri, args.experiment, f'http://{args.host}:{args.port}')}",
          flush=True)
    command = [sys.executable, "-m", "mlflow", "ui", "--backend-store-uri", uri, "--host", args.host,
               "--port", str(args.port)]
    os.execv(sys.executable, command)


if __name__ == "__main__":
    main()
