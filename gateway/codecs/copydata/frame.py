"""The values a COPYDATA frame is made of: `Frame` (dwData and its items) and `Item` (id, data bytes).

Kept apart from frames.py (which encodes and decodes them) so that errors.py can
name a `Frame` without importing the functions that raise its errors.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from gateway.codecs.copydata.layout import DWDATA_MULTI, DWDATA_SINGLE


@dataclass(frozen=True, slots=True)
class Item:
    """One variable's triple: its id and its already-encoded data bytes."""

    id: int
    data: bytes


@dataclass(frozen=True, slots=True)
class Frame:
    """What one WM_COPYDATA message (or one TCP/UDP frame) carries."""

    dwdata: int
    items: tuple[Item, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.items, tuple):
            object.__setattr__(self, "items", tuple(self.items))

    @classmethod
    def single(cls, item: Item) -> Frame:
        return cls(DWDATA_SINGLE, (item,))

    @classmethod
    def multi(cls, items: Iterable[Item]) -> Frame:
        return cls(DWDATA_MULTI, tuple(items))
