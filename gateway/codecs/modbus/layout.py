"""A field's value from the registers (or bits) a device answered with, and the registers of a value.

`decoder(field)` builds, once per field, the function that reads its value out of a response at an
offset; the driver calls it every cycle, for the fields of the responses that changed. `encode` is
the way back for writes: the registers (or the bit) to send. Both are exact inverses for every kind
and order (tests/unit/codecs/modbus/test_layout.py proves it with Hypothesis).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from typing import Any

from gateway.codecs.modbus.address import Field, Kind
from gateway.errors import OutOfRange, TypeMismatch

Decoder = Callable[[Sequence[int], int], Any]

_FORMATS: dict[Kind, str] = {
    Kind.INT32: ">i",
    Kind.UINT32: ">I",
    Kind.FLOAT32: ">f",
    Kind.INT64: ">q",
    Kind.UINT64: ">Q",
    Kind.FLOAT64: ">d",
}
_BOUNDS: dict[Kind, tuple[int, int]] = {
    Kind.INT16: (-(2**15), 2**15 - 1),
    Kind.UINT16: (0, 2**16 - 1),
    Kind.INT32: (-(2**31), 2**31 - 1),
    Kind.UINT32: (0, 2**32 - 1),
    Kind.INT64: (-(2**63), 2**63 - 1),
    Kind.UINT64: (0, 2**64 - 1),
}
_FLOAT32_MAX = 3.4028234663852886e38


def swap16(value: int) -> int:
    return ((value & 0xFF) << 8) | (value >> 8)


def decoder(field: Field) -> Decoder:
    """The function that reads `field`'s value from a response's registers (or bits) at an offset."""
    kind = field.kind
    swapped = field.order.bytes_swapped
    if kind is Kind.BOOL:
        return lambda bits, at: bool(bits[at])
    if kind is Kind.BIT:
        mask = 1 << (field.bit or 0)
        return lambda regs, at: bool(regs[at] & mask)
    if kind is Kind.INT16 or kind is Kind.UINT16:
        signed = kind is Kind.INT16
        as_float = field.as_float

        def read16(regs: Sequence[int], at: int) -> Any:
            value = regs[at]
            if swapped:
                value = ((value & 0xFF) << 8) | (value >> 8)
            if signed and value & 0x8000:
                value -= 0x10000
            return float(value) if as_float else value

        return read16
    if kind is Kind.STRING:
        count = field.count
        packer = struct.Struct(f"<{count}H" if swapped else f">{count}H")

        def read_string(regs: Sequence[int], at: int) -> str:
            data = packer.pack(*regs[at : at + count])
            end = data.find(b"\x00")
            return (data if end < 0 else data[:end]).decode("latin-1")

        return read_string
    count = kind.registers
    words = struct.Struct(f"<{count}H" if swapped else f">{count}H")
    value_format = struct.Struct(_FORMATS[kind])
    reverse = field.order.words_swapped
    to_float = field.as_float and kind.integer
    unpack, pack = value_format.unpack, words.pack

    def read_wide(regs: Sequence[int], at: int) -> Any:
        chunk = regs[at : at + count]
        if reverse:
            chunk = chunk[::-1]
        value = unpack(pack(*chunk))[0]
        return float(value) if to_float else value

    return read_wide


def decode(field: Field, values: Sequence[int] | Sequence[bool], at: int = 0) -> Any:
    """`field`'s value at `at` (one-off; the driver keeps `decoder(field)` instead)."""
    return decoder(field)(values, at)


def encode(field: Field, value: Any) -> list[int]:
    """The registers that hold `value` (a bool as [0] or [1] for coils and bits). Raises for values that
    do not fit the field: TypeMismatch for the wrong kind of value, OutOfRange for one too large."""
    kind = field.kind
    if kind is Kind.BOOL or kind is Kind.BIT:
        if not isinstance(value, bool):
            raise TypeMismatch(f"{field.describe()} takes true or false, not {value!r}")
        return [int(value)]
    if kind is Kind.STRING:
        return _encode_string(field, value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeMismatch(f"{field.describe()} takes a number, not {value!r}")
    swapped = field.order.bytes_swapped
    if kind.integer:
        number = _whole(field, value)
        if kind is Kind.INT16 or kind is Kind.UINT16:
            word = number & 0xFFFF
            return [swap16(word) if swapped else word]
        data = struct.pack(_FORMATS[kind], number)
    else:
        number_f = float(value)
        if kind is Kind.FLOAT32 and math.isfinite(number_f) and abs(number_f) > _FLOAT32_MAX:
            raise OutOfRange(f"{number_f!r} does not fit {field.describe()}")
        data = struct.pack(_FORMATS[kind], number_f)
    count = kind.registers
    words = list(struct.unpack(f"<{count}H" if swapped else f">{count}H", data))
    if field.order.words_swapped:
        words.reverse()
    return words


def _whole(field: Field, value: int | float) -> int:
    if isinstance(value, float):
        if not math.isfinite(value):
            raise OutOfRange(f"{value!r} does not fit {field.describe()}")
        value = round(value)
    low, high = _BOUNDS[field.kind]
    if not low <= value <= high:
        raise OutOfRange(f"{value} does not fit {field.describe()} ({low}..{high})")
    return value


def _encode_string(field: Field, value: Any) -> list[int]:
    if not isinstance(value, str):
        raise TypeMismatch(f"{field.describe()} takes text, not {value!r}")
    try:
        data = value.encode("latin-1")
    except UnicodeEncodeError:
        raise OutOfRange(f"{value!r} has characters a Modbus string cannot hold (Latin-1 only)") from None
    if b"\x00" in data:
        raise OutOfRange("a Modbus string cannot hold a NUL character (it ends the string)")
    room = 2 * field.count
    if len(data) > room:
        raise OutOfRange(f"{len(data)} characters do not fit {field.describe()} (at most {room})")
    data = data.ljust(room, b"\x00")
    swapped = field.order.bytes_swapped
    return list(struct.unpack(f"<{field.count}H" if swapped else f">{field.count}H", data))
