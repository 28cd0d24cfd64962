"""The commands that write an item (macros, PMC, program select and start), checked before they go."""

from __future__ import annotations

import math
import re
import struct

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.address import Item
from gateway.codecs.focas.commands import PMC, Command, command
from gateway.codecs.focas.values import encode_scaled, path_field

_O_NUMBER = re.compile(r"^O?([0-9]{1,8})$")
_FORMATS = {
    fn.PMC_BYTE: ("B", 0, 255),
    fn.PMC_WORD: ("h", -(2**15), 2**15 - 1),
    fn.PMC_LONG: ("i", -(2**31), 2**31 - 1),
}


class NotWritableItem(ValueError):
    """The item cannot be written over FOCAS."""


class WrongValueType(NotWritableItem):
    """Not a value of the kind the item takes (text for a macro, a number for a bit)."""


class ValueTooLarge(NotWritableItem):
    """A value of the right kind that the item cannot hold."""


def pmc_read_byte(item: Item) -> Command:
    """The read a bit write needs first: the byte the bit is in."""
    return command(fn.PMC_READ, item.number, item.number, fn.PMC_AREAS[item.area], fn.PMC_BYTE, device=PMC)


def write_commands(item: Item, value: object, folder: str, current_byte: int | None = None) -> list[Command]:
    """What to send to write `value` to `item` (empty: nothing to do). A PMC bit needs `current_byte`."""
    if not item.writable:
        raise NotWritableItem(f"{item.kind} {item.field or item.number} cannot be written over FOCAS")
    if item.kind == "macro":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise WrongValueType(f"a macro takes a number, not {value!r}")
        try:
            data = encode_scaled(float(value))
        except ValueError as exc:
            raise ValueTooLarge(str(exc)) from None
        return [command(fn.MACRO_WRITE, item.number, item.number, data=data)]
    if item.kind == "pmc":
        code = fn.PMC_AREAS[item.area]
        if item.bit is not None:
            if not isinstance(value, bool):
                raise WrongValueType(f"a PMC bit takes true or false, not {value!r}")
            if current_byte is None:
                raise NotWritableItem("a PMC bit is written into the byte read just before")
            byte = current_byte | (1 << item.bit) if value else current_byte & ~(1 << item.bit) & 0xFF
            return [
                command(
                    fn.PMC_WRITE, item.number, item.number, code, fn.PMC_BYTE, data=bytes([byte]), device=PMC
                )
            ]
        fmt, low, high = _FORMATS[item.size]
        if isinstance(value, bool) or not isinstance(value, int):
            raise WrongValueType(f"{item.area}{item.number} takes an integer, not {value!r}")
        if not low <= value <= high:
            raise ValueTooLarge(f"{item.area}{item.number} takes {low}..{high}, not {value}")
        width = fn.PMC_TYPE_SIZE[item.size]
        data = struct.pack(">" + fmt, value)
        return [
            command(
                fn.PMC_WRITE, item.number, item.number + width - 1, code, item.size, data=data, device=PMC
            )
        ]
    if item.field == "start":
        if value is not True:
            return []  # false: nothing to do (a start is an edge)
        return [command(fn.START)]
    if item.field == "select":
        if not isinstance(value, str) or not value.strip():
            raise WrongValueType(f"program.select takes a program name or O-number, not {value!r}")
        name = value.strip()
        m = _O_NUMBER.match(name)
        if m is not None and name[:1] in "O0123456789" and "." not in name:
            return [command(fn.SELECT_NUMBER, int(m[1]))]
        if "/" in name or "\x00" in name:
            raise NotWritableItem(f"{name!r}: give the program's name; the folder is the driver's `folder`")
        try:
            return [command(fn.SELECT_FILE, data=path_field(folder + name))]
        except ValueError as exc:
            raise ValueTooLarge(str(exc)) from None
    raise NotWritableItem(f"{item.kind}.{item.field} cannot be written")
