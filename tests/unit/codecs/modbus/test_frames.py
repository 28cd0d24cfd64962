"""The server side of Modbus TCP frames, against byte strings written from the specification's examples."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.modbus.frames import (
    ExceptionCode,
    FrameError,
    FrameReader,
    Read,
    Refused,
    WriteBits,
    WriteRegisters,
    exception_name,
    exception_response,
    exception_status,
    frame,
    parse_request,
    read_bits_response,
    read_registers_response,
    write_response,
)


def test_requests_from_the_specification() -> None:
    # Application protocol spec, 6.3: read holding registers 108-110 -> 03 00 6B 00 03
    assert parse_request(bytes.fromhex("03006B0003")) == Read(3, 0x6B, 3)
    # 6.1: read coils 20-38 -> 01 00 13 00 13
    assert parse_request(bytes.fromhex("0100130013")) == Read(1, 19, 19)
    # 6.5: write single coil 173 ON -> 05 00 AC FF 00
    assert parse_request(bytes.fromhex("0500ACFF00")) == WriteBits(5, 172, (True,))
    # 6.6: write register 2 = 3 -> 06 00 01 00 03
    assert parse_request(bytes.fromhex("0600010003")) == WriteRegisters(6, 1, (3,))
    # 6.11: write coils 20-29 = CD 01 -> 0F 00 13 00 0A 02 CD 01
    bits = parse_request(bytes.fromhex("0F0013000A02CD01"))
    assert isinstance(bits, WriteBits) and bits.values == (
        True,
        False,
        True,
        True,
        False,
        False,
        True,
        True,
        True,
        False,
    )
    # 6.12: write registers 2-3 = 000A 0102 -> 10 00 01 00 02 04 00 0A 01 02
    assert parse_request(bytes.fromhex("100001000204000A0102")) == WriteRegisters(16, 1, (10, 258))


def test_responses_from_the_specification() -> None:
    assert read_registers_response(3, [0x022B, 0, 0x64]) == bytes.fromhex("0306022B00000064")
    # 6.1's answer: coils 27-20 CD, 35-28 6B, 38-36 05
    bits = (
        [bool(0xCD >> i & 1) for i in range(8)]
        + [bool(0x6B >> i & 1) for i in range(8)]
        + [True, False, True]
    )
    assert read_bits_response(1, bits) == bytes.fromhex("0103CD6B05")
    assert write_response(WriteBits(5, 172, (True,))) == bytes.fromhex("0500ACFF00")
    assert write_response(WriteRegisters(16, 1, (10, 258))) == bytes.fromhex("1000010002")
    assert exception_response(3, ExceptionCode.ILLEGAL_DATA_ADDRESS) == bytes.fromhex("8302")
    assert frame(0x15, 1, bytes.fromhex("0300040001")) == bytes.fromhex("001500000006010300040001")


@pytest.mark.parametrize(
    ("pdu", "code"),
    [
        ("", ExceptionCode.ILLEGAL_FUNCTION),
        ("07", ExceptionCode.ILLEGAL_FUNCTION),
        ("030000007E", ExceptionCode.ILLEGAL_DATA_VALUE),  # 126 registers
        ("0300000000", ExceptionCode.ILLEGAL_DATA_VALUE),
        ("010000", ExceptionCode.ILLEGAL_DATA_VALUE),  # short
        ("03FFFF0002", ExceptionCode.ILLEGAL_DATA_ADDRESS),  # past 65535
        ("0500011234", ExceptionCode.ILLEGAL_DATA_VALUE),  # coil value neither 0000 nor FF00
        ("1000010002030001", ExceptionCode.ILLEGAL_DATA_VALUE),  # byte count disagrees
    ],
)
def test_malformed_requests_get_the_prescribed_exception(pdu: str, code: ExceptionCode) -> None:
    with pytest.raises(Refused) as refused:
        parse_request(bytes.fromhex(pdu))
    assert refused.value.code is code


def test_exception_names_and_statuses() -> None:
    assert exception_name(2) == "ILLEGAL DATA ADDRESS"
    assert exception_status(2) == "BadNodeIdUnknown"
    assert exception_name(99) == "exception 99"
    assert exception_status(99) == "BadDeviceFailure"


def test_the_reader_refuses_what_is_not_modbus() -> None:
    with pytest.raises(FrameError, match="protocol id"):
        list(FrameReader().feed(bytes.fromhex("0001000100060103000000")))
    with pytest.raises(FrameError, match="length"):
        list(FrameReader().feed(bytes.fromhex("000100000000") + b"\x01"))


@given(
    st.lists(
        st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255), st.binary(min_size=1, max_size=253)),
        max_size=8,
    ),
    st.lists(st.integers(1, 40), min_size=1),
)
def test_frames_come_out_whole_however_the_stream_is_cut(
    adus: list[tuple[int, int, bytes]], cuts: list[int]
) -> None:
    stream = b"".join(frame(t, u, p) for t, u, p in adus)
    reader = FrameReader()
    out = []
    at = 0
    i = 0
    while at < len(stream):
        step = cuts[i % len(cuts)]
        out += [(a.transaction, a.unit, a.pdu) for a in reader.feed(stream[at : at + step])]
        at += step
        i += 1
    assert out == adus
