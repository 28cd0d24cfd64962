"""Serial DNC codec: line settings, framing and its block index, software parity."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.dnc import (
    FramingError,
    LineSettings,
    LineSettingsError,
    ProgramReceived,
    ProgramReceiver,
    frame_program,
    split_program,
)

SEVEN_E2 = LineSettings(baud=9600)  # 7E2, xonxoff, LF, 20 NULs, % markers
PROGRAM = b"%\nO4711 (BRACKET)\nG21 G90\nG0 X10 Y10\nG1 X20 F1200\nM30\n%\n"


# --- line settings ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("fmt", "bits", "rate_115200"),
    [("7E2", 11, 115200 / 11), ("7N1", 9, 115200 / 9), ("8N1", 10, 11520.0), ("7O1", 10, 11520.0)],
)
def test_character_time_counts_start_parity_and_stop_bits(fmt: str, bits: int, rate_115200: float) -> None:
    line = LineSettings.from_format(fmt, LineSettings(baud=115200))
    assert line.format == fmt
    assert line.bits_per_char == bits
    assert line.bytes_per_second == pytest.approx(rate_115200)
    assert line.char_time == pytest.approx(bits / 115200)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"baud": 0}, "baud 0"),
        ({"data_bits": 6}, "data bits 6"),
        ({"parity": "M"}, "parity 'M'"),
        ({"stop_bits": 3}, "stop bits 3"),
        ({"handshake": "dtr"}, "handshake 'dtr'"),
        ({"eob": "cr"}, "end of block 'cr'"),
        ({"leader": -1}, "leader -1"),
        ({"chunk_size": 0}, "chunk size 0"),
        ({"software_parity": True, "parity": "N"}, "software parity needs"),
    ],
)
def test_impossible_settings_are_refused_with_the_reason(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(LineSettingsError, match=fragment):
        LineSettings(**kwargs)  # type: ignore[arg-type]


def test_format_shorthand_refuses_nonsense() -> None:
    with pytest.raises(LineSettingsError, match="not like 7E2"):
        LineSettings.from_format("9X9")


def test_software_parity_sets_bit_7_and_finds_every_wrong_bit() -> None:
    even = LineSettings(software_parity=True)  # 7E2
    odd = dataclasses.replace(even, parity="O")
    for char in range(128):
        ones = char.bit_count()
        assert even.encode(bytes([char]))[0].bit_count() % 2 == 0
        assert odd.encode(bytes([char]))[0].bit_count() % 2 == 1
        assert even.encode(bytes([char]))[0] & 0x7F == char
        assert (even.encode(bytes([char]))[0] >> 7) == ones % 2
    chars = bytes(range(128))
    assert even.decode(even.encode(chars)) == (chars, 0)
    # A sender that sends plain 7-bit bytes (8N1, no parity) gets a parity error for every odd character.
    odd_weight = sum(1 for c in chars if c.bit_count() % 2)
    assert even.decode(chars) == (chars, odd_weight)
    assert LineSettings().encode(b"\x93") == b"\x93"  # no software parity: bytes pass unchanged


# --- framing ---------------------------------------------------------------------------------------


def test_frame_has_leader_markers_and_the_configured_end_of_block() -> None:
    wire = frame_program(PROGRAM, SEVEN_E2)
    assert wire.data == b"\x00" * 20 + b"%\nO4711 (BRACKET)\nG21 G90\nG0 X10 Y10\nG1 X20 F1200\nM30\n%"
    crlf = frame_program(PROGRAM, dataclasses.replace(SEVEN_E2, eob="crlf", leader=3))
    assert (
        crlf.data == b"\x00\x00\x00%\r\nO4711 (BRACKET)\r\nG21 G90\r\nG0 X10 Y10\r\nG1 X20 F1200\r\nM30\r\n%"
    )
    bare = frame_program(PROGRAM, dataclasses.replace(SEVEN_E2, markers=False, leader=0))
    assert bare.data == b"O4711 (BRACKET)\nG21 G90\nG0 X10 Y10\nG1 X20 F1200\nM30\n"


def test_program_without_markers_crlf_and_text_after_the_end_marker() -> None:
    plain = b"\r\n\r\nO1 \r\nG0 X1\r\n"
    assert frame_program(plain, SEVEN_E2).data == b"\x00" * 20 + b"%\nO1 \nG0 X1\n%"
    after_end = b"%\nG0 X1\nM30\n%\ngarbage that controllers ignore\n"
    assert frame_program(after_end, SEVEN_E2).data.endswith(b"G0 X1\nM30\n%")


def test_percent_header_line_is_the_start_marker() -> None:
    sinumerik = b"%_N_PART_MPF\n;$PATH=/_N_WKS_DIR/_N_PART_WPD\nG0 X1\nM30\n"
    wire = frame_program(sinumerik, dataclasses.replace(SEVEN_E2, leader=0))
    assert wire.data == b"%_N_PART_MPF\n;$PATH=/_N_WKS_DIR/_N_PART_WPD\nG0 X1\nM30\n%"


def test_index_maps_offsets_to_source_lines() -> None:
    wire = frame_program(PROGRAM, SEVEN_E2)
    assert wire.numbers == (2, 3, 4, 5, 6)  # line 1 is the program's own %
    assert wire.body_start == 22
    assert [wire.data[s : s + 3] for s in wire.starts] == [b"O47", b"G21", b"G0 ", b"G1 ", b"M30"]
    assert wire.block_of(0) is None and wire.block_of(21) is None
    assert wire.block_of(wire.starts[2]) == 4
    assert wire.block_of(wire.starts[3] - 1) == 4  # the line end belongs to its block
    assert wire.block_of(len(wire.data) - 1) is None  # the closing %
    assert wire.line_reached(wire.starts[0]) is None
    assert wire.line_reached(wire.starts[1]) == 2
    assert wire.line_reached(wire.body_end) == 6
    assert wire.blocks_complete(len(wire.data)) == 5


@pytest.mark.parametrize(
    ("program", "line", "fragment"),
    [
        (b"G0 X1\nG1 X2 \x13F100\n", 2, "DC3"),
        (b"G0 X1\x11\n", 1, "DC1"),
        (b"G0 X1\n\x12\n", 2, "DC2"),
        (b"\x14G0 X1\n", 1, "DC4"),
        (b"G0 X1\nG0\x00 X2\n", 2, "NUL"),
        (b"G0 X1\rG1 X2\n", 1, "carriage return inside a line"),
    ],
)
def test_programs_that_cannot_travel_are_refused_with_their_line(
    program: bytes, line: int, fragment: str
) -> None:
    with pytest.raises(FramingError, match=fragment) as info:
        frame_program(program, SEVEN_E2)
    assert info.value.line == line


def test_eight_bit_bytes_only_on_eight_bit_lines() -> None:
    program = b"G0 X1\n(D\xdcSE)\n"
    with pytest.raises(FramingError, match="7-bit line") as info:
        frame_program(program, SEVEN_E2)
    assert info.value.line == 2
    assert b"(D\xdcSE)" in frame_program(program, LineSettings.from_format("8N1")).data


# --- round trips -----------------------------------------------------------------------------------

_block_text = st.text(alphabet=st.sampled_from("GXYZFMNOST0123456789.- ()#="), min_size=0, max_size=30).map(
    lambda t: t.encode("ascii").strip(b" ")
)
_programs = st.lists(_block_text.filter(lambda b: not b.startswith(b"%")), min_size=1, max_size=30)


@given(
    _programs,
    st.sampled_from(["lf", "crlf"]),
    st.integers(0, 30),
    st.booleans(),
    st.sampled_from(["7E2", "7N1", "8N1", "7O1"]),
)
@settings(max_examples=200, deadline=None)
def test_framed_programs_come_back_whole_from_the_receiver(
    blocks: list[bytes], eob: str, leader: int, software: bool, fmt: str
) -> None:
    base = LineSettings(eob=eob, leader=leader)  # type: ignore[arg-type]
    line = LineSettings.from_format(fmt, base)
    if software and line.data_bits == 7 and line.parity != "N":
        line = dataclasses.replace(line, software_parity=True)
    text = b"".join(b + b"\n" for b in blocks)
    wire = frame_program(text, line)
    port = line.encode(wire.data)
    chars, errors = line.decode(port)
    assert errors == 0
    events = ProgramReceiver().feed(chars)
    received = [e for e in events if isinstance(e, ProgramReceived)]
    assert len(received) == 1
    lines = [ln.text for ln in split_program(text).lines]
    assert received[0].text == b"".join(ln + line.eob_bytes for ln in lines)
    assert len(wire.starts) == len(lines)
    for start, source in zip(wire.starts, split_program(text).lines, strict=True):
        assert wire.data[start : start + len(source.text)] == source.text
