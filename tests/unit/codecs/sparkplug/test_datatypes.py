"""Datatypes: the gateway-to-Sparkplug table, every type's round trip both ways against an
independent host, the specification's array examples byte for byte, and every refusal."""

from __future__ import annotations

import math
from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.sparkplug import (
    BadValue,
    SparkplugType,
    Unencodable,
    WrongDatatype,
    gateway_type,
    get_metric_value,
    pack_array,
    set_metric_value,
    sparkplug_type,
    unpack_array,
)
from gateway.codecs.sparkplug.sparkplug_b_pb2 import DataType as PbDataType
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.model.types import DataType, TypeSpec
from tests.unit.codecs.sparkplug import host
from tests.unit.codecs.sparkplug.strategies import ALL_SPECS, same, values

T = TypeSpec.parse
SP = SparkplugType

# Sparkplug 3.0, 6.4.16: the datatype numbers, written out here from the specification's table.
EXPECTED_NUMBERS = {
    "SByte": 1, "Int16": 2, "Int32": 3, "Int64": 4, "Byte": 5, "UInt16": 6, "UInt32": 7, "UInt64": 8,
    "Float": 9, "Double": 10, "Boolean": 11, "String": 12, "DateTime": 13,
    "SByte[]": 22, "Int16[]": 23, "Int32[]": 24, "Int64[]": 25, "Byte[]": 26, "UInt16[]": 27,
    "UInt32[]": 28, "UInt64[]": 29, "Float[]": 30, "Double[]": 31, "Boolean[]": 32, "String[]": 33,
    "DateTime[]": 34,
}  # fmt: skip


def test_every_gateway_type_has_the_specifications_number() -> None:
    assert {str(spec): int(sparkplug_type(spec)) for spec in ALL_SPECS} == EXPECTED_NUMBERS


def test_the_enum_is_the_schemas() -> None:
    assert {t.name: t.value for t in SparkplugType} == dict(PbDataType.items())


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
def test_every_gateway_type_maps_back(spec: TypeSpec) -> None:
    assert gateway_type(sparkplug_type(spec)) == spec


@pytest.mark.parametrize("sp", [SP.Text, SP.UUID, SP.Bytes, SP.File, SP.DataSet, SP.Template, SP.Unknown])
def test_types_without_a_gateway_counterpart(sp: SparkplugType) -> None:
    assert gateway_type(sp) is None


# --- round trips ------------------------------------------------------------------------------


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@given(data=st.data())
def test_a_host_reads_what_the_codec_writes(spec: TypeSpec, data: st.DataObject) -> None:
    value = data.draw(values(spec), label="value")
    metric = Payload.Metric()
    set_metric_value(metric, spec, value)
    wire = Payload(metrics=[metric]).SerializeToString()
    seen = host.read(wire, {"": int(sparkplug_type(spec))}).metrics[0]
    assert same(seen.value, value)
    assert same(get_metric_value(Payload.FromString(wire).metrics[0], spec), value)


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@given(data=st.data())
def test_the_codec_reads_what_a_host_writes(spec: TypeSpec, data: st.DataObject) -> None:
    value = data.draw(values(spec), label="value")
    wire = host.command(host.write(value, int(sparkplug_type(spec)), alias=1))
    assert same(get_metric_value(Payload.FromString(wire).metrics[0], spec), value)


def test_none_is_a_null_without_a_value() -> None:
    metric = Payload.Metric()
    set_metric_value(metric, T("Double"), None)
    assert metric.is_null and metric.WhichOneof("value") is None
    with pytest.raises(BadValue, match="null"):
        get_metric_value(metric, T("Double"))


