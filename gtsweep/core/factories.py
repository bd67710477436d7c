"""Configs are data: a method's ``factory:`` resolves by its exact name, never by walking attributes.

A YAML file may declare a method by the name of its constructor (``factory: cv2.ORB_create``). The name is looked
up whole, in one of three tables, and nothing else is reachable:

- OpenCV's constructors: ``cv2.<Name>_create`` and ``cv2.xfeatures2d.<Name>_create``, found in the module's own
  namespace (``vars(cv2)``), so that ``cv2.os.system`` or ``cv2.importlib.import_module`` are no names at all;
- gtsweep's constructors: those of the methods its registries hold in code (:func:`note_built_in`);
- a plug-in's constructors: a module the user named on the command line (``plugins=[mypkg.features]``) marks its
  own with :func:`gtsweep.core.plugins.constructor`.

Every refusal is one :class:`~gtsweep.core.errors.BadInput` line, given before the named module is imported.
"""
from __future__ import annotations

import importlib
import re
from typing import Callable

from gtsweep.core import plugins
from gtsweep.core.errors import BadInput

#: A dotted name whose components are public identifiers (no dunder, no private name, no other punctuation).
PUBLIC_DOTTED = re.compile(r"^[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*$")
#: OpenCV's constructors: ``<Name>_create`` in ``cv2`` or ``cv2.xfeatures2d``.
OPENCV = re.compile(r"^cv2\.(?:(xfeatures2d)\.)?([A-Z][A-Za-z0-9]*_create)$")
#: gtsweep's own constructors by name (filled as the registries register their methods of code).
_BUILT_IN: dict[str, Callable] = {}


def constructor_name(create: Callable) -> str | None:
    """The dotted name a config may give for ``create`` (a class or function of a gtsweep module; a lazy one's
    declared name), or None for a lambda, a partial or OpenCV's own."""
    name = getattr(create, "constructor_name", None) if callable(create) else None
    if name or not callable(create):
        return name
    module, qualname = getattr(create, "__module__", None), getattr(create, "__qualname__", "")
    if not module or not module.startswith("gtsweep.") or not qualname or "<" in qualname:
        return None
    return f"{module}.{qualname}"


def note_built_in(create: Callable) -> None:
    """Record the constructor of a method registered in code, so that a config may name it."""
    name = constructor_name(create)
    if name:
        _BUILT_IN[name] = create


def resolve(path, where: str) -> Callable:
    """The constructor a config's ``factory`` names; a one-line BadInput for any other name."""
    if not isinstance(path, str) or not path:
        raise BadInput(f"{where}: factory must be a constructor's name such as cv2.ORB_create, got {path!r}")
    if not PUBLIC_DOTTED.match(path):
        raise refused(path, where, "not a plain dotted name of public identifiers")
    found = _opencv(path) if path.startswith("cv2.") else _BUILT_IN.get(path) or _plugin(path, where)
    if found is None:
        module, _, name = path.rpartition(".")
        opencv = OPENCV.match(path)
        raise refused(path, where, f"{module} has no constructor '{name}'" if opencv else
                      "no known method constructor has this name")
    return found


def _opencv(path: str) -> Callable | None:
    """``cv2.<Name>_create`` or ``cv2.xfeatures2d.<Name>_create``, from the module's own namespace only."""
    match = OPENCV.match(path)
    if match is None:
        return None
    import cv2

    module = vars(cv2).get(match.group(1)) if match.group(1) else cv2
    if module is None or getattr(module, "__name__", None) != ".".join(path.split(".")[:-1]):
        return None
    found = vars(module).get(match.group(2))
    return found if type(found).__name__ == "builtin_function_or_method" else None


def _plugin(path: str, where: str) -> Callable | None:
    """A constructor a user's plug-in module registered (:func:`gtsweep.core.plugins.constructor`); the module is
    imported only when the user enabled it by name."""
    module = path.rpartition(".")[0]
    if module not in plugins.named():
        return None
    try:
        importlib.import_module(module)
    except ImportError as e:
        raise BadInput(f"{where}: factory '{path}': the plug-in {module} cannot be imported: {e}") from None
    return plugins.registered(path)


def check_composed(cfg, overrides) -> None:
    """Pre-flight of a composed config (nothing resolved yet): its ``plugins`` are named in ``overrides`` (the
    command line) and enabled, and every method of a grid group that declares a ``factory`` gives a constructor's
    name written out (not an interpolation) that :func:`resolve` knows; their interpolations resolve."""
    from omegaconf import DictConfig, OmegaConf

    from gtsweep.core.config import METHOD_GROUPS

    plugins.enable(plugins.check_named(cfg.get("plugins"), overrides))
    for group in METHOD_GROUPS:
        methods = cfg.get(group)
        for name, node in (methods.items() if isinstance(methods, DictConfig) else ()):
            if not isinstance(node, DictConfig) or "factory" not in node:
                continue
            if OmegaConf.is_interpolation(node, "factory"):
                raise refused(OmegaConf.to_container(node)["factory"], f"{group} '{name}'", "an interpolation")
            resolve(node.factory, f"{group} '{name}'")
        try:  # the methods' interpolations, resolved before anything is created (a resolver may act)
            OmegaConf.to_container(methods, resolve=True) if isinstance(methods, DictConfig) else None
        except Exception as e:  # noqa: BLE001 - OmegaConf wraps the resolver's error
            reason = re.sub(r"^\w+ raised while resolving interpolation: ", "", str(e).strip().splitlines()[0])
            raise BadInput(f"{group}: {reason}") from None


def refused(path: str, where: str, why: str) -> BadInput:
    """The one line for a factory that is not a known constructor."""
    return BadInput(f"{where}: factory {path!r} is refused ({why}); configs are data: a factory is the exact name "
                    f"of a constructor, cv2.<Name>_create, cv2.xfeatures2d.<Name>_create, one of gtsweep's methods "
                    f"or one that a plug-in you name on the command line (plugins=[mypkg.features]) registers")
