"""Allowed values of a setting, declared once beside the setting and checked before any work."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable

from gtsweep.core.errors import BadInput


class _Rule:
    """What every rule does with its ``admits`` and ``describe``: check a value, or say in one line why not."""

    def detail(self, value: Any) -> str:
        return ""

    def check(self, name: str, value: Any) -> Any:
        """``value`` if admitted, else a one-line BadInput naming the setting and what it admits."""
        if not self.admits(value):
            raise BadInput(f"{name} must be {self.describe()}, got {value!r}{self.detail(value)}")
        return value


@dataclass(frozen=True)
class Range(_Rule):
    """Numbers in ``[low, high]`` (either end open, either end None for unbounded); ``integer`` admits only ints;
    ``optional`` admits None (the setting's "off" or "all")."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    optional: bool = False

    def describe(self) -> str:
        kind = "an integer" if self.integer else "a number"
        low = "-inf" if self.low is None else f"{self.low:g}"
        high = "inf" if self.high is None else f"{self.high:g}"
        opening = "(" if self.low_open or self.low is None else "["
        closing = ")" if self.high_open or self.high is None else "]"
        span = f"{opening}{low}, {high}{closing}"
        return f"{kind} in {span}" + (" or null" if self.optional else "")

    def admits(self, value: Any) -> bool:
        if value is None:
            return self.optional
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        if self.integer and not isinstance(value, int):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)


@dataclass(frozen=True)
class Choice(_Rule):
    """One of a fixed set of values."""

    options: tuple
    optional: bool = False

    def describe(self) -> str:
        return "one of " + ", ".join(map(str, self.options)) + (" or null" if self.optional else "")

    def admits(self, value: Any) -> bool:
        return (value is None and self.optional) or value in self.options


@dataclass(frozen=True)
class ListOf(_Rule):
    """A non-empty list whose items are admitted by ``item`` (None admitted when ``optional``)."""

    item: Range | Choice
    optional: bool = False

    def describe(self) -> str:
        return f"a non-empty list of {self.item.describe()}" + (" or null" if self.optional else "")

    def admits(self, value: Any) -> bool:
        if value is None:
            return self.optional
        return isinstance(value, (list, tuple)) and len(value) > 0 and all(self.item.admits(v) for v in value)

    def detail(self, value: Any) -> str:
        bad = [v for v in value if not self.item.admits(v)] if isinstance(value, (list, tuple)) else []
        return f" ({bad[0]!r} is not {self.item.describe()})" if bad else ""


def check_all(values: dict, rules: dict, prefix: str = "") -> None:
    """Check every dotted key of ``rules`` that ``values`` (a nested dict) has; absent keys are skipped."""
    for key, rule in rules.items():
        node: Any = values
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                break
            node = node[part]
        else:
            rule.check(f"{prefix}{key}", node)


def describe_all(rules: dict) -> Iterable[str]:
    """``key: what it admits`` lines, for documentation and --help."""
    return (f"{key}: {rule.describe()}" for key, rule in rules.items())