# --- the wire forms the specification describes --------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "value", "hexes"),
    [
        # 6.4.17's examples, with the corrections of eclipse-sparkplug/sparkplug#435 (Int8 -17, not -23;
        # Float/Double little-endian; DateTime 8 bytes each).
        ("SByte[]", [-17, 123], "ef 7b"),
        ("Int16[]", [-30000, 30000], "d0 8a 30 75"),
        ("Int32[]", [-1, 315338746], "ff ff ff ff fa af cb 12"),
        ("Int32[]", [123456789, 987654321], "15 cd 5b 07 b1 68 de 3a"),
        ("Int64[]", [-4270929666821191986, -3601064768563266876],
         "ce 06 72 ac 18 9c ba c4 c4 ba 9c 18 ac 72 06 ce"),
        ("Byte[]", [23, 250], "17 fa"),
        ("UInt16[]", [30, 52360], "1e 00 88 cc"),
        ("UInt32[]", [52, 3293969225], "34 00 00 00 49 fb 55 c4"),
        ("UInt64[]", [52, 16444743074749521625], "34 00 00 00 00 00 00 00 d9 9e 02 d1 b2 76 37 e4"),
        ("Float[]", [1.2300000190734863, 89.34100341796875], "a4 70 9d 3f 98 ae b2 42"),
        ("Double[]", [12.354213, 1022.9123213], "d7 a2 05 68 5b b5 28 40 8e 17 1c 6f 4c f7 8f 40"),
        # 12 values: the count, then two bytes; the 4 unused low bits of the last byte are zero.
        ("Boolean[]", [False, False, True, True, False, True, False, False, True, True, False, True],
         "0c 00 00 00 34 d0"),
        ("String[]", ["ABC", "hello"], "41 42 43 00 68 65 6c 6c 6f 00"),
        ("DateTime[]", [datetime(2009, 10, 21, 5, 27, 55, 335000, tzinfo=UTC),
                        datetime(2022, 6, 24, 21, 57, 55, tzinfo=UTC)],
         "c7 d0 90 75 24 01 00 00 b8 ba b8 97 81 01 00 00"),
        ("Boolean[]", [], "00 00 00 00"),
        ("String[]", [], ""),
        ("String[]", [""], "00"),
    ],
)  # fmt: skip
def test_array_bytes_are_the_specifications(spec: str, value: list[object], hexes: str) -> None:
    sp = sparkplug_type(T(spec))
    assert pack_array(sp, value) == bytes.fromhex(hexes)
    assert same(unpack_array(sp, bytes.fromhex(hexes)), value)


@pytest.mark.parametrize(
    ("spec", "value", "field", "raw"),
    [
        ("SByte", -1, "int_value", 0xFFFFFFFF),  # 32-bit two's complement, as Java widens it
        ("Int16", -2, "int_value", 0xFFFFFFFE),
        ("Int32", -(2**31), "int_value", 2**31),
        ("Byte", 255, "int_value", 255),
        ("UInt32", 2**32 - 1, "int_value", 2**32 - 1),
        ("Int64", -1, "long_value", 2**64 - 1),
        ("UInt64", 2**64 - 1, "long_value", 2**64 - 1),
        (
            "DateTime",
            datetime(2017, 2, 3, 17, 55, 2, 122000, tzinfo=UTC),
            "long_value",
            1486144502122,
        ),
        (
            "DateTime",
            datetime(1969, 12, 31, 23, 59, 59, 999000, tzinfo=UTC),
            "long_value",
            2**64 - 1,
        ),
        ("Boolean", True, "boolean_value", True),
        ("String", "Grüße", "string_value", "Grüße"),
        ("Double", 0.1, "double_value", 0.1),
    ],
)
def test_scalar_fields_and_wire_values(spec: str, value: object, field: str, raw: object) -> None:
    metric = Payload.Metric()
    set_metric_value(metric, T(spec), value)
    assert metric.WhichOneof("value") == field
    assert getattr(metric, field) == raw
    assert get_metric_value(metric, T(spec)) == value


def test_a_datetime_is_floored_to_the_millisecond_and_naive_means_utc() -> None:
    metric = Payload.Metric()
    set_metric_value(metric, T("DateTime"), datetime(2024, 1, 1, 0, 0, 0, 999999))
    assert metric.long_value == 1704067200999


def test_a_float_beyond_float32_becomes_an_infinity() -> None:
    metric = Payload.Metric()
    set_metric_value(metric, T("Float"), -1e39)
    assert metric.float_value == -math.inf
    assert unpack_array(SP.FloatArray, pack_array(SP.FloatArray, [1e39, 1.5])) == [math.inf, 1.5]


def test_uint32_is_also_read_from_long_value_where_java_hosts_put_it() -> None:
    metric = Payload.Metric(long_value=4_000_000_000)
    assert get_metric_value(metric, T("UInt32")) == 4_000_000_000
    with pytest.raises(BadValue, match="does not fit a UInt32"):
        get_metric_value(Payload.Metric(long_value=2**32), T("UInt32"))


