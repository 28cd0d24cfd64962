"""COPYDATA frames: known answers, round trips over every width, and one test per malformed case."""

from __future__ import annotations

import itertools
from datetime import UTC, datetime
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.copydata import (
    WM_COPYDATA,
    BadBoolean,
    BadText,
    CopydataError,
    FieldOverflow,
    Frame,
    FrameDecoder,
    FrameTooLarge,
    Item,
    ItemCountMismatch,
    Layout,
    LengthOverrun,
    TrailingBytes,
    TruncatedFrame,
    TruncatedHeader,
    UnknownDwData,
    UnknownId,
    ValueOutOfRange,
    ValueTypeError,
    Variable,
    VariableTable,
    WrongSize,
    copydatastruct_layout,
    decode_lpdata,
    encode_lpdata,
    encode_multi,
    encode_single,
    pack_copydatastruct,
    pack_tcp,
    unpack_datagram,
)
from gateway.model.types import TypeSpec
from tests.unit.codecs.copydata_strategies import ALL_SPECS, ENCODINGS, WIDTHS, same, values

T = TypeSpec.parse
DEFAULT = Layout()


def hexb(text: str) -> bytes:
    """Hex with spaces and '|' separators, as written in the known answers below."""
    return bytes.fromhex(text.replace("|", " "))


def decode_tcp(wire: bytes, layout: Layout) -> list[Frame]:
    decoder = FrameDecoder(layout)
    frames = decoder.feed(wire)
    decoder.feed_eof()
    return frames


# --- known answers (hand-computed) -----------------------------------------------------------


def test_known_answer_single_double() -> None:
    # dwData=1 | cbData=12 | id 1 | length 8 | -2.5 = 0xC004000000000000
    wire = hexb("01 00 00 00 | 0c 00 00 00 | 01 00 | 08 00 | 00 00 00 00 00 00 04 c0")
    table = VariableTable([Variable(1, "Axes/X/Position", T("Double"))])

    frame = table.encode({1: -2.5}, DEFAULT)
    assert frame == Frame(1, (Item(1, hexb("00 00 00 00 00 00 04 c0")),))
    assert pack_tcp(frame, DEFAULT) == wire
    assert encode_single(frame.items[0], DEFAULT) == wire[8:]

    [decoded] = decode_tcp(wire, DEFAULT)
    assert decoded == frame
    [reading] = table.decode(decoded, DEFAULT)
    assert reading.variable.name == "Axes/X/Position" and reading.value == -2.5


def test_known_answer_multi_int32_and_utf8_string() -> None:
    # dwData=2 | cbData=19 | id 3, length 4, Int32 -2 | id 0x0102, length 7, "Grüße" in utf-8
    lpdata = hexb("03 00 | 04 00 | fe ff ff ff | 02 01 | 07 00 | 47 72 c3 bc c3 9f 65")
    wire = hexb("02 00 00 00 | 13 00 00 00") + lpdata
    table = VariableTable.from_ids({3: ("Machine/State", "Int32"), 0x0102: ("Program/Name", "String")})

    frame = table.encode([(3, -2), (0x0102, "Grüße")], DEFAULT)
    assert frame.dwdata == 2
    assert encode_multi(frame.items, DEFAULT) == lpdata
    assert pack_tcp(frame, DEFAULT) == wire

    assert decode_lpdata(2, lpdata, DEFAULT) == frame
    assert [(r.variable.id, r.value) for r in table.decode(frame, DEFAULT)] == [(3, -2), (0x0102, "Grüße")]


@pytest.mark.parametrize(
    ("layout", "item", "lpdata"),
    [
        (Layout(id_width=1, len_width=4), Item(200, hexb("34 12")), "c8 | 02 00 00 00 | 34 12"),
        (Layout(id_width=4, len_width=1), Item(0x01020304, hexb("ab")), "04 03 02 01 | 01 | ab"),
        (Layout(id_width=1, len_width=1), Item(255, b""), "ff | 00"),
        (Layout(id_width=4, len_width=4), Item(2**32 - 1, b"\x01"), "ff ff ff ff | 01 00 00 00 | 01"),
    ],
)
def test_known_answer_other_widths(layout: Layout, item: Item, lpdata: str) -> None:
    assert encode_single(item, layout) == hexb(lpdata)
    assert decode_lpdata(1, hexb(lpdata), layout) == Frame.single(item)


