"""Pre-flight: Hydra composes every job of a command line before anything runs, and its error becomes gtsweep's
one line.

Composition does the config work (:mod:`gtsweep.cli.schemas`): a method's YAML and the command line are merged
onto the method's defaults, and Hydra's struct mode refuses an unknown key or a value of the wrong type. Its
error carries the key (``ConfigCompositionException.__cause__.full_key``); :func:`translate` says it in gtsweep's
words: an option that is not selected, a method's unknown parameter, a near miss, a setting that moved. The
ranges Hydra does not know are checked on the composed config (:func:`gtsweep.orchestration.settings.
check_settings`). A method declared in YAML alone has no defaults in code: its parameters are passed to Hydra
in the force-add form ``++group.name.params.key=value`` and checked against its file here.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

from gtsweep.cli.search import (
    GRID_GROUPS,
    PRIMARY_MODULE,
    PRIMARY_NAME,
    configs,
    keyed_methods,
    parse,
    user_searchpath,
    with_searchpath,
)
from gtsweep.core.config import plain
from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod, nearest
from gtsweep.core.factories import check_composed
from gtsweep.core.registry import require_available
from gtsweep.orchestration.grid import MOVED, REGISTRIES
from gtsweep.orchestration.settings import check_settings
from gtsweep.stages import device as devices

SINGLE_GROUPS = ("dataset", "experiment", "sweeps")
KINDS = {"IntegerNode": "an int", "FloatNode": "a float", "BooleanNode": "a bool", "StringNode": "a str"}


def choices(group: str, args=()) -> list[str]:
    """The valid options of a config group on the search path of ``args``, a grid group's tuned ones included."""
    found = configs(args)
    tuned = [f"tuned/{name}" for name in found.options(f"{group}/tuned")] if group in GRID_GROUPS else []
    return found.options(group) + tuned


def parsed(overrides):
    """The overrides as Hydra's parser reads them; a one-line BadInput for one it cannot parse."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        return OverridesParser.create().parse_overrides(list(overrides))
    except HydraException as e:
        raise BadInput(f"cannot parse the overrides: {str(e).splitlines()[0]}") from None


def declares_method(group: str, name: str, args=()) -> bool:
    """Whether option ``name`` of grid group ``group`` is a file that declares a method (``factory: ...``, its
    content not keyed by its name), whose ``params`` are its defaults."""
    raw = configs(args).load(f"{group}/{name}")
    raw.pop("defaults", None)
    return bool(raw) and set(raw) != {name}


def declared_param(override: str, args=()) -> tuple[str, str, str] | None:
    """``(group, name, parameter)`` of an override ``group.name.params.parameter=...`` of a declared method."""
    key = override.lstrip("+").partition("=")[0]
    parts = key.split(".")
    if "=" not in override or override.startswith(("~", "+")) and not override.startswith("++"):
        return None
    if len(parts) == 4 and parts[0] in GRID_GROUPS and parts[2] == "params" and declares_method(*parts[:2], args):
        return parts[0], parts[1], parts[3]
    return None


def force_add_declared(overrides: list[str], args=()) -> list[str]:
    """A declared method's parameter overrides in Hydra's force-add form (its node is keyed by name only after
    composition: :func:`gtsweep.cli.search.keyed_methods`)."""
    return [f"++{o.lstrip('+')}" if declared_param(o, args) else o for o in overrides]


def jobs(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override lists to compose: one job, or with ``-m`` each value of every swept override once (the others
    at their first value); a sweep Hydra's plain composition cannot take (an interval) is left to the sweeper."""
    if not multirun:
        return [list(overrides)]
    fixed, swept = [], []
    for text, override in zip(overrides, parsed(overrides)):
        if not override.is_sweep_override():
            fixed.append(text)
            continue
        try:
            values = list(override.sweep_string_iterator())
        except Exception:  # noqa: BLE001 - an interval or a glob: the sweeper's business
            continue
        swept.append([f"{override.get_key_element()}={value}" for value in values])
    first = [values[0] for values in swept]
    variants = [first] + [first[:i] + [value] + first[i + 1:] for i, values in enumerate(swept) for value in values[1:]]
    return [[*fixed, *variant] for variant in variants]


