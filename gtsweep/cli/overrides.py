"""``python -m gtsweep``: the Hydra application.

Before Hydra parses the command line, gtsweep expands ``group=all`` to every option of a grid group, checks every
override (unknown method, unknown key, wrong type) so that a mistake costs one clear line instead of a traceback,
and, with ``resume=true``, points Hydra at the newest earlier output directory of the same command. A method's
parameters are checked against its registry defaults (its YAML holds only overrides; a method declared in YAML
has its ``params`` as defaults), and an override of one is passed to Hydra in its force-add form
``++group.name.params.key=value``, since the key may be absent from the YAML.

Only the overrides are touched, as Hydra's own parser finds them (:mod:`gtsweep.cli.search`): Hydra's flags
(``--cfg``, ``--info``, ``-m``, ``--config-dir``, ...) may stand anywhere, and ``-sc install=bash`` is left alone.
Valid choices are the options on Hydra's search path, a user's ``--config-dir`` included.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

from gtsweep.cli.search import (
    GRID_GROUPS,
    check_yaml,
    configs,
    parse,
    user_searchpath,
    with_searchpath,
)
from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod, nearest
from gtsweep.core.registry import compatible
from gtsweep.orchestration.settings import SETTINGS

SINGLE_GROUPS = ("dataset", "experiment", "sweeps")
SWEEP_RECORD = "sweep.json"


def options(group: str, args=()) -> list[str]:
    """The options of a config group on the search path of ``args`` (user directories included)."""
    return configs(args).options(group)


def tuned_options(group: str, args=()) -> list[str]:
    """Configs written by ``experiment=optimize``: ``tuned/<name>`` for ``<root>/<group>/tuned/<name>.yaml``."""
    return [f"tuned/{name}" for name in configs(args).options(f"{group}/tuned")]


def _rewrite(args: list[str], rewrite) -> list[str]:
    """``args`` with ``rewrite(overrides)`` in place of its overrides (a shell completion is left alone)."""
    invocation = parse(args)
    return list(args) if invocation.passthrough else invocation.with_overrides(rewrite(list(invocation.overrides)))


def expand_all(args: list[str]) -> list[str]:
    """``detector=all`` -> ``detector=[every option]`` for the grid groups; ``group=glob(...)`` -> the options it
    matches, ``group=a,b`` (Hydra's sweeper globs over its main directory only, not the search path)."""

    def expand(overrides):
        expanded = []
        for arg in overrides:
            group, _, value = arg.partition("=")
            if group in GRID_GROUPS and value == "all":
                arg = f"{group}=[{','.join(options(group, args))}]"
            elif group in (*GRID_GROUPS, *SINGLE_GROUPS) and value.startswith("glob("):
                arg = f"{group}={','.join(_glob(group, arg, args))}"
            expanded.append(arg)
        return expanded

    return _rewrite(args, expand)


def _glob(group: str, override: str, args) -> list[str]:
    """The options of ``group`` that ``group=glob(...)`` matches; a one-line error when none does."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        matches = OverridesParser.create().parse_override(override).value().filter(options(group, args))
    except HydraException as e:
        raise BadInput(f"cannot parse '{override}': {str(e).splitlines()[0]}") from None
    if not matches:
        raise BadInput(f"'{override}' matches no {group}; choices: {', '.join(options(group, args))}")
    return matches


def searchpath(args: list[str]) -> list[str]:
    """A ``hydra.searchpath=[...]`` of the user with gtsweep's entries appended (it would replace them)."""
    return _rewrite(args, with_searchpath)


def _overrides(args: list[str]):
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    invocation = parse(args)
    if invocation.passthrough:  # shell completion: Hydra's own business
        return []
    try:
        return OverridesParser.create().parse_overrides(list(invocation.overrides))
    except HydraException as e:
        raise BadInput(f"cannot parse the overrides: {str(e).splitlines()[0]}") from None


def _values(override, args=()) -> list:
    """The values an override sets (each choice of a sweep; a glob expanded over the group's options)."""
    from hydra.core.override_parser.types import (
        ChoiceSweep,
        Glob,
        IntervalSweep,
        RangeSweep,
    )

    value = override.value()
    if isinstance(value, Glob):
        return value.filter(options(override.key_or_group, args))
    if isinstance(value, ChoiceSweep):
        return list(value.list)
    if isinstance(value, RangeSweep):
        return list(override.sweep_iterator())
    if isinstance(value, IntervalSweep):
        return [float(value.start), float(value.end)]
    return [value]


def _check_group(group: str, values: list, args) -> None:
    valid = options(group, args) + (tuned_options(group, args) if group in GRID_GROUPS else [])
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
    for arg in parse(args).overrides:
        key, _, value = arg.lstrip("+").partition("=")
        if key == group and "," not in value:
            return value
    return _config_default(group, args)


def _config_default(group: str, args):
    """The option of ``group`` in the defaults list of the settings (``config``)."""
    for entry in configs(args).load("config").get("defaults", []):
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


def method_node(group: str, name: str, args=()) -> tuple[dict | None, bool]:
    """``(node, declared)`` of option ``name`` of a grid group: its config (None if there is no such file), and
    whether the file declares a new method (its content not keyed by its name, e.g. ``factory: ...``)."""
    raw = configs(args).load(f"{group}/{name}")
    raw.pop("defaults", None)
    if not raw and name not in options(group, args):
        return None, False
    keyed = set(raw) == {name}
    return (raw[name] if keyed else raw), not keyed


def _default_value(key: str, args: list[str]):
    """``(found, default)`` of a dotted key: a method parameter's registry default, else the YAML value."""
    parts = key.split(".")
    head = parts[0]
    if head in GRID_GROUPS:
        node, declared = method_node(head, parts[1], args) if len(parts) > 1 else (None, False)
        if node is None:
            raise UnknownMethod(head, parts[1] if len(parts) > 1 else "", options(head, args))
        param = _param_key(key)
        method = _method(head, parts[1]) if param and not declared else None
        if method is not None:
            if param[2] not in method.defaults:
                method.params({param[2]: None})  # raises: no parameter '...'; its parameters: ...
            return True, method.defaults[param[2]]
        if param and declared and param[2] not in (node.get("params") or {}):
            valid = ", ".join(sorted(node.get("params") or {})) or "none"
            raise BadInput(f"{head} '{parts[1]}' has no parameter '{param[2]}'; its parameters: {valid}")
        node, inner = (node, parts[2:]) if declared else ({parts[1]: node}, parts[1:])
    elif head in ("dataset", "experiment"):
        node, inner = configs(args).load(f"{head}/{_default_option(head, args)}"), parts[1:]
    else:
        node, inner = configs(args).load("config"), parts
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
            _check_group(key, _values(override, args), args)
            continue
        if override.is_add():
            continue
        found, default = _default_value(key, args)
        if not found:
            _moved(key)
            raise BadInput(f"unknown config key '{key}'" + "".join(f"; did you mean '{near}'?"
                                                                    for near in _near_keys(key, args)))
        _check_selected(override.input_line, args)
        for value in _values(override, args):
            if default != "???" and not compatible(default, value):
                kind = type(default).__name__
                raise BadInput(f"override '{key}={value}': expected {'an' if kind[0] in 'aeiou' else 'a'} {kind} "
                               f"like the default {default!r}, got {type(value).__name__}")
            if key in SETTINGS:  # its allowed values: before Hydra creates an output directory
                SETTINGS[key].check(key, value)


def _near_keys(key: str, args) -> list[str]:
    """The known key nearest to a mistyped one (at most one), by its first unknown part: ``detectr`` ->
    ``detector``, ``runner.num_cpuz`` -> ``runner.num_cpus``."""
    parts = key.split(".")
    for depth in range(len(parts) - 1, -1, -1):
        prefix = ".".join(parts[:depth])
        try:
            found, node = _default_value(prefix, args) if prefix else (True, _top_level_keys(args))
        except GtsweepError:
            continue
        if found and isinstance(node, dict):
            return [".".join([*parts[:depth], near, *parts[depth + 1:]]) for near in nearest(parts[depth], node)]
    return []


def _top_level_keys(args) -> dict:
    keys = {k: None for k in configs(args).load("config") if k != "defaults"}
    return {**keys, **{group: None for group in (*GRID_GROUPS, *SINGLE_GROUPS)}}


def _check_selected(override: str, args) -> None:
    """A setting of a grid group's option (``transform.rotation.strengths=...``) needs that option selected in
    every job: else Hydra would refuse it, or a force-add would put the option into the grid."""
    key = override.lstrip("+").partition("=")[0]
    parts = key.split(".")
    if parts[0] not in GRID_GROUPS or len(parts) < 3 or override.startswith("~"):
        return
    selected = _selected(parts[0], args)
    if selected is not None and parts[1] not in selected:
        raise BadInput(f"override '{override}': {parts[0]} '{parts[1]}' is not selected (selected: "
                       f"{', '.join(sorted(selected))}); add it, e.g. {parts[0]}=[{parts[1]},...]")


def _moved(key: str) -> None:
    """A one-line BadInput for a setting that moved to a matcher's or an estimator's parameters."""
    from gtsweep.orchestration.grid import MOVED

    new = MOVED.get(key.removeprefix("experiment."))
    if key.startswith("experiment.") and new:
        group, name = new.split(".")[:2]
        raise BadInput(f"'{key}' moved to the {group} group: write {new}=... ({group}={name} must be selected; "
                       f"conf/{group}/{name}.yaml)")


def force_add(args: list[str]) -> list[str]:
    """Method parameter overrides in Hydra's force-add form ``++group.name.params.key=value``.

    A method's YAML holds only the parameters a user overrides, and Hydra's struct mode refuses a key absent from
    it. The method must be selected in every job, else the force-add would put it in the grid.
    """

    def rewrite(overrides):
        rewritten = []
        for arg in overrides:
            key = arg.lstrip("+").partition("=")[0]
            param = _param_key(key) if "=" in arg and not arg.startswith("~") else None
            if param is None or arg.startswith("+") and not arg.startswith("++"):
                rewritten.append(arg)
                continue
            _check_selected(arg, args)
            rewritten.append(f"++{arg.lstrip('+')}")
        return rewritten

    return _rewrite(args, rewrite)


def _selected(group: str, args: list[str]) -> set[str] | None:
    """The options of a grid group that every job selects (``tuned/sift`` selects ``sift``); None if unknown."""
    from hydra.core.override_parser.types import Glob

    jobs, presets = None, [_config_default("sweeps", args)]
    for override in _overrides(args):
        if override.key_or_group == group and not override.is_delete():
            value = override.value()
            jobs = [value.filter(options(group, args))] if isinstance(value, Glob) else _values(override, args)
        elif override.key_or_group == "sweeps":
            presets = _values(override, args)
    if jobs is None:
        if len(presets) != 1:
            return None
        entries = configs(args).load(f"sweeps/{presets[0]}").get("defaults", []) if presets[0] else []
        jobs = [entry[f"override /{group}"] for entry in entries
                if isinstance(entry, dict) and f"override /{group}" in entry]
    if not jobs:
        jobs = [_config_default(group, args)]
    names = [{str(n).split("/")[-1] for n in (job if isinstance(job, list) else [job])} for job in jobs]
    return set.intersection(*names) if names else None


def place(args: list[str], extra: list[str]) -> list[str]:
    """``args`` with ``extra`` overrides after its own: Hydra's parser takes the overrides as one run of
    positional arguments, so one appended after a flag such as ``--cfg job`` or ``--info`` would be refused."""
    return _rewrite(args, lambda overrides: [*overrides, *extra]) if extra else list(args)


def sweep_key(args: list[str]) -> str:
    """What identifies "the same command" for resume: the overrides, without resume and hydra settings."""
    kept = sorted(a for a in parse(args).overrides if not a.startswith(("resume=", "hydra.")))
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


def prepare(args: list[str]) -> list[str]:
    """The command line Hydra gets: ``all`` expanded, every override checked, method parameters force-added, a
    user's ``hydra.searchpath`` completed with gtsweep's entries. A :class:`GtsweepError` for a mistake."""
    check_yaml(args)
    args = expand_all(list(args))
    validate(args)
    return searchpath(force_add(args))


def compose_config(overrides: list[str], config_dir: str | None = None):
    """The composed config for ``overrides``, as ``python -m gtsweep [--config-dir DIR]`` would see it (for scripts
    and tests); YAML-declared methods keyed by their names (:func:`gtsweep.cli.search.keyed_methods`)."""
    from hydra import compose, initialize_config_module

    from gtsweep.cli.search import PRIMARY_MODULE, PRIMARY_NAME, keyed_methods
    from gtsweep.core.searchpath import ignore_missing_dir, register_help_resolver
    from gtsweep.core.paths import DEFAULT_TUNED_ROOT

    args = ["--config-dir", config_dir, *overrides] if config_dir else list(overrides)
    args = prepare(args)
    overrides = list(parse(args).overrides)
    if config_dir:  # compose() has no --config-dir: the same place on the search path, via hydra.searchpath
        user = [f"file://{Path(config_dir).resolve()}", *(user_searchpath(overrides) or [])]
        overrides = [o for o in overrides if not o.lstrip("+").startswith("hydra.searchpath=")]
        overrides = with_searchpath([*overrides, f"hydra.searchpath=[{','.join(user)}]"])
    ignore_missing_dir(str(DEFAULT_TUNED_ROOT))
    register_help_resolver()
    with initialize_config_module(config_module=PRIMARY_MODULE, version_base=None):
        cfg = compose(config_name=PRIMARY_NAME, overrides=overrides)
        keyed_methods(cfg, configs(args), overrides)
    return cfg


def fail(error: Exception) -> None:
    print(f"gtsweep: error: {error}", file=sys.stderr)
    sys.exit(2)
