"""Read Var / Write Var PDUs and their plan: bytes checked against the S7comm layout by hand, and
Hypothesis: every plan reads every field, fits the PDU both ways, and parses back item by item."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.s7.address import Area, Field, Kind, parse_address, resolve
from gateway.codecs.s7.pdu import (
    MAX_ITEMS,
    REQUEST_HEADER,
    S7ProtocolError,
    S7Refused,
    max_item,
    parse_read_response,
    parse_write_response,
    plan,
    read_request,
    response_size,
    write_request,
)


def test_a_read_request_as_wireshark_shows_it() -> None:
    pdu = read_request(7, [(Area.DB, 10, 4, 4), (Area.FLAGS, 0, 20, 2)])
    assert pdu.hex(" ") == (
        "32 01 00 00 00 07 00 1a 00 00"  # header: job, sequence 7, 26 bytes of parameters
        " 04 02"  # Read Var, 2 items
        " 12 0a 10 02 00 04 00 0a 84 00 00 20"  # BYTE x4, DB10, area DB, bit address 32 (byte 4)
        " 12 0a 10 02 00 02 00 00 83 00 00 a0"  # BYTE x2, flags, byte 20
    )


def answer(sequence: int, items: list[bytes | int], error: int = 0) -> bytes:
    data = b""
    for index, item in enumerate(items):
        if isinstance(item, int):
            data += struct.pack(">BBH", item, 0, 0)
            continue
        data += struct.pack(">BBH", 0xFF, 0x04, len(item) * 8) + item
        if len(item) % 2 and index < len(items) - 1:
            data += b"\x00"
    params = bytes((0x04, len(items)))
    return (
        struct.pack(">BBHHHHBB", 0x32, 3, 0, sequence, 2, len(data), error >> 8, error & 0xFF) + params + data
    )


def test_answers_item_by_item() -> None:
    got = parse_read_response(answer(7, [b"\x01\x02\x03", 0x0A, b"\x04"]), 7, [3, 5, 1])
    assert got == [b"\x01\x02\x03", 0x0A, b"\x04"]
    with pytest.raises(S7ProtocolError, match="not to 8"):
        parse_read_response(answer(7, [b"\x01"]), 8, [1])
    with pytest.raises(S7ProtocolError, match="2 bytes answered, 3 asked"):
        parse_read_response(answer(7, [b"\x01\x02"]), 7, [3])
    with pytest.raises(S7ProtocolError, match="items answered"):
        parse_read_response(answer(7, [b"\x01"]), 7, [1, 1])
    with pytest.raises(S7ProtocolError):
        parse_read_response(answer(7, [b"\x01\x02"])[:-1], 7, [2])
    with pytest.raises(S7Refused, match="PUT/GET") as refused:
        parse_read_response(answer(7, [], error=0x8104), 7, [2])
    assert refused.value.code == 0x8104


def test_writes_of_bytes_and_of_a_bit() -> None:
    pdu = write_request(9, Area.DB, 10, 4, b"\x42\xf6\xe9\x79")
    assert pdu[10:].hex(" ") == "05 01 12 0a 10 02 00 04 00 0a 84 00 00 20 00 04 00 20 42 f6 e9 79"
    bit = write_request(9, Area.OUTPUTS, 0, 4, b"\x01", bit=3)
    assert bit[10:].hex(" ") == "05 01 12 0a 10 01 00 01 00 00 82 00 00 23 00 03 00 01 01"
    ok = struct.pack(">BBHHHHBB", 0x32, 3, 0, 9, 2, 1, 0, 0) + b"\x05\x01\xff"
    assert parse_write_response(ok, 9) == 0xFF


def test_the_plan_coalesces_and_packs_within_the_pdu() -> None:
    fields = [(i, resolve(parse_address(f"DB10.DBD{4 * i}"), "Float")) for i in range(200)]  # 800 bytes
    got = plan(fields, 240)
    assert got.too_large == []
    assert [[(i.start, i.size) for i in r.items] for r in got.requests] == [
        [(0, 220)],
        [(220, 220)],
        [(440, 220)],
        [(660, 140)],
    ]  # max_item(240) = 222: whole REALs only
    scattered = [(i, resolve(parse_address(f"DB{i + 1}.DBW0"), "Int16")) for i in range(50)]
    requests = plan(scattered, 480).requests
    assert [len(r.items) for r in requests] == [MAX_ITEMS, MAX_ITEMS, 10]
    big = plan([(0, resolve(parse_address("DB1.DBB0:STRING[254]"), "String"))], 240)
    assert big.requests == [] and big.too_large[0][0] == 0


@st.composite
def fields(draw: st.DrawFn) -> list[tuple[int, Field]]:
    out = []
    for i in range(draw(st.integers(0, 80))):
        area = draw(st.sampled_from([Area.DB, Area.FLAGS, Area.INPUTS]))
        db = draw(st.integers(1, 3)) if area is Area.DB else 0
        kind = draw(st.sampled_from([Kind.BOOL, Kind.BYTE, Kind.INT, Kind.REAL, Kind.LREAL, Kind.STRING]))
        length = draw(st.integers(1, 120)) if kind is Kind.STRING else None
        size = (length or 0) + 2 if kind is Kind.STRING else kind.size
        bit = draw(st.integers(0, 7)) if kind is Kind.BOOL else None
        out.append((i, Field(area, db, draw(st.integers(0, 600)), size, kind, bit, length)))
    return out


@given(
    fields(), st.sampled_from([240, 480, 960]), st.integers(0, 20), st.sets(st.integers(0, 79), max_size=4)
)
def test_every_plan_fits_and_reads_everything(
    fs: list[tuple[int, Field]], pdu: int, gap: int, alone: set[int]
) -> None:
    got = plan(fs, pdu, max_gap=gap, isolated=alone)
    seen = {k for k, _ in got.too_large}
    for request in got.requests:
        assert 1 <= len(request.items) <= MAX_ITEMS
        assert REQUEST_HEADER + 2 + 12 * len(request.items) <= pdu
        assert request.response_size <= pdu
        for item in request.items:
            assert item.size <= max_item(pdu)
            for key, f, offset in item.fields:
                assert (f.area, f.db) == (item.area, item.db) and offset == f.start - item.start
                assert offset + f.size <= item.size
                seen.add(key)
        # the answer to it parses back into the same items
        sizes = [i.size for i in request.items]
        assert parse_read_response(answer(1, [bytes(s) for s in sizes]), 1, sizes) == [
            bytes(s) for s in sizes
        ]
        assert response_size(sizes) == len(answer(1, [bytes(s) for s in sizes]))
    assert seen == {k for k, _ in fs}
