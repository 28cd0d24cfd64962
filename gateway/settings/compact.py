"""Smaller records for the config models a gateway holds by the ten thousand (a mapping's variables).

A validated pydantic model keeps its fields in a dict of its own and the names of the fields the file
gave in a set of its own: about 460 and 220 bytes for a variable's spec, some 7 MB for 10,000
variables, held for as long as the gateway runs (the sources and sinks read the specs when they
connect). Both have the same keys, in the same order, from one variable to the next, so:

* the fields go into a key-sharing dict (CPython's split table, as a plain instance's `__dict__` has:
  one table of keys per shape, the values apart), about half the size, with every key still there,
  so pydantic, `==`, `model_dump` and `model_copy` see what they saw;
* the names of the given fields are one shared, immutable set per distinct set of names, which copies
  itself into a mutable set when pydantic copies it (`model_copy(update=...)` adds to the copy).

The models are frozen (gateway/settings/base.py), so nothing writes to either afterwards.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel


class SharedFieldNames(frozenset[str]):
    """The names of the fields a file gave, shared by every record that gave the same ones."""

    def __copy__(self) -> set[str]:
        return set(self)

    def __deepcopy__(self, memo: dict[int, Any]) -> set[str]:
        return set(self)


_NAMES: dict[frozenset[str], SharedFieldNames] = {}
_SHAPES: dict[type, type] = {}


def _holder(model: type) -> type:
    """A plain class per model, whose instances' dicts share one table of keys (made once per model)."""
    holder = _SHAPES.get(model)
    if holder is None:
        holder = _SHAPES[model] = type(f"_{model.__name__}Fields", (), {})
    return holder


def compact(record: BaseModel) -> None:
    """Put `record`'s fields in a key-sharing dict and its given names in a shared set, in place."""
    fields = record.__dict__
    holder = _holder(type(record))()
    for key, value in fields.items():  # same order for every record of a model: one shared key table
        setattr(holder, key, value)
    object.__setattr__(record, "__dict__", holder.__dict__)
    given = frozenset(record.__pydantic_fields_set__)
    names = _NAMES.get(given)
    if names is None:
        names = _NAMES[given] = SharedFieldNames(given)
    object.__setattr__(record, "__pydantic_fields_set__", names)
