"""Where MLflow's UI should open on a sweep: the model-training view, with a saved view for comparing pairings.

MLflow 3.17's UI picks its GenAI or its model-training layout from the URL (``workflowType=machine_learning``) or
from the browser's last choice (GenAI at first), whatever the experiment's ``mlflow.experimentKind`` tag says; so
every address gtsweep prints carries ``workflowType=machine_learning``.

A saved view of the runs page is an experiment tag ``mlflow.sharedViewState.<key>`` holding
``{"name", "createdAt", "updatedAt", "state"}``, ``state`` being the page's search and table settings as JSON
(what the UI's "Views" menu saves; ``viewStateShareKey=<key>`` in the address opens it). gtsweep saves one,
"gtsweep: pairings": the cell runs only, grouped by one short tag, the pairing within its sweep
(:data:`~gtsweep.tracking.tags.PAIRING_TAG`: ``sift·brief·inc · sweeps=smoke``; a group averages one sweep's repeats
over seeds, never runs of another sweep), with the method and data-set columns (no seed column: a group's average of
seeds means nothing) and the headline metrics; its charts start with the headline metrics
(:data:`~gtsweep.tracking.metricnames.SECTIONS`). What the UI cannot be told (digits shown, the order of its
generated charts): docs/mlflow.md says what to click.
"""
from __future__ import annotations

import json
import time

from gtsweep.evaluation import schema
from gtsweep.tracking.metricnames import SECTIONS
from gtsweep.tracking.tags import PAIRING_TAG

VIEW_KEY = "gtsweep-pairings"
VIEW_NAME = "gtsweep: pairings"
VIEW_TAG_PREFIX = "mlflow.sharedViewState."
TRAINING_VIEW = "workflowType=machine_learning"
#: The runs table's column of run names and group labels, and its width in pixels (a pairing tag of ~60 characters).
RUN_NAME_COLUMN = "attributes.`Run Name`"
RUN_NAME_WIDTH = 460
#: The method and data-set params shown as columns.
PAIRING = ("detector", "selector", "descriptor", "matcher", "estimator", "transform", "dataset")
#: Shown as a column besides each experiment kind's headline: the survey's other main number.
SECOND_METRIC = "precision"


def headline_metrics() -> tuple[str, ...]:
    """The headline metric of each registered experiment kind (:data:`gtsweep.evaluation.schema.ROWS`), and
    precision, as columns."""
    return tuple(dict.fromkeys([*(rows.headline for rows in schema.ROWS.values()), SECOND_METRIC]))


def _column(kind: str, name: str) -> str:
    return f"{kind}.`{name}`"


def pairings_state(cell_tag: str) -> dict:
    """The runs page's settings of the saved view; ``cell_tag`` is the tag every cell run has."""
    columns = [*(_column("metrics", m) for m in headline_metrics()), *(_column("params", p) for p in PAIRING)]
    return {
        "searchFilter": f"tags.`{cell_tag}` LIKE '%'",
        "orderByKey": "attributes.start_time",
        "orderByAsc": False,
        "selectedColumns": columns,
        # the Run Name column (which holds a group's label) wide enough for the label, then the headline metrics,
        # then the methods (MLflow applies the widths to the columns that columnOrder lists)
        "columnOrder": [RUN_NAME_COLUMN, *columns],
        "columnWidths": {RUN_NAME_COLUMN: RUN_NAME_WIDTH},
        "groupBy": {"aggregateFunction": "average", "groupByKeys": [{"mode": "tag", "groupByData": PAIRING_TAG}]},
        "runsHiddenMode": "SHOW_ALL",
        # the chart view: MLflow's generated charts, in sections ordered headline first (kept as given when
        # isAccordionReordered; MLflow would sort the prefixed sections before its "Model metrics")
        "compareRunCharts": [],
        "compareRunSections": [{"uuid": f"gtsweep-section-{index}", "name": name, "display": True,
                                "isReordered": False} for index, name in enumerate(SECTIONS)],
        "isAccordionReordered": True,
    }


def save_pairings_view(client, experiment_id: str, cell_tag: str) -> None:
    """Create (or bring up to date) the experiment's "gtsweep: pairings" view; a user's own views stay as they are."""
    state = json.dumps(pairings_state(cell_tag), sort_keys=True)
    tag = VIEW_TAG_PREFIX + VIEW_KEY
    old = (client.get_experiment(experiment_id).tags or {}).get(tag)
    try:
        envelope = json.loads(old) if old else {}
    except ValueError:
        envelope = {}
    if envelope.get("state") == state:
        return
    now = int(time.time() * 1000)
    envelope = {"name": VIEW_NAME, "createdAt": envelope.get("createdAt", now), "updatedAt": now, "state": state}
    client.set_experiment_tag(experiment_id, tag, json.dumps(envelope))


def runs_url(base: str, experiment_id: str, saved_view: bool = True) -> str:
    """The experiment's runs in the model-training view (with the pairings view unless ``saved_view`` is False)."""
    query = TRAINING_VIEW + (f"&viewStateShareKey={VIEW_KEY}" if saved_view else "")
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs?{query}"


def run_url(base: str, experiment_id: str, run_id: str, tab: str = "") -> str:
    """One run's page (``tab``: ``model-metrics``, ``artifacts``, ...) in the model-training view."""
    path = f"#/experiments/{experiment_id}/runs/{run_id}" + (f"/{tab}" if tab else "")
    return f"{base.rstrip('/')}/{path}?{TRAINING_VIEW}"
