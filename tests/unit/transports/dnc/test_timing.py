"""Where a drip-feed is estimated to be, from the bytes sent: the block running, lead, time left, resume."""

from __future__ import annotations

from gateway.codecs.dnc import LineSettings, block_times, frame_program
from gateway.transports.dnc.transfer import Timing

PROGRAM = (
    b"%\nO1 (T)\nG21 G90\nG0 X0 Y0\n"
    + b"".join(b"G1 X%d Y0 F600\n" % (i + 1) for i in range(50))
    + b"M30\n%\n"
)


def timing(buffer: int) -> Timing:
    wire = frame_program(PROGRAM, LineSettings(leader=0))
    return Timing(wire, block_times(PROGRAM.decode()), buffer)


def test_nothing_sent_is_no_block_and_the_whole_run_left() -> None:
    t = timing(64)
    pos = t.position(0, "waiting for DC1")
    assert (
        pos.line is None
        and pos.remaining is not None
        and pos.remaining > 4.9
        and pos.held == "waiting for DC1"
    )


def test_the_block_running_is_a_buffer_behind_what_was_sent() -> None:
    t = timing(64)
    wire = t.wire
    offset = wire.starts[30]  # blocks 0..29 sent whole
    pos = t.position(offset, "")
    behind = wire.block_of(offset - 64)
    assert pos.line == behind
    assert pos.lead is not None and 0 < pos.lead <= 64 / 13 * 0.1 + 0.5  # about 5 blocks of 0.1 s
    assert pos.remaining is not None and pos.lead < pos.remaining


def test_a_resume_starts_one_block_before_the_one_possibly_running() -> None:
    t = timing(64)
    offset = t.wire.starts[40]
    running = t.position(offset, "").line
    assert running is not None and t.resume_line(offset) == running - 1
    assert t.resume_line(0) is None
