"""The run settings a sweep reads (runner, seed, cache, mlflow, report) with their allowed values, declared once, and
typed nodes of such settings for Hydra's ConfigStore (an experiment kind's settings are its entry's).

:func:`check_settings` runs before any work: a value outside its range is one line and exit code 2, never a
cell labelled "not applicable" or an "ok" cell with wrong numbers (``experiment.ratio=0`` would keep no match).
Method parameters and transform strengths are checked by their registries (:mod:`gtsweep.core.registry`).
"""
from __future__ import annotations

from typing import Any, Mapping

from omegaconf import MISSING
from omegaconf.nodes import AnyNode, BooleanNode, FloatNode, IntegerNode, StringNode, ValueNode

from gtsweep.core.config import plain
from gtsweep.core.ranges import Choice, Range, check_all

_COUNT = Range(1, None, integer=True)
#: Where gtsweep's structured configs live in Hydra's ConfigStore (``schema/<group>/<name>``, ``schema/run``).
SCHEMA_GROUP = "schema"
NODES = {bool: BooleanNode, int: IntegerNode, float: FloatNode, str: StringNode}

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


def check_settings(cfg: Mapping, experiment: Mapping[str, object] | None = None) -> None:
    """Raise a one-line BadInput for the first run setting of ``cfg`` outside its allowed values, and the first
    ``experiment.*`` value outside the rules of its kind (``experiment``: ``{key: rule}``, its entry's settings)."""
    values = {key: plain(cfg.get(key)) for key in ("seed", "experiment", "runner", "cache", "mlflow", "report")
              if key in cfg}
    check_all(values, SETTINGS)
    check_all(values.get("experiment") or {}, experiment or {}, prefix="experiment.")
    if (values.get("runner") or {}).get("dashboard"):  # its packages, before anything is created
        from gtsweep.orchestration.dashboard import check_dashboard

        check_dashboard(values["runner"])


def typed(value: Any) -> ValueNode:
    """A node that admits values of the kind of ``value`` (an int where a float stands; None stays untyped)."""
    return NODES.get(type(value), AnyNode)(value)


def setting_node(rule) -> ValueNode | None:
    """An empty node of the type a setting's rule admits (None for a rule without one type, e.g. a list)."""
    if isinstance(rule, Range):
        return (IntegerNode if rule.integer else FloatNode)(MISSING, is_optional=rule.optional)
    if isinstance(rule, Choice):
        kinds = {type(choice) for choice in rule.options if choice is not None}
        if len(kinds) == 1 and kinds.pop() in (bool, str):
            return NODES[type(next(c for c in rule.options if c is not None))](MISSING, is_optional=rule.optional)
    return None


def typed_settings(rules: Mapping[str, object]) -> dict:
    """The typed nodes of dotted settings, nested (``runner.num_cpus`` -> ``{runner: {num_cpus}}``): what Hydra
    merges a config's values onto, so that a value of the wrong type is Hydra's own error (it has no ranges)."""
    schema: dict = {}
    for key, rule in rules.items():
        node = setting_node(rule)
        if node is None:
            continue
        *parents, leaf = key.split(".")
        section = schema
        for parent in parents:
            section = section.setdefault(parent, {})
        section[leaf] = node
    return schema
