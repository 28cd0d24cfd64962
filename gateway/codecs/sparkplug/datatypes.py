"""Sparkplug B datatypes, the gateway's types mapped onto them, and values in and out of a Metric.

The table (Sparkplug 3.0, 6.4.16-17): Int8/16/32 and UInt8/16/32 travel in `int_value` (uint32),
Int64, UInt64 and DateTime in `long_value` (uint64), Float, Double, Boolean and String in their own
fields, and every array type in `bytes_value`, packed little-endian. Rules the specification states
in prose, and this module follows:

- signed integers are their two's complement in the unsigned field, at 32 bits for Int8/16/32 (so
  Int8 -1 is int_value 4294967295, as Java's widening gives) and 64 for Int64;
- DateTime is milliseconds since 1970-01-01 UTC; a time before 1970 is a negative count in two's
  complement (what a Java host's Date.getTime() gives and reads back);
- BooleanArray is a 4-byte little-endian count, then the values packed eight to a byte, first value
  in the most significant bit (the specification's example, and Eclipse Tahu); the unused low bits
  of the last byte are zero;
- StringArray is each string's UTF-8 followed by a NUL byte;
- DateTimeArray is 8-byte little-endian millisecond counts (the 3.0 text; its printed example
  lost two bytes per value, eclipse-sparkplug/sparkplug#435), FloatArray and DoubleArray are
  little-endian (the printed examples are big-endian by mistake, same issue).

Reading is strict where a wrong guess would write a wrong value to a machine: a value in another
field than its type's is refused, with one exception that real hosts need: UInt32 is also read
from `long_value`, where Eclipse Tahu's Java library puts it. Floats are carried as IEEE-754,
NaN and infinities included (a Float beyond float32's range becomes an infinity, as a cast does):
the codec mirrors values, the tree judges writes.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from datetime import UTC, datetime, timedelta
from enum import IntEnum
from typing import NoReturn

from gateway.codecs.sparkplug.errors import BadValue, Unencodable, WrongDatatype
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec

Scalar = bool | int | float | str | datetime
Value = Scalar | list[Scalar]

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_MS = timedelta(milliseconds=1)


class SparkplugType(IntEnum):
    """The DataType enum of the Sparkplug B schema (numbers as on the wire)."""

    Unknown = 0
    Int8 = 1
    Int16 = 2
    Int32 = 3
    Int64 = 4
    UInt8 = 5
    UInt16 = 6
    UInt32 = 7
    UInt64 = 8
    Float = 9
    Double = 10
    Boolean = 11
    String = 12
    DateTime = 13
    Text = 14
    UUID = 15
    DataSet = 16
    Bytes = 17
    File = 18
    Template = 19
    PropertySet = 20
    PropertySetList = 21
    Int8Array = 22
    Int16Array = 23
    Int32Array = 24
    Int64Array = 25
    UInt8Array = 26
    UInt16Array = 27
    UInt32Array = 28
    UInt64Array = 29
    FloatArray = 30
    DoubleArray = 31
    BooleanArray = 32
    StringArray = 33
    DateTimeArray = 34


T = SparkplugType

# The gateway's base types and their Sparkplug scalar and array types.
_SCALAR_OF: dict[DataType, SparkplugType] = {
    DataType.BOOLEAN: T.Boolean,
    DataType.SBYTE: T.Int8,
    DataType.BYTE: T.UInt8,
    DataType.INT16: T.Int16,
    DataType.UINT16: T.UInt16,
    DataType.INT32: T.Int32,
    DataType.UINT32: T.UInt32,
    DataType.INT64: T.Int64,
    DataType.UINT64: T.UInt64,
    DataType.FLOAT: T.Float,
    DataType.DOUBLE: T.Double,
    DataType.STRING: T.String,
    DataType.DATETIME: T.DateTime,
}
_ARRAY_OF: dict[DataType, SparkplugType] = {
    DataType.BOOLEAN: T.BooleanArray,
    DataType.SBYTE: T.Int8Array,
    DataType.BYTE: T.UInt8Array,
    DataType.INT16: T.Int16Array,
    DataType.UINT16: T.UInt16Array,
    DataType.INT32: T.Int32Array,
    DataType.UINT32: T.UInt32Array,
    DataType.INT64: T.Int64Array,
    DataType.UINT64: T.UInt64Array,
    DataType.FLOAT: T.FloatArray,
    DataType.DOUBLE: T.DoubleArray,
    DataType.STRING: T.StringArray,
    DataType.DATETIME: T.DateTimeArray,
}
_SPEC_OF: dict[SparkplugType, TypeSpec] = {
    **{sp: TypeSpec(base) for base, sp in _SCALAR_OF.items()},
    **{sp: TypeSpec(base, array=True) for base, sp in _ARRAY_OF.items()},
}
# Sparkplug scalar types that have a gateway base type (Text and UUID read as strings).
_BASE_OF: dict[SparkplugType, DataType] = {
    **{sp: base for base, sp in _SCALAR_OF.items()},
    T.Text: DataType.STRING,
    T.UUID: DataType.STRING,
}

_INT32_TYPES = frozenset({T.Int8, T.Int16, T.Int32, T.UInt8, T.UInt16, T.UInt32})
_SIGNED_BITS: dict[SparkplugType, int] = {T.Int8: 32, T.Int16: 32, T.Int32: 32, T.Int64: 64}

# The oneof field each scalar type travels in.
_FIELD: dict[SparkplugType, str] = {
    **dict.fromkeys(_INT32_TYPES, "int_value"),
    T.Int64: "long_value",
    T.UInt64: "long_value",
    T.DateTime: "long_value",
    T.Float: "float_value",
    T.Double: "double_value",
    T.Boolean: "boolean_value",
    T.String: "string_value",
    T.Text: "string_value",
    T.UUID: "string_value",
}
# What a reader also accepts (see the module's docstring).
_ALSO_READ: dict[SparkplugType, str] = {T.UInt32: "long_value"}

# struct letters of the fixed-width arrays (DateTime: its signed millisecond count).
_PACK: dict[SparkplugType, str] = {
    T.Int8Array: "b",
    T.Int16Array: "h",
    T.Int32Array: "i",
    T.Int64Array: "q",
    T.UInt8Array: "B",
    T.UInt16Array: "H",
    T.UInt32Array: "I",
    T.UInt64Array: "Q",
    T.FloatArray: "f",
    T.DoubleArray: "d",
    T.DateTimeArray: "q",
}
_ELEMENT: dict[SparkplugType, DataType] = {sp: base for base, sp in _ARRAY_OF.items()}

ValueMessage = Payload.Metric | Payload.PropertyValue


def sparkplug_type(spec: TypeSpec) -> SparkplugType:
    """The Sparkplug datatype of a gateway type; every gateway type has one."""
    return (_ARRAY_OF if spec.array else _SCALAR_OF)[spec.base]


def gateway_type(sp: SparkplugType) -> TypeSpec | None:
    """The gateway type a Sparkplug datatype maps back to; None for those it has no counterpart of
    (Text, UUID, Bytes, File, DataSet, Template, property sets)."""
    return _SPEC_OF.get(sp)


def value_field(sp: SparkplugType) -> str:
    """The Metric oneof field a value of this datatype travels in (DataSet, Template: their own)."""
    if sp in _FIELD:
        return _FIELD[sp]
    if sp in _PACK or sp in (T.BooleanArray, T.StringArray, T.Bytes, T.File):
        return "bytes_value"
    return {T.DataSet: "dataset_value", T.Template: "template_value"}.get(sp, "extension_value")


# --- Metric and PropertyValue ------------------------------------------------------------------


def set_metric_value(metric: Payload.Metric, spec: TypeSpec, value: object) -> None:
    """Put `value` (the gateway's canonical Python form) into `metric`; None sets is_null."""
    if value is None:
        metric.is_null = True
        return
    sp = sparkplug_type(spec)
    if spec.array:
        metric.bytes_value = pack_array(sp, value)
    else:
        set_scalar(metric, sp, value)


def get_metric_value(metric: Payload.Metric, spec: TypeSpec) -> Value:
    """Read `metric`'s value as the gateway type `spec`; WrongDatatype or BadValue if it is not one.

    A null (is_null, or no value at all) is a BadValue: a caller that accepts nulls checks
    `metric.is_null` first.
    """
    sp = sparkplug_type(spec)
    if not spec.array:
        return get_scalar(metric, sp)
    present = metric.WhichOneof("value")
    if present != "bytes_value":
        _refuse_field(metric, sp, present, "bytes_value")
    return unpack_array(sp, metric.bytes_value)


def set_scalar(message: ValueMessage, sp: SparkplugType, value: object) -> None:
    """Set the value field of a Metric or PropertyValue to a scalar of Sparkplug type `sp`."""
    field = _FIELD.get(sp)
    if field is None:
        raise Unencodable(f"{sp.name} is not a scalar type this codec writes")
    setattr(message, field, _to_wire(sp, value))


def get_scalar(message: ValueMessage, sp: SparkplugType) -> Scalar:
    """Read the value field of a Metric or PropertyValue as a scalar of Sparkplug type `sp`."""
    expected = _FIELD.get(sp)
    if expected is None:
        raise WrongDatatype(f"{sp.name} is not a scalar type this codec reads")
    present = message.WhichOneof("value")
    if present is None or (present != expected and present != _ALSO_READ.get(sp)):
        _refuse_field(message, sp, present, expected)
    return _from_wire(sp, getattr(message, present))


def _refuse_field(message: ValueMessage, sp: SparkplugType, present: str | None, expected: str) -> NoReturn:
    if present is None:
        if message.is_null:
            raise BadValue(f"the value is null; {_an(sp)} is needed")
        raise BadValue(f"no value; {_an(sp)} in {expected} is needed")
    raise WrongDatatype(f"{_an(sp)} travels in {expected}, got {present}")


# --- scalars ------------------------------------------------------------------------------------


def _to_wire(sp: SparkplugType, value: object) -> int | float | bool | str:
    if sp in _SIGNED_BITS or sp in _INT32_TYPES or sp is T.UInt64:
        number = _int(sp, value)
        bits = _SIGNED_BITS.get(sp)
        return number & ((1 << bits) - 1) if bits and number < 0 else number
    if sp in (T.Float, T.Double):
        return _number(sp, value)
    if sp is T.Boolean:
        if not isinstance(value, bool):
            raise Unencodable(f"a Boolean needs true or false, got {_kind(value)}")
        return value
    if sp in (T.String, T.Text, T.UUID):
        if not isinstance(value, str):
            raise Unencodable(f"{_an(sp)} needs text, got {_kind(value)}")
        _check_utf8(value)
        return value
    if sp is T.DateTime:
        return to_millis(value) & 0xFFFF_FFFF_FFFF_FFFF
    raise Unencodable(f"{sp.name} is not a scalar type this codec writes")  # pragma: no cover


def _from_wire(sp: SparkplugType, raw: object) -> Scalar:
    if sp in (T.String, T.Text, T.UUID):
        if not isinstance(raw, str):  # protobuf hands back bytes when a proto2 string is not UTF-8
            raise BadValue(f"the {sp.name} is not UTF-8 text")
        return raw
    if sp in (T.Float, T.Double):
        assert isinstance(raw, float)
        return raw
    if sp is T.Boolean:
        assert isinstance(raw, bool)
        return raw
    assert isinstance(raw, int) and not isinstance(raw, bool)
    if sp is T.DateTime:
        return from_millis(_signed(raw, 64))
    bits = _SIGNED_BITS.get(sp)
    number = _signed(raw, bits) if bits else raw
    base = _BASE_OF[sp]
    lo, hi = INT_BOUNDS[base]
    if not lo <= number <= hi:
        raise BadValue(f"{number} does not fit {_an(sp)} ({lo}..{hi})")
    return number


def _signed(raw: int, bits: int) -> int:
    return raw - (1 << bits) if raw >= 1 << (bits - 1) else raw


def _int(sp: SparkplugType, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise Unencodable(f"{_an(sp)} needs an integer, got {_kind(value)}")
    base = _BASE_OF.get(sp) or _ELEMENT[sp]
    lo, hi = INT_BOUNDS[base]
    if not lo <= value <= hi:
        raise Unencodable(f"{value} does not fit {_an(sp)} ({lo}..{hi})")
    return value


def to_millis(value: object) -> int:
    """A datetime as milliseconds since 1970-01-01 UTC (floored; naive times are UTC)."""
    if not isinstance(value, datetime):
        raise Unencodable(f"a DateTime needs a datetime, got {_kind(value)}")
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return (value - EPOCH) // _MS


def from_millis(ms: int) -> datetime:
    """Milliseconds since 1970-01-01 UTC as an aware datetime; BadValue past year 1..9999."""
    try:
        return EPOCH + timedelta(milliseconds=ms)
    except OverflowError:
        raise BadValue(f"{ms} ms since 1970 is not a date between years 1 and 9999") from None


# --- arrays -------------------------------------------------------------------------------------


def pack_array(sp: SparkplugType, values: object) -> bytes:
    """The bytes_value of an array of Sparkplug array type `sp`."""
    if not isinstance(values, (list, tuple)):
        raise Unencodable(f"{_an(sp)} needs a list, got {_kind(values)}")
    if sp is T.BooleanArray:
        return _pack_booleans(values)
    if sp is T.StringArray:
        return _pack_strings(values)
    letter = _PACK.get(sp)
    if letter is None:
        raise Unencodable(f"{sp.name} is not an array type")
    if sp is T.DateTimeArray:
        numbers: list[int] | list[float] = [to_millis(v) for v in values]
    elif sp in (T.FloatArray, T.DoubleArray):
        numbers = [_number(sp, v) for v in values]
    else:
        numbers = [_int(sp, v) for v in values]
    try:
        return struct.pack(f"<{len(numbers)}{letter}", *numbers)
    except OverflowError:  # a finite double beyond float32: a cast makes it an infinity
        return b"".join(_pack_float32(float(v)) for v in numbers)


def unpack_array(sp: SparkplugType, data: bytes) -> list[Scalar]:
    """The values of a bytes_value of Sparkplug array type `sp`; BadValue if the bytes are not one."""
    if sp is T.BooleanArray:
        return list(_unpack_booleans(data))
    if sp is T.StringArray:
        return list(_unpack_strings(data))
    letter = _PACK.get(sp)
    if letter is None:
        raise WrongDatatype(f"{sp.name} is not an array type")
    size = struct.calcsize(letter)
    if len(data) % size:
        raise BadValue(f"{_an(sp)} is {size}-byte values; {len(data)} bytes is not a whole number of them")
    numbers = struct.unpack(f"<{len(data) // size}{letter}", data)
    if sp is T.DateTimeArray:
        return [from_millis(ms) for ms in numbers]
    return list(numbers)


def _number(sp: SparkplugType, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise Unencodable(f"{_an(sp)} needs a number, got {_kind(value)}")
    try:
        return float(value)
    except OverflowError:
        raise Unencodable(f"{_an(sp)} cannot hold an integer beyond the range of a double") from None


def _pack_float32(value: float) -> bytes:
    try:
        return struct.pack("<f", value)
    except OverflowError:
        return struct.pack("<f", math.copysign(math.inf, value))


def _pack_booleans(values: Iterable[object]) -> bytes:
    flags = list(values)
    if len(flags) > 0xFFFF_FFFF:
        raise Unencodable("a BooleanArray holds at most 2**32 - 1 values")
    packed = bytearray((len(flags) + 7) // 8)
    for index, flag in enumerate(flags):
        if not isinstance(flag, bool):
            raise Unencodable(f"a BooleanArray element needs true or false, got {_kind(flag)}")
        if flag:
            packed[index >> 3] |= 0x80 >> (index & 7)
    return struct.pack("<I", len(flags)) + bytes(packed)


def _unpack_booleans(data: bytes) -> Iterable[bool]:
    if len(data) < 4:
        raise BadValue(f"a BooleanArray starts with a 4-byte count; got {len(data)} bytes")
    (count,) = struct.unpack_from("<I", data)
    needed = (count + 7) // 8
    if len(data) - 4 != needed:
        raise BadValue(f"a BooleanArray of {count} values has {needed} bytes of bits, got {len(data) - 4}")
    bits = data[4:]
    return ((bits[i >> 3] & (0x80 >> (i & 7))) != 0 for i in range(count))


def _pack_strings(values: Iterable[object]) -> bytes:
    out = bytearray()
    for value in values:
        if not isinstance(value, str):
            raise Unencodable(f"a StringArray element needs text, got {_kind(value)}")
        if "\x00" in value:
            raise Unencodable(f"a StringArray element cannot contain NUL, which ends it: {value[:40]!r}")
        out += _check_utf8(value)
        out.append(0)
    return bytes(out)


def _unpack_strings(data: bytes) -> Iterable[str]:
    if not data:
        return []
    if data[-1] != 0:
        raise BadValue("a StringArray ends each string with a NUL byte; the last one has none")
    try:
        return data[:-1].decode("utf-8").split("\x00")
    except UnicodeDecodeError as exc:
        raise BadValue(f"a StringArray element is not UTF-8 (byte {exc.start})") from None


def _check_utf8(text: str) -> bytes:
    try:
        return text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise Unencodable(f"text with a lone surrogate at {exc.start} cannot be UTF-8") from None


def _an(sp: SparkplugType) -> str:
    return f"an {sp.name}" if sp.name.startswith("I") else f"a {sp.name}"


def _kind(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        return "a list"
    text = repr(value)
    return f"{type(value).__name__} {text[:40]}"
