"""Config files that nobody named stay data: what ``./tuned`` and a user's config directory may hold.

Checked on the files' text (YAML's safe loader, nothing resolved, nothing imported), before Hydra composes:

- ``./tuned`` (found in the working directory, not named on the command line) holds tuned method files only:
  ``<group>/tuned/<name>.yaml``, under the package ``<group>``, that set the parameters (and search space) of a
  method that already exists, in the package or in a ``--config-dir``. Such a file names no factory, no
  plug-in, no other config (its defaults list is the method's schema at most) and holds no interpolation
  (``${...}``: a resolver such as ``${gtsweep.new_dir:...}`` acts when read). A tuned file of a method declared in
  a ``--config-dir`` repeats that file's factory and capabilities unchanged (``experiment=optimize`` writes them).
- A config directory the user passes (``--config-dir``, ``hydra.searchpath``) may declare methods by factory
  (:mod:`gtsweep.core.factories` resolves them by exact name), but names no code otherwise: no ``_target_`` (Hydra
  would instantiate it), no ``hydra.job.env_set`` (it sets the environment, :data:`gtsweep.core.plugins.ENV`
  included) and no ``plugins`` (they are enabled on the command line only).

Each refusal is one :class:`~gtsweep.core.errors.BadInput` line naming the file.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Iterator

import yaml

from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.errors import BadInput
from gtsweep.core.searchpath import stray_tuned_files

#: What a tuned file may set of a method: its parameters, their search space, a descriptor's per-detector params.
TUNABLE = ("params", "search_space", "per_detector")
#: Keys that name code in a config file: Hydra instantiates ``_target_``, ``env_set`` changes the environment.
CODE_KEYS = ("_target_", "env_set")


def check_config_files(entries) -> None:
    """Check the user's directories and ``./tuned`` of a search path (``file://``, ``tuned://``, ``pkg://``)."""
    roots = [entry.partition("://") for entry in entries]
    user_dirs = [Path(root) for scheme, _, root in roots if scheme == "file" and os.path.isdir(root)]
    for directory in user_dirs:
        for file in _yaml_files(directory):
            check_user_file(file, load_yaml(file))
    for scheme, _, root in roots:
        if scheme == "tuned" and os.path.isdir(root):
            check_tuned_root(Path(root), lambda group, name: declaring_file(group, name, user_dirs))


def check_user_file(file: Path, data: Any) -> None:
    """A file of the user's config directory: no key that names code, no ``plugins``."""
    for path, key, value in _walk(data):
        if key == "factory" and "${" in str(value):
            raise BadInput(f"{file}: '{'.'.join([*path, key])}' is an interpolation; a factory is a constructor's "
                           f"name, written out")
        if key in CODE_KEYS:
            raise BadInput(f"{file}: '{'.'.join([*path, key])}' names code; gtsweep runs no code from a config file "
                           f"(a method's factory is a constructor's name; plug-ins are named on the command line)")
    if isinstance(data, dict) and data.get("plugins"):
        raise BadInput(f"{file}: plugins are named on the command line only (plugins=[...]), not in a config file")


def check_tuned_root(root: Path, declaring: Callable[[str, str], dict | None]) -> None:
    """Every YAML file under ``root`` (``./tuned``) is a tuned method file of an existing method."""
    stray = stray_tuned_files(root)
    if stray:
        raise BadInput(f"{root}/{stray[0]} is not a tuned method file: ./{root.name} holds only "
                       f"<group>/tuned/<name>.yaml (written by experiment=optimize) and gtsweep reads nothing else "
                       f"from it; move presets and methods to a --config-dir of yours")
    for file in _yaml_files(root):
        group, name = file.relative_to(root).parts[0], file.stem
        check_tuned_file(file, group, name, declaring(group, name))


def check_tuned_file(file: Path, group: str, name: str, declared: dict | None) -> None:
    """``file`` sets parameters of method ``name`` of ``group`` and nothing else; ``declared`` is the raw file
    that declares the method ({} for a method of the package, None for no such method)."""
    def refuse(why: str):
        raise BadInput(f"{file}: {why}; a file in ./tuned only sets the parameters of an existing method "
                       f"(experiment=optimize writes them)")

    text = file.read_text(encoding="utf-8")
    from hydra.plugins.config_source import ConfigSource

    package = ConfigSource._get_header_dict(text).get("package")
    if package not in (None, group):
        refuse(f"its package is '{package}', not '{group}'")
    data = load_yaml(file)
    if not isinstance(data, dict):
        refuse("it is not a mapping of the method's name to its parameters")
    if any("${" in str(item) for _, key, value in _walk(data) for item in (key, value)):
        refuse("it holds an interpolation (${...})")
    if declared is None:
        refuse(f"{group} '{name}' is no method of the package or of a --config-dir you passed")
    extra = set(data or {}) - {"defaults", name}
    if extra:
        refuse(f"it sets '{sorted(extra)[0]}', which is not the method '{name}'")
    if set(data.get("defaults") or []) - {f"/schema/{group}/{name}@_here_", "_self_"}:
        refuse(f"its defaults list loads {data['defaults']!r}, not the method's schema")
    node = data.get(name) or {}
    for key, value in (node.items() if isinstance(node, dict) else [(None, node)]):
        if key not in TUNABLE and (key not in declared or declared[key] != value):
            refuse(f"'{key}' is not a parameter of {group} '{name}'" if key else f"'{name}' is not a mapping")


def declaring_file(group: str, name: str, user_dirs) -> dict | None:
    """The raw content of the file that declares method ``name`` of ``group`` in a user's directory (the first
    on the search path), {} for a method of the package, None when none exists."""
    for directory in user_dirs:
        file = Path(directory) / group / f"{name}.yaml"
        if file.is_file():
            data = load_yaml(file)
            return {k: v for k, v in data.items() if k != "defaults"} if isinstance(data, dict) else {}
    from importlib import resources

    from gtsweep.core.paths import CONF_PACKAGE

    if group in METHOD_GROUPS and resources.files(CONF_PACKAGE).joinpath(group, f"{name}.yaml").is_file():
        return {}
    return None


def _yaml_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.suffix in (".yaml", ".yml") and p.is_file())


def load_yaml(file: str | os.PathLike) -> Any:
    """The data of a YAML ``file`` (YAML's safe loader: no ``!!python`` tag); a one-line BadInput naming
    ``file:line`` when it is malformed or unreadable."""
    try:
        with open(file, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        raise BadInput(f"malformed YAML in {file}:{mark.line + 1 if mark else '?'}: {e.problem or e.context}") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise BadInput(f"cannot read the config {file}: {e}") from None


def _walk(data: Any, path: tuple = ()) -> Iterator[tuple[tuple, Any, Any]]:
    """``(path, key, value)`` of every mapping entry and list item in ``data`` (a list item's key is None)."""
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else ()
    for key, value in items:
        yield path, (key if isinstance(data, dict) else None), value
        yield from _walk(value, (*path, str(key)))
