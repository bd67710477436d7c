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

from gtsweep.orchestration.grid import REGISTRIES
from gtsweep.orchestration.settings import SCHEMA_GROUP, SETTINGS, typed, typed_settings

#: The sections of the primary config whose settings ``schema/run`` types (the experiment's are its kind's).
RUN_SECTIONS = ("seed", "runner", "cache", "mlflow", "report")


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
    register_sweeper()


def register_sweeper() -> None:
    """gtsweep's sweeper (``hydra/sweeper: gtsweep``) known to Hydra in this process, also where Hydra's plugin
    discovery does not look (an editable install's package finder)."""
    from hydra.core.plugins import Plugins

    from hydra_plugins.gtsweep_sweeper import GtsweepSweeper  # also stores its config node

    Plugins.instance().register(GtsweepSweeper)
