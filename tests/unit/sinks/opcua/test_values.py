from __future__ import annotations

import math
from datetime import UTC, datetime

import pytest
from asyncua import ua

from gateway.model.sample import Sample
from gateway.model.types import DataType, TypeSpec
from gateway.sinks.opcua.values import (
    UNECE_NAMESPACE,
    UNECE_UNITS,
    ValueKind,
    ValueMismatch,
    array_dimensions,
    data_type_id,
    eu_information,
    status_code,
    unece_unit_id,
    value_rank,
    variant_type,
)

TS = datetime(2026, 11, 21, 12, 0, tzinfo=UTC)
NOW = datetime(2026, 11, 21, 12, 0, 1, tzinfo=UTC)

EXPECTED = {
    "Boolean": (ua.VariantType.Boolean, 1),
    "SByte": (ua.VariantType.SByte, 2),
    "Byte": (ua.VariantType.Byte, 3),
    "Int16": (ua.VariantType.Int16, 4),
    "UInt16": (ua.VariantType.UInt16, 5),
    "Int32": (ua.VariantType.Int32, 6),
    "UInt32": (ua.VariantType.UInt32, 7),
    "Int64": (ua.VariantType.Int64, 8),
    "UInt64": (ua.VariantType.UInt64, 9),
    "Float": (ua.VariantType.Float, 10),
    "Double": (ua.VariantType.Double, 11),
    "String": (ua.VariantType.String, 12),
    "DateTime": (ua.VariantType.DateTime, 13),
}


def test_every_base_type_is_covered() -> None:
    assert set(EXPECTED) == {t.value for t in DataType}


@pytest.mark.parametrize("name", sorted(EXPECTED))
@pytest.mark.parametrize("array", [False, True])
def test_type_maps_to_variant_type_data_type_and_rank(name: str, array: bool) -> None:
    spec = TypeSpec.parse(name + ("[]" if array else ""))
    vtype, dtype = EXPECTED[name]
    assert variant_type(spec) is vtype
    assert data_type_id(spec) == ua.NodeId(dtype, 0)
    assert value_rank(spec) == (1 if array else -1)
    assert array_dimensions(spec) == ([0] if array else None)


def test_aliases_map_like_their_targets() -> None:
    assert variant_type(TypeSpec.parse("Int8")) is ua.VariantType.SByte
    assert variant_type(TypeSpec.parse("UInt8[]")) is ua.VariantType.Byte


# --- units ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("unit", "code"),
    [
        ("mm", "MMT"),
        ("m", "MTR"),
        ("mm/min", "H81"),
        ("m/min", "2X"),
        ("mm/s", "C16"),
        ("W", "WTT"),
        ("kW", "KWT"),
        ("bar", "BAR"),
        ("Pa", "PAL"),
        ("%", "P1"),
        ("s", "SEC"),
        ("ms", "C26"),
        ("min", "MIN"),
        ("h", "HUR"),
        ("degC", "CEL"),
        ("°C", "CEL"),
        ("Hz", "HTZ"),
        ("rpm", "RPM"),
        ("1/min", "C94"),
        ("A", "AMP"),
        ("V", "VLT"),
        ("N", "NEW"),
        ("kg", "KGM"),
    ],
)
def test_usual_machine_units_have_their_unece_code(unit: str, code: str) -> None:
    assert UNECE_UNITS[unit][0] == code
    eu = eu_information(unit)
    assert eu.NamespaceUri == UNECE_NAMESPACE == "http://www.opcfoundation.org/UA/units/un/cefact"
    assert eu.UnitId == unece_unit_id(code)
    assert eu.DisplayName == ua.LocalizedText(unit)


def test_unit_id_follows_part_8() -> None:
    # values published with the UNECE to OPC UA mapping
    assert unece_unit_id("MMT") == 5066068
    assert unece_unit_id("H81") == 4732977
    assert unece_unit_id("2X") == 12888
    assert unece_unit_id("RPM") == 5394509
    assert unece_unit_id("C94") == 4405556


def test_every_table_code_is_a_short_code() -> None:
    for unit, (code, description) in UNECE_UNITS.items():
        assert 1 <= len(code) <= 3 and code.isalnum() and code.upper() == code, unit
        assert description


def test_unknown_unit_keeps_its_text_with_unit_id_minus_one() -> None:
    eu = eu_information("furlong/fortnight")
    assert eu.UnitId == -1
    assert eu.DisplayName == ua.LocalizedText("furlong/fortnight")
    assert eu.NamespaceUri == UNECE_NAMESPACE


