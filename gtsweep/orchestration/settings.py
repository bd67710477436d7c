"""The run settings a sweep reads (runner, seed, cache, mlflow, report) with their allowed values and defaults,
declared once (an experiment kind's settings are its entry's: ``gtsweep.experiments``).

:func:`check_settings` runs before any work: a value outside its range is one line and exit code 2, never a
cell labelled "not applicable" or an "ok" cell with wrong numbers (``experiment.ratio=0`` would keep no match).
Method parameters and transform strengths are checked by their registries (:mod:`gtsweep.core.registry`).
"""
from __future__ import annotations

from typing import Mapping

import yaml

from gtsweep.core.config import plain
from gtsweep.core.paths import CONF_DIR
from gtsweep.core.ranges import Choice, Range, check_all

_COUNT = Range(1, None, integer=True)

SETTINGS = {
    "seed": Range(0, None, integer=True),
    "runner.backend": Choice(("ray", "serial")),
    "runner.num_cpus": Range(1, None, integer=True, optional=True),
    "runner.shard_size": _COUNT,
    "runner.opencv_threads": Range(1, None, integer=True, optional=True),
    "runner.describe_together": Choice((True, False)),
    "runner.device": Choice(("auto", "cpu", "cuda")),
    "runner.gpus_per_task": Range(0, 1, low_open=True),
    "runner.progress": Choice((True, False)),
    "runner.dashboard": Choice((True, False)),
    "runner.ray_log_level": Choice(("debug", "info", "warning", "error")),
    "runner.connect_timeout_s": Range(0, 600, low_open=True),
    "cache.enabled": Choice((True, False)),
    "mlflow.enabled": Choice((True, False)),
    "mlflow.timeout_s": Range(0, 600, low_open=True),
    "report.plots": Choice((True, False)),
    "report.by": Choice(("texture",), optional=True),
    "report.alpha": Range(0, 1, low_open=True, high_open=True),
}


#: The sections of the primary config that hold run settings.
RUN_SECTIONS = ("seed", "experiment", "runner", "cache", "mlflow", "report")
#: Their defaults, written once: conf/config.yaml (a caller that gives only some settings gets the rest here).
_PRIMARY = yaml.safe_load((CONF_DIR / "config.yaml").read_text())


def default(key: str):
    """The default of the run setting ``key`` (``runner.backend``): conf/config.yaml's."""
    section, name = key.split(".")
    return _PRIMARY[section][name]


def check_settings(cfg: Mapping, experiment: Mapping[str, object] | None = None) -> None:
    """Raise a one-line BadInput for the first run setting of ``cfg`` outside its allowed values, and the first
    ``experiment.*`` value outside the rules of its kind (``experiment``: ``{key: rule}``, its entry's settings)."""
    values = {key: plain(cfg.get(key)) for key in RUN_SECTIONS if key in cfg}
    check_all(values, SETTINGS)
    check_all(values.get("experiment") or {}, experiment or {}, prefix="experiment.")
    if (values.get("runner") or {}).get("dashboard"):  # its packages, before anything is created
        from gtsweep.orchestration.dashboard import check_dashboard

        check_dashboard(values["runner"])