@contextlib.contextmanager
def composer(args):
    """``compose(overrides)``: the config ``python -m gtsweep ARGS`` composes for one job's overrides, with
    ``--config-dir`` of ``args`` on the search path; Hydra's error as a one-line GtsweepError."""
    from hydra import compose, initialize_config_module

    from gtsweep.cli.lifecycle import register_resolvers
    from gtsweep.cli.schemas import register_schemas
    from gtsweep.core.paths import DEFAULT_TUNED_ROOT
    from gtsweep.core.searchpath import ignore_missing_dir, register_help_resolver, register_sources

    config_dir = parse(args).config_dir
    ignore_missing_dir(str(DEFAULT_TUNED_ROOT))
    for register in (register_sources, register_resolvers, register_help_resolver, register_schemas):
        register()

    def composed(overrides):
        overrides = list(overrides)
        if config_dir:  # compose() has no --config-dir: the same place on the search path, via hydra.searchpath
            user = [f"file://{Path(config_dir).resolve()}", *(user_searchpath(overrides) or [])]
            overrides = [o for o in overrides if not o.lstrip("+").startswith("hydra.searchpath=")]
            overrides = with_searchpath([*overrides, f"hydra.searchpath=[{','.join(user)}]"])
        try:
            cfg = compose(config_name=PRIMARY_NAME, overrides=overrides)
        except Exception as e:  # noqa: BLE001 - Hydra's and OmegaConf's errors, translated
            raise translate(e, overrides, args) from None
        keyed_methods(cfg, configs(args), overrides)
        return cfg

    with initialize_config_module(config_module=PRIMARY_MODULE, version_base=None):
        yield composed


def check(args: list[str]) -> None:
    """Compose every job of ``args`` (already expanded) as Hydra will; a one-line GtsweepError for a mistake."""
    invocation = parse(args)
    if invocation.passthrough:
        return
    overrides = list(invocation.overrides)
    for override in parsed(overrides):
        group = override.key_or_group
        if group in SINGLE_GROUPS and any(isinstance(value, list) for value in values_of(override)):
            raise BadInput(f"{group} takes one option, not a list; choices: {', '.join(choices(group, args))}")
    with composer(args) as compose:
        for job in jobs(overrides, invocation.multirun):
            cfg = compose(job)
            require_available(*(REGISTRIES[g][n] for g in GRID_GROUPS for n in cfg.get(g) or () if n in REGISTRIES[g]))
            for override in job:
                found = declared_param(override, args)
                if found:
                    check_declared(cfg, *found, args)
            check_composed(cfg, overrides)
            check_settings(cfg)
            check_device(cfg)


def check_device(cfg) -> None:
    """``runner.device=cuda`` where torch sees no CUDA device and the grid has a torch method: one line, before
    the output directory exists (``auto`` falls back to the CPU and never fails)."""
    runner = plain(cfg.get("runner")) or {}
    if runner.get("device") != devices.CUDA:
        return
    chosen = {group: plain(cfg.get(group)) or {} for group in devices.TORCH_METHODS}
    devices.resolve(devices.CUDA, any(devices.moves(group, name) for group, names in chosen.items()
                                      for name in names))


def values_of(override) -> list:
    """The values an override sets (each choice of a sweep)."""
    value = override.value()
    return list(value.list) if hasattr(value, "list") else [value]


def check_declared(cfg, group: str, name: str, parameter: str, args) -> None:
    """A parameter override of a declared method: the method selected, the parameter one of its file's."""
    node = cfg[group].get(name)
    if node is None or "factory" not in node:
        raise not_selected(group, name, [n for n in cfg[group] if n != name])
    raw = configs(args).load(f"{group}/{name}").get("params") or {}
    if parameter not in raw:
        raise BadInput(f"{group} '{name}' has no parameter '{parameter}'; its parameters: "
                       f"{', '.join(sorted(raw)) or 'none'}")