# --- round trips -----------------------------------------------------------------------------


@pytest.mark.parametrize(("id_width", "len_width"), list(itertools.product(WIDTHS, WIDTHS)))
@pytest.mark.parametrize("spec", ALL_SPECS, ids=str)
@settings(max_examples=10)
@given(data=st.data())
def test_every_type_round_trips_through_tcp_for_every_width(
    id_width: int, len_width: int, spec: TypeSpec, data: st.DataObject
) -> None:
    encoding = data.draw(st.sampled_from(ENCODINGS), label="encoding")
    layout = Layout(id_width=id_width, len_width=len_width, encoding=encoding)
    var_id = data.draw(st.integers(0, layout.max_id), label="id")
    value = data.draw(values(spec, encoding), label="value")
    table = VariableTable([Variable(var_id, "V", spec)])
    try:
        frame = table.encode({var_id: value}, layout)
    except FieldOverflow:
        # Only a length wider than len_width may be refused, and only with 1-byte lengths.
        assert len_width == 1
        return
    [decoded] = decode_tcp(pack_tcp(frame, layout), layout)
    assert decoded == frame
    [reading] = table.decode(decoded, layout)
    assert same(reading.value, value)


@pytest.mark.parametrize(("id_width", "len_width"), list(itertools.product(WIDTHS, WIDTHS)))
@settings(max_examples=30)
@given(data=st.data())
def test_multi_frames_round_trip_for_every_width(id_width: int, len_width: int, data: st.DataObject) -> None:
    layout = Layout(id_width=id_width, len_width=len_width, encoding=data.draw(st.sampled_from(ENCODINGS)))
    ids = data.draw(st.lists(st.integers(0, layout.max_id), min_size=1, max_size=6, unique=True), label="ids")
    specs = [data.draw(st.sampled_from(ALL_SPECS)) for _ in ids]
    table = VariableTable(Variable(i, f"V{i}", s) for i, s in zip(ids, specs, strict=True))
    pairs: list[tuple[int, Any]] = [
        (i, data.draw(values(s, layout.encoding))) for i, s in zip(ids, specs, strict=True)
    ]
    if len_width == 1:  # keep every item under 256 bytes
        pairs = [(i, v) for i, v in pairs if len(table[i].encode(v, layout).data) <= 255] or [(ids[0], None)]
        if pairs[0][1] is None:
            return
    frame = table.encode(pairs, layout)
    assert frame.dwdata == (1 if len(pairs) == 1 else 2)
    wire = pack_tcp(frame, layout)
    assert unpack_datagram(wire, layout) == frame
    [decoded] = decode_tcp(wire, layout)
    assert decoded == frame
    got = [(r.variable.id, r.value) for r in table.decode(decoded, layout)]
    assert [i for i, _ in got] == [i for i, _ in pairs]
    assert all(same(a, b) for (_, a), (_, b) in zip(got, pairs, strict=True))


def test_dwdata_2_with_one_item_is_valid() -> None:
    frame = Frame.multi([Item(1, b"\x01")])
    assert decode_tcp(pack_tcp(frame, DEFAULT), DEFAULT) == [frame]


# --- malformed lpData: one test per case -------------------------------------------------------


def test_length_past_the_end_of_lpdata() -> None:
    lpdata = hexb("01 00 | 01 00 | 07 | 02 00 | 09 00 | 41 42 43")
    with pytest.raises(
        LengthOverrun, match=r"item 1 \(id 2\) declares 9 data bytes but only 3 remain"
    ) as info:
        decode_lpdata(2, lpdata, DEFAULT)
    assert info.value.offset == 7  # the length field of the second item
    assert info.value.kind == "length_overrun"


