"""A job's config checked where Hydra composes it (:func:`check_job`: what Hydra's types do not check), and Hydra's
composition errors said in gtsweep's one line (:func:`translate`: an option not selected, a method's unknown
parameter, a near miss, a setting that moved)."""
from __future__ import annotations

import sys

from gtsweep.core.config import METHOD_GROUPS, plain
from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod, causes, nearest
from gtsweep.core.factories import check_composed
from gtsweep.core.registry import availability, left_out_line, require_available
from gtsweep.core.searchpath import Configs
from gtsweep.experiments.kinds import EXPERIMENTS
from gtsweep.experiments.pairs.grid import MOVED
from gtsweep.orchestration.grid import REGISTRIES
from gtsweep.orchestration.settings import check_settings
from gtsweep.stages import device as devices

SINGLE_GROUPS = ("dataset", "experiment", "sweeps")
KINDS = {"IntegerNode": "an int", "FloatNode": "a float", "BooleanNode": "a bool", "StringNode": "a str"}


def choices(group: str, found: Configs) -> list[str]:
    """The valid options of a config group, a grid group's tuned ones included."""
    tuned = [f"tuned/{name}" for name in found.options(f"{group}/tuned")] if group in METHOD_GROUPS else []
    return found.options(group) + tuned


def check_single_groups(overrides, found: Configs) -> None:
    """A group that takes one option (``dataset``) given a list: one line."""
    for override in overrides:
        group, _, value = override.partition("=")
        if group in SINGLE_GROUPS and value.startswith("["):
            raise BadInput(f"{group} takes one option, not a list; choices: {', '.join(choices(group, found))}")


_left_out: dict[str, dict] = {}  # group -> {name: reason} that group=all left out in this command
_noted: set = set()


def runnable_options(group: str, names: list[str]) -> list[str]:
    """The options ``group=all`` takes: those this install can run (:func:`gtsweep.core.registry.availability`);
    the others are noted once (:func:`note_left_out`)."""
    runnable, left_out = availability(REGISTRIES[group], names) if group in REGISTRIES else (names, {})
    if left_out:
        _left_out[group] = left_out
    return runnable


def note_left_out() -> None:
    """One line, once per command, for the methods ``all`` left out (which, and what adds them)."""
    line = left_out_line([_left_out[group] for group in METHOD_GROUPS if group in _left_out])
    _left_out.clear()
    if line and line not in _noted:
        _noted.add(line)
        print(f"gtsweep: note: {line}", file=sys.stderr)


def forget_notes() -> None:
    """A new command (in this process): nothing left out or noted yet."""
    _left_out.clear()
    _noted.clear()


def check_job(cfg, overrides, found: Configs) -> None:
    """What Hydra's composition does not check: a single-option group given a list, a method this install cannot
    run, factories and plug-ins (:func:`gtsweep.core.factories.check_composed`), the ranges of the run settings and
    of its experiment kind's, the device."""
    check_single_groups(overrides, found)
    require_available(*(REGISTRIES[g][n] for g in METHOD_GROUPS for n in cfg.get(g) or () if n in REGISTRIES[g]))
    check_composed(cfg, overrides)
    check_settings(cfg, EXPERIMENTS.get((plain(cfg.get("experiment")) or {}).get("name")).settings)
    check_device(cfg)
    note_left_out()


def check_device(cfg) -> None:
    """``runner.device=cuda`` where torch sees no CUDA device and the grid has a torch method: one line, before
    the output directory exists (``auto`` falls back to the CPU and never fails)."""
    runner = plain(cfg.get("runner")) or {}
    if runner.get("device") != devices.CUDA:
        return
    chosen = {group: plain(cfg.get(group)) or {} for group in devices.TORCH_METHODS}
    devices.resolve(devices.CUDA, any(devices.moves(group, name) for group, names in chosen.items()
                                      for name in names))


def not_selected(group: str, name: str, selected) -> BadInput:
    return BadInput(f"{group} '{name}' is not selected (selected: {', '.join(sorted(selected)) or 'none'}); add it, "
                    f"e.g. {group}=[{name},...]")


def translate(error: Exception, overrides, found: Configs) -> GtsweepError:
    """Hydra's composition error (or a config file's YAML error) as gtsweep's one line."""
    import yaml
    from hydra.errors import MissingConfigException, OverrideParseException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, ValidationError

    try:
        check_single_groups(overrides, found)
    except BadInput as e:
        return e
    for cause in causes(error):
        if isinstance(cause, GtsweepError):
            return cause
        if isinstance(cause, yaml.MarkedYAMLError):
            mark = cause.problem_mark or cause.context_mark
            where = f"{mark.name}:{mark.line + 1}" if mark else "?"
            return BadInput(f"malformed YAML in {where}: {cause.problem or cause.context}")
    if isinstance(error, OverrideParseException):
        return BadInput(f"cannot parse the overrides: {str(error).splitlines()[0]}")
    missing = getattr(error, "missing_cfg_file", None) if isinstance(error, MissingConfigException) else None
    if missing:
        group, _, name = missing.partition("/")
        return UnknownMethod("sweep" if group == "sweeps" else group, name, choices(group, found))
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
        return unknown_key(written[0], key, cause, found)
    return BadInput(str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__)


def unknown_key(written: str, missing: str, cause, found: Configs) -> GtsweepError:
    """An override of ``written`` whose part ``missing`` (its first absent prefix) the composed config lacks."""
    parts, depth = written.split("."), len(missing.split("."))
    parent = cause.parent_node
    if parts[0] in METHOD_GROUPS and len(parts) > 1:
        unknown = unknown_method_key(parts, depth, parent, found)
        if unknown is not None:
            return unknown
    moved = MOVED.get(written.removeprefix("experiment."))
    if written.startswith("experiment.") and moved:
        group, name = moved.split(".")[:2]
        return BadInput(f"'{written}' moved to the {group} group: write {moved}=... ({group}={name} must be "
                        f"selected; conf/{group}/{name}.yaml)")
    near = nearest(parts[depth - 1], list(parent or ())) if depth <= len(parts) else []
    return BadInput(f"unknown config key '{written}'" + "".join(
        f"; did you mean '{'.'.join([*parts[:depth - 1], n, *parts[depth:]])}'?" for n in near))


def unknown_method_key(parts: list[str], depth: int, parent, found: Configs) -> GtsweepError | None:
    """A key under ``<group>.<name>`` that the composed config lacks: the method not selected or unknown, or its
    parameter (or per-detector entry) unknown; None for anything else."""
    group, name, written = parts[0], parts[1], ".".join(parts)
    if depth == 2:
        if name in choices(group, found):
            return not_selected(group, name, list(parent or ()))
        return UnknownMethod(group, name, choices(group, found))
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
    return None
