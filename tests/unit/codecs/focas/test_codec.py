"""The FOCAS codec: frames, requests, responses and numbers round-trip, and a stream split anywhere reads
the same; the values others documented decode as they said (pyfanuc's sample answers)."""

from __future__ import annotations

import contextlib
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.address import Item, parse_address
from gateway.codecs.focas.commands import (
    Command,
    Reply,
    command,
    decode_request,
    decode_response,
    encode_request,
    encode_response,
)
from gateway.codecs.focas.errors import FocasError
from gateway.codecs.focas.frame import Frame, FrameReader, Junk, Kind, encode_frame
from gateway.codecs.focas.plan import Context, make_plan
from gateway.codecs.focas.program import download_frames, read_start, upload_name
from gateway.codecs.focas.values import (
    AlarmEntry,
    DirEntry,
    StatInfo,
    SysInfo,
    decode_alarms,
    decode_dir,
    decode_scaled,
    encode_scaled,
)
from gateway.codecs.focas.writes import ValueTooLarge, WrongValueType, write_commands
from gateway.errors import AddressError

int32 = st.integers(-(2**31), 2**31 - 1)
commands = st.builds(
    Command,
    function=st.integers(0, 0xFFFF),
    args=st.tuples(int32, int32, int32, int32, int32),
    data=st.binary(max_size=300),
    device=st.integers(1, 2),
    path=st.integers(1, 10),
)
replies = st.builds(
    Reply,
    function=st.integers(0, 0xFFFF),
    error=st.just(0) | st.integers(-17, 17),
    data=st.binary(max_size=300),
    device=st.integers(1, 2),
    path=st.integers(1, 10),
)


@given(st.lists(commands, min_size=1, max_size=20))
def test_requests_round_trip(cmds: list[Command]) -> None:
    assert decode_request(encode_request(cmds)) == cmds


@given(st.lists(replies, min_size=1, max_size=20))
def test_responses_round_trip(rs: list[Reply]) -> None:
    expected = [r if not r.error else Reply(r.function, r.error, b"", r.device, r.path) for r in rs]
    assert decode_response(encode_response(rs)) == expected


@given(
    st.lists(st.tuples(st.integers(0, 0xFFFF), st.binary(max_size=2000)), min_size=1, max_size=8), st.data()
)
def test_a_stream_split_at_every_offset_reads_the_same_frames(
    frames: list[tuple[int, bytes]], data: st.DataObject
) -> None:
    stream = b"".join(encode_frame(k, p) for k, p in frames)
    expected = [Frame(k, p) for k, p in frames]
    for cut in range(len(stream) + 1) if len(stream) < 400 else [data.draw(st.integers(0, len(stream)))]:
        reader = FrameReader()
        got = reader.feed(stream[:cut]) + reader.feed(stream[cut:])
        assert got == expected and reader.pending == 0


def test_every_offset_byte_by_byte() -> None:
    stream = encode_frame(
        Kind.RESPONSE, encode_response([Reply(0x19, 0, StatInfo(1, 3, 1, 0, 0, 0, 0).encode())])
    )
    reader = FrameReader()
    got = [e for b in stream for e in reader.feed(bytes([b]))]
    assert got == [Frame(Kind.RESPONSE, stream[10:])]


def test_junk_before_a_frame_is_skipped_and_counted() -> None:
    reader = FrameReader()
    events = reader.feed(b"HTTP/1.1 400\r\n" + encode_frame(Kind.CLOSE_OK))
    assert isinstance(events[0], Junk) and events[0].skipped == 14
    assert events[1] == Frame(Kind.CLOSE_OK)


@given(st.floats(-1e6, 1e6, allow_nan=False).map(lambda v: round(v, 4)))
def test_numbers_round_trip(value: float) -> None:
    """Exact to the decimals a 32-bit mantissa leaves (about nine significant digits), as on a Fanuc."""
    decimals = next(d for d in range(9, -1, -1) if abs(value) * 10**d <= 2**31 - 1)
    assert decode_scaled(encode_scaled(value)) == pytest.approx(value, abs=10**-decimals)


def test_numbers_as_pyfanuc_and_pyfocas_documented_them() -> None:
    # pyfocas's doctest: 0x0bc77120 with base 10, exponent 6 is 197.62
    assert decode_scaled(b"\x0b\xc7q \x00\n\x00\x06") == 197.62
    # pyfanuc's multi-packet sample: an absolute position of 3111.657 (4 decimals)
    assert decode_scaled(bytes.fromhex("002f7ae9000a0004")) == 311.1657
    assert decode_scaled(bytes.fromhex("0000000000 0aff ff".replace(" ", ""))) is None  # vacant
    with pytest.raises(FocasError):
        decode_scaled(bytes.fromhex("0000000100030001"))  # base 3
    with pytest.raises(ValueError):
        encode_scaled(1e12)


