"""The command line as Hydra's own parser reads it, the config search path it gives, and the configs on it (first
match wins): the primary config's ``hydra.searchpath`` (``./tuned``, ``pkg://gtsweep.conf``, ``every://all``), after
Hydra's main directory and ``--config-dir``; a user's ``hydra.searchpath=[...]`` gets gtsweep's entries appended."""
from __future__ import annotations

import argparse
import os
from functools import lru_cache
from importlib import resources

import yaml

from gtsweep.core.searchpath import Configs

PRIMARY_MODULE = "gtsweep.cli.primary"
PRIMARY = f"pkg://{PRIMARY_MODULE}"
PRIMARY_NAME = "gtsweep"


def hydra_args(argv) -> argparse.Namespace:
    """``argv`` as Hydra's parser reads it, Hydra's flags anywhere between the overrides; a user's
    ``hydra.searchpath`` completed with gtsweep's entries."""
    from hydra._internal.utils import get_args_parser

    args = get_args_parser().parse_intermixed_args(list(argv))
    args.overrides = with_searchpath(args.overrides)
    return args


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
        return list(overrides)
    entries = [*user, *(e for e in primary_searchpath() if e not in user)]
    return [f"hydra.searchpath=[{','.join(entries)}]" if o.lstrip("+").startswith("hydra.searchpath=") else o
            for o in overrides]


def search_path(args: argparse.Namespace) -> tuple[str, ...]:
    """Hydra's search path for a command line: main directory, ``--config-dir``, the user's then gtsweep's
    entries."""
    config_dir = [f"file://{os.path.abspath(args.config_dir)}"] if args.config_dir else []
    user = user_searchpath(args.overrides) or []
    return (PRIMARY, *config_dir, *user, *(e for e in primary_searchpath() if e not in user))


@lru_cache(maxsize=16)
def _configs(entries: tuple[str, ...], cwd: str) -> Configs:
    return Configs(entries)


def configs(argv=()) -> Configs:
    """The configs ``python -m gtsweep ARGV`` composes from (``./tuned`` is relative to the working directory)."""
    try:
        args = hydra_args(argv)
    except SystemExit:  # a command line Hydra refuses: the package's configs
        args = hydra_args(())
    return _configs(search_path(args), os.getcwd())

