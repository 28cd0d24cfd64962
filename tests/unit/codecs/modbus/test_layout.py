"""Register layouts: known values in each word and byte order (worked out by hand, not by the codec),
and Hypothesis round trips value → registers → value for every kind and order."""

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.modbus.address import Field, Kind, Order, Table
from gateway.codecs.modbus.layout import decode, decoder, encode
from gateway.errors import OutOfRange, TypeMismatch


def field(kind: Kind, order: Order = Order.ABCD, count: int | None = None, **kw: object) -> Field:
    return Field(Table.HOLDING, 0, count or kind.registers, kind, order, **kw)  # type: ignore[arg-type]


# 123.456 as an IEEE-754 single is 0x42F6E979: bytes A=42 B=F6 C=E9 D=79.
FLOAT_123_456 = {
    Order.ABCD: [0x42F6, 0xE979],
    Order.CDAB: [0xE979, 0x42F6],
    Order.BADC: [0xF642, 0x79E9],
    Order.DCBA: [0x79E9, 0xF642],
}


@pytest.mark.parametrize("order", list(Order))
def test_float32_in_each_order(order: Order) -> None:
    registers = FLOAT_123_456[order]
    assert decode(field(Kind.FLOAT32, order), registers) == pytest.approx(123.456, rel=1e-7)
    assert encode(field(Kind.FLOAT32, order), 123.456) == registers


def test_known_integers() -> None:
    assert decode(field(Kind.INT16), [0xFFFE]) == -2
    assert decode(field(Kind.UINT16), [0xFFFE]) == 65534
    assert decode(field(Kind.INT16, Order.BADC), [0xFEFF]) == -2  # bytes swapped: 0xFFFE
    assert decode(field(Kind.INT16, Order.CDAB), [0xFFFE]) == -2  # one word: nothing to swap
    # 0x12345678: ABCD = [0x1234, 0x5678]
    assert decode(field(Kind.UINT32), [0x1234, 0x5678]) == 0x12345678
    assert decode(field(Kind.UINT32, Order.CDAB), [0x5678, 0x1234]) == 0x12345678
    assert decode(field(Kind.UINT32, Order.BADC), [0x3412, 0x7856]) == 0x12345678
    assert decode(field(Kind.UINT32, Order.DCBA), [0x7856, 0x3412]) == 0x12345678
    assert decode(field(Kind.INT32), [0xFFFF, 0xFFFF]) == -1
    # 0x0102030405060708 as 64 bits: ABCD keeps the words in order, CDAB reverses all four
    words = [0x0102, 0x0304, 0x0506, 0x0708]
    assert decode(field(Kind.UINT64), words) == 0x0102030405060708
    assert decode(field(Kind.UINT64, Order.CDAB), words[::-1]) == 0x0102030405060708
    assert decode(field(Kind.UINT64, Order.DCBA), [0x0807, 0x0605, 0x0403, 0x0201]) == 0x0102030405060708
    one = struct.unpack(">4H", struct.pack(">d", 1.0))
    assert decode(field(Kind.FLOAT64), list(one)) == 1.0


def test_strings_bits_and_floats_of_integers() -> None:
    assert decode(field(Kind.STRING, count=3), [0x4142, 0x4300, 0x5858]) == "ABC"  # ends at the NUL
    assert decode(field(Kind.STRING, Order.BADC, count=2), [0x4241, 0x0043]) == "ABC"
    assert decode(field(Kind.STRING, Order.CDAB, count=2), [0x4142, 0x4344]) == "ABCD"  # only bytes count
    assert encode(field(Kind.STRING, count=3), "AB") == [0x4142, 0, 0]
    assert decode(field(Kind.BIT, bit=3), [0b1000]) is True
    assert decode(field(Kind.BIT, bit=2), [0b1000]) is False
    assert decode(Field(Table.COIL, 0, 1, Kind.BOOL), [False, True], 1) is True
    value = decode(field(Kind.INT16, as_float=True), [7])
    assert value == 7.0 and isinstance(value, float)
    assert decoder(field(Kind.UINT16))([1, 2, 3], 2) == 3  # at an offset into a response


def test_writes_that_do_not_fit_are_refused() -> None:
    with pytest.raises(OutOfRange):
        encode(field(Kind.INT16), 40000)
    with pytest.raises(OutOfRange):
        encode(field(Kind.UINT16), -1)
    with pytest.raises(OutOfRange):
        encode(field(Kind.FLOAT32), 1e39)
    with pytest.raises(OutOfRange):
        encode(field(Kind.STRING, count=1), "ABC")
    with pytest.raises(OutOfRange):
        encode(field(Kind.STRING, count=4), "€")
    with pytest.raises(TypeMismatch):
        encode(field(Kind.INT16), "7")
    with pytest.raises(TypeMismatch):
        encode(field(Kind.INT16), True)
    with pytest.raises(TypeMismatch):
        encode(field(Kind.BIT, bit=1), 1)
    assert encode(field(Kind.INT16), 12.6) == [13]  # a scaled write arrives as a float: rounded


_INT_RANGES = {
    Kind.INT16: (-(2**15), 2**15 - 1), Kind.UINT16: (0, 2**16 - 1),
    Kind.INT32: (-(2**31), 2**31 - 1), Kind.UINT32: (0, 2**32 - 1),
    Kind.INT64: (-(2**63), 2**63 - 1), Kind.UINT64: (0, 2**64 - 1),
}  # fmt: skip


@st.composite
def kind_and_value(draw: st.DrawFn) -> tuple[Field, object]:
    kind = draw(st.sampled_from(list(Kind)))
    order = draw(st.sampled_from(list(Order)))
    if kind in _INT_RANGES:
        low, high = _INT_RANGES[kind]
        return field(kind, order), draw(st.integers(low, high))
    if kind is Kind.FLOAT32:
        return field(kind, order), draw(st.floats(width=32, allow_nan=False))
    if kind is Kind.FLOAT64:
        return field(kind, order), draw(st.floats(allow_nan=False))
    if kind is Kind.STRING:
        count = draw(st.integers(1, 20))
        alphabet = st.characters(min_codepoint=1, max_codepoint=255)
        return field(kind, order, count), draw(st.text(alphabet, max_size=2 * count))
    if kind is Kind.BIT:
        return field(kind, bit=draw(st.integers(0, 15))), draw(st.booleans())
    return Field(Table.COIL, 0, 1, Kind.BOOL), draw(st.booleans())


@given(kind_and_value())
def test_every_kind_and_order_round_trips(case: tuple[Field, object]) -> None:
    f, value = case
    registers = encode(f, value)
    assert len(registers) == f.count
    assert all(0 <= r <= 0xFFFF for r in registers)
    if f.kind is Kind.BIT:  # a bit is written into its register by the driver (read-modify-write)
        registers = [(1 << (f.bit or 0)) if registers[0] else 0]
    back = decode(f, registers)
    if isinstance(value, float) and math.isinf(value):
        assert back == value
    else:
        assert back == value


@given(st.lists(st.integers(0, 0xFFFF), min_size=4, max_size=4), st.sampled_from(list(Order)),
       st.sampled_from([Kind.INT32, Kind.UINT32, Kind.INT64, Kind.UINT64, Kind.FLOAT64]))  # fmt: skip
def test_every_register_pattern_round_trips(registers: list[int], order: Order, kind: Kind) -> None:
    f = field(kind, order)
    words = registers[: f.count]
    assert encode(f, decode(f, words)) == words
