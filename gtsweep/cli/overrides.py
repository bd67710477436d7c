"""``python -m gtsweep``: the Hydra application.

Before Hydra parses the command line, gtsweep expands ``group=all`` to every option of a grid group, checks every
override (unknown method, unknown key, wrong type) so that a mistake costs one clear line instead of a traceback,
and, with ``resume=true``, points Hydra at the newest earlier output directory of the same command. A method's
parameters are checked against its registry defaults (its YAML holds only overrides), and an override of one is
passed to Hydra in its force-add form ``++group.name.params.key=value``, since the key may be absent from the YAML.
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
from gtsweep.core.registry import compatible

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


def _param_key(key: str) -> tuple[str, str, str] | None:
    """``(group, method, parameter)`` for ``group.method.params.parameter`` (or a descriptor's
    ``descriptor.method.per_detector.detector.parameter``), else None."""
    parts = key.split(".")
    if parts[0] not in GRID_GROUPS or len(parts) < 4:
        return None
    if parts[2] == "params" and len(parts) == 4 or parts[2] == "per_detector" and len(parts) == 5:
        return parts[0], parts[1], parts[-1]
    return None


def _method(group: str, name: str):
    """The registry entry of a grid group's option; None for an option without one (the real-pair transforms)."""
    from gtsweep.orchestration.grid import REGISTRIES

    return REGISTRIES[group].get(name, None)


def _default_value(key: str, args: list[str]):
    """``(found, default)`` of a dotted key: a method parameter's registry default, else the YAML value."""
    parts = key.split(".")
    head = parts[0]
    if head in GRID_GROUPS:
        path, inner = CONF_DIR / head / f"{parts[1]}.yaml" if len(parts) > 1 else None, parts[1:]
        if path is None or not path.exists():
            raise UnknownMethod(head, parts[1] if len(parts) > 1 else "", options(head))
        param = _param_key(key)
        method = _method(head, parts[1]) if param else None
        if method is not None:
            if param[2] not in method.defaults:
                method.params({param[2]: None})  # raises: no parameter '...'; its parameters: ...
            return True, method.defaults[param[2]]
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
            if default != "???" and not compatible(default, value):
                kind = type(default).__name__
                raise BadInput(f"override '{key}={value}': expected {'an' if kind[0] in 'aeiou' else 'a'} {kind} "
                               f"like the default {default!r}, got {type(value).__name__}")


def force_add(args: list[str]) -> list[str]:
    """Method parameter overrides in Hydra's force-add form ``++group.name.params.key=value``.

    A method's YAML holds only the parameters a user overrides, and Hydra's struct mode refuses a key absent from
    it. The method must be selected in every job, else the force-add would put it in the grid.
    """
    rewritten = []
    for arg in args:
        key = arg.lstrip("+").partition("=")[0]
        param = _param_key(key) if "=" in arg and not arg.startswith(("-", "~")) else None
        if param is None or arg.startswith("+") and not arg.startswith("++"):
            rewritten.append(arg)
            continue
        group, name, _ = param
        selected = _selected(group, args)
        if selected is not None and name not in selected:
            raise BadInput(f"override '{arg}': {group} '{name}' is not selected (selected: "
                           f"{', '.join(sorted(selected))}); add it, e.g. {group}=[{name},...]")
        rewritten.append(f"++{arg.lstrip('+')}")
    return rewritten


def _selected(group: str, args: list[str]) -> set[str] | None:
    """The options of a grid group that every job selects (``tuned/sift`` selects ``sift``); None if unknown."""
    from hydra.core.override_parser.types import Glob

    jobs, presets = None, [_default_option("sweeps", [])]
    for override in _overrides(args):
        if override.key_or_group == group and not override.is_delete():
            value = override.value()
            jobs = [value.filter(options(group))] if isinstance(value, Glob) else _values(override)
        elif override.key_or_group == "sweeps":
            presets = _values(override)
    if jobs is None:
        if len(presets) != 1:
            return None
        entries = _yaml(group_dir("sweeps") / f"{presets[0]}.yaml").get("defaults", []) if presets[0] else []
        jobs = [entry[f"override /{group}"] for entry in entries
                if isinstance(entry, dict) and f"override /{group}" in entry]
    if not jobs:
        jobs = [entry[group] for entry in _yaml(CONF_DIR / "config.yaml").get("defaults", [])
                if isinstance(entry, dict) and group in entry]
    names = [{str(n).split("/")[-1] for n in (job if isinstance(job, list) else [job])} for job in jobs]
    return set.intersection(*names) if names else None


def place(args: list[str], extra: list[str]) -> list[str]:
    """``args`` with ``extra`` overrides next to the first override: Hydra's parser takes the overrides as one run
    of positional arguments, so one appended after a flag such as ``--cfg job`` would be refused."""
    first = next((i for i, a in enumerate(args) if "=" in a and not a.startswith("-")), None)
    return [*args, *extra] if first is None else [*args[:first + 1], *extra, *args[first + 1:]]


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
    overrides = force_add(overrides)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return compose(config_name="config", overrides=[*overrides, searchpath_override()])


def fail(error: Exception) -> None:
    print(f"gtsweep: error: {error}", file=sys.stderr)
    sys.exit(2)
