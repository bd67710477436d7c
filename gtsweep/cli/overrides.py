"""``python -m gtsweep``: the Hydra application.

Before Hydra parses the command line, gtsweep expands ``group=all`` to every option of a grid group, checks every
override (unknown method, unknown key, wrong type) so that a mistake costs one clear line instead of a traceback,
and, with ``resume=true``, points Hydra at the newest earlier output directory of the same command.
"""
from __future__ import annotations

import hashlib
import json
import sys
from functools import lru_cache
from pathlib import Path

import yaml

from gtsweep.core.errors import BadInput, UnknownMethod
from gtsweep.core.paths import CONF_DIR, PROJECT_DIR

GRID_GROUPS = ("detector", "selector", "descriptor", "transform")
SINGLE_GROUPS = ("dataset", "experiment", "sweeps")
SWEEP_RECORD = "sweep.json"


def group_dir(group: str) -> Path:
    return PROJECT_DIR / "sweeps" if group == "sweeps" else CONF_DIR / group


def options(group: str) -> list[str]:
    """The options of a config group: its YAML files."""
    return sorted(p.stem for p in group_dir(group).glob("*.yaml"))


def tuned_options(group: str) -> list[str]:
    """Configs written by ``experiment=optimize``: ``tuned/<name>`` for conf/<group>/tuned/<name>.yaml."""
    return sorted(f"tuned/{p.stem}" for p in (group_dir(group) / "tuned").glob("*.yaml"))


@lru_cache(maxsize=None)
def _yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text()) or {}


def expand_all(args: list[str]) -> list[str]:
    """``detector=all`` -> ``detector=[every option]`` for the grid groups."""
    expanded = []
    for arg in args:
        group, _, value = arg.partition("=")
        if group in GRID_GROUPS and value == "all":
            arg = f"{group}=[{','.join(options(group))}]"
        expanded.append(arg)
    return expanded


def _overrides(args: list[str]):
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    candidates = [a for a in args if "=" in a and not a.startswith("-") or a.startswith("~")]
    try:
        return OverridesParser.create().parse_overrides(candidates)
    except HydraException as e:
        raise BadInput(f"cannot parse the overrides: {str(e).splitlines()[0]}") from None


def _values(override) -> list:
    """The values an override sets (each choice of a sweep; a glob expanded over the group's options)."""
    from hydra.core.override_parser.types import (
        ChoiceSweep,
        Glob,
        IntervalSweep,
        RangeSweep,
    )

    value = override.value()
    if isinstance(value, Glob):
        return value.filter(options(override.key_or_group))
    if isinstance(value, ChoiceSweep):
        return list(value.list)
    if isinstance(value, RangeSweep):
        return list(override.sweep_iterator())
    if isinstance(value, IntervalSweep):
        return [float(value.start), float(value.end)]
    return [value]


def _check_group(group: str, values: list) -> None:
    valid = options(group) + (tuned_options(group) if group in GRID_GROUPS else [])
    for value in values:
        names = value if isinstance(value, list) else [value]
        if group in SINGLE_GROUPS and isinstance(value, list):
            raise BadInput(f"{group} takes one option, not a list; choices: {', '.join(valid)}")
        for name in names:
            if name is None and group == "sweeps":
                continue
            if not isinstance(name, str) or name not in valid:
                raise UnknownMethod(group.rstrip("s") if group == "sweeps" else group, str(name), valid)


def _default_option(group: str, args: list[str]) -> str | None:
    for arg in args:
        key, _, value = arg.lstrip("+").partition("=")
        if key == group and "," not in value:
            return value
    for entry in _yaml(CONF_DIR / "config.yaml").get("defaults", []):
        if isinstance(entry, dict) and group in entry:
            return entry[group]
    return None


def _default_value(key: str, args: list[str]):
    """``(found, default)`` of a dotted key, looked up in the YAML file that defines it."""
    parts = key.split(".")
    head = parts[0]
    if head in GRID_GROUPS:
        path, inner = CONF_DIR / head / f"{parts[1]}.yaml" if len(parts) > 1 else None, parts[1:]
        if path is None or not path.exists():
            raise UnknownMethod(head, parts[1] if len(parts) > 1 else "", options(head))
    elif head in ("dataset", "experiment"):
        option = _default_option(head, args)
        path, inner = CONF_DIR / head / f"{option}.yaml", parts[1:]
    else:
        path, inner = CONF_DIR / "config.yaml", parts
    node = _yaml(path)
    for part in inner:
        if not isinstance(node, dict) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _compatible(default, value) -> bool:
    if default is None or default == "???" or value is None:
        return True
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, (int, float)):
        return isinstance(value, int) if isinstance(default, int) else isinstance(value, (int, float))
    if isinstance(default, str):
        return isinstance(value, str)
    return isinstance(value, type(default))


def validate(args: list[str]) -> None:
    """Raise a one-line :class:`GtsweepError` for an override that cannot work."""
    for override in _overrides(args):
        key = override.key_or_group
        if key.startswith("hydra") or override.is_delete():
            continue
        if key in GRID_GROUPS or key in SINGLE_GROUPS:
            _check_group(key, _values(override))
            continue
        if override.is_add():
            continue
        found, default = _default_value(key, args)
        if not found:
            raise BadInput(f"unknown config key '{key}' (to add a new key write +{key}=...)")
        for value in _values(override):
            if not _compatible(default, value):
                kind = type(default).__name__
                raise BadInput(f"override '{key}={value}': expected {'an' if kind[0] in 'aeiou' else 'a'} {kind} "
                               f"like the default {default!r}, got {type(value).__name__}")


def sweep_key(args: list[str]) -> str:
    """What identifies "the same command" for resume: the overrides, without resume and hydra settings."""
    kept = sorted(a for a in args if not a.startswith(("resume=", "hydra.", "-")))
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()[:16]


def resume_args(args: list[str], multirun: bool) -> list[str]:
    """With ``resume=true``, the hydra.run.dir/hydra.sweep.dir override that reopens the newest earlier run."""
    if "resume=true" not in args or any(a.startswith(("hydra.run.dir=", "hydra.sweep.dir=")) for a in args):
        return []
    key = sweep_key(args)
    pattern = "multirun/*/*/*/" + SWEEP_RECORD if multirun else "outputs/*/*/" + SWEEP_RECORD
    records = [p for p in Path.cwd().glob(pattern) if json.loads(p.read_text()).get("key") == key]
    if not records:
        print("gtsweep: resume=true but no earlier run of this command was found; starting afresh", file=sys.stderr)
        return []
    newest = max(records, key=lambda p: p.stat().st_mtime)
    if multirun:
        return [f"hydra.sweep.dir={newest.parent.parent}"]
    return [f"hydra.run.dir={newest.parent}"]


def searchpath_override() -> str:
    """Makes ``sweeps/`` (outside ``conf/``) a config group: presets are selected with ``sweeps=<name>``."""
    return f"hydra.searchpath=[file://{PROJECT_DIR}]"


def compose_config(overrides: list[str]):
    """The composed config for ``overrides``, as ``python -m gtsweep`` would see it (for scripts and tests)."""
    from hydra import compose, initialize_config_dir

    overrides = expand_all(list(overrides))
    validate(overrides)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose(config_name="config", overrides=[*overrides, searchpath_override()])


def fail(error: Exception) -> None:
    print(f"gtsweep: error: {error}", file=sys.stderr)
    sys.exit(2)
