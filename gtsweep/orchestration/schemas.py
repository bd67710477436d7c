"""Structured configs in Hydra's ConfigStore, so that Hydra merges and checks what gtsweep used to re-check.

- ``schema/<group>/<name>``: a registered method's parameters, typed by their defaults in code
  (``{name: {params: {...}}}``). Each package method YAML lists ``/schema/<group>/<name>@_here_`` first in its
  defaults: its own values, then the command line's, are merged onto the code defaults once, during composition.
- ``schema/run``: the run settings of :data:`gtsweep.orchestration.settings.SETTINGS` outside the experiment
  (``seed``, ``runner.*``, ``cache.*``, ``mlflow.*``, ``report.*``), typed by their declared ranges; the
  primary config lists it first. Their values stay in ``conf/config.yaml`` and their ranges in ``SETTINGS``
  (checked before any work): Hydra has no ranges.

Hydra sets struct mode on the composed config, so an unknown key and a value of the wrong type are Hydra's own
errors (:mod:`gtsweep.cli.checks` makes them gtsweep's one line).
"""
from __future__ import annotations

from typing import Any, Mapping

from omegaconf import MISSING
from omegaconf.nodes import AnyNode, BooleanNode, FloatNode, IntegerNode, StringNode, ValueNode

from gtsweep.core.ranges import Choice, Range
from gtsweep.orchestration.grid import REGISTRIES
from gtsweep.orchestration.settings import SETTINGS

#: Where gtsweep's structured configs live in Hydra's ConfigStore (``schema/<group>/<name>``, ``schema/run``, an
#: experiment kind's ``schema/experiment/<name>``).
SCHEMA_GROUP = "schema"
#: The sections of the primary config whose settings ``schema/run`` types (the experiment's are its kind's).
RUN_SECTIONS = ("seed", "runner", "cache", "mlflow", "report")
NODES = {bool: BooleanNode, int: IntegerNode, float: FloatNode, str: StringNode}


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


def method_schema(name: str, defaults: Mapping[str, Any]) -> dict:
    """``{name: {params: {key: typed default}}}``: what ``schema/<group>/<name>`` holds."""
    return {name: {"params": {key: typed(value) for key, value in defaults.items()}}}


def run_schema() -> dict:
    """The typed run settings, nested as in the primary config (``runner.num_cpus`` -> ``{runner: {num_cpus}}``)."""
    return typed_settings({key: rule for key, rule in SETTINGS.items() if key.split(".")[0] in RUN_SECTIONS})


def register_schemas() -> None:
    """Store every registered method's schema and the run settings' in Hydra's ConfigStore (this process)."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    for group, registry in REGISTRIES.items():
        for name, method in registry.items():
            store.store(group=f"{SCHEMA_GROUP}/{group}", name=name, node=method_schema(name, method.defaults))
    store.store(group=SCHEMA_GROUP, name="run", node=run_schema())
