"""Adapters other packages ship: specs declared under an entry point group, read once at start-up.

The adapters of this repository are static tables (gateway/sources/registry.py, gateway/sinks/registry.py,
gateway/sinks/opcua/extensions.py), which the import contracts and mypy see whole. A package of its own
adds a driver, a sink or an OPC UA extension without a line there: `[project.entry-points.<group>]
<name> = "<module>:SPEC"` in its pyproject.toml. What it declares is checked here, so that a wrong one
stops the start with its entry point named instead of failing somewhere later.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from importlib.metadata import entry_points
from typing import TypeVar

S = TypeVar("S")


def installed(group: str, kind: type[S], built_in: Iterable[S], key: Callable[[S], str]) -> tuple[S, ...]:
    """The specs of `kind` under entry point `group`, by entry point name. A value of another type, or a
    key (`type` of a driver, `name` of a sink) that another spec has, raises TypeError naming the entry
    point: two adapters behind one name would make configuration files ambiguous."""
    taken = {key(spec): "cnc-gateway" for spec in built_in}
    found = []
    for point in sorted(entry_points(group=group), key=lambda p: p.name):
        spec = point.load()
        where = f"entry point {point.name} = {point.value} ({group})"
        if not isinstance(spec, kind):
            raise TypeError(f"{where} is a {type(spec).__name__}, not a {kind.__name__}")
        name = key(spec)
        if name in taken:
            raise TypeError(f"{where}: {name!r} is already {taken[name]}'s")
        taken[name] = where
        found.append(spec)
    return tuple(found)
