from __future__ import annotations

from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.errors import OutOfRange, TypeMismatch
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec, coerce, parse_text


def test_parse_names_aliases_and_arrays() -> None:
    assert TypeSpec.parse("Double") == TypeSpec(DataType.DOUBLE)
    assert TypeSpec.parse("Int8") == TypeSpec(DataType.SBYTE)
    assert TypeSpec.parse("UInt8[]") == TypeSpec(DataType.BYTE, array=True)
    assert str(TypeSpec.parse("UInt8[]")) == "Byte[]"
    with pytest.raises(ValueError, match="unknown data type 'Real'"):
        TypeSpec.parse("Real")


@pytest.mark.parametrize("base", list(INT_BOUNDS))
def test_integer_bounds_are_enforced(base: DataType) -> None:
    lo, hi = INT_BOUNDS[base]
    spec = TypeSpec(base)
    assert coerce(spec, lo) == lo and coerce(spec, hi) == hi
    with pytest.raises(OutOfRange):
        coerce(spec, hi + 1)
    with pytest.raises(OutOfRange):
        coerce(spec, lo - 1)


@given(st.integers(-(2**31), 2**31 - 1))
def test_int32_accepts_integral_floats_from_json(value: int) -> None:
    assert coerce(TypeSpec(DataType.INT32), float(value)) == value


@pytest.mark.parametrize(
    ("type_name", "value"),
    [
        ("Int32", 1.5),
        ("Int32", True),
        ("Int32", "5"),
        ("Double", "1.0"),
        ("Double", False),
        ("Boolean", 1),
        ("String", 5),
        ("Double[]", 1.0),
        ("Double", [1.0]),
        ("DateTime", "yesterday"),
        ("Double", None),
    ],
)
def test_wrong_types_are_refused(type_name: str, value: object) -> None:
    with pytest.raises(TypeMismatch):
        coerce(TypeSpec.parse(type_name), value)


def test_float_range_and_finiteness() -> None:
    with pytest.raises(OutOfRange):
        coerce(TypeSpec(DataType.FLOAT), 1e39)
    with pytest.raises(OutOfRange):
        coerce(TypeSpec(DataType.DOUBLE), float("nan"))
    assert coerce(TypeSpec(DataType.DOUBLE), 3) == 3.0


def test_array_elements_are_checked_with_their_index() -> None:
    with pytest.raises(OutOfRange, match="element 1"):
        coerce(TypeSpec(DataType.BYTE, array=True), [1, 256])


def test_datetime_from_iso_text_is_utc_aware() -> None:
    value = coerce(TypeSpec(DataType.DATETIME), "2026-11-21T10:00:00Z")
    assert value == datetime(2026, 11, 21, 10, tzinfo=UTC)


@pytest.mark.parametrize(
    ("type_name", "text", "expected"),
    [
        ("Double", "12.5", 12.5),
        ("UInt16", "80", 80),
        ("Boolean", "true", True),
        ("Boolean", "0", False),
        ("String", " hi ", " hi "),
        ("Int32[]", "[1, 2]", [1, 2]),
    ],
)
def test_parse_text(type_name: str, text: str, expected: object) -> None:
    assert parse_text(TypeSpec.parse(type_name), text) == expected


def test_parse_text_refuses_junk() -> None:
    with pytest.raises(TypeMismatch):
        parse_text(TypeSpec(DataType.DOUBLE), "fast")
