"""One registry shape for every method family (detectors, selectors, descriptors, transforms, data set loaders,
matchers, pose estimators).

A :class:`Method` is a name, the label the survey prints, a factory and the factory's default parameters, declared
in code; a family subclasses it to add its capabilities (a detector's orientation, a descriptor's norm). A method's
YAML holds only what a user overrides: :meth:`Method.params` merges it onto the defaults strictly, as glue-factory
merges a config onto a model's ``default_conf`` — an unknown parameter or a value of the wrong type is a one-line
:class:`~gtsweep.core.errors.BadInput`, never a silent extra keyword. A :class:`Registry` holds one family, with
one lookup (:meth:`Registry.get`) that lists the valid names when a name is unknown.
"""
from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass, field
from typing import Any, Callable, Generic, Iterable, Iterator, Mapping, TypeVar

from gtsweep.core.errors import BadInput, GtsweepError, UnknownMethod


def reason_line(error: BaseException) -> str:
    """The line of an error message that says why: OpenCV puts it last (``error: (-215:Assertion failed) ...``)."""
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    return lines[-1] if lines else type(error).__name__


def _compatible(default, value) -> bool:
    """``value`` can stand where ``default`` stands: same kind of value (an int is a fine float); None is free."""
    if default is None or value is None:
        return True
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(default, bool) and isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float))
    if isinstance(default, int):
        return isinstance(value, int)
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

    def params(self, overrides: Mapping[str, Any] | None = None) -> dict:
        """The defaults with ``overrides`` merged in strictly (unknown key or wrong type: one-line BadInput)."""
        merged = dict(self.defaults)
        for key, value in (overrides or {}).items():
            if key not in self.defaults:
                valid = ", ".join(sorted(self.defaults)) or "none"
                raise BadInput(f"{self.family} '{self.name}' has no parameter '{key}'; its parameters: {valid}")
            if not _compatible(self.defaults[key], value):
                raise BadInput(f"{self.family} '{self.name}': parameter {key}={value!r} should be "
                               f"{type(self.defaults[key]).__name__} like its default {self.defaults[key]!r}")
            merged[key] = value
        return merged

    def build(self, overrides: Mapping[str, Any] | None = None):
        """``create(**params)``; a method that is not installed or rejects its parameters is a one-line error."""
        params = self.params(overrides)
        try:
            return self.create(**params)
        except ImportError as e:
            raise GtsweepError(f"{self.family} '{self.name}' is not available: {e}") from None
        except GtsweepError:
            raise
        except Exception as e:  # OpenCV's cv2.error, TypeError, ValueError: the parameters were rejected
            raise BadInput(f"{self.family} '{self.name}' rejects its parameters {params}: {reason_line(e)}") from None


def function_defaults(function: Callable, positional: int) -> dict:
    """The keyword parameters of ``function`` after its first ``positional`` ones, with their defaults."""
    parameters = list(inspect.signature(function).parameters.values())[positional:]
    return {p.name: (None if p.default is inspect.Parameter.empty else p.default) for p in parameters}


def partial_factory(function: Callable) -> Callable[..., Callable]:
    """A factory for a method that is a plain function: ``create(**params)`` binds the parameters."""
    return lambda **params: functools.partial(function, **params)


M = TypeVar("M", bound=Method)


class Registry(Generic[M]):
    """The methods of one family by name."""

    def __init__(self, family: str, methods: Iterable[M] = ()):
        self.family = family
        self._methods: dict[str, M] = {}
        for method in methods:
            self.register(method)

    def register(self, method: M) -> M:
        if method.name in self._methods:
            raise ValueError(f"{self.family} '{method.name}' is registered twice")
        self._methods[method.name] = method
        return method

    def get(self, name: str) -> M:
        """The method called ``name``; :class:`UnknownMethod` lists the valid names otherwise."""
        try:
            return self._methods[name]
        except (KeyError, TypeError):
            raise UnknownMethod(self.family, str(name), self._methods) from None

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
