"""Conditions of commands (guards and completions): bound to arguments, tested, and put into words.

Pure: no I/O, no asyncio. Comparison is by value, as users mean it in a mapping:
numbers compare as numbers (1 = 1.0), Booleans only with Booleans, text with text.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gateway.commands.config import Condition, render


@dataclass(frozen=True, slots=True)
class Check:
    """A condition with its arguments put in."""

    path: str
    values: tuple[Any, ...]
    test: str  # "equals" | "in" | "not"
    names: Mapping[str, str] = field(default_factory=dict)

    def holds(self, value: Any) -> bool:
        hit = any(same(value, wanted) for wanted in self.values)
        return not hit if self.test == "not" else hit

    def label(self, value: Any) -> str:
        """`3 (Alarm)` when the condition names the value, else the value as written."""
        text = repr(value) if isinstance(value, str) else _plain(value)
        name = self.names.get(_key(value))
        return f"{text} ({name})" if name else text

    def expected(self) -> str:
        """What the condition asks for, in words: `= 1 (Running)`, `in 0 (Idle), 2 (Paused)`, `≠ 0 (Idle)`."""
        listed = ", ".join(self.label(v) for v in self.values)
        if self.test == "equals":
            return f"= {listed}"
        if self.test == "in":
            return f"in {listed}" if len(self.values) > 1 else f"= {listed}"
        return f"≠ {listed}" if len(self.values) == 1 else f"not in {listed}"

    def __str__(self) -> str:
        return f"{self.path} {self.expected()}"


def bind(condition: Condition, args: Mapping[str, Any]) -> Check:
    test = "equals" if condition.equals is not None else "in" if condition.in_ is not None else "not"
    values = tuple(render(v, args) for v in condition.values)
    return Check(condition.path, values, test, dict(condition.names))


def same(value: Any, wanted: Any) -> bool:
    if isinstance(value, bool) or isinstance(wanted, bool):
        return isinstance(value, bool) and isinstance(wanted, bool) and value is wanted
    if isinstance(value, (int, float)) and isinstance(wanted, (int, float)):
        return float(value) == float(wanted)
    return bool(value == wanted)


def _key(value: Any) -> str:
    """How `names` keys a value (YAML's `{0: Idle}` arrives as "0"; 1.0 finds "1")."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _plain(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)
