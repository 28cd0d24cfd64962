"""The typed view: which variable an id stands for, and its values in and out of items.

The table comes from the mapping (`copydata: {id: 12}` on a variable). Frames
and the stream decoder know nothing of it, so framing stays separate from
meaning. A receiver can take a frame apart first, then decide what to do with
an id it does not know.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from gateway.codecs.copydata.errors import CopydataError, UnknownId
from gateway.codecs.copydata.frame import Frame, Item
from gateway.codecs.copydata.layout import DWDATA_MULTI, DWDATA_SINGLE, U32_MAX, Layout
from gateway.codecs.copydata.values import decode_value, encode_value
from gateway.model.types import TypeSpec


@dataclass(frozen=True, slots=True)
class Variable:
    """A variable as the nesting software knows it: an id, a name for messages, a type."""

    id: int
    name: str
    type: TypeSpec

    def __post_init__(self) -> None:
        if isinstance(self.id, bool) or not isinstance(self.id, int) or not 0 <= self.id <= U32_MAX:
            raise ValueError(f"copydata id of {self.name!r} must be an integer 0..{U32_MAX}, got {self.id!r}")

    def encode(self, value: Any, layout: Layout) -> Item:
        """The item for `value`. Errors name this variable."""
        try:
            return Item(self.id, encode_value(self.type, value, layout))
        except CopydataError as exc:
            raise exc._shift(0, f"{self.name} (id {self.id}, {self.type})") from None

    def decode(self, data: bytes, layout: Layout) -> Any:
        """The value in an item's data bytes; error offsets count from the start of `data`."""
        try:
            return decode_value(self.type, data, layout)
        except CopydataError as exc:
            raise exc._shift(0, f"{self.name} (id {self.id}, {self.type})") from None


@dataclass(frozen=True, slots=True)
class Reading:
    """One decoded item: the variable it names and its value."""

    variable: Variable
    value: Any


class VariableTable:
    """An immutable id -> Variable table for one target; ids and names are unique."""

    __slots__ = ("_by_id", "_by_name")

    def __init__(self, variables: Iterable[Variable] = ()) -> None:
        by_id: dict[int, Variable] = {}
        by_name: dict[str, Variable] = {}
        for var in variables:
            if var.id in by_id:
                raise ValueError(
                    f"copydata id {var.id} is used by both {by_id[var.id].name!r} and {var.name!r}"
                )
            if var.name in by_name:
                raise ValueError(
                    f"variable {var.name!r} appears twice (ids {by_name[var.name].id} and {var.id})"
                )
            by_id[var.id] = var
            by_name[var.name] = var
        self._by_id = by_id
        self._by_name = by_name

    @classmethod
    def from_ids(cls, ids: Mapping[int, tuple[str, TypeSpec | str]]) -> VariableTable:
        """Build from `{id: (name, type)}`; types may be given as names such as "Double[]"."""
        return cls(
            Variable(i, name, spec if isinstance(spec, TypeSpec) else TypeSpec.parse(spec))
            for i, (name, spec) in ids.items()
        )

    def __getitem__(self, variable_id: int) -> Variable:
        try:
            return self._by_id[variable_id]
        except KeyError:
            raise UnknownId(f"id {variable_id} is not in the variable table") from None

    def get(self, variable_id: int) -> Variable | None:
        return self._by_id.get(variable_id)

    def by_name(self, name: str) -> Variable:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"no copydata variable named {name!r}") from None

    def __contains__(self, variable_id: object) -> bool:
        return variable_id in self._by_id

    def __iter__(self) -> Iterator[Variable]:
        return iter(self._by_id.values())

    def __len__(self) -> int:
        return len(self._by_id)

    def __repr__(self) -> str:
        return f"VariableTable({list(self._by_id.values())!r})"

    def check_layout(self, layout: Layout) -> None:
        """Refuse a layout whose id field is too narrow for some id (a configuration error)."""
        too_big = sorted(i for i in self._by_id if i > layout.max_id)
        if too_big:
            raise ValueError(
                f"copydata ids {too_big} do not fit the {layout.id_width}-byte id field (max {layout.max_id})"
            )

    def encode(self, values: Mapping[int, Any] | Iterable[tuple[int, Any]], layout: Layout) -> Frame:
        """A frame for these `(id, value)` pairs: dwData=1 for one pair, dwData=2 for more."""
        pairs = values.items() if isinstance(values, Mapping) else values
        items = tuple(self[variable_id].encode(value, layout) for variable_id, value in pairs)
        return Frame(DWDATA_SINGLE if len(items) == 1 else DWDATA_MULTI, items)

    def decode(self, frame: Frame, layout: Layout) -> tuple[Reading, ...]:
        """Every item's value. Error offsets count from the start of the frame's lpData."""
        readings: list[Reading] = []
        offset = 0
        header_size = layout.header.size
        for item in frame.items:
            var = self._by_id.get(item.id)
            if var is None:
                raise UnknownId(f"id {item.id} is not in the variable table", offset=offset)
            try:
                readings.append(Reading(var, var.decode(item.data, layout)))
            except CopydataError as exc:
                raise exc._shift(offset + header_size) from None
            offset += header_size + len(item.data)
        return tuple(readings)
