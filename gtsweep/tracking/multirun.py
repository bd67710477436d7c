"""A multirun's record, ``multirun.json`` in its directory: its command's key, its swept keys and the MLflow run
that holds its jobs' runs; and the names of those runs."""
from __future__ import annotations

import json
from pathlib import Path

from gtsweep.core.rundirs import MULTIRUN_RECORD
from gtsweep.tracking.tags import overrides_name


def multirun_record(sweep_dir: Path) -> dict:
    """What the multirun recorded for its jobs (empty before it did)."""
    path = Path(sweep_dir) / MULTIRUN_RECORD
    return json.loads(path.read_text()) if path.exists() else {}


def update_record(sweep_dir: Path, **fields) -> dict:
    """The multirun's record with ``fields`` set, written back."""
    record = {**multirun_record(sweep_dir), **fields}
    (Path(sweep_dir) / MULTIRUN_RECORD).write_text(json.dumps(record))
    return record


def swept(overrides, keys) -> list[str]:
    """The overrides of the swept ``keys``."""
    return [o for o in overrides if o.lstrip("+").split("=")[0] in keys]


def open_multirun_run(mlflow_cfg, sweep_dir: Path, overrides) -> None:
    """Record the swept keys (``seed=0,1``; ``detector=glob(a*)``) and open (or, resuming, reopen) the multirun's
    MLflow run when MLflow is on."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(list(overrides))
    keys = [o.key_or_group for o in parsed if o.is_sweep_override()]
    fields = {"swept": keys}
    if mlflow_cfg.enabled:
        from gtsweep.tracking.sweep import open_multirun

        name = "multirun " + overrides_name(swept(overrides, keys), "")
        fields["parent_run_id"] = open_multirun(mlflow_cfg, name, sweep_dir, multirun_record(sweep_dir).get(
            "parent_run_id"))
    update_record(sweep_dir, **fields)

def job_run(overrides, output_dir: Path, sweep_dir: Path | None, job_num=None) -> tuple[str, str | None]:
    """The name of a job's MLflow run (its overrides; in a multirun, the swept ones) and the run of the multirun it
    nests under (None for a single run, ``sweep_dir`` None)."""
    if sweep_dir is None:
        return overrides_name(overrides, output_dir.name), None
    record = multirun_record(sweep_dir)
    return overrides_name(swept(overrides, record.get("swept", [])) or overrides, f"job {job_num}"), \
        record.get("parent_run_id")
