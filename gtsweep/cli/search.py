"""What gtsweep's Hydra application sees: the command line as Hydra parses it, the config search path, the options
of a config group and the raw config files, first match wins.

The primary config (``pkg://gtsweep.cli.primary``, ``gtsweep.yaml``) sits alone in Hydra's main directory and
declares ``hydra.searchpath``: ``./tuned`` (configs written by ``experiment=optimize``) then ``pkg://gtsweep.conf``
(the package's groups and presets). Hydra searches the main directory, then ``--config-dir``, then the search
path; a ``hydra.searchpath=[...]`` on the command line replaces the primary's list, so gtsweep appends its own
entries to it (:func:`with_searchpath`). A user's configs therefore win over the package's.
"""
from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import yaml

from gtsweep.core.configguard import load_yaml
from gtsweep.core.errors import BadInput
from gtsweep.core.searchpath import METHOD_GROUPS, Configs

PRIMARY_MODULE = "gtsweep.cli.primary"
PRIMARY = f"pkg://{PRIMARY_MODULE}"
PRIMARY_NAME = "gtsweep"
#: The config groups that hold a list of methods and span the grid.
GRID_GROUPS = METHOD_GROUPS


@dataclass(frozen=True)
class Invocation:
    """A command line as Hydra's own parser reads it: Hydra's flags (wherever they stood, in their order) and the
    overrides (every positional argument, in its order)."""

    flags: tuple[str, ...]
    overrides: tuple[str, ...]
    config_dir: str | None
    multirun: bool
    passthrough: bool  # shell completion (``-sc install=bash``), or a command line Hydra will refuse: left as is

    @property
    def argv(self) -> list[str]:
        """The command line as Hydra's parser takes it: the overrides as one run, then the flags (a flag standing
        between overrides would end Hydra's positional arguments; an override after ``--info`` would be taken for
        its value)."""
        return [*self.overrides, *self.flags]

    def with_overrides(self, overrides: list[str]) -> list[str]:
        """The command line with its overrides replaced by ``overrides``."""
        return [*overrides, *self.flags]


def _raise(message: str):
    raise BadInput(message)


#: Hydra 1.3's flags (``hydra.main``'s command line; only the overrides are gtsweep's): switches, flags that take
#: the next token as their value (``--cfg`` with its choices), and ``--info`` with an optional value.
SWITCHES = (("--help", "-h"), ("--hydra-help",), ("--version",), ("--resolve",), ("--run", "-r"),
            ("--multirun", "-m"), ("--shell-completion", "-sc"))
VALUED = {("--cfg", "-c"): ["job", "hydra", "all"], ("--package", "-p"): None, ("--config-path", "-cp"): None,
          ("--config-name", "-cn"): None, ("--config-dir", "-cd"): None, ("--experimental-rerun",): None}
INFO = (("--info", "-i"), ["all", "config", "defaults", "defaults-tree", "plugins", "searchpath"])
VALUE_FLAGS = tuple(flag for flags in VALUED for flag in flags)


def hydra_flags() -> argparse.ArgumentParser:
    """A parser of Hydra's command line (``tests/test_cli_hydra.py`` holds it against Hydra's own, so that a new
    Hydra flag is noticed)."""
    parser = argparse.ArgumentParser(add_help=False, prog="python -m gtsweep")
    parser.add_argument("overrides", nargs="*")
    for flags in SWITCHES:
        parser.add_argument(*flags, action="store_true")
    for flags, choices in VALUED.items():
        parser.add_argument(*flags, choices=choices)
    parser.add_argument(*INFO[0], const="all", nargs="?", choices=INFO[1])
    return parser


def _without(argv: tuple[str, ...], overrides: tuple[str, ...]) -> tuple[str, ...]:
    """``argv`` without the tokens that are ``overrides`` (matched in order; a flag's value is never one)."""
    flags, remaining = [], list(overrides)
    for i, token in enumerate(argv):
        takes_value = i > 0 and argv[i - 1] in VALUE_FLAGS
        if remaining and token == remaining[0] and not takes_value:
            remaining.pop(0)
        else:
            flags.append(token)
    return tuple(flags)


@lru_cache(maxsize=64)
def _parse(argv: tuple[str, ...]) -> Invocation:
    parser = hydra_flags()
    parser.error = _raise  # a command line Hydra refuses is Hydra's to report
    try:
        args = parser.parse_intermixed_args(list(argv))
    except (BadInput, argparse.ArgumentError, TypeError):
        return Invocation(argv, (), None, "-m" in argv or "--multirun" in argv, True)
    overrides = tuple(args.overrides)
    return Invocation(_without(argv, overrides), overrides, args.config_dir, bool(args.multirun),
                      bool(args.shell_completion))


