"""``python -m gtsweep``: the command line before Hydra runs.

gtsweep's own steps: ``group=all`` and ``group=glob(...)`` expanded over the options on the search path (Hydra's
sweeper globs over its main directory only), a user's ``hydra.searchpath`` completed with gtsweep's entries, every
job composed once before anything runs (:mod:`gtsweep.cli.preflight`: Hydra checks, gtsweep says it in one line)
and, with ``resume=true``, the newest earlier output directory of the same command reopened.

Only the overrides are touched, as Hydra's own parser finds them (:mod:`gtsweep.cli.search`): Hydra's flags
(``--cfg``, ``--info``, ``-m``, ``--config-dir``, ...) may stand anywhere, and ``-sc install=bash`` is left alone.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

from gtsweep.cli import preflight
from gtsweep.cli.search import GRID_GROUPS, check_yaml, configs, parse, with_searchpath
from gtsweep.core.errors import BadInput
from gtsweep.core.registry import availability, left_out_line
from gtsweep.orchestration.grid import REGISTRIES
from gtsweep.orchestration.resume_pick import pick

SWEEP_RECORD = "sweep.json"


def options(group: str, args=()) -> list[str]:
    """The options of a config group on the search path of ``args`` (user directories included)."""
    return configs(args).options(group)


def _rewrite(args: list[str], rewrite) -> list[str]:
    """``args`` with ``rewrite(overrides)`` in place of its overrides (a shell completion is left alone)."""
    invocation = parse(args)
    return list(args) if invocation.passthrough else invocation.with_overrides(rewrite(list(invocation.overrides)))


def expand_all(args: list[str]) -> list[str]:
    """``detector=all`` -> ``detector=[every option this install can run]`` for the grid groups (one line names
    those it leaves out: :func:`gtsweep.core.registry.availability`); ``group=glob(...)`` -> the options it
    matches, ``group=a,b`` (Hydra's sweeper globs over its main directory only, not the search path)."""
    left_out = []

    def expand(overrides):
        expanded = []
        for arg in overrides:
            group, _, value = arg.partition("=")
            if group in GRID_GROUPS and value == "all":
                runnable, skipped = availability(REGISTRIES[group], options(group, args))
                arg = f"{group}=[{','.join(runnable)}]"
                left_out.append(skipped)
            elif group in (*GRID_GROUPS, *preflight.SINGLE_GROUPS) and value.startswith("glob("):
                arg = f"{group}={','.join(_glob(group, arg, args))}"
            expanded.append(arg)
        return expanded

    expanded = _rewrite(args, expand)
    if left_out_line(left_out):
        print(f"gtsweep: note: {left_out_line(left_out)}", file=sys.stderr)
    return expanded


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
    picked = pick(list(Path.cwd().glob(pattern)), key)  # the newest directory that holds a run, and why
    print(f"gtsweep: {picked.why}", file=sys.stderr)
    if picked.directory is None:
        return []
    return [f"hydra.sweep.dir={picked.directory.parent}" if multirun else f"hydra.run.dir={picked.directory}"]


def prepare(args: list[str]) -> list[str]:
    """The command line Hydra gets: ``all`` and globs expanded, a declared method's parameters force-added, a
    user's ``hydra.searchpath`` completed with gtsweep's entries, every job composed once. A
    :class:`~gtsweep.core.errors.GtsweepError` for a mistake."""
    check_yaml(args)
    args = expand_all(list(args))
    args = searchpath(_rewrite(args, lambda overrides: preflight.force_add_declared(overrides, args)))
    preflight.check(args)
    return args


def compose_config(overrides: list[str], config_dir: str | None = None):
    """The composed config for ``overrides``, as ``python -m gtsweep [--config-dir DIR]`` would see it (for scripts
    and tests); YAML-declared methods keyed by their names (:func:`gtsweep.cli.search.keyed_methods`)."""
    args = prepare(["--config-dir", config_dir, *overrides] if config_dir else list(overrides))
    with preflight.composer(args) as compose:
        return compose(parse(args).overrides)


def fail(error: Exception) -> None:
    print(f"gtsweep: error: {error}", file=sys.stderr)
    sys.exit(2)