def test_structs_round_trip() -> None:
    info = SysInfo(0, 8, "31", "M", "G4A1", "14.0", "3")
    assert SysInfo.decode(info.encode()) == info and info.axis_count == 3
    alarms = [AlarmEntry(1001, 4, 1, "Soft limit X+"), AlarmEntry(2001, 3, 0, "x" * 64)]
    assert decode_alarms(b"".join(a.encode() for a in alarms)) == alarms
    entry = DirEntry("demo.nc", True, 1234, (2024, 5, 1, 12, 0, 0), "DEMO")
    assert decode_dir(entry.encode()) == [entry]


def test_a_poll_group_is_few_commands() -> None:
    sources = ["status.run", "status.mode", "status.alarm", "position.absolute[X]", "position.absolute[Y]",
               "position.machine[X]", "#500", "#501", "#505", "#3901", "pmc:R100", "pmc:R101.3", "pmc:R110",
               "alarms.number", "alarms.message", "feed.actual"]  # fmt: skip
    plan = make_plan([parse_address(s) for s in sources])
    # statinfo, absolute, machine, 2 macro ranges, R bytes, alarms, feed
    assert len(plan.commands) == 8
    assert sum(1 for c in plan.commands if c.function == fn.MACRO_READ) == 2


def test_outcomes_come_out_of_the_answers() -> None:
    items = [
        parse_address(s)
        for s in ["status.run", "position.absolute[Y]", "#501", "pmc:R100.3", "alarms.message"]
    ]
    plan = make_plan(items)
    answers = {
        fn.STATINFO: StatInfo(1, 3, 1, 0, 0, 1, 0).encode(),
        fn.POSITION: encode_scaled(1.5, 3) + encode_scaled(-2.25, 3) + encode_scaled(0.0, 3),
        fn.MACRO_READ: encode_scaled(42.5),
        fn.PMC_READ: bytes([0b1000]),
        fn.ALARM_MESSAGES: AlarmEntry(1001, 4, 0, "Soft limit").encode(),
    }
    rs = [Reply(c.function, 0, answers[c.function], c.device, c.path) for c in plan.commands]
    values = [o.value for o in plan.outcomes(rs, Context(("X", "Y", "Z")))]
    assert values == [3, -2.25, 42.5, True, ["Soft limit"]]


def test_addresses() -> None:
    assert parse_address("#500") == Item("macro", number=500)
    assert parse_address("pmc:D2204:word").size == fn.PMC_WORD
    assert parse_address("position.absolute[x]").axis == "X"
    assert parse_address("diag:300[2]").axis == 2
    for bad in ["#0", "pmc:Q1", "pmc:D2205:word", "pmc:R1.3:word", "position.up", "status.speed", "macro"]:
        with pytest.raises(AddressError):
            parse_address(bad)


def test_writes() -> None:
    folder = "//CNC_MEM/USER/PATH1/"
    (macro,) = write_commands(parse_address("#500"), 12.5, folder)
    assert (macro.function, macro.args[:2], decode_scaled(macro.data)) == (fn.MACRO_WRITE, (500, 500), 12.5)
    (bit,) = write_commands(parse_address("pmc:G8.7"), True, folder, current_byte=0x01)
    assert bit.data == b"\x81" and bit.device == 2
    (word,) = write_commands(parse_address("pmc:D2204:word"), -2, folder)
    assert word.data == struct.pack(">h", -2) and word.args[:2] == (2204, 2205)
    (select,) = write_commands(parse_address("program.select"), "O1234", folder)
    assert select.function == fn.SELECT_NUMBER and select.args[0] == 1234
    (by_name,) = write_commands(parse_address("program.select"), "demo.nc", folder)
    assert by_name.function == fn.SELECT_FILE and by_name.data.startswith(folder.encode() + b"demo.nc\x00")
    assert write_commands(parse_address("program.start"), False, folder) == []
    with pytest.raises(WrongValueType):
        write_commands(parse_address("#500"), "12", folder)
    with pytest.raises(ValueTooLarge):
        write_commands(parse_address("pmc:R1"), 256, folder)


def test_program_transfer_frames() -> None:
    start, data, end = download_frames(
        "//CNC_MEM/USER/PATH1/O1234", b"%\nO1234\nG0X1\nM30\n%\n" * 200, chunk=512
    )
    reader = FrameReader()
    frames = [f for f in reader.feed(start + b"".join(data) + end) if isinstance(f, Frame)]
    assert frames[0].kind == Kind.DOWNLOAD_START and read_start(frames[0].payload).endswith("O1234")
    assert b"".join(f.payload for f in frames[1:-1]) == b"%\nO1234\nG0X1\nM30\n%\n" * 200
    assert frames[-1].kind == Kind.DOWNLOAD_END
    assert upload_name("O1234") == "O1234-O1234" and upload_name("demo.nc") == "demo.nc"


@given(st.binary(max_size=200))
def test_any_bytes_are_frames_junk_or_a_focas_error(data: bytes) -> None:
    for event in FrameReader().feed(data):
        if isinstance(event, Frame):
            for decode in (decode_request, decode_response):
                with contextlib.suppress(FocasError):
                    decode(event.payload)


def test_command_helper_puts_the_data_length_in_the_fifth_argument() -> None:
    assert command(fn.DELETE_FILE, data=b"x" * 256).args[4] == 256
