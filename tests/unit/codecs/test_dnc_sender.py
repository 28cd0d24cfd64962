"""Serial DNC sender: DC1/DC3 handling, chunking, progress and the count of characters after DC3."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.codecs.dnc import DncSender, Junk, LineSettings, Pause, Resume, frame_program

LINE = LineSettings(baud=9600, leader=5, chunk_size=8)
PROGRAM = b"O1\nG0 X10\nG1 X20 F100\nM30\n"


def sender(line: LineSettings = LINE, **kwargs: bool) -> DncSender:
    return DncSender(frame_program(PROGRAM, line), line, **kwargs)


def drain(s: DncSender) -> bytes:
    out = bytearray()
    while chunk := s.take():
        out += chunk
    return bytes(out)


def test_waits_for_the_first_dc1_then_sends_in_chunks() -> None:
    s = sender()
    assert s.paused and s.waiting_for_dc1
    assert s.next_chunk() == b""
    assert s.feed(b"\x11") == [Resume()]
    assert not s.waiting_for_dc1
    assert s.next_chunk() == b"\x00" * 5 + b"%\nO"  # chunk_size 8
    assert s.next_chunk(3) == b"\x00" * 3
    assert s.offset == 0  # next_chunk does not advance
    assert drain(s) == s.program.data
    assert s.done and s.line == 4 and s.blocks_sent == 4


def test_without_waiting_for_dc1_or_with_hardware_handshake_it_starts_at_once() -> None:
    assert sender(wait_for_dc1=False).next_chunk() != b""
    rts = dataclasses.replace(LINE, handshake="rtscts")
    s = DncSender(frame_program(PROGRAM, rts), rts)
    assert s.next_chunk() != b""
    events = s.feed(b"\x13")  # DC3 means nothing when the port does the flow control
    assert [type(e) for e in events] == [Junk] and "handshake is rtscts" in events[0].reason  # type: ignore[union-attr]
    assert not s.paused


def test_dc3_stops_and_counts_what_was_sent_after_it() -> None:
    s = sender()
    s.feed(b"\x11")
    s.sent(10)
    assert s.feed(b"\x13") == [Pause()]
    assert s.next_chunk() == b""
    # Bytes already handed to the port when DC3 arrived went out after it.
    assert s.sent(3) == 3
    assert s.after_dc3_last == 3 and s.after_dc3_max == 3
    assert s.feed(b"\x13") == [Pause()]  # a repeated DC3 is the same episode
    assert s.sent(1) == 1 and s.after_dc3_last == 4 and s.pauses == 1
    assert s.feed(b"\x11") == [Resume()]
    assert s.sent(5) == 0
    s.feed(b"\x13")
    s.sent(2)
    s.feed(b"\x11")
    assert (s.after_dc3_last, s.after_dc3_max, s.after_dc3_total, s.pauses) == (2, 4, 6, 2)


def test_last_flow_byte_in_one_read_wins() -> None:
    s = sender()
    assert s.feed(b"\x11\x13\x11\x13") == [Resume(), Pause(), Resume(), Pause()]
    assert s.paused


def test_junk_is_counted_and_described_and_never_acted_on() -> None:
    s = sender()
    events = s.feed(b"\xfe\x11garbage\x13")
    assert [type(e) for e in events] == [Junk, Resume, Junk, Pause]
    assert events[0] == Junk(
        1, b"\xfe", "bytes above 0x7F on a 7-bit line (wrong baud rate or character format?)"
    )
    assert isinstance(events[2], Junk) and events[2].count == 7 and "other than DC1/DC3" in events[2].reason
    assert s.junk_bytes == 8


def test_software_parity_on_both_directions() -> None:
    line = dataclasses.replace(LINE, software_parity=True)  # 7E2 through an 8-bit port
    s = DncSender(frame_program(PROGRAM, line), line)
    # The controller's DC1 with its even parity bit: 0x11 has two ones, so bit 7 stays 0.
    assert s.feed(b"\x11") == [Resume()]
    assert s.feed(b"\x93") == [Pause()]  # DC3 (0x13, three ones) with its parity bit
    assert s.flow_wrong_bit7 == 0 and s.format_hint() is None
    # Another character with a wrong parity bit is junk, counted as a parity error.
    events = s.feed(b"\x41")  # "A" has two ones: 0x41 carries its even parity bit, 0xC1 does not
    assert [type(e) for e in events] == [Junk] and s.parity_errors == 0
    events = s.feed(b"\xc1")
    assert [type(e) for e in events] == [Junk] and "parity" in events[0].reason  # type: ignore[union-attr]
    assert s.parity_errors == 1
    s.feed(b"\x11")
    wire = drain(s)
    assert line.decode(wire) == (s.program.data, 0)
    assert wire != s.program.data  # some characters carry a parity bit


def test_a_7bit_device_servers_dc3_stops_a_software_parity_sender() -> None:
    """The defect of issue 22: a device server whose UART does the 7E2 parity hands DC3 to TCP as 0x13.
    With software parity on, its bit 7 is "wrong"; the DC3 must stop the sender all the same."""
    line = dataclasses.replace(LINE, software_parity=True)
    s = DncSender(frame_program(PROGRAM, line), line)
    assert s.feed(b"\x11") == [Resume()]
    s.sent(10)
    assert s.feed(b"\x13") == [Pause()]
    assert s.paused and s.next_chunk() == b""
    assert s.parity_errors == 0 and s.flow_wrong_bit7 == 1
    hint = s.format_hint()
    assert hint is not None and "software_parity: false" in hint


def test_a_transparent_ports_dc3_stops_a_plain_7bit_sender() -> None:
    """The other way round: a transparent port passes the parity bit as bit 7 (DC3 = 0x93) to a sender
    that expects 7-bit characters."""
    s = sender()
    assert s.feed(b"\x11") == [Resume()]
    assert s.feed(b"\x93") == [Pause()]
    assert s.junk_bytes == 0 and s.flow_wrong_bit7 == 1
    hint = s.format_hint()
    assert hint is not None and "software_parity: true" in hint


@given(
    st.sampled_from(["7E2", "7O2", "7E1", "7N1", "8N1", "8N2"]),
    st.booleans(),
    st.lists(st.integers(0, 255), max_size=40),
    st.sampled_from([0x13, 0x93]),
)
def test_every_dc3_pauses_whatever_its_bit_7_and_the_line(
    fmt: str, soft: bool, noise: list[int], dc3: int
) -> None:
    line = LineSettings.from_format(fmt, LINE)
    if soft and line.seven_bit and line.parity != "N":
        line = dataclasses.replace(line, software_parity=True)
    s = DncSender(frame_program(PROGRAM, line), line)
    s.feed(b"\x11")
    events = s.feed(bytes(b for b in noise if b & 0x7F not in (0x11, 0x13)) + bytes([dc3]))
    assert events[-1] == Pause() and s.paused and s.next_chunk() == b""


def test_sent_refuses_more_than_remains() -> None:
    s = sender(wait_for_dc1=False)
    with pytest.raises(ValueError, match="remain"):
        s.sent(s.total + 1)


@given(st.lists(st.tuples(st.integers(1, 20), st.sampled_from([b"", b"\x11", b"\x13"])), max_size=80))
@settings(max_examples=300, deadline=None)
def test_a_sender_that_obeys_next_chunk_never_sends_after_dc3(steps: list[tuple[int, bytes]]) -> None:
    """Fed any sequence of DC1/DC3 at any points, an obedient caller sends nothing while paused,
    all bytes in order, and the after-DC3 count stays 0."""
    s = sender()
    out = bytearray()
    for size, flow in steps:
        s.feed(flow)
        chunk = s.next_chunk(size)
        if s.paused:
            assert chunk == b""
        out += chunk
        assert s.sent(len(chunk)) == 0
    s.feed(b"\x11")
    out += drain(s)
    assert bytes(out) == s.program.data
    assert s.after_dc3_total == 0
