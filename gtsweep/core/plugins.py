"""Configs are data: which modules a method's ``factory:`` may name.

A YAML file can declare a method by a dotted path (``factory: cv2.ORB_create``); gtsweep imports and calls it with
the file's params. So that a config file nobody chose (a planted ``tuned/`` file, a copied preset) cannot run code,
a factory resolves only inside an allow-list, checked on the path's text before anything is imported:

- OpenCV (``cv2``) and gtsweep's own modules, always;
- the modules the user names in the top-level config key ``plugins`` (``plugins=[mypkg.features]`` on the command
  line, or ``plugins: [...]`` in a file of a ``--config-dir`` they pass). Under Hydra, a plugin named anywhere else
  (a preset or method file found on another search-path entry) is refused: only the user's own words enable code.

The enabled plugins travel to Ray workers in the environment variable :data:`ENV` (set before Ray starts, and in
the runtime environment of a remote cluster: :func:`gtsweep.orchestration.executor.ray_options`).
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Iterable

from gtsweep.core.errors import BadInput

#: Modules any config may name: OpenCV and gtsweep itself.
BUILT_IN = ("cv2", "gtsweep")
#: The enabled plugins, comma-separated (inherited by Ray workers).
ENV = "GTSWEEP_PLUGINS"
#: Hydra's names for config directories the user gave: ``--config-dir`` and ``hydra.searchpath=`` overrides.
USER_PROVIDERS = ("command-line", "hydra.searchpath in command-line")
_DOTTED = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def enabled() -> tuple[str, ...]:
    """The modules a factory may come from in this process: :data:`BUILT_IN` and the enabled plugins."""
    return BUILT_IN + tuple(p for p in os.environ.get(ENV, "").split(",") if p)


def inside(path: str, module: str) -> bool:
    """``path`` names ``module`` or something inside it (whole dotted components: ``cv2x`` is not ``cv2``)."""
    return path == module or path.startswith(module + ".")


def check_factory(path: str, where: str) -> None:
    """A one-line BadInput unless the dotted ``path`` lies inside an allowed module (nothing is imported)."""
    allowed = enabled()
    if not any(inside(path, module) for module in allowed):
        raise BadInput(f"{where}: factory '{path}' is outside the allowed modules ({', '.join(allowed)}); "
                       f"configs are data: to run code from another module, name it yourself, "
                       f"e.g. plugins=[{path.rpartition('.')[0] or path}] on the command line")


def enable(plugins) -> tuple[str, ...]:
    """Enable the ``plugins`` of a composed config (a list of dotted module names) for this process and its Ray
    workers. In a running Hydra job each must be named by the user: in a ``plugins=`` override on the command line
    or in a YAML file of a ``--config-dir``; a plugin from any other config file is refused. (Called from Python,
    the caller is the user.)"""
    names = _names(plugins)
    hydra_cfg = _hydra_job() if names else None
    if hydra_cfg is not None:
        for name in names:
            if not _named_by_user(name, hydra_cfg):
                raise BadInput(f"plugins: '{name}' comes from a config file you did not pass; name a plugin on "
                               f"the command line (plugins=[{name}]) or in a --config-dir of yours")
    if names:
        os.environ[ENV] = ",".join(dict.fromkeys([*enabled()[len(BUILT_IN):], *names]))
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


def _named_by_user(name: str, hydra_cfg) -> bool:
    """``name`` appears in a ``plugins=`` command-line override or in a YAML file under a config directory the
    user gave (``--config-dir``, or ``hydra.searchpath=`` on the command line)."""
    for override in hydra_cfg.overrides.task:
        key, _, value = str(override).lstrip("+~").partition("=")
        if key == "plugins" and name in re.split(r"[\s,\[\]'\"]+", value):
            return True
    for source in hydra_cfg.runtime.config_sources:
        if source.provider in USER_PROVIDERS and source.schema == "file":
            root = Path(str(source.path))
            for file in [*root.rglob("*.yaml"), *root.rglob("*.yml")]:
                if _mentions_plugin(file, name):
                    return True
    return False


def _mentions_plugin(file: Path, name: str) -> bool:
    """``file`` (YAML) sets the top-level ``plugins`` key to a list that holds ``name``."""
    import yaml

    try:
        node = yaml.safe_load(file.read_text())
    except (OSError, yaml.YAMLError):
        return False
    plugins = node.get("plugins") if isinstance(node, dict) else None
    return isinstance(plugins, list) and name in [str(p) for p in plugins]
