"""What MLflow's UI reads from tags: the experiment's kind (its model-training view rather than the GenAI one),
each run's source, user and git commit, and short run names, unique within the experiment, that fit the runs
table's name column."""
from __future__ import annotations

import getpass
import re
from typing import Iterable, Mapping

KIND_TAG = "mlflow.experimentKind"
MODEL_DEVELOPMENT = "custom_model_development"
SOURCE_NAME = "python -m gtsweep"
#: Short names of the survey's transforms in run names.
TRANSFORM_SHORT = {"incremental": "inc", "absolute": "abs", "rotation": "rot", "translation": "trans",
                   "noise": "noise", "gamma": "gamma"}
SEPARATOR = "·"
CLUSTER_TAG = "gtsweep.cluster."
MAX_NAME = 40
#: Overrides that say how a sweep ran rather than what it evaluated: left out of run names when others remain.
PLUMBING = ("hydra.", "++hydra", "resume=", "dataset.", "runner.", "mlflow.", "cache.", "report.")


def quiet_mlflow() -> None:
    """MLflow's and alembic's INFO lines (store creation, migrations) and its artifact download progress bars (one
    per file: a report from MLflow fetches every cell's rows) are noise in a sweep's output."""
    import logging
    import os

    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")  # read at each download

    for name in ("mlflow", "alembic"):
        logging.getLogger(name).setLevel(logging.WARNING)


def model_development(client, experiment_id: str) -> None:
    """Mark the experiment as model development (the UI's training-runs view), unless it is marked already."""
    experiment = client.get_experiment(experiment_id)
    if not (experiment.tags or {}).get(KIND_TAG):
        client.set_experiment_tag(experiment_id, KIND_TAG, MODEL_DEVELOPMENT)


def source_tags() -> dict[str, str]:
    """MLflow's standard run tags (the fluent API sets them; ``MlflowClient.create_run`` does not)."""
    from mlflow.utils.mlflow_tags import MLFLOW_GIT_COMMIT, MLFLOW_SOURCE_NAME, MLFLOW_SOURCE_TYPE, MLFLOW_USER

    from gtsweep.tracking.store import git_commit

    tags = {MLFLOW_SOURCE_NAME: SOURCE_NAME, MLFLOW_SOURCE_TYPE: "LOCAL", MLFLOW_USER: _user()}
    commit = git_commit()
    if commit != "unknown":
        tags[MLFLOW_GIT_COMMIT] = commit
    return tags


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):  # no user name for this uid (e.g. in a container)
        return "unknown"


def cell_names(cells: Iterable, several_selectors: bool) -> dict[str, str]:
    """A short run name per cell key: ``sift·brief·inc`` (the selector too when the grid has several, or no
    descriptor; the matcher and the estimator when the grid has several, ``sift·brief·inc·flann·magsac``); the full
    key stays in the ``gtsweep.cell`` tag."""
    methods = {cell.key: cell.methods for cell in cells}
    several = [k for k in ("matcher", "estimator") if len({m.get(k) for m in methods.values()}) > 1]
    names = {}
    for key, m in methods.items():
        parts = [m["detector"]]
        if several_selectors or m.get("descriptor") is None:
            parts.append(m["selector"])
        if m.get("descriptor") is not None:
            parts.append(m["descriptor"])
        parts.append(TRANSFORM_SHORT.get(m["transform"], m["transform"]))
        parts += [m[k] for k in several if m.get(k) is not None]
        names[key] = SEPARATOR.join(parts)
    return names


def overrides_name(overrides: Iterable[str], fallback: str) -> str:
    """A run name from a job's overrides (``sweeps=smoke``, ``seed=1 detector=[orb]``), what it evaluates first
    (settings such as ``dataset.*`` or ``runner.*`` only when nothing else is given), shortened to fit the name
    column; the whole command stays in the ``gtsweep.command`` tag."""
    overrides = [o for o in overrides if not o.startswith(PLUMBING[:3])]
    name = " ".join(o for o in overrides if not o.lstrip("+").startswith(PLUMBING)) or " ".join(overrides) or fallback
    return name if len(name) <= MAX_NAME else name[:MAX_NAME - 1] + "…"


def unique_name(client, experiment_id: str, name: str) -> str:
    """``name``, else ``name (2)``, ``name (3)``, ...: the first that no run of the experiment has (MLflow does not
    keep run names unique; a sweep's cell runs are named after their parent, so theirs are unique too)."""
    from mlflow.exceptions import MlflowException

    pattern = name.replace("'", "_")  # a quote would end the filter's string; _ matches any one character
    try:
        runs = client.search_runs([experiment_id], f"attributes.run_name LIKE '{pattern}%'", max_results=50000)
    except MlflowException:  # a name the filter parser refuses: kept as it is
        return name
    taken = {run.info.run_name for run in runs}
    number = 1
    while (candidate := name if number == 1 else f"{name} ({number})") in taken:
        number += 1
    return candidate


#: A cell run's pairing within its sweep: the saved view groups by it (one short label; one sweep's runs apart).
PAIRING_TAG = "gtsweep.pairing"
_SEEDS = re.compile(r"(?:^|\s)\+*(?:dataset\.)?seed=\S+")


def pairing_label(cell_name: str, sweep_name: str, job_name: str = "") -> str:
    """What a group of cell runs shares: the cell (``sift·brief·inc``), its sweep (a multirun's run for its jobs)
    and the job's setting without its seeds, so that the repeats over seeds of one sweep pool and nothing else:
    ``sift·brief·inc · sweeps=smoke``, ``sift·brief·inc · -m seed=0,1 · matcher=[flann]``."""
    setting = _SEEDS.sub("", job_name).strip()
    return f" {SEPARATOR} ".join([cell_name, sweep_name, *([setting] if setting else [])])


def child_name(cell_name: str, parent_name: str) -> str:
    """A cell run's name: the cell (``sift·brief·inc``), then its sweep's run (``seed=1``)."""
    return f"{cell_name} {SEPARATOR} {parent_name}" if parent_name else cell_name


def cluster_tags(run_record: Mapping) -> dict[str, str]:
    """Where a sweep's tasks ran, from its ``run.json`` (``"cluster"``: ``backend``, and for Ray its ``address``,
    ``nodes``, ``cpus``), as the tags ``gtsweep.cluster.<key>``; none when the record has no cluster."""
    cluster = run_record.get("cluster") or {}
    return {CLUSTER_TAG + str(k): str(v) for k, v in cluster.items()} if isinstance(cluster, Mapping) else {}


def ms(seconds: float | None) -> int | None:
    """Seconds since the epoch as MLflow's milliseconds (None stays None: MLflow then uses "now")."""
    return None if seconds is None else int(round(seconds * 1000))
