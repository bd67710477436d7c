"""Config files as Hydra finds them on a search path: the options of a group and raw files, first match wins.

Hydra's ``--help`` lists the groups of its main directory only, not those of ``hydra.searchpath`` entries declared
in a primary config; the resolver ``${gtsweep.groups:}`` (:func:`register_help_resolver`) lists what a running job
really composes from, for a help template.

The working directory's ``./tuned`` is on the search path as ``tuned://tuned`` (:class:`TunedMethods`): it supplies
tuned method files only, ``<group>/tuned/<name>.yaml`` of a method group, never a preset or any other config.
"""
from __future__ import annotations

import os
import sys
import warnings

from hydra._internal.core_plugins.file_config_source import FileConfigSource
from hydra.core.object_type import ObjectType
from hydra.core.plugins import Plugins
from hydra.plugins.config_source import ConfigLoadError, ConfigResult, ConfigSource

from gtsweep.core.config import METHOD_GROUPS


class TunedMethods(ConfigSource):
    """A directory (``tuned://DIR``) of which Hydra sees only ``<method group>/tuned/<name>.yaml``: what
    ``experiment=optimize`` writes. A preset (``sweeps/...``) or a group's own option planted there does not exist
    for Hydra."""

    @staticmethod
    def scheme() -> str:
        return "tuned"

    def _served(self, config_path: str, config: bool) -> bool:
        parts = [p for p in config_path.strip("/").split("/") if p]
        if not parts:
            return not config
        if parts[0] not in METHOD_GROUPS:
            return False
        return len(parts) == 3 and parts[1] == "tuned" if config else len(parts) <= 2 and parts[1:] in ([], ["tuned"])

    def _file(self, config_path: str) -> str:
        return os.path.realpath(os.path.join(self.path, self._normalize_file_name(config_path)))

    def load_config(self, config_path: str) -> ConfigResult:
        from omegaconf import OmegaConf

        if not self.is_config(config_path):
            raise ConfigLoadError(f"Config not found : {config_path} in {self.full_path()}")
        with open(self._file(config_path), encoding="utf-8") as f:
            header = ConfigSource._get_header_dict(f.read(512))
            f.seek(0)
            return ConfigResult(config=OmegaConf.load(f), path=self.full_path(), provider=self.provider,
                                header=header)

    def available(self) -> bool:
        return os.path.isdir(self.path)

    def is_group(self, config_path: str) -> bool:
        return self._served(config_path, config=False) and os.path.isdir(os.path.join(self.path, config_path))

    def is_config(self, config_path: str) -> bool:
        return self._served(config_path.removesuffix(".yaml"), config=True) and os.path.isfile(
            self._file(config_path))

    def list(self, config_path: str, results_filter: ObjectType | None) -> list[str]:
        found: list[str] = []
        if self.is_group(config_path):
            for name in os.listdir(os.path.join(self.path, config_path)):
                self._list_add_result(found, os.path.join(config_path, name), name, results_filter)
        return sorted(set(found))


#: The option of a method group that stands for every option of the group (``detector=all``).
ALL = "all"


class EveryOption(ConfigSource):
    """``every://``: the config ``<method group>/all``, whose defaults list selects every option of the group
    (:func:`options_of`) on the search path it is composed from, so that ``detector=all`` is Hydra's own choice of
    an option in a single run and in every job of ``-m``. It lists nothing (``all`` is not a file)."""

    @staticmethod
    def scheme() -> str:
        return "every"

    def available(self) -> bool:
        return True

    def is_group(self, config_path: str) -> bool:
        return False

    def is_config(self, config_path: str) -> bool:
        group, _, name = config_path.removesuffix(".yaml").strip("/").partition("/")
        return group in METHOD_GROUPS and name == ALL

    def list(self, config_path: str, results_filter: ObjectType | None) -> list[str]:
        return []

    def load_config(self, config_path: str) -> ConfigResult:
        from omegaconf import OmegaConf

        if not self.is_config(config_path):
            raise ConfigLoadError(f"Config not found : {config_path} in {self.full_path()}")
        group = config_path.strip("/").partition("/")[0]
        every = options_of(Configs.of(s for s in _searched_with(self) if s is not self), group)
        return ConfigResult(config=OmegaConf.create({"defaults": every}), path=self.full_path(),
                            provider=self.provider, header={"package": None})


def _searched_with(source: ConfigSource) -> list[ConfigSource]:
    """The sources of the config repository that asks ``source`` for a config (Hydra hands a source no reference
    to its siblings; the repository is the caller's ``self``, a few frames up)."""
    frame = sys._getframe(1)
    while frame is not None:
        sources = getattr(frame.f_locals.get("self"), "sources", None)
        if isinstance(sources, list) and any(s is source for s in sources):
            return sources
        frame = frame.f_back
    raise ConfigLoadError(f"{source.full_path()}: no config repository asked for it")


