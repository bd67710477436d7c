"""Configs are data: which plug-in modules may give constructors to a method's ``factory:``.

A YAML file can declare a method by the exact name of its constructor (:mod:`gtsweep.core.factories`). Besides
OpenCV's and gtsweep's own, a constructor may come from a plug-in: a module the user names in a ``plugins=[...]``
override on the command line (in a running Hydra job a ``plugins`` list from any config file is refused: only the
user's own words enable code). The plug-in marks what a config may name with :func:`constructor`::

    from gtsweep.core.plugins import constructor

    @constructor
    def MyDetector_create(threshold=10): ...

and a config says ``factory: mypkg.features.MyDetector_create``. The enabled plugins travel to Ray workers in the
environment variable :data:`ENV` (set before Ray starts, and in the runtime environment of a remote cluster:
:func:`gtsweep.orchestration.executor.ray_options`).
"""
from __future__ import annotations

import os
import re
from typing import Callable, Iterable

from gtsweep.core.errors import BadInput

#: Modules whose constructors any config may name: OpenCV and gtsweep itself.
BUILT_IN = ("cv2", "gtsweep")
#: The enabled plugins, comma-separated (inherited by Ray workers).
ENV = "GTSWEEP_PLUGINS"
#: The constructors plug-ins marked (:func:`constructor`), by dotted name.
_CONSTRUCTORS: dict[str, Callable] = {}
_DOTTED = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def enabled() -> tuple[str, ...]:
    """The modules a factory may come from in this process: :data:`BUILT_IN` and the enabled plugins."""
    return BUILT_IN + tuple(p for p in os.environ.get(ENV, "").split(",") if p)


def named() -> tuple[str, ...]:
    """The plug-in modules enabled in this process."""
    return enabled()[len(BUILT_IN):]


def constructor(create: Callable) -> Callable:
    """Mark ``create`` (a function or class of a plug-in module) as a constructor a config may name."""
    _CONSTRUCTORS[f"{create.__module__}.{create.__qualname__}"] = create
    return create


def registered(path: str) -> Callable | None:
    """The constructor a plug-in marked under the dotted name ``path`` (None if none)."""
    return _CONSTRUCTORS.get(path)


def on_command_line(name: str, overrides) -> bool:
    """``name`` appears in a ``plugins=`` override of the command line ``overrides``."""
    for override in overrides:
        key, _, value = str(override).lstrip("+~").partition("=")
        if key == "plugins" and name in re.split(r"[\s,\[\]'\"]+", value):
            return True
    return False


def check_named(plugins, overrides) -> tuple[str, ...]:
    """The ``plugins`` of a composed config, each named in ``overrides`` (the command line); one line otherwise."""
    names = _names(plugins)
    for name in names:
        if not on_command_line(name, overrides):
            raise BadInput(f"plugins: '{name}' comes from a config file, not from your command line; plug-ins run "
                           f"code, so name one on the command line: plugins=[{name}]")
    return names


def enable(plugins) -> tuple[str, ...]:
    """Enable the ``plugins`` of a composed config (a list of dotted module names) for this process and its Ray
    workers. In a running Hydra job each must be named in a ``plugins=`` override on the command line; a plugin
    from a config file is refused. (Called from Python, the caller is the user.)"""
    hydra_cfg = _hydra_job() if plugins else None
    names = check_named(plugins, hydra_cfg.overrides.task) if hydra_cfg is not None else _names(plugins)
    if names:
        os.environ[ENV] = ",".join(dict.fromkeys([*named(), *names]))
    return names


def _hydra_job():
    from hydra.core.hydra_config import HydraConfig

    return HydraConfig.get() if HydraConfig.initialized() else None


def _names(plugins) -> tuple[str, ...]:
    if plugins is None:
        return ()
    if isinstance(plugins, str) or not isinstance(plugins, Iterable):
        raise BadInput(f"plugins must be a list of module names such as [mypkg.features], got {plugins!r}")
    names = tuple(str(p).strip() for p in plugins)
    for name in names:
        if not _DOTTED.match(name):
            raise BadInput(f"plugins: '{name}' is not a dotted module name such as mypkg.features")
    return names
