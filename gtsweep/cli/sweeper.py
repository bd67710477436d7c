"""The sweeper of ``-m`` (docs/architecture.md): Hydra's basic sweeper, with ``group=glob(...)`` over the whole
search path, and every job of every batch composed and checked before the first one runs."""
from __future__ import annotations

import dataclasses

from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

from gtsweep.cli.checks import SINGLE_GROUPS, check_job, translate
from gtsweep.cli.lifecycle import fail
from gtsweep.cli.runs import start_sweep_dir
from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.searchpath import Configs, configs_of_sources, options_of
from gtsweep.tracking.multirun import open_multirun_run


def globbed(override: str, found: Configs) -> str:
    """``group=glob(...)`` as the choice sweep of the options it matches on the search path; others as they are."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    group, _, value = override.partition("=")
    if group not in (*METHOD_GROUPS, *SINGLE_GROUPS) or not value.startswith("glob("):
        return override
    try:
        matches = OverridesParser.create().parse_override(override).value().filter(options_of(found, group))
    except HydraException as e:
        raise BadInput(f"cannot parse '{override}': {str(e).splitlines()[0]}") from None
    if not matches:
        raise BadInput(f"'{override}' matches no {group}; choices: {', '.join(options_of(found, group))}")
    return f"{group}={','.join(matches)}"


class ComposedOnce:
    """Hydra's config loader, handing the launcher each job's config as the checks composed it, so that a job is
    composed once; composed again only when the multirun's own overrides changed since (``resume=true`` points
    ``hydra.sweep.dir`` at the earlier run)."""

    def __init__(self, loader):
        self.loader, self.composed = loader, {}

    def compose(self, master, job):
        config = self.loader.load_sweep_config(master, list(job))
        self.composed[self.key(master, job)] = config
        return config

    def load_sweep_config(self, master, job):
        from omegaconf import OmegaConf

        config = self.composed.pop(self.key(master, job), None)
        if config is None:
            return self.loader.load_sweep_config(master, job)
        OmegaConf.copy_cache(from_config=master, to_config=config)  # the master's resolved values, as Hydra's
        return config

    @staticmethod
    def key(master, job) -> tuple:
        return tuple(master.hydra.overrides.hydra), tuple(job)

    def __getattr__(self, name):
        return getattr(self.loader, name)


class CheckingSweeper(BasicSweeper):
    """Globs over the search path; every job checked before any runs, then the multirun's directory claimed and
    its MLflow run opened."""

    def sweep(self, arguments):
        from hydra.core.override_parser.overrides_parser import OverridesParser

        found = configs_of_sources(self.config.hydra.runtime.config_sources)
        try:
            self.params = {key: globbed(f"{key}={value}", found).partition("=")[2]
                           for key, value in (self.params or {}).items()}
            arguments = [globbed(argument, found) for argument in arguments]
            parsed = OverridesParser.create().parse_overrides([*self._parse_config(), *arguments])
        except Exception as e:  # noqa: BLE001 - Hydra's parser errors, translated
            fail(translate(e, arguments, found))
        loader = ComposedOnce(self.hydra_context.config_loader)
        if hasattr(self.launcher, "hydra_context"):  # Hydra's launchers compose each job through it
            self.launcher.hydra_context = dataclasses.replace(self.launcher.hydra_context, config_loader=loader)
        for job in self.split_arguments(parsed, None)[0]:
            try:
                check_job(loader.compose(self.config, job), job, found)
            except Exception as e:  # noqa: BLE001 - Hydra's and OmegaConf's errors, translated
                fail(translate(e, job, found))
        try:
            open_multirun_run(self.config.mlflow, start_sweep_dir(self.config), self.config.hydra.overrides.task)
        except GtsweepError as e:
            fail(e)
        return super().sweep(arguments)

    def validate_batch_is_legal(self, batch) -> None:
        """Every job was composed and checked before the first batch (:meth:`sweep`)."""
