"""Modbus sources as mappings write them: parsed strictly, reported back 0-based, resolved against the
variable's type; and the overlaps the loader refuses."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.modbus.address import (
    Field,
    Kind,
    ModbusAddress,
    ModbusAddressError,
    Order,
    Table,
    overlaps,
    parse_address,
    resolve,
)

H, IN = Table.HOLDING, Table.INPUT
A, K, Ord = ModbusAddress, Kind, Order


@pytest.mark.parametrize(
    ("text", "expected", "canonical"),
    [
        ("holding:100", A(H, 100), "holding:100"),
        ("hr:100", A(H, 100), "holding:100"),
        ("40101", A(H, 100), "holding:100"),
        ("400101", A(H, 100), "holding:100"),
        ("40001", A(H, 0), "holding:0"),
        ("465536", A(H, 65535), "holding:65535"),
        ("30001:float32:CDAB", A(IN, 0, None, K.FLOAT32, None, Ord.CDAB), "input:0:float32:CDAB"),
        ("00008", A(Table.COIL, 7, None, K.BOOL), "coil:7"),
        ("10003", A(Table.DISCRETE, 2, None, K.BOOL), "discrete:2"),
        ("coil:7", A(Table.COIL, 7, None, K.BOOL), "coil:7"),
        ("di:12:bool", A(Table.DISCRETE, 12, None, K.BOOL), "discrete:12"),
        ("holding:3.5", A(H, 3, 5, K.BIT), "holding:3.5"),
        ("40004.15", A(H, 3, 15, K.BIT), "holding:3.15"),
        ("ir:9:int64:dcba", A(IN, 9, None, K.INT64, None, Ord.DCBA), "input:9:int64:DCBA"),
        ("holding:200:string[8]", A(H, 200, None, K.STRING, 8), "holding:200:string[8]"),
        ("hr:200:string(8):BADC", A(H, 200, None, K.STRING, 8, Ord.BADC), "holding:200:string[8]:BADC"),
        (" hr : 5 : CDAB : uint32 ", A(H, 5, None, K.UINT32, None, Ord.CDAB), "holding:5:uint32:CDAB"),
    ],
)  # fmt: skip
def test_parses_and_reports_back_zero_based(text: str, expected: ModbusAddress, canonical: str) -> None:
    parsed = parse_address(text)
    assert parsed == expected
    assert str(parsed) == canonical
    assert parse_address(str(parsed)) == parsed


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "must not be empty"),
        ("100", "give the table"),
        ("50001", "give the table"),
        ("40000", "counts from 1"),
        ("holding", "no address"),
        ("holding:70000", "past 65535"),
        ("465537", "past 65535"),
        ("holding:65535:float32", "past 65535"),
        ("holding:65530:string[8]", "past 65535"),
        ("holding:1:float", "not a Modbus type"),
        ("holding:1:string", "needs its length"),
        ("holding:1:string[0]", "1 to 125"),
        ("holding:1:string[126]", "1 to 125"),
        ("holding:1.16", "0-15"),
        ("holding:1:bool", "holds 16 bits"),
        ("holding:1.3:float32", "no other type"),
        ("coil:1.2", "single bit already"),
        ("coil:1:int16", "holds one bit"),
        ("coil:1:ABCD", "holds one bit"),
        ("register:1", "not a Modbus table"),
        ("holding:x", "not an address"),
        ("holding:1:ABCD:CDAB", "two word orders"),
        ("holding:1:int16:uint16", "neither an order"),
    ],
)
def test_refuses_what_is_not_an_address(text: str, says: str) -> None:
    with pytest.raises(ModbusAddressError, match=says):
        parse_address(text)


def _spec(name: str) -> str:
    return name


def test_resolves_the_kind_from_the_variable_type() -> None:
    assert resolve(parse_address("holding:4"), _spec("Float")) == Field(
        Table.HOLDING, 4, 2, Kind.FLOAT32, Order.ABCD, None, True
    )
    assert resolve(parse_address("holding:4"), _spec("Int32"), Order.CDAB).order is Order.CDAB
    assert resolve(parse_address("holding:4:DCBA"), _spec("Int32"), Order.CDAB).order is Order.DCBA
    assert resolve(parse_address("holding:4"), _spec("UInt64")).count == 4
    assert resolve(parse_address("input:4:int16"), _spec("Double")).as_float
    assert resolve(parse_address("holding:4.2"), _spec("Boolean")).kind is Kind.BIT
    assert resolve(parse_address("coil:4"), _spec("Boolean")).count == 1
    assert resolve(parse_address("holding:4:string[3]"), _spec("String")).count == 3


@pytest.mark.parametrize(
    ("text", "type_name", "says"),
    [
        ("holding:4", "Boolean", "coil, a discrete input or a bit"),
        ("holding:4", "String", "length in registers"),
        ("holding:4", "DateTime", "no Modbus layout"),
        ("coil:4", "Int16", "must be Boolean"),
        ("holding:4.1", "Double", "must be Boolean"),
        ("holding:4:string[2]", "Int16", "must be String"),
        ("holding:4:int16", "String", "cannot hold it"),
        ("holding:4:float32", "Int32", "lose its fraction"),
        ("holding:4", "Double[]", "scalars"),
    ],
)
def test_refuses_a_variable_type_the_field_cannot_hold(text: str, type_name: str, says: str) -> None:
    with pytest.raises(ModbusAddressError, match=says):
        resolve(parse_address(text), _spec(type_name))


def test_overlaps_are_found_but_bits_of_one_register_may_stand_together() -> None:
    fields = [
        resolve(parse_address("holding:100:float32"), _spec("Float")),  # 100-101
        resolve(parse_address("holding:101:float32"), _spec("Float")),  # 101-102: overlaps 0
        resolve(parse_address("holding:103"), _spec("UInt16")),
        resolve(parse_address("holding:103.0"), _spec("Boolean")),  # a bit of the word beside it: fine
        resolve(parse_address("holding:103.1"), _spec("Boolean")),
        resolve(parse_address("holding:103.1"), _spec("Boolean")),  # the same bit twice: 5 overlaps 4
        resolve(parse_address("input:100:float32"), _spec("Float")),  # another table
        resolve(parse_address("coil:100"), _spec("Boolean")),
        resolve(parse_address("coil:100"), _spec("Boolean")),  # 8 overlaps 7
    ]
    assert overlaps(fields) == [(1, 0), (5, 4), (8, 7)]


@given(
    st.sampled_from(list(Table)),
    st.integers(0, 65535),
    st.sampled_from([k for k in Kind if k not in (Kind.BOOL, Kind.BIT, Kind.STRING)]),
    st.sampled_from([None, *Order]),
)
def test_any_register_address_reads_back_as_itself(
    table: Table, address: int, kind: Kind, order: Order | None
) -> None:
    if table.bits or address + kind.registers - 1 > 65535:
        return
    parsed = ModbusAddress(table, address, None, kind, None, order)
    assert parse_address(str(parsed)) == parsed
