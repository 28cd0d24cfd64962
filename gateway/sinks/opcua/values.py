"""Translations between the tree's terms and OPC UA's: types, status codes, units, values.

Pure mapping code over `asyncua.ua` types only (no server, no I/O), so it can be
unit-tested on its own and reused by anything that speaks OPC UA.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from datetime import UTC, datetime
from functools import cache
from typing import Any

from asyncua import ua

from gateway.errors import CodecError
from gateway.model.sample import Sample
from gateway.model.types import FLOAT32_MAX, INT_BOUNDS, DataType, TypeSpec
from gateway.shims.ua import NULL_ARRAY, new_data_value, new_node_id, new_status_code

# --- types -------------------------------------------------------------------------------------

VARIANT_TYPES: dict[DataType, ua.VariantType] = {
    DataType.BOOLEAN: ua.VariantType.Boolean,
    DataType.SBYTE: ua.VariantType.SByte,
    DataType.BYTE: ua.VariantType.Byte,
    DataType.INT16: ua.VariantType.Int16,
    DataType.UINT16: ua.VariantType.UInt16,
    DataType.INT32: ua.VariantType.Int32,
    DataType.UINT32: ua.VariantType.UInt32,
    DataType.INT64: ua.VariantType.Int64,
    DataType.UINT64: ua.VariantType.UInt64,
    DataType.FLOAT: ua.VariantType.Float,
    DataType.DOUBLE: ua.VariantType.Double,
    DataType.STRING: ua.VariantType.String,
    DataType.DATETIME: ua.VariantType.DateTime,
}

# The built-in DataType nodes of namespace 0 carry the same numbers as the VariantTypes
# (Boolean = i=1 ... DateTime = i=13); spelled out by name so a reader need not know that.
DATA_TYPE_IDS: dict[DataType, ua.NodeId] = {
    base: new_node_id(getattr(ua.ObjectIds, vtype.name), 0) for base, vtype in VARIANT_TYPES.items()
}

SCALAR = -1  # ValueRank
ONE_DIMENSION = 1


def variant_type(spec: TypeSpec) -> ua.VariantType:
    """The VariantType of a value of this type (arrays use their element's VariantType)."""
    return VARIANT_TYPES[spec.base]


def data_type_id(spec: TypeSpec) -> ua.NodeId:
    return DATA_TYPE_IDS[spec.base]


def value_rank(spec: TypeSpec) -> int:
    return ONE_DIMENSION if spec.array else SCALAR


def array_dimensions(spec: TypeSpec) -> list[int]:
    """[0] = one dimension of unknown length; a null array (None) for scalars."""
    return [0] if spec.array else NULL_ARRAY


# --- status codes --------------------------------------------------------------------------------

_STATUS_CACHE: dict[str, ua.StatusCode] = {}


def status_code(name: str) -> ua.StatusCode:
    """The StatusCode for a status name ("Good", "BadNotConnected"...); unknown names are BadInternalError.

    Sample.status and RequestError.status both carry names, and a typo in a driver must
    never crash the sink, so anything that is not a real code maps to BadInternalError.
    """
    code = _STATUS_CACHE.get(name)
    if code is None:
        value = getattr(ua.StatusCodes, name, None) if name and not name.startswith("_") else None
        if not isinstance(value, int) or isinstance(value, bool):
            return _INTERNAL_ERROR
        code = new_status_code(value)
        _STATUS_CACHE[name] = code
    return code


_INTERNAL_ERROR = new_status_code(ua.StatusCodes.BadInternalError)


# --- engineering units (UNECE Recommendation 20 common codes, as OPC UA Part 8 prescribes) --------

UNECE_NAMESPACE = "http://www.opcfoundation.org/UA/units/un/cefact"

# unit text as written in mappings -> (UNECE common code, description)
UNECE_UNITS: dict[str, tuple[str, str]] = {
    "µm": ("4H", "micrometre"),
    "um": ("4H", "micrometre"),
    "mm": ("MMT", "millimetre"),
    "cm": ("CMT", "centimetre"),
    "m": ("MTR", "metre"),
    "in": ("INH", "inch"),
    "mm/min": ("H81", "millimetre per minute"),
    "m/min": ("2X", "metre per minute"),
    "mm/s": ("C16", "millimetre per second"),
    "m/s": ("MTS", "metre per second"),
    "mm/s²": ("M41", "millimetre per second squared"),
    "mm/s2": ("M41", "millimetre per second squared"),
    "m/s²": ("MSK", "metre per second squared"),
    "m/s2": ("MSK", "metre per second squared"),
    "W": ("WTT", "watt"),
    "kW": ("KWT", "kilowatt"),
    "kWh": ("KWH", "kilowatt hour"),
    "bar": ("BAR", "bar"),
    "mbar": ("MBR", "millibar"),
    "Pa": ("PAL", "pascal"),
    "kPa": ("KPA", "kilopascal"),
    "MPa": ("MPA", "megapascal"),
    "%": ("P1", "percent"),
    "s": ("SEC", "second"),
    "ms": ("C26", "millisecond"),
    "min": ("MIN", "minute"),
    "h": ("HUR", "hour"),
    "degC": ("CEL", "degree Celsius"),
    "°C": ("CEL", "degree Celsius"),
    "K": ("KEL", "kelvin"),
    "Hz": ("HTZ", "hertz"),
    "kHz": ("KHZ", "kilohertz"),
    "rpm": ("RPM", "revolutions per minute"),
    "r/min": ("RPM", "revolutions per minute"),
    "1/min": ("C94", "reciprocal minute"),
    "deg": ("DD", "degree [unit of angle]"),
    "°": ("DD", "degree [unit of angle]"),
    "A": ("AMP", "ampere"),
    "mA": ("4K", "milliampere"),
    "V": ("VLT", "volt"),
    "N": ("NEW", "newton"),
    "Nm": ("NU", "newton metre"),
    "kg": ("KGM", "kilogram"),
    "g": ("GRM", "gram"),
    "l/min": ("L2", "litre per minute"),
}


def unece_unit_id(common_code: str) -> int:
    """OPC UA Part 8 §5.6.3: the common code's ASCII bytes, big-endian, as an Int32."""
    unit_id = 0
    for char in common_code:
        unit_id = (unit_id << 8) | ord(char)
    return unit_id


def eu_information(unit: str) -> ua.EUInformation:
    """EngineeringUnits for a unit text; unknown units keep their text with UnitId -1."""
    known = UNECE_UNITS.get(unit)
    if known is None:
        return ua.EUInformation(
            NamespaceUri=UNECE_NAMESPACE,
            UnitId=-1,
            DisplayName=ua.LocalizedText(unit),
            Description=ua.LocalizedText(unit),
        )
    code, description = known
    return ua.EUInformation(
        NamespaceUri=UNECE_NAMESPACE,
        UnitId=unece_unit_id(code),
        DisplayName=ua.LocalizedText(unit),
        Description=ua.LocalizedText(description),
    )


# --- values --------------------------------------------------------------------------------------


_NULL = ua.Variant(None, ua.VariantType.Null)  # Variants are immutable: one null serves every DataValue
_TYPE_MISMATCH = new_status_code(ua.StatusCodes.BadTypeMismatch)


class ValueMismatch(CodecError):
    """A value that cannot be carried by its variable's VariantType."""


def _bool(value: Any) -> bool:
    if isinstance(value, bool):
        return value
    raise ValueMismatch(f"expected Boolean, got {type(value).__name__}")


def _int_checker(base: DataType) -> Callable[[Any], int]:
    lo, hi = INT_BOUNDS[base]

    def check(value: Any) -> int:
        if isinstance(value, bool):
            raise ValueMismatch(f"expected {base.value}, got bool")
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise ValueMismatch(f"expected {base.value}, got {type(value).__name__} {value!r}")
        if not lo <= value <= hi:
            raise ValueMismatch(f"{value} does not fit {base.value}")
        return value

    return check


def _double(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueMismatch(f"expected a number, got {type(value).__name__}")
    return float(value)


def _float(value: Any) -> float:
    number = _double(value)
    if math.isfinite(number) and abs(number) > FLOAT32_MAX:
        raise ValueMismatch(f"{number!r} does not fit a 32-bit Float")
    return number


def _string(value: Any) -> str:
    if isinstance(value, str):
        return value
    raise ValueMismatch(f"expected String, got {type(value).__name__}")


def _datetime(value: Any) -> datetime:
    if isinstance(value, datetime):
        return value if value.tzinfo else value.replace(tzinfo=UTC)
    raise ValueMismatch(f"expected DateTime, got {type(value).__name__}")


_SCALAR_CHECKS: dict[DataType, Callable[[Any], Any]] = {
    DataType.BOOLEAN: _bool,
    DataType.FLOAT: _float,
    DataType.DOUBLE: _double,
    DataType.STRING: _string,
    DataType.DATETIME: _datetime,
    **{base: _int_checker(base) for base in INT_BOUNDS},
}


class ValueKind:
    """Everything needed to turn a variable's Sample into a DataValue, computed once per variable."""

    __slots__ = ("_check", "spec", "vtype")

    def __init__(self, spec: TypeSpec) -> None:
        self.spec = spec
        self.vtype = variant_type(spec)
        self._check = _SCALAR_CHECKS[spec.base]

    def variant(self, value: Any) -> ua.Variant:
        """A Variant that will encode; raises ValueMismatch for a value of the wrong kind.

        asyncua only notices a bad value when it encodes a notification for a client,
        which would break that client's whole publish response, so check here.
        """
        check = self._check
        if self.spec.array:
            if isinstance(value, (bytes, bytearray)) and self.spec.base is DataType.BYTE:
                value = list(value)
            if not isinstance(value, (list, tuple)):
                raise ValueMismatch(
                    f"expected an array of {self.spec.base.value}, got {type(value).__name__}"
                )
            return ua.Variant([check(v) for v in value], self.vtype, is_array=True)
        if value is None:
            raise ValueMismatch("no value")
        return ua.Variant(check(value), self.vtype)

    def datavalue(self, sample: Sample, server_ts: datetime) -> ua.DataValue:
        """The DataValue for a Sample. Bad samples carry no value, as OPC UA requires."""
        status = status_code(sample.status)
        variant = _NULL if status.is_bad() else self.variant(sample.value)
        return new_data_value(variant, status, SourceTimestamp=sample.source_ts, ServerTimestamp=server_ts)

    def mismatch(self, sample: Sample, server_ts: datetime) -> ua.DataValue:
        """What clients see when the tree holds a value the type cannot carry."""
        return new_data_value(
            _NULL,
            _TYPE_MISMATCH,
            SourceTimestamp=sample.source_ts,
            ServerTimestamp=server_ts,
        )


@cache
def value_kind(spec: TypeSpec) -> ValueKind:
    """One shared ValueKind per type (TypeSpec is frozen, so it can key the cache)."""
    return ValueKind(spec)
