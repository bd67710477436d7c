"""What a sweep's tasks cost, from the per-view timings its cells record, and the fixed full protocol's cost
estimated from them.

Every cell's per-view rows (``cells/<cell>.csv``) carry ``t_detect`` (detection and selection of the test image;
a cached detection keeps the seconds it took when it was computed), ``t_describe`` (reference and test image),
``t_match`` and ``t_pose``. :func:`work_seconds` adds them up as the tasks share work: one detection per
(detector, image) whatever the selector or descriptor (the keypoint cache), one description per (detector,
selector, descriptor, view, reference count), one match per matcher. A reference image's detection is not
recorded apart; it is taken at the mean cost of its views' test images (for a pair, its test image's). A
synthetic view's reference description is counted with every view (it is timed with each), so the description
cost of Tables 2, 3 and 6 is an upper bound.

:func:`scaled_seconds` then separates a run's wall time into the task work spread over its CPUs and the rest
(start-up, data set, summaries, report), and scales only the task work to another count.
"""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from gtsweep.core.rundirs import RUN_RECORD
from gtsweep.orchestration.results import ResultStore

#: Per-view columns that identify one description (with the cell's methods); one match adds the matcher.
DESCRIPTION = ("detector", "selector", "descriptor", "view", "reference_count")
TIMINGS = ("t_detect", "t_describe", "t_match", "t_pose")


def view_rows(output: Path) -> pd.DataFrame:
    """Every cell's per-view rows of the sweep in ``output``, with the cell's methods as columns."""
    store, frames = ResultStore(output), []
    for summary in sorted(store.cells_dir.glob("*.json")):
        rows = store.rows(summary.stem)
        if len(rows.columns):
            frames.append(rows.assign(**json.loads(summary.read_text()).get("methods", {})))
    if not frames:
        return pd.DataFrame(columns=["detector", "view", "image", "t_detect"])
    return pd.concat(frames, ignore_index=True)


def detections(rows: pd.DataFrame) -> pd.DataFrame:
    """One row per (detector, view) with its test image's detection seconds and the view's reference image."""
    return rows.drop_duplicates(["detector", "view"])[["detector", "view", "image", "t_detect"]]


def work_seconds(rows: pd.DataFrame, skip: set | None = None) -> dict[str, float]:
    """CPU seconds of the tasks behind ``rows`` (:func:`view_rows`): detection, description, matching, pose.
    ``skip``: (detector, view) detections already paid for (another sweep's, through the keypoint cache)."""
    found = detections(rows)
    if skip:
        found = found[[key not in skip for key in zip(found["detector"], found["view"])]]
    tests = found["t_detect"].sum()
    references = found.groupby(["detector", "image"])["t_detect"].mean().sum() if len(found) else 0.0
    keys = [c for c in DESCRIPTION if c in rows.columns]
    described = rows.drop_duplicates(keys) if "t_describe" in rows.columns else rows.iloc[:0]
    matched = rows.drop_duplicates([*keys, "matcher"]) if "matcher" in rows.columns else described
    return {"detect": float(tests + references),
            "describe": float(described.get("t_describe", pd.Series(dtype=float)).sum()),
            "match": float(matched.get("t_match", pd.Series(dtype=float)).sum()),
            "pose": float(rows.get("t_pose", pd.Series(dtype=float)).sum())}


def scaled_seconds(wall: float, work: float, cpus: int, scale: float) -> float:
    """Wall seconds of a run whose task work is ``scale`` times ``work`` (CPU seconds over ``cpus``), its other
    costs unchanged: the measured ``wall`` less the work's share, plus the scaled work's share."""
    rest = max(wall - work / cpus, 0.0)
    return rest + work * scale / cpus


def cpus_of(output: Path) -> int:
    """The CPUs a sweep's tasks ran on (``run.json``'s cluster; 1 when serial or not recorded)."""
    record = Path(output) / RUN_RECORD
    cluster = json.loads(record.read_text()).get("cluster", {}) if record.exists() else {}
    return max(int(cluster.get("cpus") or 1), 1)