# --- status codes --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name", ["Good", "BadNotConnected", "UncertainLastUsableValue", "BadWaitingForInitialData"]
)
def test_status_names_map_to_their_codes(name: str) -> None:
    assert status_code(name) == ua.StatusCode(getattr(ua.StatusCodes, name))


@pytest.mark.parametrize("name", ["", "BadNoSuchThing", "_private", "good", "__class__"])
def test_unknown_status_names_are_bad_internal_error(name: str) -> None:
    assert status_code(name) == ua.StatusCode(ua.StatusCodes.BadInternalError)


# --- samples -> DataValues -------------------------------------------------------------------------


def kind(text: str) -> ValueKind:
    return ValueKind(TypeSpec.parse(text))


def test_good_sample_becomes_datavalue_with_both_timestamps() -> None:
    dv = kind("Double").datavalue(Sample(12.5, TS), NOW)
    assert dv.Value == ua.Variant(12.5, ua.VariantType.Double)
    assert dv.StatusCode == ua.StatusCode(ua.StatusCodes.Good)
    assert dv.SourceTimestamp == TS
    assert dv.ServerTimestamp == NOW


def test_bad_sample_carries_its_status_and_no_value() -> None:
    dv = kind("Double").datavalue(Sample(12.5, TS, "BadNotConnected", "down"), NOW)
    assert dv.StatusCode == ua.StatusCode(ua.StatusCodes.BadNotConnected)
    assert dv.Value is not None and dv.Value.Value is None
    assert dv.SourceTimestamp == TS


def test_uncertain_sample_keeps_its_value() -> None:
    dv = kind("Int32").datavalue(Sample(7, TS, "UncertainLastUsableValue"), NOW)
    assert dv.StatusCode == ua.StatusCode(ua.StatusCodes.UncertainLastUsableValue)
    assert dv.Value == ua.Variant(7, ua.VariantType.Int32)


def test_unknown_status_name_is_reported_not_raised() -> None:
    dv = kind("Double").datavalue(Sample(1.0, TS, "BadMadeUp"), NOW)
    assert dv.StatusCode == ua.StatusCode(ua.StatusCodes.BadInternalError)


@pytest.mark.parametrize(
    ("type_name", "value", "expected"),
    [
        ("Boolean", True, True),
        ("Int32", 5.0, 5),  # integral floats from a controller are fine
        ("UInt64", 2**64 - 1, 2**64 - 1),
        ("Double", 3, 3.0),
        ("Float", 1.5, 1.5),
        ("String", "abc", "abc"),
        ("DateTime", datetime(2026, 1, 1), datetime(2026, 1, 1, tzinfo=UTC)),
        ("Double[]", [1, 2.5], [1.0, 2.5]),
        ("UInt16[]", [], []),
        ("Byte[]", b"\x01\x02", [1, 2]),
        ("String[]", ("a", "b"), ["a", "b"]),
    ],
)
def test_values_that_fit_become_typed_variants(type_name: str, value: object, expected: object) -> None:
    k = kind(type_name)
    variant = k.variant(value)
    assert variant.VariantType is k.vtype
    assert variant.Value == expected
    assert variant.is_array is type_name.endswith("[]")


def test_nan_and_infinity_are_valid_doubles() -> None:
    assert math.isnan(kind("Double").variant(float("nan")).Value)
    assert kind("Float").variant(float("inf")).Value == float("inf")


@pytest.mark.parametrize(
    ("type_name", "value"),
    [
        ("Double", "1.5"),
        ("Double", None),
        ("Double", True),
        ("Int32", 1.5),
        ("Int32", True),
        ("Int16", 40000),
        ("UInt32", -1),
        ("Float", 1e39),
        ("Boolean", 1),
        ("String", 5),
        ("DateTime", "2026-01-01"),
        ("Double[]", 1.0),
        ("Double[]", [1.0, "x"]),
        ("Int32", [1]),
    ],
)
def test_values_that_do_not_fit_raise_value_mismatch(type_name: str, value: object) -> None:
    with pytest.raises(ValueMismatch):
        kind(type_name).variant(value)
    with pytest.raises(ValueMismatch):
        kind(type_name).datavalue(Sample(value, TS), NOW)


def test_mismatch_datavalue_is_bad_type_mismatch_with_the_source_time() -> None:
    dv = kind("Double").mismatch(Sample("oops", TS), NOW)
    assert dv.StatusCode == ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
    assert dv.SourceTimestamp == TS and dv.ServerTimestamp == NOW