def parse(argv) -> Invocation:
    """The command line ``argv`` (a command line Hydra would refuse comes back untouched, for Hydra to report)."""
    return _parse(tuple(argv))


@lru_cache(maxsize=1)
def primary_searchpath() -> tuple[str, ...]:
    """``hydra.searchpath`` of the primary config: gtsweep's entries, in the order Hydra searches them."""
    text = resources.files(PRIMARY_MODULE).joinpath(f"{PRIMARY_NAME}.yaml").read_text()
    return tuple(yaml.safe_load(text)["hydra"]["searchpath"])


def user_searchpath(overrides) -> list[str] | None:
    """The entries of a ``hydra.searchpath=[...]`` override, or None."""
    for override in overrides:
        key, _, value = override.lstrip("+").partition("=")
        if key == "hydra.searchpath":
            entries = yaml.safe_load(value)
            return [str(e) for e in (entries if isinstance(entries, list) else [entries])]
    return None


def with_searchpath(overrides: list[str]) -> list[str]:
    """A user's ``hydra.searchpath=[...]`` with gtsweep's entries appended (it would replace them otherwise)."""
    user = user_searchpath(overrides)
    if user is None:
        return overrides
    entries = [*user, *(e for e in primary_searchpath() if e not in user)]
    return [f"hydra.searchpath=[{','.join(entries)}]" if o.lstrip("+").startswith("hydra.searchpath=") else o
            for o in overrides]


def search_path(argv) -> tuple[str, ...]:
    """Hydra's search path for ``argv``: main directory, ``--config-dir``, the user's then gtsweep's entries."""
    invocation = parse(argv)
    user = user_searchpath(invocation.overrides) or []
    config_dir = [f"file://{os.path.abspath(invocation.config_dir)}"] if invocation.config_dir else []
    return (PRIMARY, *config_dir, *user, *(e for e in primary_searchpath() if e not in user))


@lru_cache(maxsize=16)
def _configs(entries: tuple[str, ...], cwd: str) -> Configs:
    return Configs(entries)


def configs(argv=()) -> Configs:
    """The configs ``python -m gtsweep ARGV`` composes from (``./tuned`` is relative to the working directory)."""
    return _configs(search_path(argv), os.getcwd())




def check_yaml(argv) -> None:
    """A one-line BadInput naming ``file:line`` for a config file of the user's directories on the search path
    (``--config-dir``, ``hydra.searchpath``, ``./tuned``) that is not valid YAML, before Hydra reads it."""
    for entry in search_path(argv):
        scheme, _, root = entry.partition("://")
        if scheme not in ("file", "tuned") or not os.path.isdir(root):
            continue
        for folder, _, names in os.walk(root):
            for name in sorted(n for n in names if n.endswith(".yaml")):
                load_yaml(os.path.join(folder, name))


def loaded_files(overrides) -> list[tuple[str, str]]:
    """``(package, config path)`` of every config file that composing the primary with ``overrides`` loads (Hydra's
    defaults list, from the running Hydra's config loader; ``runtime.choices`` leaves out the groups that take a
    list)."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode

    loader = GlobalHydra.instance().config_loader()
    defaults = loader.compute_defaults_list(PRIMARY_NAME, list(overrides), RunMode.RUN)
    return [(d.package, d.config_path) for d in defaults.defaults if d.config_path and not d.is_self]


def keyed_methods(cfg, found: Configs, overrides) -> None:
    """Key the methods declared in YAML by their option names, in place.

    The package's method configs are keyed by name (``sift: {params: ...}``), so that the options of a multi-select
    group sit side by side; a user's file that declares a new method (``factory: ...``, ``params: ...``) is not,
    and Hydra merges it into the group itself. Its keys are moved to ``<group>.<name>`` (command-line overrides
    there win), read from the file itself, so that two such files never mix.
    """
    from omegaconf import OmegaConf, open_dict

    for package, path in loaded_files(overrides):
        group, _, option = path.partition("/")
        if package != group or group not in GRID_GROUPS or group not in cfg:
            continue
        name = option.split("/")[-1]
        raw = OmegaConf.to_container(found.source(path).config) or {}
        raw.pop("defaults", None)
        if not raw or set(raw) == {name}:
            continue
        with open_dict(cfg[group]):
            for key in set(raw) & set(cfg[group].keys()):  # deleted unread: reading resolves interpolations
                del cfg[group][key]
            cfg[group][name] = OmegaConf.merge(raw, cfg[group].get(name) or {})