def not_selected(group: str, name: str, selected) -> BadInput:
    return BadInput(f"{group} '{name}' is not selected (selected: {', '.join(sorted(selected)) or 'none'}); add it, "
                    f"e.g. {group}=[{name},...]")


def translate(error: Exception, overrides: list[str], args) -> GtsweepError:
    """Hydra's composition error as gtsweep's one line."""
    from hydra.errors import MissingConfigException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, ValidationError

    if isinstance(error, GtsweepError):
        return error
    missing = getattr(error, "missing_cfg_file", None) if isinstance(error, MissingConfigException) else None
    if missing:
        group, _, name = missing.partition("/")
        return UnknownMethod("sweep" if group == "sweeps" else group, name, choices(group, args))
    cause = error.__cause__
    key = str(getattr(cause, "full_key", "") or "")
    written = next((o.lstrip("+~").partition("=") for o in overrides
                    if f"{o.lstrip('+~').partition('=')[0]}.".startswith(f"{key}.")), None) if key else None
    if isinstance(cause, ValidationError) and written and cause.child_node is not None:
        kind = KINDS.get(type(cause.child_node).__name__)
        default = cause.parent_node.get(cause.key) if cause.parent_node is not None else None
        like = f" like the default {default!r}" if default is not None and str(default) != "???" else ""
        if kind:
            return BadInput(f"override '{''.join(written)}': expected {kind}{like}, got {written[2]!r}")
    if isinstance(cause, (ConfigAttributeError, ConfigKeyError)) and written:
        return unknown_key(written[0], key, cause, args)
    return BadInput(str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__)


def unknown_key(written: str, missing: str, cause, args) -> GtsweepError:
    """An override of ``written`` whose part ``missing`` (its first absent prefix) the composed config lacks."""
    parts, depth = written.split("."), len(missing.split("."))
    parent = cause.parent_node
    if parts[0] in GRID_GROUPS and len(parts) > 1:
        group, name = parts[:2]
        if depth == 2:
            if name in choices(group, args):
                return not_selected(group, name, list(parent or ()))
            return UnknownMethod(group, name, choices(group, args))
        if depth == len(parts) and (parts[2] == "params" and depth == 4 or parts[2] == "per_detector" and depth == 5):
            method = REGISTRIES[group].get(name, None)
            known = sorted(method.defaults) if method is not None else sorted(parent or ())
            if parts[-1] in known:  # a config of the user's that replaces the package's without its schema
                return BadInput(f"{group} '{name}': its config does not compose onto its defaults, so '{parts[-1]}' "
                                f"cannot be set; list /schema/{group}/{name}@_here_ first in its defaults")
            return BadInput(f"{group} '{name}' has no parameter '{parts[-1]}'; its parameters: "
                            f"{', '.join(known) or 'none'}")
        if parts[2] == "per_detector" and depth == 4 and len(parts) == 5:
            return BadInput(f"{group} '{name}' has no per_detector entry '{parts[3]}' (its entries: "
                            f"{', '.join(sorted(parent or ())) or 'none'}); a new one is appended: +{written}=...")
    moved = MOVED.get(written.removeprefix("experiment."))
    if written.startswith("experiment.") and moved:
        group, name = moved.split(".")[:2]
        return BadInput(f"'{written}' moved to the {group} group: write {moved}=... ({group}={name} must be "
                        f"selected; conf/{group}/{name}.yaml)")
    near = nearest(parts[depth - 1], list(parent or ())) if depth <= len(parts) else []
    return BadInput(f"unknown config key '{written}'" + "".join(
        f"; did you mean '{'.'.join([*parts[:depth - 1], n, *parts[depth:]])}'?" for n in near))