# --- refusals: reading ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "metric", "error", "fragment"),
    [
        ("Int32", Payload.Metric(long_value=5), WrongDatatype,
         "an Int32 travels in int_value, got long_value"),
        ("Double", Payload.Metric(float_value=1.5), WrongDatatype, "got float_value"),
        ("Boolean", Payload.Metric(int_value=1), WrongDatatype, "got int_value"),
        ("String", Payload.Metric(bytes_value=b"x"), WrongDatatype, "got bytes_value"),
        ("Double[]", Payload.Metric(double_value=1.0), WrongDatatype, "travels in bytes_value"),
        ("Int16", Payload.Metric(), BadValue, "no value"),
        ("Int16", Payload.Metric(is_null=True), BadValue, "the value is null"),
        ("SByte", Payload.Metric(int_value=200), BadValue, "200 does not fit an Int8 (-128..127)"),
        ("Byte", Payload.Metric(int_value=0xFFFFFFFF), BadValue, "does not fit a UInt8"),
        ("UInt16", Payload.Metric(int_value=65536), BadValue, "does not fit a UInt16"),
        ("DateTime", Payload.Metric(long_value=2**62), BadValue, "not a date between years 1 and 9999"),
        ("Int32[]", Payload.Metric(bytes_value=b"\x01\x02\x03"), BadValue, "3 bytes is not a whole number"),
        ("Double[]", Payload.Metric(bytes_value=b"\x00" * 12), BadValue, "8-byte values"),
        ("Boolean[]", Payload.Metric(bytes_value=b"\x09\x00"), BadValue, "starts with a 4-byte count"),
        ("Boolean[]", Payload.Metric(bytes_value=b"\x09\x00\x00\x00\xff"), BadValue,
         "of 9 values has 2 bytes of bits, got 1"),
        ("Boolean[]", Payload.Metric(bytes_value=b"\xff\xff\xff\xff\x00"), BadValue, "4294967295 values"),
        ("String[]", Payload.Metric(bytes_value=b"abc"), BadValue, "the last one has none"),
        ("String[]", Payload.Metric(bytes_value=b"ok\x00\xff\x00"), BadValue, "not UTF-8 (byte 3)"),
        ("DateTime[]", Payload.Metric(bytes_value=b"\xff" * 7 + b"\x7f"), BadValue, "not a date"),
    ],
)  # fmt: skip
def test_reading_refuses_with_a_reason(spec: str, metric: Payload.Metric, error: type, fragment: str) -> None:
    with pytest.raises(error) as info:
        get_metric_value(metric, T(spec))
    assert fragment in str(info.value)


def test_text_that_is_not_utf8_is_refused() -> None:
    # proto2 does not check UTF-8; the runtime hands such a string back as bytes.
    raw = bytes.fromhex("12 05 7a 03 61 ff 62")  # metrics { string_value: "a\xffb" }
    metric = Payload.FromString(raw).metrics[0]
    with pytest.raises(BadValue, match="not UTF-8"):
        get_metric_value(metric, T("String"))


# --- refusals: writing ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "value", "fragment"),
    [
        ("Int32", True, "needs an integer, got bool"),
        ("Int32", 1.0, "needs an integer, got float"),
        ("Int32", 2**31, "does not fit an Int32"),
        ("Byte", -1, "does not fit a UInt8"),
        ("UInt64", 2**64, "does not fit a UInt64"),
        ("Double", "1.5", "needs a number, got str"),
        ("Float", False, "needs a number, got bool"),
        ("Boolean", 1, "needs true or false"),
        ("String", 5, "needs text"),
        ("String", "\ud800", "lone surrogate"),
        ("DateTime", "2024-01-01", "needs a datetime"),
        ("Int16[]", 5, "needs a list"),
        ("Int16[]", [1, 70000], "does not fit"),
        ("Boolean[]", [True, 0], "element needs true or false"),
        ("String[]", ["a\x00b"], "cannot contain NUL"),
        ("String[]", [b"x"], "element needs text"),
        ("Double[]", [None], "a DoubleArray needs a number, got null"),
        ("Double", 10**400, "a Double cannot hold an integer beyond the range"),
        ("Float[]", [10**400], "a FloatArray cannot hold an integer beyond"),
        ("DateTime[]", [0], "needs a datetime"),
    ],
)
def test_writing_refuses_values_the_type_cannot_carry(spec: str, value: object, fragment: str) -> None:
    with pytest.raises(Unencodable) as info:
        set_metric_value(Payload.Metric(), T(spec), value)
    assert fragment in str(info.value)


def test_every_gateway_base_type_is_covered() -> None:
    assert {spec.base for spec in ALL_SPECS} == set(DataType)