@pytest.mark.parametrize("dwdata", [0, 3, 0xFFFFFFFF])
def test_unknown_dwdata(dwdata: int) -> None:
    with pytest.raises(UnknownDwData, match=f"dwData {dwdata} is neither 1"):
        decode_lpdata(dwdata, hexb("01 00 01 00 01"), DEFAULT)
    with pytest.raises(UnknownDwData) as info:
        unpack_datagram(dwdata.to_bytes(4, "little") + hexb("05 00 00 00 01 00 01 00 01"), DEFAULT)
    assert info.value.offset == 0
    with pytest.raises(UnknownDwData):
        encode_lpdata(Frame(dwdata, (Item(1, b"\x01"),)), DEFAULT)


@pytest.mark.parametrize(("tail", "left"), [("05", 1), ("05 00", 2), ("05 00 01", 3)])
def test_truncated_item_header(tail: str, left: int) -> None:
    lpdata = hexb("01 00 | 01 00 | 01 |" + tail)
    with pytest.raises(
        TruncatedHeader, match=f"item 1: {left} bytes left, its id and length fields need 4"
    ) as info:
        decode_lpdata(2, lpdata, DEFAULT)
    assert info.value.offset == 5


def test_truncated_header_respects_the_widths() -> None:
    with pytest.raises(TruncatedHeader, match="need 8"):
        decode_lpdata(1, hexb("01 00 00 00 | 01 00 00"), Layout(id_width=4, len_width=4))


def test_truncated_frame_header_in_a_datagram() -> None:
    with pytest.raises(TruncatedFrame, match="datagram of 5 bytes is shorter than the 8-byte frame header"):
        unpack_datagram(hexb("01 00 00 00 05"), DEFAULT)


def test_truncated_lpdata_in_a_datagram() -> None:
    with pytest.raises(TruncatedFrame, match="cbData says 5 bytes but the datagram holds 4"):
        unpack_datagram(hexb("01 00 00 00 | 05 00 00 00 | 01 00 01 00"), DEFAULT)


def test_trailing_bytes_in_a_datagram() -> None:
    with pytest.raises(TrailingBytes, match="2 bytes follow") as info:
        unpack_datagram(hexb("01 00 00 00 | 05 00 00 00 | 01 00 01 00 01 | ee ee"), DEFAULT)
    assert info.value.offset == 13


def test_datagram_errors_inside_lpdata_count_from_the_datagram_start() -> None:
    with pytest.raises(LengthOverrun) as info:
        unpack_datagram(hexb("02 00 00 00 | 05 00 00 00 | 01 00 09 00 01"), DEFAULT)
    assert info.value.offset == 10


def test_cbdata_over_the_maximum() -> None:
    layout = Layout(max_cbdata=16)
    with pytest.raises(FrameTooLarge, match="cbData 17 is over max_cbdata 16"):
        decode_lpdata(2, bytes(17), layout)
    with pytest.raises(FrameTooLarge) as info:
        unpack_datagram(hexb("02 00 00 00 | 11 00 00 00"), layout)  # refused before lpData is even looked at
    assert info.value.offset == 4


def test_encoding_over_the_maximum_is_refused() -> None:
    layout = Layout(max_cbdata=16)
    assert len(encode_single(Item(1, bytes(12)), layout)) == 16
    with pytest.raises(FrameTooLarge, match="lpData would be 17 bytes, over max_cbdata 16"):
        encode_single(Item(1, bytes(13)), layout)


def test_id_not_in_the_table() -> None:
    table = VariableTable.from_ids({1: ("A", "Byte")})
    frame = decode_lpdata(2, hexb("01 00 | 01 00 | 07 | 63 00 | 01 00 | 08"), DEFAULT)  # framing is fine
    with pytest.raises(UnknownId, match="id 99 is not in the variable table") as info:
        table.decode(frame, DEFAULT)
    assert info.value.offset == 5
    with pytest.raises(UnknownId):
        table.encode({99: 1}, DEFAULT)


