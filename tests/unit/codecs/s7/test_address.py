"""S7 sources in STEP 7's notation: parsed strictly, printed back the same way, resolved against types."""

import pytest

from gateway.codecs.s7.address import Area, Kind, S7Address, S7AddressError, overlaps, parse_address, resolve

A = S7Address


@pytest.mark.parametrize(
    ("text", "expected", "canonical"),
    [
        ("DB10.DBD4", A(Area.DB, 10, 4, None, 4), "DB10.DBD4"),
        ("db10.dbx2.3", A(Area.DB, 10, 2, 3, 0, Kind.BOOL), "DB10.DBX2.3"),
        ("DB5.DBW0", A(Area.DB, 5, 0, None, 2), "DB5.DBW0"),
        ("DB1.DBB7", A(Area.DB, 1, 7, None, 1), "DB1.DBB7"),
        ("MW20", A(Area.FLAGS, 0, 20, None, 2), "MW20"),
        ("M0.1", A(Area.FLAGS, 0, 0, 1, 0, Kind.BOOL), "M0.1"),
        ("I0.1", A(Area.INPUTS, 0, 0, 1, 0, Kind.BOOL), "I0.1"),
        ("E0.1", A(Area.INPUTS, 0, 0, 1, 0, Kind.BOOL), "I0.1"),
        ("Q4.0", A(Area.OUTPUTS, 0, 4, 0, 0, Kind.BOOL), "Q4.0"),
        ("AW4", A(Area.OUTPUTS, 0, 4, None, 2), "QW4"),
        ("ID8:REAL", A(Area.INPUTS, 0, 8, None, 4, Kind.REAL), "ID8:REAL"),
        ("DB5.DBB20:STRING[30]", A(Area.DB, 5, 20, None, 1, Kind.STRING, 30), "DB5.DBB20:STRING[30]"),
        ("DB5.DBB20 : string(30)", A(Area.DB, 5, 20, None, 1, Kind.STRING, 30), "DB5.DBB20:STRING[30]"),
        ("DB10.DBB40:DT", A(Area.DB, 10, 40, None, 1, Kind.DATE_AND_TIME), "DB10.DBB40:DATE_AND_TIME"),
        ("DB10.DBB8:LREAL", A(Area.DB, 10, 8, None, 1, Kind.LREAL), "DB10.DBB8:LREAL"),
        ("MD4:DINT", A(Area.FLAGS, 0, 4, None, 4, Kind.DINT), "MD4:DINT"),
    ],
)
def test_parses_the_notation_people_use(text: str, expected: S7Address, canonical: str) -> None:
    parsed = parse_address(text)
    assert parsed == expected
    assert str(parsed) == canonical
    assert parse_address(str(parsed)) == parsed


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("", "must not be empty"),
        ("DB0.DBW2", "numbered 1-65535"),
        ("DB1.DBX2", "needs its bit"),
        ("M9.8", "0-7"),
        ("DB1.DBW2.1", "only bit addresses"),
        ("DB1.DBW2:REAL", "takes 4 bytes, the address names 2"),
        ("DB10.DBD4:LREAL", r"starts at a byte \(DBB, MB\): DB10.DBB4:LREAL"),
        ("DB1.DBB2:STRING", "declared length"),
        ("DB1.DBB2:STRING[255]", "1 to 254"),
        ("DB1.DBB2:FLOAT", "not an S7 type"),
        ("DB1.DBX0.0:INT", "a BOOL, not INT"),
        ("DB1.DBW0:BOOL", "a BOOL is a bit address"),
        ("T5", "not an S7 address"),
        ("DB1.DBB2097152", "past 2097151"),
    ],
)
def test_refuses_what_is_not_an_address(text: str, says: str) -> None:
    with pytest.raises(S7AddressError, match=says):
        parse_address(text)


def test_types_follow_the_width_and_the_variable() -> None:
    assert resolve(parse_address("DB1.DBD0"), "Float").kind is Kind.REAL
    assert resolve(parse_address("DB1.DBD0"), "Int32").kind is Kind.DINT
    assert resolve(parse_address("DB1.DBD0"), "UInt32").kind is Kind.DWORD
    assert resolve(parse_address("DB1.DBW0"), "Int16").kind is Kind.INT
    assert resolve(parse_address("DB1.DBW0"), "UInt16").kind is Kind.WORD
    assert resolve(parse_address("DB1.DBW0:INT"), "Double").as_float
    assert resolve(parse_address("DB1.DBB0:STRING[30]"), "String").size == 32
    assert resolve(parse_address("DB1.DBX3.7"), "Boolean").bit == 7
    for text, type_name, says in [
        ("DB1.DBB0", "Double", "DB1.DBB0:LREAL"),
        ("DB1.DBW0", "String", r"DB1.DBB0:STRING\[30\]"),
        ("DB1.DBD0:REAL", "Int32", "lose its fraction"),
        ("DB1.DBX0.0", "Int16", "must be Boolean"),
        ("DB1.DBB0:DT", "String", "must be DateTime"),
        ("DB1.DBW0", "Int16[]", "scalars"),
    ]:
        with pytest.raises(S7AddressError, match=says):
            resolve(parse_address(text), type_name)


def test_overlaps() -> None:
    fields = [
        resolve(parse_address("DB1.DBD0"), "Float"),
        resolve(parse_address("DB1.DBD2"), "Float"),  # shares 2-3 with the first
        resolve(parse_address("DB1.DBB8"), "Byte"),
        resolve(parse_address("DB1.DBX8.0"), "Boolean"),  # a bit of that byte: fine
        resolve(parse_address("DB1.DBX8.0"), "Boolean"),  # the same bit again
        resolve(parse_address("DB2.DBD0"), "Float"),  # another block
    ]
    assert overlaps(fields) == [(1, 0), (4, 3)]
