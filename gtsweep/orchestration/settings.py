"""The run settings a sweep reads (experiment, runner, seed) with their allowed values, declared once.

:func:`check_settings` runs before any work: a value outside its range is one line and exit code 2, never a
cell labelled "not applicable" or an "ok" cell with wrong numbers (``experiment.ratio=0`` would keep no match).
Method parameters and transform strengths are checked by their registries (:mod:`gtsweep.core.registry`).
"""
from __future__ import annotations

from typing import Mapping

import yaml

from gtsweep.core.config import plain
from gtsweep.core.paths import CONF_DIR
from gtsweep.core.ranges import Choice, ListOf, Range, check_all
from gtsweep.stages.scales import FOREIGN_SCALES

_COUNT = Range(1, None, integer=True)
_POSITIVE = Range(0, None, low_open=True)

SETTINGS = {
    "seed": Range(0, None, integer=True),
    "experiment.iou_threshold": Range(0, 1, low_open=True, high_open=True),
    "experiment.min_keypoints": _COUNT,
    "experiment.budget_per_mpx": Range(0, None, low_open=True, optional=True),
    "experiment.ratio": Range(0, 1, low_open=True),
    "experiment.mutual": Choice((True, False)),
    "experiment.pose.model": Choice(("similarity", "euclidean")),
    "experiment.pose.iterations": _COUNT,
    "experiment.pose.threshold": _POSITIVE,
    "experiment.pose.max_position_error": _POSITIVE,
    "experiment.pose.max_orientation_error": Range(0, 180, low_open=True),
    "experiment.reference_counts": ListOf(_COUNT, optional=True),
    "experiment.test_count": Range(1, None, integer=True, optional=True),
    "experiment.foreign_scale": Choice(FOREIGN_SCALES, optional=True),
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


def check_settings(cfg: Mapping) -> None:
    """Raise a one-line BadInput for the first run setting of ``cfg`` outside its allowed values."""
    values = {key: plain(cfg.get(key)) for key in RUN_SECTIONS if key in cfg}
    check_all(values, SETTINGS)
    if (values.get("runner") or {}).get("dashboard"):  # its packages, before anything is created
        from gtsweep.orchestration.dashboard import check_dashboard

        check_dashboard(values["runner"])