def test_value_errors_count_from_the_start_of_lpdata_and_name_the_variable() -> None:
    table = VariableTable.from_ids({1: ("A", "Byte"), 2: ("Laser/On", "Boolean"), 3: ("Name", "String")})
    frame = decode_lpdata(2, hexb("01 00 01 00 07 | 02 00 01 00 05"), DEFAULT)
    with pytest.raises(BadBoolean, match=r"^Laser/On \(id 2, Boolean\): Boolean byte 0x05") as info:
        table.decode(frame, DEFAULT)
    assert info.value.offset == 9
    frame = decode_lpdata(2, hexb("01 00 01 00 07 | 03 00 03 00 61 62 ff"), DEFAULT)
    with pytest.raises(BadText) as text_info:
        table.decode(frame, DEFAULT)
    assert text_info.value.offset == 11
    frame = decode_lpdata(1, hexb("01 00 02 00 07 07"), DEFAULT)
    with pytest.raises(WrongSize, match="Byte needs 1 bytes, got 2") as size_info:
        table.decode(frame, DEFAULT)
    assert size_info.value.offset == 4


@pytest.mark.parametrize(
    ("lpdata", "message", "offset"),
    [
        ("", "exactly one item, this lpData is empty", 0),
        ("01 00 01 00 07 | 02 00 01 00 08", "exactly one item, but 5 more bytes follow it", 5),
        ("01 00 01 00 07 | 02", "exactly one item, but 1 more bytes follow it", 5),
    ],
)
def test_dwdata_1_with_other_than_one_item(lpdata: str, message: str, offset: int) -> None:
    with pytest.raises(ItemCountMismatch, match=message) as info:
        decode_lpdata(1, hexb(lpdata), DEFAULT)
    assert info.value.offset == offset


def test_dwdata_1_encode_with_other_than_one_item() -> None:
    for items in ((), (Item(1, b"a"), Item(2, b"b"))):
        with pytest.raises(ItemCountMismatch, match=f"exactly one item, this one has {len(items)}"):
            pack_tcp(Frame(1, items), DEFAULT)


def test_dwdata_2_without_items() -> None:
    with pytest.raises(ItemCountMismatch, match="at least one item"):
        decode_lpdata(2, b"", DEFAULT)
    with pytest.raises(ItemCountMismatch, match="at least one item"):
        encode_multi([], DEFAULT)


def test_value_that_does_not_fit_its_type_names_the_variable() -> None:
    table = VariableTable.from_ids({4: ("Feed/Override", "Byte")})
    with pytest.raises(
        ValueOutOfRange, match=r"^Feed/Override \(id 4, Byte\): 300 does not fit Byte \(0\.\.255\)$"
    ):
        table.encode({4: 300}, DEFAULT)


def test_length_that_does_not_fit_len_width() -> None:
    with pytest.raises(
        FieldOverflow, match=r"item 0 \(id 1\): 256 data bytes do not fit a 1-byte length field"
    ):
        encode_single(Item(1, bytes(256)), Layout(len_width=1))
    with pytest.raises(FieldOverflow, match="65536 data bytes do not fit a 2-byte length field"):
        encode_multi([Item(1, b""), Item(2, bytes(65536))], DEFAULT)
    assert len(encode_single(Item(1, bytes(255)), Layout(len_width=1))) == 2 + 1 + 255


def test_id_that_does_not_fit_id_width() -> None:
    with pytest.raises(FieldOverflow, match=r"item 1: id 256 does not fit a 1-byte id field \(0\.\.255\)"):
        encode_multi([Item(1, b""), Item(256, b"")], Layout(id_width=1))
    with pytest.raises(FieldOverflow, match="id -1 does not fit"):
        encode_single(Item(-1, b""), DEFAULT)
    with pytest.raises(ValueTypeError, match="id must be an integer"):
        encode_single(Item("1", b""), DEFAULT)  # type: ignore[arg-type]


# --- the variable table ------------------------------------------------------------------------


