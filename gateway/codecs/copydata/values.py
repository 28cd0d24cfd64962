"""Value encodings: a typed Python value to the data bytes of one item, and back.

Numbers are little-endian at the type's own width, Booleans one byte (0 or 1),
Strings raw bytes in the layout's encoding without a terminator, DateTime a
Windows FILETIME (u64, 100 ns ticks since 1601-01-01 UTC). An array is its
elements back to back; a String[] element carries its own length field
(len_width bytes) in front, because text alone has no boundary. Floats pass
through as IEEE-754 unchanged, NaN and infinities included: the codec mirrors the
controller, it does not judge values.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

from gateway.codecs.copydata.errors import (
    BadBoolean,
    BadFiletime,
    BadText,
    FieldOverflow,
    LengthOverrun,
    TruncatedHeader,
    Unencodable,
    ValueOutOfRange,
    ValueTypeError,
    WrongSize,
)
from gateway.codecs.copydata.layout import Layout
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec

FILETIME_EPOCH = datetime(1601, 1, 1, tzinfo=UTC)
_MAX_TICKS = ((datetime.max.replace(tzinfo=UTC) - FILETIME_EPOCH) // timedelta(microseconds=1)) * 10 + 9

# struct format letter of every fixed-width type; DateTime is its FILETIME.
_FORMATS: dict[DataType, str] = {
    DataType.BOOLEAN: "B",
    DataType.SBYTE: "b",
    DataType.BYTE: "B",
    DataType.INT16: "h",
    DataType.UINT16: "H",
    DataType.INT32: "i",
    DataType.UINT32: "I",
    DataType.INT64: "q",
    DataType.UINT64: "Q",
    DataType.FLOAT: "f",
    DataType.DOUBLE: "d",
    DataType.DATETIME: "Q",
}
_SCALARS: dict[DataType, struct.Struct] = {t: struct.Struct("<" + f) for t, f in _FORMATS.items()}


def fixed_size(base: DataType) -> int | None:
    """Bytes per element of a fixed-width type; None for String."""
    s = _SCALARS.get(base)
    return s.size if s else None


# --- Python value -> canonical form, with strict type checks --------------------------------


def _describe(value: Any) -> str:
    return f"{type(value).__name__} {value!r}"[:80]


def _as_int(base: DataType, value: Any) -> int:
    if type(value) is int:
        return value
    if isinstance(value, bool):
        raise ValueTypeError(f"expected {base.value} (an integer), got {value!r}")
    if isinstance(value, int):
        return int(value)
    if isinstance(value, float) and value.is_integer():
        return int(value)
    raise ValueTypeError(f"expected {base.value} (an integer), got {_describe(value)}")


def _int_range_error(base: DataType, value: int) -> ValueOutOfRange:
    lo, hi = INT_BOUNDS[base]
    return ValueOutOfRange(f"{value} does not fit {base.value} ({lo}..{hi})")


def _as_float(base: DataType, value: Any) -> float:
    if type(value) is float:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueTypeError(f"expected {base.value} (a number), got {_describe(value)}")
    try:
        return float(value)
    except OverflowError:
        raise ValueOutOfRange(f"{value} does not fit {base.value}") from None


def _as_bool(base: DataType, value: Any) -> int:
    if value is True:
        return 1
    if value is False:
        return 0
    raise ValueTypeError(f"expected Boolean (True/False), got {_describe(value)}")


def filetime_ticks(value: datetime) -> int:
    """100 ns ticks since 1601-01-01 UTC; naive datetimes are taken as UTC, like the tree does."""
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    delta = value - FILETIME_EPOCH
    ticks = (delta.days * 86_400 + delta.seconds) * 10_000_000 + delta.microseconds * 10
    if ticks < 0:
        raise ValueOutOfRange(f"{value.isoformat()} is before 1601-01-01, the start of FILETIME")
    return ticks


def _as_ticks(base: DataType, value: Any) -> int:
    if not isinstance(value, datetime):
        raise ValueTypeError(f"expected DateTime (a datetime), got {_describe(value)}")
    return filetime_ticks(value)


_CANONICAL: dict[DataType, Callable[[DataType, Any], Any]] = {
    DataType.BOOLEAN: _as_bool,
    DataType.FLOAT: _as_float,
    DataType.DOUBLE: _as_float,
    DataType.DATETIME: _as_ticks,
    **dict.fromkeys(INT_BOUNDS, _as_int),
}


def _pack_error(base: DataType, value: Any) -> ValueOutOfRange:
    if base in INT_BOUNDS:
        return _int_range_error(base, value)
    return ValueOutOfRange(f"{value!r} does not fit a 32-bit Float")


# --- encode ----------------------------------------------------------------------------------


def _encode_text(value: Any, layout: Layout) -> bytes:
    if not isinstance(value, str):
        raise ValueTypeError(f"expected String, got {_describe(value)}")
    try:
        return value.encode(layout.encoding)
    except UnicodeEncodeError as exc:
        raise Unencodable(
            f"character {value[exc.start]!r} at position {exc.start} cannot be encoded in {layout.encoding}"
        ) from None


def _encode_scalar(base: DataType, value: Any, layout: Layout) -> bytes:
    if base is DataType.STRING:
        return _encode_text(value, layout)
    canonical = _CANONICAL[base](base, value)
    try:
        return _SCALARS[base].pack(canonical)
    except (struct.error, OverflowError):
        raise _pack_error(base, canonical) from None


def _encode_strings(values: Sequence[Any], layout: Layout) -> bytes:
    pack_len, max_len = layout.length.pack, layout.max_length
    parts: list[bytes] = []
    for index, value in enumerate(values):
        try:
            data = _encode_text(value, layout)
        except ValueTypeError as exc:
            raise exc._shift(0, f"element {index}") from None
        except Unencodable as exc:
            raise exc._shift(0, f"element {index}") from None
        if len(data) > max_len:
            raise FieldOverflow(
                f"element {index}: {len(data)} bytes do not fit a {layout.len_width}-byte length "
                f"(max {max_len})"
            )
        parts.append(pack_len(len(data)))
        parts.append(data)
    return b"".join(parts)


def _encode_array(base: DataType, values: Any, layout: Layout) -> bytes:
    if not isinstance(values, (list, tuple)):
        raise ValueTypeError(f"expected an array of {base.value} (a list), got {_describe(values)}")
    if base is DataType.STRING:
        return _encode_strings(values, layout)
    canonical_of = _CANONICAL[base]
    canonical: Sequence[Any] = values
    if not (base in INT_BOUNDS and all(type(v) is int for v in values)) and not (
        base in (DataType.FLOAT, DataType.DOUBLE) and all(type(v) is float for v in values)
    ):
        out = []
        for index, value in enumerate(values):
            try:
                out.append(canonical_of(base, value))
            except (ValueTypeError, ValueOutOfRange) as exc:
                raise exc._shift(0, f"element {index}") from None
        canonical = out
    try:
        return struct.pack(f"<{len(canonical)}{_FORMATS[base]}", *canonical)
    except (struct.error, OverflowError):
        pass
    # Slow path, only on error: name the first element that does not fit.
    scalar = _SCALARS[base]
    for index, value in enumerate(canonical):
        try:
            scalar.pack(value)
        except (struct.error, OverflowError):
            raise _pack_error(base, value)._shift(0, f"element {index}") from None
    raise ValueOutOfRange(f"array of {base.value} cannot be packed")  # pragma: no cover - unreachable


def encode_value(spec: TypeSpec, value: Any, layout: Layout) -> bytes:
    """The data bytes of one item. Raises a CopydataEncodeError subclass if `value` does not fit `spec`."""
    if spec.array:
        return _encode_array(spec.base, value, layout)
    return _encode_scalar(spec.base, value, layout)


# --- decode ----------------------------------------------------------------------------------


def _ticks_to_datetime(ticks: int, offset: int) -> datetime:
    if ticks > _MAX_TICKS:
        raise BadFiletime(
            f"FILETIME {ticks:#x} is after 9999-12-31, the last date Python can hold", offset=offset
        )
    # Sub-microsecond ticks are dropped: Python's datetime stops at microseconds.
    return FILETIME_EPOCH + timedelta(microseconds=ticks // 10)


def _decode_text(data: bytes, layout: Layout, offset: int = 0) -> str:
    try:
        return data.decode(layout.encoding)
    except UnicodeDecodeError as exc:
        raise BadText(
            f"bytes are not valid {layout.encoding}: {exc.reason}", offset=offset + exc.start
        ) from None


def _check_booleans(data: bytes) -> None:
    bad = data.translate(None, b"\x00\x01")
    if bad:
        index = data.index(bad[0])  # the first byte outside {0, 1}
        raise BadBoolean(f"Boolean byte {bad[0]:#04x} is neither 0 nor 1", offset=index)


def _decode_strings(data: bytes, layout: Layout) -> list[str]:
    unpack_len, width = layout.length.unpack_from, layout.len_width
    out: list[str] = []
    offset, end = 0, len(data)
    while offset < end:
        if end - offset < width:
            raise TruncatedHeader(
                f"String[] element {len(out)}: {end - offset} bytes left, its length field needs {width}",
                offset=offset,
            )
        (length,) = unpack_len(data, offset)
        start = offset + width
        if start + length > end:
            raise LengthOverrun(
                f"String[] element {len(out)} declares {length} bytes but only {end - start} remain",
                offset=offset,
            )
        out.append(_decode_text(data[start : start + length], layout, start))
        offset = start + length
    return out


def decode_value(spec: TypeSpec, data: bytes, layout: Layout) -> Any:
    """The Python value of one item's data bytes; offsets in errors count from the start of `data`.

    Arrays come back as lists, DateTime as an aware UTC datetime.
    """
    base = spec.base
    if base is DataType.STRING:
        return _decode_strings(data, layout) if spec.array else _decode_text(data, layout)
    scalar = _SCALARS[base]
    size = scalar.size
    if not spec.array:
        if len(data) != size:
            raise WrongSize(f"{base.value} needs {size} bytes, got {len(data)}", offset=0)
        if base is DataType.BOOLEAN:
            _check_booleans(data)
            return data[0] == 1
        (value,) = scalar.unpack(data)
        if base is DataType.DATETIME:
            return _ticks_to_datetime(value, 0)
        return value
    count, rest = divmod(len(data), size)
    if rest:
        raise WrongSize(
            f"{base.value}[] needs a multiple of {size} bytes, got {len(data)}", offset=len(data) - rest
        )
    if base is DataType.BOOLEAN:
        _check_booleans(data)
        return list(map(bool, data))
    values = list(struct.unpack(f"<{count}{_FORMATS[base]}", data))
    if base is DataType.DATETIME:
        return [_ticks_to_datetime(t, i * size) for i, t in enumerate(values)]
    return values
