"""A field's value from the bytes a PLC answered, and the bytes of a value: S7's elementary types.

Everything is big-endian. A STRING is its declared length, its current length and the characters
(Latin-1, as S7 strings are bytes); DATE_AND_TIME is eight BCD bytes, year (90-99: 1990s, 00-89:
2000-2089), month, day, hour, minute, second, milliseconds and the weekday (1 = Sunday), read as UTC
(an S7 clock has no time zone: the README says to keep PLCs on UTC, or to read the value as local time).
`decoder(field)` builds, once per field, the function that reads it out of an item's bytes at an offset.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from gateway.codecs.s7.address import Field, Kind
from gateway.errors import CodecError, OutOfRange, TypeMismatch

Decoder = Callable[[bytes, int], Any]


class S7ValueError(CodecError):
    """Bytes that are not a value of their type (a DATE_AND_TIME that is not BCD, a month 13)."""


_FORMATS: dict[Kind, str] = {
    Kind.BYTE: ">B", Kind.USINT: ">B", Kind.SINT: ">b",
    Kind.WORD: ">H", Kind.UINT: ">H", Kind.INT: ">h",
    Kind.DWORD: ">I", Kind.UDINT: ">I", Kind.DINT: ">i", Kind.REAL: ">f",
    Kind.LINT: ">q", Kind.ULINT: ">Q", Kind.LREAL: ">d",
}  # fmt: skip
_BOUNDS: dict[Kind, tuple[int, int]] = {
    Kind.BYTE: (0, 255), Kind.USINT: (0, 255), Kind.SINT: (-128, 127),
    Kind.WORD: (0, 65535), Kind.UINT: (0, 65535), Kind.INT: (-32768, 32767),
    Kind.DWORD: (0, 2**32 - 1), Kind.UDINT: (0, 2**32 - 1), Kind.DINT: (-(2**31), 2**31 - 1),
    Kind.LINT: (-(2**63), 2**63 - 1), Kind.ULINT: (0, 2**64 - 1),
}  # fmt: skip
_FLOAT32_MAX = 3.4028234663852886e38


def decoder(field: Field) -> Decoder:
    kind = field.kind
    if kind is Kind.BOOL:
        mask = 1 << (field.bit or 0)
        return lambda data, at: bool(data[at] & mask)
    if kind is Kind.STRING:
        declared = field.length or 0
        return lambda data, at: _read_string(data, at, declared)
    if kind is Kind.DATE_AND_TIME:
        return _read_dt
    unpack = struct.Struct(_FORMATS[kind]).unpack_from
    if field.as_float and kind.integer:
        return lambda data, at: float(unpack(data, at)[0])
    return lambda data, at: unpack(data, at)[0]


def decode(field: Field, data: bytes, at: int = 0) -> Any:
    return decoder(field)(data, at)


def _read_string(data: bytes, at: int, declared: int) -> str:
    current = data[at + 1]
    count = min(current, data[at], declared)
    return bytes(data[at + 2 : at + 2 + count]).decode("latin-1")


def _bcd(value: int) -> int:
    high, low = value >> 4, value & 0x0F
    if high > 9 or low > 9:
        raise S7ValueError(f"{value:#04x} is not a BCD number")
    return high * 10 + low


def _read_dt(data: bytes, at: int) -> datetime:
    raw = data[at : at + 8]
    try:
        year = _bcd(raw[0])
        year += 1900 if year >= 90 else 2000
        milliseconds = _bcd(raw[6]) * 10 + (raw[7] >> 4)
        if raw[7] >> 4 > 9:
            raise S7ValueError(f"{raw[7]:#04x} is not a BCD digit and a weekday")
        return datetime(year, _bcd(raw[1]), _bcd(raw[2]), _bcd(raw[3]), _bcd(raw[4]), _bcd(raw[5]),
                        milliseconds * 1000, tzinfo=UTC)  # fmt: skip
    except ValueError as exc:
        raise S7ValueError(f"DATE_AND_TIME {bytes(raw).hex(' ')}: {exc}") from None


def encode(field: Field, value: Any) -> bytes:
    """The bytes of `value` (a BOOL: one byte, 0 or 1, written as a bit). TypeMismatch for the wrong kind
    of value, OutOfRange for one that does not fit."""
    kind = field.kind
    if kind is Kind.BOOL:
        if not isinstance(value, bool):
            raise TypeMismatch(f"{field.describe()} takes true or false, not {value!r}")
        return bytes((int(value),))
    if kind is Kind.STRING:
        return _string(field, value)
    if kind is Kind.DATE_AND_TIME:
        return _dt(field, value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeMismatch(f"{field.describe()} takes a number, not {value!r}")
    if kind.integer:
        if isinstance(value, float):
            if not math.isfinite(value):
                raise OutOfRange(f"{value!r} does not fit {field.describe()}")
            value = round(value)
        low, high = _BOUNDS[kind]
        if not low <= value <= high:
            raise OutOfRange(f"{value} does not fit {field.describe()} ({low}..{high})")
        return struct.pack(_FORMATS[kind], value)
    number = float(value)
    if kind is Kind.REAL and math.isfinite(number) and abs(number) > _FLOAT32_MAX:
        raise OutOfRange(f"{number!r} does not fit {field.describe()}")
    return struct.pack(_FORMATS[kind], number)


def _string(field: Field, value: Any) -> bytes:
    if not isinstance(value, str):
        raise TypeMismatch(f"{field.describe()} takes text, not {value!r}")
    try:
        data = value.encode("latin-1")
    except UnicodeEncodeError:
        raise OutOfRange(f"{value!r} has characters an S7 STRING cannot hold (Latin-1 only)") from None
    declared = field.length or 0
    if len(data) > declared:
        raise OutOfRange(f"{len(data)} characters do not fit {field.describe()} (at most {declared})")
    return bytes((declared, len(data))) + data.ljust(declared, b"\x00")


def _dt(field: Field, value: Any) -> bytes:
    if not isinstance(value, datetime):
        raise TypeMismatch(f"{field.describe()} takes a date and time, not {value!r}")
    moment = (value if value.tzinfo else value.replace(tzinfo=UTC)).astimezone(UTC)
    if not 1990 <= moment.year <= 2089:
        raise OutOfRange(f"{moment.isoformat()} is outside DATE_AND_TIME's 1990-2089")

    def bcd(number: int) -> int:
        return (number // 10) << 4 | number % 10

    ms = moment.microsecond // 1000
    weekday = (moment.isoweekday() % 7) + 1  # 1 = Sunday
    parts = (moment.year % 100, moment.month, moment.day, moment.hour, moment.minute, moment.second, ms // 10)
    return bytes(bcd(n) for n in parts) + bytes(((ms % 10) << 4 | weekday,))
