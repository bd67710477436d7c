"""Search spaces for parameter optimisation, declared in a method's YAML next to its default ``params``.

A space maps parameter names to a range and a type::

    search_space:
      contrastThreshold: {type: float, low: 0.005, high: 0.1, log: true}
      edgeThreshold: {type: float, low: 5.0, high: 30.0}
      threshold: {type: int, low: 3, high: 60, step: 1}
      diffusivity: {type: categorical, choices: [0, 1, 2, 3]}
      nonmaxSuppression: {type: bool}

:func:`parse_space` checks a space against the method's defaults (every searched parameter must have a default
of a matching type) and turns it into Optuna distributions; a mistake raises a one-line :class:`BadInput`.
"""
from __future__ import annotations

import math
from typing import Mapping

from gtsweep.core.errors import BadInput

TYPES = ("float", "int", "categorical", "bool")
_KEYS = {"float": {"type", "low", "high", "log", "step"}, "int": {"type", "low", "high", "log", "step"},
         "categorical": {"type", "choices"}, "bool": {"type"}}


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _range(where: str, kind: str, spec: Mapping):
    """``(low, high, log, step)`` of a float or int range, checked."""
    low, high, log, step = spec.get("low"), spec.get("high"), spec.get("log", False), spec.get("step")
    if not _number(low) or not _number(high):
        raise BadInput(f"{where}: low and high must be numbers, got low={low!r} high={high!r}")
    if kind == "int" and not (isinstance(low, int) and isinstance(high, int)):
        raise BadInput(f"{where}: an int range needs integer low and high, got low={low!r} high={high!r}")
    if not low < high:
        raise BadInput(f"{where}: low must be below high, got low={low!r} high={high!r}")
    if not isinstance(log, bool):
        raise BadInput(f"{where}: log must be true or false, got {log!r}")
    if log and low <= 0:
        raise BadInput(f"{where}: a log range needs low > 0, got low={low!r}")
    if step is not None and (not _number(step) or step <= 0 or (kind == "int" and not isinstance(step, int))):
        raise BadInput(f"{where}: step must be a positive {'integer' if kind == 'int' else 'number'}, got {step!r}")
    if step is not None and log:
        raise BadInput(f"{where}: step and log cannot be combined")
    return low, high, log, step


def _distribution(where: str, spec, default):
    """The Optuna distribution of one parameter; its type must fit the default value."""
    from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

    if not isinstance(spec, Mapping):
        raise BadInput(f"{where} must be a mapping like {{type: float, low: 0.01, high: 0.1}}, got {spec!r}")
    kind = spec.get("type")
    if kind not in TYPES:
        raise BadInput(f"{where}.type must be one of {', '.join(TYPES)}, got {kind!r}")
    unknown = sorted(set(spec) - _KEYS[kind])
    if unknown:
        raise BadInput(f"{where}: unknown key(s) {', '.join(unknown)} for type {kind}; "
                       f"valid: {', '.join(sorted(_KEYS[kind]))}")
    if kind == "bool":
        if not isinstance(default, bool):
            raise BadInput(f"{where}: type bool, but the default {default!r} is not a bool")
        return CategoricalDistribution([False, True])
    if kind == "categorical":
        choices = spec.get("choices")
        if not isinstance(choices, list) or not choices or len(set(map(repr, choices))) != len(choices):
            raise BadInput(f"{where}: choices must be a non-empty list without repeats, got {choices!r}")
        if not all(c is None or isinstance(c, (bool, int, float, str)) for c in choices):
            raise BadInput(f"{where}: choices must be numbers, strings, booleans or null, got {choices!r}")
        return CategoricalDistribution(choices)
    if isinstance(default, bool) or not _number(default):
        raise BadInput(f"{where}: type {kind}, but the default {default!r} is not a number")
    if kind == "float" and isinstance(default, int):
        raise BadInput(f"{where}: type float, but the default {default!r} is an int (OpenCV wants an int here); "
                       f"use type: int")
    low, high, log, step = _range(where, kind, spec)
    if kind == "int":
        return IntDistribution(low, high, log=log, step=step or 1)
    return FloatDistribution(float(low), float(high), log=log, step=None if step is None else float(step))


def parse_space(where: str, space, defaults: Mapping, excluded: tuple[str, ...] = ()) -> dict:
    """Optuna distributions ``{param: distribution}`` of the space declared at ``where`` (for messages).

    ``defaults`` are the method's ``params``: each searched parameter must be one of them. ``excluded`` names
    parameters that must not be searched (the count parameter set to the survey's N).
    """
    if space is None:
        raise BadInput(f"{where} is missing: declare the parameters to search next to params, e.g. "
                       f"search_space: {{threshold: {{type: int, low: 5, high: 50}}}}")
    if not isinstance(space, Mapping) or not space:
        raise BadInput(f"{where} must be a non-empty mapping of parameter: {{type, low, high}}, got {space!r}")
    distributions = {}
    for name, spec in space.items():
        if name not in defaults:
            raise BadInput(f"{where}.{name}: no such parameter among the defaults "
                           f"({', '.join(sorted(defaults)) or 'none'})")
        if name in excluded:
            raise BadInput(f"{where}.{name}: the number of keypoints is fixed to the survey's N, not searched")
        distributions[name] = _distribution(f"{where}.{name}", spec, defaults[name])
    return distributions


def defaults_in_space(distributions: Mapping, defaults: Mapping) -> dict | None:
    """The default values of the searched parameters, or None when one lies outside its range."""
    values = {name: defaults[name] for name in distributions}
    for name, dist in distributions.items():
        try:
            if not dist._contains(dist.to_internal_repr(values[name])):
                return None
        except (ValueError, TypeError):
            return None
    return values