#: ``(group, names) -> names``: which options ``group=all`` and ``glob()`` may take (:func:`choose_options_with`).
_choosable = {"of": lambda group, names: names}


def choose_options_with(function) -> None:
    """Let ``function(group, names)`` pick the options ``all`` and ``glob()`` choose from (the command line leaves
    out the methods this install cannot run)."""
    _choosable["of"] = function


def options_of(configs: Configs, group: str) -> list[str]:
    """What ``group=all`` and ``group=glob(...)`` choose from: the options of ``group`` on the search path."""
    return _choosable["of"](group, [name for name in configs.options(group) if name != ALL])


def stray_tuned_files(root: str | os.PathLike) -> list[str]:
    """The YAML files under ``root`` (the working directory's ``./tuned``) that are not tuned method files
    (``<method group>/tuned/<name>.yaml``): Hydra never sees them, and a config planted there (a preset, a method)
    is refused by the command line rather than silently ignored."""
    found = []
    for folder, _, names in os.walk(root):
        for name in names:
            if name.endswith((".yaml", ".yml")):
                parts = os.path.relpath(os.path.join(folder, name), root).split(os.sep)
                if not (len(parts) == 3 and parts[0] in METHOD_GROUPS and parts[1] == "tuned"
                        and name.endswith(".yaml")):
                    found.append("/".join(parts))
    return sorted(found)


class DeclaredMethods(FileConfigSource):
    """``file://`` as Hydra reads it, but a method declared in YAML (``<method group>/<name>.yaml`` holding
    ``factory:``, ``params:``..., not keyed by its name) is keyed by its option name when loaded: its keys land at
    ``<group>.<name>``, beside the package's methods, and Hydra checks overrides of it like any other."""

    def load_config(self, config_path: str) -> ConfigResult:
        return keyed_by_name(super().load_config(config_path), config_path)


def keyed_by_name(result: ConfigResult, config_path: str) -> ConfigResult:
    """``result`` with its content under its option name if it is a method group's option that declares a method."""
    from omegaconf import OmegaConf

    parts = config_path.removesuffix(".yaml").strip("/").split("/")
    if len(parts) != 2 or parts[0] not in METHOD_GROUPS or result.header.get("package"):
        return result
    content = OmegaConf.to_container(result.config) if OmegaConf.is_dict(result.config) else None
    defaults = content.pop("defaults", None) if content else None
    if not content or set(content) == {parts[1]}:
        return result
    result.config = OmegaConf.create({**({"defaults": defaults} if defaults is not None else {}),
                                      parts[1]: content})
    return result


def register_sources() -> None:
    """Make gtsweep's config sources known to Hydra in this process (the CLI's and every launcher worker's):
    ``tuned://``, ``every://`` and ``file://`` with declared methods keyed by name (it takes the place of Hydra's
    own reader of ``file://``, which Hydra's registry keeps one of per scheme)."""
    from hydra._internal.sources_registry import SourcesRegistry

    Plugins.instance().register(TunedMethods)
    Plugins.instance().register(EveryOption)
    SourcesRegistry.instance().types[DeclaredMethods.scheme()] = DeclaredMethods


class Configs:
    """The config files on a search path (``file://dir``, ``pkg://package``, ``tuned://dir`` entries, in order)."""

    def __init__(self, entries):
        from hydra._internal.sources_registry import SourcesRegistry

        from gtsweep.core.paths import mount_checkout_configs

        mount_checkout_configs()  # a checkout's sweeps/ under gtsweep.conf, as in the wheel (before it is imported)
        register_sources()
        self.entries = tuple(entries)
        self.sources = [SourcesRegistry.instance().resolve(entry.split("://")[0])("gtsweep", entry)
                        for entry in self.entries]

    @classmethod
    def of(cls, sources) -> Configs:
        """The configs of Hydra's own sources (a running composition's)."""
        found = cls(())
        found.sources = list(sources)
        found.entries = tuple(f"{s.scheme()}://{s.path}" for s in found.sources)
        return found

    def _listing(self, path: str, kind: ObjectType) -> set[str]:
        return {name for source in self.sources if source.available() and source.is_group(path)
                for name in source.list(path, kind)}

    def options(self, group: str) -> list[str]:
        """The options of a config group (``detector``; ``detector/tuned``), from every directory searched."""
        return sorted(self._listing(group, ObjectType.CONFIG))

    def groups(self, parent: str = "") -> list[str]:
        """Every config group under ``parent`` that has options, e.g. ``detector`` and ``detector/tuned``."""
        found = []
        for name in sorted(self._listing(parent, ObjectType.GROUP)):
            group = f"{parent}/{name}" if parent else name
            if name != "__pycache__":
                found += ([group] if self.options(group) else []) + self.groups(group)
        return found

    def source(self, config: str):
        """The first file ``config`` (``detector/sift``) on the path, as Hydra's ``ConfigResult`` (None if none)."""
        for source in self.sources:
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
