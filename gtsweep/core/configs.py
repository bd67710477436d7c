"""Config files as Hydra finds them on a search path: the options of a group and raw files, first match wins.

Hydra's ``--help`` lists the groups of its main directory only, not those of ``hydra.searchpath`` entries declared
in a primary config; the resolver ``${gtsweep.groups:}`` (:func:`register_help_resolver`) lists what a running job
really composes from, for a help template.
"""
from __future__ import annotations

import warnings


class Configs:
    """The config files on a search path (``file://dir``, ``pkg://package`` entries, searched in order)."""

    def __init__(self, entries):
        from hydra._internal.config_repository import ConfigRepository
        from hydra._internal.config_search_path_impl import ConfigSearchPathImpl
        from hydra.core.plugins import Plugins

        Plugins.instance()  # registers the config sources (file://, pkg://)
        path = ConfigSearchPathImpl()
        for entry in entries:
            path.append("gtsweep", entry)
        self.entries = tuple(entries)
        self.repository = ConfigRepository(path)

    def options(self, group: str) -> list[str]:
        """The options of a config group (``detector``; ``detector/tuned``), from every directory searched."""
        from hydra.core.object_type import ObjectType

        return sorted(self.repository.get_group_options(group, ObjectType.CONFIG))

    def groups(self, parent: str = "") -> list[str]:
        """Every config group under ``parent`` that has options, e.g. ``detector`` and ``detector/tuned``."""
        from hydra.core.object_type import ObjectType

        found = []
        for name in self.repository.get_group_options(parent, ObjectType.GROUP):
            group = f"{parent}/{name}" if parent else name
            if name != "__pycache__":
                found += ([group] if self.options(group) else []) + self.groups(group)
        return found

    def source(self, config: str):
        """The first file ``config`` (``detector/sift``) on the path, as Hydra's ``ConfigResult`` (None if none)."""
        for source in self.repository.sources:
            if source.available() and source.is_config(config):
                return source.load_config(config)
        return None

    def load(self, config: str) -> dict:
        """The raw content of ``config`` as plain data (its ``defaults`` list included); {} when missing."""
        from omegaconf import OmegaConf

        result = self.source(config)
        return (OmegaConf.to_container(result.config) or {}) if result is not None else {}


def configs_of_sources(sources) -> Configs:
    """The configs of a running job, from ``HydraConfig.get().runtime.config_sources``."""
    return Configs([f"{s['schema']}://{s['path']}" for s in sources if s["schema"] != "structured"])


def group_listing(configs: Configs, only=()) -> str:
    """``group: option, option`` per line (the groups ``only`` and their subgroups; Hydra's own left out)."""
    return "\n".join(f"{group}: {', '.join(configs.options(group))}" for group in sorted(configs.groups())
                     if group.split("/")[0] != "hydra" and (not only or group.split("/")[0] in only))


def _job_groups(*only: str) -> str:
    from hydra.core.hydra_config import HydraConfig

    return group_listing(configs_of_sources(HydraConfig.get().runtime.config_sources), only)


def register_help_resolver() -> None:
    """``${gtsweep.groups:}`` (``${gtsweep.groups:dataset}``: that group only): the config groups of the running
    job and their options, for a help template."""
    from omegaconf import OmegaConf

    OmegaConf.register_new_resolver("gtsweep.groups", _job_groups, replace=True)


def ignore_missing_dir(path: str) -> None:
    """Hydra warns for every search path entry that does not exist; ``path`` (e.g. ./tuned) may well not."""
    warnings.filterwarnings("ignore", message=rf"provider=.*, path={path} is not available", category=UserWarning)
