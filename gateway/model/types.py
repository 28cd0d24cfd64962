"""Data types of mapped variables, and strict value checks for writes.

The names are OPC UA's built-in type names (with Int8/UInt8 accepted as aliases
of SByte/Byte), because that is what SCADA engineers read in a client. A trailing
`[]` makes a one-dimensional array. Everything here is pure: no I/O, no asyncio.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import Enum
from typing import Any

from gateway.errors import OutOfRange, TypeMismatch


class DataType(str, Enum):
    BOOLEAN = "Boolean"
    SBYTE = "SByte"
    BYTE = "Byte"
    INT16 = "Int16"
    UINT16 = "UInt16"
    INT32 = "Int32"
    UINT32 = "UInt32"
    INT64 = "Int64"
    UINT64 = "UInt64"
    FLOAT = "Float"
    DOUBLE = "Double"
    STRING = "String"
    DATETIME = "DateTime"


ALIASES: dict[str, DataType] = {
    "Int8": DataType.SBYTE,
    "UInt8": DataType.BYTE,
    **{t.value: t for t in DataType},
}

INT_BOUNDS: dict[DataType, tuple[int, int]] = {
    DataType.SBYTE: (-(2**7), 2**7 - 1),
    DataType.BYTE: (0, 2**8 - 1),
    DataType.INT16: (-(2**15), 2**15 - 1),
    DataType.UINT16: (0, 2**16 - 1),
    DataType.INT32: (-(2**31), 2**31 - 1),
    DataType.UINT32: (0, 2**32 - 1),
    DataType.INT64: (-(2**63), 2**63 - 1),
    DataType.UINT64: (0, 2**64 - 1),
}

FLOAT32_MAX = 3.4028234663852886e38

TYPE_NAMES = sorted(ALIASES) + [f"{n}[]" for n in sorted(ALIASES)]


@dataclass(frozen=True, slots=True)
class TypeSpec:
    """A variable's data type: a base type, scalar or one-dimensional array."""

    base: DataType
    array: bool = False

    @classmethod
    def parse(cls, text: str) -> TypeSpec:
        """The type named `text`; one shared object per type (a mapping names the same few thousands of
        times, and every variable keeps its own)."""
        name = text.strip()
        array = name.endswith("[]")
        if array:
            name = name[:-2].strip()
        try:
            key = (ALIASES[name], array)
        except KeyError:
            raise ValueError(
                f"unknown data type {text!r}; expected one of {', '.join(sorted(ALIASES))}, "
                "optionally followed by [] for an array"
            ) from None
        held = _PARSED.get(key)
        if held is None:
            held = _PARSED[key] = cls(*key)
        return held

    def __str__(self) -> str:
        return self.base.value + ("[]" if self.array else "")

    @property
    def is_numeric(self) -> bool:
        return self.base in INT_BOUNDS or self.base in (DataType.FLOAT, DataType.DOUBLE)

    @property
    def is_integer(self) -> bool:
        return self.base in INT_BOUNDS

    def default(self) -> Any:
        """A neutral value, used before the controller has reported one."""
        if self.array:
            return []
        return _DEFAULTS[self.base]


_DEFAULTS: dict[DataType, Any] = {
    DataType.BOOLEAN: False,
    DataType.FLOAT: 0.0,
    DataType.DOUBLE: 0.0,
    DataType.STRING: "",
    DataType.DATETIME: datetime(1601, 1, 1, tzinfo=UTC),
    **dict.fromkeys(INT_BOUNDS, 0),
}


def coerce(spec: TypeSpec, value: Any) -> Any:
    """Check a written value against its type and return it in canonical Python form.

    Strict on purpose: a string is never silently turned into a number and a bool is
    never taken as an integer. Integral floats (5.0) are accepted for integer types,
    because JSON clients often cannot tell the two apart.
    """
    if spec.array:
        if not isinstance(value, (list, tuple)):
            raise TypeMismatch(f"expected an array of {spec.base.value}, got {_kind(value)}")
        out = []
        for index, item in enumerate(value):
            try:
                out.append(_coerce_scalar(spec.base, item))
            except (TypeMismatch, OutOfRange) as exc:
                raise type(exc)(f"element {index}: {exc.reason}") from None
        return out
    return _coerce_scalar(spec.base, value)


def _coerce_scalar(base: DataType, value: Any) -> Any:
    if base is DataType.BOOLEAN:
        if isinstance(value, bool):
            return value
        raise TypeMismatch(f"expected Boolean (true/false), got {_kind(value)}")
    if base in INT_BOUNDS:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeMismatch(f"expected {base.value} (an integer), got {_kind(value)}")
        if isinstance(value, float):
            if not value.is_integer():
                raise TypeMismatch(f"expected {base.value} (an integer), got {value!r}")
            value = int(value)
        check_int_bounds(base, value)
        return value
    if base in (DataType.FLOAT, DataType.DOUBLE):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeMismatch(f"expected {base.value} (a number), got {_kind(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise OutOfRange(f"{value!r} is not a finite number")
        if base is DataType.FLOAT and abs(value) > FLOAT32_MAX:
            raise OutOfRange(f"{value!r} does not fit a 32-bit Float")
        return value
    if base is DataType.STRING:
        if isinstance(value, str):
            return value
        raise TypeMismatch(f"expected String, got {_kind(value)}")
    if base is DataType.DATETIME:
        if isinstance(value, datetime):
            return value if value.tzinfo else value.replace(tzinfo=UTC)
        if isinstance(value, str):
            try:
                parsed = datetime.fromisoformat(value)
            except ValueError:
                raise TypeMismatch(f"expected an ISO-8601 DateTime, got {value!r}") from None
            return parsed if parsed.tzinfo else parsed.replace(tzinfo=UTC)
        raise TypeMismatch(f"expected DateTime, got {_kind(value)}")
    raise TypeMismatch(f"unsupported type {base}")  # pragma: no cover - enum is exhaustive


def check_int_bounds(base: DataType, value: int) -> None:
    lo, hi = INT_BOUNDS[base]
    if not lo <= value <= hi:
        raise OutOfRange(f"{value} does not fit {base.value} ({lo}..{hi})")


_PARSED: dict[tuple[DataType, bool], TypeSpec] = {}  # TypeSpec.parse's one object per type


def parse_text(spec: TypeSpec, text: str) -> Any:
    """Read a value written as plain text (an MQTT raw payload, a CLI argument)."""
    stripped = text.strip()
    if spec.array or spec.base is not DataType.STRING:
        if spec.base is DataType.DATETIME and not spec.array:
            return coerce(spec, stripped.strip('"'))
        lowered = stripped.lower()
        if spec.base is DataType.BOOLEAN and lowered in ("true", "false", "1", "0", "on", "off"):
            return lowered in ("true", "1", "on")
        try:
            value = json.loads(stripped)
        except ValueError:
            raise TypeMismatch(f"expected {spec}, got text {stripped[:40]!r}") from None
        return coerce(spec, value)
    return text


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"Boolean {value!r}"
    if isinstance(value, str):
        return f"text {value[:40]!r}"
    if isinstance(value, (list, tuple)):
        return "an array"
    if isinstance(value, dict):
        return "an object"
    return f"{type(value).__name__} {value!r}"
