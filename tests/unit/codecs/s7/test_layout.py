"""S7 values: known encodings (from the S7 manuals' examples) and Hypothesis round trips for every type."""

import math
import struct
from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.s7.address import Area, Field, Kind
from gateway.codecs.s7.layout import S7ValueError, decode, encode
from gateway.errors import OutOfRange, TypeMismatch


def field(kind: Kind, length: int | None = None, bit: int | None = None) -> Field:
    size = (length or 0) + 2 if kind is Kind.STRING else kind.size
    return Field(Area.DB, 1, 0, size, kind, bit, length)


def test_known_encodings() -> None:
    assert decode(field(Kind.REAL), bytes.fromhex("42F6E979")) == pytest.approx(123.456)
    assert decode(field(Kind.INT), bytes.fromhex("FFFE")) == -2
    assert decode(field(Kind.WORD), bytes.fromhex("FFFE")) == 65534
    assert decode(field(Kind.DINT), bytes.fromhex("FFFFFFFF")) == -1
    assert decode(field(Kind.BOOL, bit=5), bytes((0b00100000,))) is True
    # STRING[10] holding 'ABC': declared 10, current 3, then the characters
    assert decode(field(Kind.STRING, 10), b"\x0a\x03ABC\x00\x00\x00\x00\x00\x00\x00") == "ABC"
    assert encode(field(Kind.STRING, 4), "AB") == b"\x04\x02AB\x00\x00"
    # DT#2024-05-01-13:45:07.123, a Wednesday (4)
    dt = bytes.fromhex("2405011345071234")
    assert decode(field(Kind.DATE_AND_TIME), dt) == datetime(2024, 5, 1, 13, 45, 7, 123000, tzinfo=UTC)
    assert encode(field(Kind.DATE_AND_TIME), datetime(2024, 5, 1, 13, 45, 7, 123000, tzinfo=UTC)) == dt
    assert decode(field(Kind.DATE_AND_TIME), bytes.fromhex("9912311259590001")).year == 1999


def test_what_does_not_fit_is_refused() -> None:
    with pytest.raises(OutOfRange):
        encode(field(Kind.INT), 40000)
    with pytest.raises(OutOfRange):
        encode(field(Kind.STRING, 2), "ABC")
    with pytest.raises(OutOfRange):
        encode(field(Kind.DATE_AND_TIME), datetime(2090, 1, 1, tzinfo=UTC))
    with pytest.raises(TypeMismatch):
        encode(field(Kind.REAL), "1.0")
    with pytest.raises(TypeMismatch):
        encode(field(Kind.BOOL, bit=0), 1)
    with pytest.raises(S7ValueError):
        decode(field(Kind.DATE_AND_TIME), bytes(8))  # month 0: an uninitialised DT
    with pytest.raises(S7ValueError):
        decode(field(Kind.DATE_AND_TIME), bytes.fromhex("2A05011345071234"))  # not BCD


_INTS = {Kind.BYTE: (0, 255), Kind.USINT: (0, 255), Kind.SINT: (-128, 127), Kind.WORD: (0, 65535),
         Kind.UINT: (0, 65535), Kind.INT: (-32768, 32767), Kind.DWORD: (0, 2**32 - 1),
         Kind.UDINT: (0, 2**32 - 1), Kind.DINT: (-(2**31), 2**31 - 1), Kind.LINT: (-(2**63), 2**63 - 1),
         Kind.ULINT: (0, 2**64 - 1)}  # fmt: skip


@st.composite
def values(draw: st.DrawFn) -> tuple[Field, object]:
    kind = draw(st.sampled_from(list(Kind)))
    if kind in _INTS:
        return field(kind), draw(st.integers(*_INTS[kind]))
    if kind is Kind.REAL:
        return field(kind), draw(st.floats(width=32, allow_nan=False))
    if kind is Kind.LREAL:
        return field(kind), draw(st.floats(allow_nan=False))
    if kind is Kind.BOOL:
        return field(kind, bit=draw(st.integers(0, 7))), draw(st.booleans())
    if kind is Kind.STRING:
        length = draw(st.integers(1, 254))
        text = draw(st.text(st.characters(min_codepoint=0, max_codepoint=255), max_size=length))
        return field(kind, length), text
    moment = draw(
        st.datetimes(datetime(1990, 1, 1), datetime(2089, 12, 31, 23, 59, 59), timezones=st.just(UTC))
    )
    return field(kind), moment.replace(microsecond=moment.microsecond // 1000 * 1000)


@given(values())
def test_every_type_round_trips(case: tuple[Field, object]) -> None:
    f, value = case
    data = encode(f, value)
    if f.kind is Kind.BOOL:  # written as a bit: the byte holds it at its place
        data = bytes(((1 << (f.bit or 0)) if data[0] else 0,))
    assert len(data) == f.size
    back = decode(f, data)
    if isinstance(value, float) and math.isnan(value):
        assert math.isnan(back)
    else:
        assert back == value


@given(st.binary(min_size=8, max_size=8))
def test_eight_bytes_as_lreal_round_trip_bit_for_bit(data: bytes) -> None:
    f = field(Kind.LREAL)
    assert encode(f, decode(f, data)) == data or math.isnan(struct.unpack(">d", data)[0])
