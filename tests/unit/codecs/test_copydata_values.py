"""Value encodings: round trips for every type, exact bytes, and every refusal."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta, timezone

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.copydata import (
    BadBoolean,
    BadFiletime,
    BadText,
    CopydataEncodeError,
    FieldOverflow,
    Layout,
    LengthOverrun,
    TruncatedHeader,
    Unencodable,
    ValueOutOfRange,
    ValueTypeError,
    WrongSize,
    decode_value,
    encode_value,
)
from gateway.model.types import INT_BOUNDS, DataType, TypeSpec
from tests.unit.codecs.copydata_strategies import ALL_SPECS, ENCODINGS, WIDTHS, same, values

T = TypeSpec.parse
UTF8 = Layout()


@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@given(data=st.data())
def test_every_type_round_trips(spec: TypeSpec, data: st.DataObject) -> None:
    encoding = data.draw(st.sampled_from(ENCODINGS), label="encoding")
    layout = Layout(len_width=data.draw(st.sampled_from(WIDTHS), label="len_width"), encoding=encoding)
    value = data.draw(values(spec, encoding), label="value")
    encoded = encode_value(spec, value, layout)
    assert same(decode_value(spec, encoded, layout), value)


@pytest.mark.parametrize("base", [b for b in DataType if b is not DataType.STRING], ids=str)
@given(data=st.data())
def test_arrays_are_their_elements_back_to_back(base: DataType, data: st.DataObject) -> None:
    elements = data.draw(values(TypeSpec(base, True)))
    joined = b"".join(encode_value(TypeSpec(base), v, UTF8) for v in elements)
    assert encode_value(TypeSpec(base, True), elements, UTF8) == joined


@pytest.mark.parametrize(
    ("type_name", "value", "hex_bytes"),
    [
        ("Double", 1234.5, "00 00 00 00 00 4a 93 40"),
        ("Double", -2.5, "00 00 00 00 00 00 04 c0"),
        ("Double", math.inf, "00 00 00 00 00 00 f0 7f"),
        ("Float", 1.0, "00 00 80 3f"),
        ("Float", -math.inf, "00 00 80 ff"),
        ("SByte", -1, "ff"),
        ("Byte", 200, "c8"),
        ("Int16", -2, "fe ff"),
        ("UInt16", 0x1234, "34 12"),
        ("Int32", -2, "fe ff ff ff"),
        ("UInt32", 0xDEADBEEF, "ef be ad de"),
        ("Int64", -(2**63), "00 00 00 00 00 00 00 80"),
        ("UInt64", 2**64 - 1, "ff ff ff ff ff ff ff ff"),
        ("Boolean", True, "01"),
        ("Boolean", False, "00"),
        ("String", "Grüße", "47 72 c3 bc c3 9f 65"),
        ("String", "", ""),
        # FILETIME of the Unix epoch: 116444736000000000 = 0x019DB1DED53E8000
        ("DateTime", datetime(1970, 1, 1, tzinfo=UTC), "00 80 3e d5 de b1 9d 01"),
        ("DateTime", datetime(1601, 1, 1, 0, 0, 0, 1, tzinfo=UTC), "0a 00 00 00 00 00 00 00"),
        ("Int16[]", [1, -1], "01 00 ff ff"),
        ("Boolean[]", [True, False, True], "01 00 01"),
        ("Double[]", [], ""),
        ("String[]", ["ab", "é", ""], "02 00 61 62 02 00 c3 a9 00 00"),
    ],
)
def test_known_answers(type_name: str, value: object, hex_bytes: str) -> None:
    """Hand-computed bytes: a mistake shared by encoder and decoder cannot cancel out here."""
    expected = bytes.fromhex(hex_bytes)
    assert encode_value(T(type_name), value, UTF8) == expected
    assert same(decode_value(T(type_name), expected, UTF8), value)


def test_text_follows_the_layout_encoding() -> None:
    assert encode_value(T("String"), "激光", Layout(encoding="gbk")) == bytes.fromhex("bca4 b9e2")
    assert encode_value(T("String"), "激光", Layout(encoding="utf-16-le")) == bytes.fromhex("c06f 4951")
    assert encode_value(T("String[]"), ["激"], Layout(encoding="gbk", len_width=1)) == bytes.fromhex(
        "02 bca4"
    )
    assert encode_value(T("String[]"), ["a"], Layout(len_width=4)) == bytes.fromhex("01000000 61")


def test_datetime_naive_is_utc_and_other_zones_are_converted() -> None:
    naive = datetime(2024, 5, 6, 7, 8, 9, 123456)
    aware = naive.replace(tzinfo=UTC)
    plus2 = aware.astimezone(timezone(timedelta(hours=2)))
    spec = T("DateTime")
    assert (
        encode_value(spec, naive, UTF8) == encode_value(spec, aware, UTF8) == encode_value(spec, plus2, UTF8)
    )
    assert decode_value(spec, encode_value(spec, plus2, UTF8), UTF8) == aware
    assert decode_value(spec, encode_value(spec, plus2, UTF8), UTF8).tzinfo is UTC


def test_sub_microsecond_filetime_ticks_are_truncated() -> None:
    # 7 ticks = 700 ns after 1601-01-01: below Python's resolution.
    assert decode_value(T("DateTime"), (17).to_bytes(8, "little"), UTF8) == datetime(
        1601, 1, 1, 0, 0, 0, 1, tzinfo=UTC
    )


def test_integral_floats_are_accepted_for_integer_types() -> None:
    assert encode_value(T("Int32"), 5.0, UTF8) == bytes.fromhex("05000000")
    assert encode_value(T("Byte[]"), [1.0, 2], UTF8) == bytes.fromhex("0102")


def test_integers_are_accepted_for_float_types() -> None:
    assert encode_value(T("Double"), 2, UTF8) == encode_value(T("Double"), 2.0, UTF8)
    assert encode_value(T("Float[]"), [1, 2.5], UTF8) == bytes.fromhex("0000803f 00002040")


# --- refusals: encoding ------------------------------------------------------------------------


@pytest.mark.parametrize("base", list(INT_BOUNDS), ids=str)
def test_integer_out_of_range_is_refused(base: DataType) -> None:
    lo, hi = INT_BOUNDS[base]
    assert decode_value(TypeSpec(base), encode_value(TypeSpec(base), hi, UTF8), UTF8) == hi
    for bad in (lo - 1, hi + 1):
        with pytest.raises(ValueOutOfRange, match=f"{bad} does not fit {base.value}"):
            encode_value(TypeSpec(base), bad, UTF8)


def test_300_as_byte_is_refused_with_the_bounds() -> None:
    with pytest.raises(ValueOutOfRange, match=r"300 does not fit Byte \(0\.\.255\)") as info:
        encode_value(T("Byte"), 300, UTF8)
    assert info.value.kind == "value_range" and info.value.offset is None


def test_array_element_out_of_range_names_the_element() -> None:
    with pytest.raises(ValueOutOfRange, match=r"element 2: 300 does not fit Byte"):
        encode_value(T("Byte[]"), [1, 2, 300, 4], UTF8)
    with pytest.raises(ValueOutOfRange, match=r"element 1: .* does not fit a 32-bit Float"):
        encode_value(T("Float[]"), [1.0, 1e39], UTF8)


def test_float_too_large_for_32_bits_is_refused() -> None:
    with pytest.raises(ValueOutOfRange, match="32-bit Float"):
        encode_value(T("Float"), 1e39, UTF8)
    with pytest.raises(ValueOutOfRange, match="does not fit Double"):
        encode_value(T("Double"), 10**400, UTF8)


def test_datetime_before_1601_is_refused() -> None:
    with pytest.raises(ValueOutOfRange, match="before 1601-01-01"):
        encode_value(T("DateTime"), datetime(1600, 12, 31, 23, 59, 59, tzinfo=UTC), UTF8)


@pytest.mark.parametrize(
    ("type_name", "value"),
    [
        ("Int32", True),
        ("Int32", 1.5),
        ("Int32", "5"),
        ("Double", "1.0"),
        ("Double", False),
        ("Double", None),
        ("Boolean", 1),
        ("Boolean", "true"),
        ("String", 5),
        ("String", b"bytes"),
        ("DateTime", "2024-01-01T00:00:00Z"),
        ("Double[]", 1.0),
        ("String[]", "abc"),
        ("Int16[]", [1, "2"]),
        ("Boolean[]", [True, 0]),
        ("String[]", ["a", 1]),
    ],
)
def test_wrong_python_types_are_refused(type_name: str, value: object) -> None:
    with pytest.raises(ValueTypeError) as info:
        encode_value(T(type_name), value, UTF8)
    assert isinstance(info.value, CopydataEncodeError) and info.value.kind == "value_type"


def test_text_the_encoding_cannot_represent_is_refused() -> None:
    with pytest.raises(Unencodable, match=r"'€' at position 3 cannot be encoded in latin-1"):
        encode_value(T("String"), "abc€", Layout(encoding="latin-1"))
    with pytest.raises(Unencodable, match=r"element 1: character '\\ud800'"):
        encode_value(T("String[]"), ["ok", "\ud800"], UTF8)


def test_string_array_element_longer_than_len_width_is_refused() -> None:
    with pytest.raises(FieldOverflow, match=r"element 1: 256 bytes do not fit a 1-byte length \(max 255\)"):
        encode_value(T("String[]"), ["a", "x" * 256], Layout(len_width=1))
    assert len(encode_value(T("String[]"), ["x" * 255], Layout(len_width=1))) == 256


# --- refusals: decoding ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("type_name", "size", "needed"),
    [
        ("Double", 7, 8),
        ("Double", 9, 8),
        ("Float", 8, 4),
        ("Int32", 2, 4),
        ("Boolean", 0, 1),
        ("DateTime", 4, 8),
    ],
)
def test_wrong_size_for_a_fixed_width_type(type_name: str, size: int, needed: int) -> None:
    with pytest.raises(WrongSize, match=f"{type_name} needs {needed} bytes, got {size}") as info:
        decode_value(T(type_name), bytes(size), UTF8)
    assert info.value.offset == 0


def test_array_with_a_partial_element_points_at_it() -> None:
    with pytest.raises(WrongSize, match=r"Int32\[\] needs a multiple of 4 bytes, got 10") as info:
        decode_value(T("Int32[]"), bytes(10), UTF8)
    assert info.value.offset == 8


@pytest.mark.parametrize("byte", [2, 0x80, 0xFF])
def test_boolean_byte_other_than_0_or_1(byte: int) -> None:
    with pytest.raises(BadBoolean, match=f"{byte:#04x} is neither 0 nor 1") as info:
        decode_value(T("Boolean"), bytes([byte]), UTF8)
    assert info.value.offset == 0


def test_boolean_array_points_at_the_first_bad_byte() -> None:
    with pytest.raises(BadBoolean) as info:
        decode_value(T("Boolean[]"), bytes([1, 0, 1, 7, 9]), UTF8)
    assert info.value.offset == 3


def test_invalid_text_points_at_the_bad_byte() -> None:
    with pytest.raises(BadText, match="not valid utf-8") as info:
        decode_value(T("String"), b"ab\xffcd", UTF8)
    assert info.value.offset == 2
    with pytest.raises(BadText, match="not valid utf-16-le") as info:
        decode_value(T("String"), b"a\x00b", Layout(encoding="utf-16-le"))
    assert info.value.offset == 2
    with pytest.raises(BadText) as info:
        decode_value(T("String[]"), bytes.fromhex("0100 61 0200 c3 28"), UTF8)
    assert info.value.offset == 5


def test_filetime_after_year_9999_is_refused() -> None:
    last = encode_value(T("DateTime"), datetime(9999, 12, 31, 23, 59, 59, 999999, tzinfo=UTC), UTF8)
    after = (int.from_bytes(last, "little") + 10).to_bytes(8, "little")
    with pytest.raises(BadFiletime, match="after 9999-12-31") as info:
        decode_value(T("DateTime"), after, UTF8)
    assert info.value.offset == 0
    with pytest.raises(BadFiletime) as info:
        decode_value(T("DateTime[]"), last + b"\xff" * 8, UTF8)
    assert info.value.offset == 8


def test_string_array_with_a_truncated_length_field() -> None:
    with pytest.raises(TruncatedHeader, match="element 1: 1 bytes left") as info:
        decode_value(T("String[]"), bytes.fromhex("0100 61 05"), UTF8)
    assert info.value.offset == 3


def test_string_array_element_longer_than_the_data() -> None:
    with pytest.raises(LengthOverrun, match="element 1 declares 5 bytes but only 2 remain") as info:
        decode_value(T("String[]"), bytes.fromhex("0100 61 0500 6263"), UTF8)
    assert info.value.offset == 3


@settings(max_examples=300)
@given(
    spec=st.sampled_from(ALL_SPECS),
    data=st.binary(max_size=40),
    layout_args=st.tuples(st.sampled_from(WIDTHS), st.sampled_from(ENCODINGS)),
)
def test_arbitrary_bytes_decode_or_raise_a_copydata_error(
    spec: TypeSpec, data: bytes, layout_args: tuple[int, str]
) -> None:
    from gateway.codecs.copydata import CopydataError

    layout = Layout(len_width=layout_args[0], encoding=layout_args[1])
    try:
        value = decode_value(spec, data, layout)
    except CopydataError as exc:
        assert exc.offset is None or 0 <= exc.offset <= len(data)
        return
    # Fixed-width values re-encode to the same bytes (Float NaN payloads and sub-microsecond
    # FILETIME ticks aside).
    if spec.base not in (DataType.STRING, DataType.DATETIME, DataType.FLOAT):
        assert encode_value(spec, value, layout) == data