def test_table_refuses_duplicate_ids_and_names() -> None:
    with pytest.raises(ValueError, match="copydata id 1 is used by both 'A' and 'B'"):
        VariableTable([Variable(1, "A", T("Byte")), Variable(1, "B", T("Byte"))])
    with pytest.raises(ValueError, match="'A' appears twice"):
        VariableTable([Variable(1, "A", T("Byte")), Variable(2, "A", T("Byte"))])
    with pytest.raises(ValueError, match=r"must be an integer 0\.\.4294967295"):
        Variable(-1, "A", T("Byte"))


def test_table_lookup_and_layout_check() -> None:
    table = VariableTable.from_ids({1: ("A", "Byte"), 300: ("B", T("Double[]"))})
    assert len(table) == 2 and 300 in table and 2 not in table
    assert table[300].type == T("Double[]") and table.by_name("A").id == 1 and table.get(2) is None
    assert [v.id for v in table] == [1, 300]
    table.check_layout(DEFAULT)
    with pytest.raises(ValueError, match=r"ids \[300\] do not fit the 1-byte id field \(max 255\)"):
        table.check_layout(Layout(id_width=1))
    with pytest.raises(KeyError, match="no copydata variable named 'C'"):
        table.by_name("C")


def test_variable_encode_and_decode() -> None:
    var = Variable(9, "Program/Name", T("String"))
    assert var.encode("é", Layout(encoding="utf-16-le")) == Item(9, hexb("e9 00"))
    assert var.decode(hexb("e9 00"), Layout(encoding="utf-16-le")) == "é"


# --- layout and COPYDATASTRUCT -----------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [
        {"id_width": 3},
        {"len_width": 8},
        {"id_width": True},
        {"max_cbdata": 0},
        {"max_cbdata": 2**32},
        {"encoding": "no-such-codec"},
        {"encoding": "base64"},
    ],
)
def test_layout_refuses_bad_settings(kwargs: dict[str, Any]) -> None:
    with pytest.raises(ValueError):
        Layout(**kwargs)


def test_layout_defaults() -> None:
    assert Layout(2, 2, "utf-8", 1 << 20) == DEFAULT
    assert (DEFAULT.max_id, DEFAULT.max_length, DEFAULT.header.size) == (65535, 65535, 4)


def test_copydatastruct_layout() -> None:
    assert WM_COPYDATA == 0x4A
    assert copydatastruct_layout(8) == (24, 0, 8, 16)
    assert copydatastruct_layout(4) == (12, 0, 4, 8)
    assert copydatastruct_layout(8).offset_lpdata == 16
    with pytest.raises(ValueError):
        copydatastruct_layout(2)


def test_pack_copydatastruct_matches_the_layout() -> None:
    raw64 = pack_copydatastruct(8, 2, 19, 0x1122334455667788)
    assert raw64 == hexb("02 00 00 00 00 00 00 00 | 13 00 00 00 | 00 00 00 00 | 88 77 66 55 44 33 22 11")
    assert len(raw64) == copydatastruct_layout(8).size
    assert pack_copydatastruct(4, 1, 12, 0x11223344) == hexb("01 00 00 00 | 0c 00 00 00 | 44 33 22 11")
    with pytest.raises(ValueError, match="out of range for 32-bit"):
        pack_copydatastruct(4, 1, 12, 2**32)


def test_errors_are_codec_errors_with_a_kind() -> None:
    from gateway.errors import CodecError

    with pytest.raises(CodecError) as info:
        decode_lpdata(2, hexb("01"), DEFAULT)
    assert isinstance(info.value, CopydataError) and isinstance(info.value, ValueError)
    assert str(info.value) == "item 0: 1 bytes left, its id and length fields need 4 (at byte 0)"


def test_datetime_values_survive_a_frame() -> None:
    table = VariableTable.from_ids({1: ("T", "DateTime")})
    when = datetime(2024, 2, 29, 12, 0, 0, 1, tzinfo=UTC)
    [reading] = table.decode(
        decode_tcp(pack_tcp(table.encode({1: when}, DEFAULT), DEFAULT), DEFAULT)[0], DEFAULT
    )
    assert reading.value == when
