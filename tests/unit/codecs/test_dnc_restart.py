"""Restart at block N, and the per-block run-time model the drip scheduler uses."""

from __future__ import annotations

import math

import pytest

from gateway.codecs.dnc import (
    GENERATED,
    FramingError,
    LineSettings,
    block_times,
    frame_program,
    restart_lines,
)

PROGRAM = b"""%
O4711 (BRACKET)
(MATERIAL 2MM STEEL)
G21 G90 G17
G54
T1 M6
G92 X0 Y0
S3000 M3
G4 P1
G0 X10 Y10
G1 X50 F1200
G91
G1 X10
G90
G2 X60 Y20 I0 J5 F800
G0 X0 Y0
M30
%
"""


def test_restart_is_header_then_modal_state_then_the_tail() -> None:
    restart = restart_lines(PROGRAM, 15)
    assert restart.text() == (
        b"%\n"
        b"O4711 (BRACKET)\n"
        b"(MATERIAL 2MM STEEL)\n"
        b"G21 G90 G17\n"
        b"G54\n"
        b"T1 M6\n"
        b"S3000 M3\n"
        b"G21 G90 G17 G54 G1 F1200 (RESTART AT LINE 15)\n"
        b"G2 X60 Y20 I0 J5 F800\n"
        b"G0 X0 Y0\n"
        b"M30\n"
        b"%\n"
    )
    assert [ln.number for ln in restart.lines] == [2, 3, 4, 5, 6, 8, GENERATED, 15, 16, 17]


def test_restart_keeps_incremental_mode_when_the_tail_needs_it() -> None:
    restart = restart_lines(PROGRAM, 13)
    assert restart.lines[6].text == b"G21 G91 G17 G54 G1 F1200 (RESTART AT LINE 13)"
    assert restart.lines[7].text == b"G1 X10"


def test_restart_frames_with_the_original_line_numbers() -> None:
    wire = frame_program(restart_lines(PROGRAM, 16), LineSettings(leader=0))
    assert wire.numbers[-3:] == (GENERATED, 16, 17)
    assert wire.line_reached(wire.body_end) == 17


def test_restart_at_or_before_the_first_motion_sends_the_whole_program() -> None:
    whole = restart_lines(PROGRAM, 10)
    assert [ln.number for ln in whole.lines] == list(range(2, 18))
    assert restart_lines(PROGRAM, 3) == whole


@pytest.mark.parametrize("line", [1, 18, 19, 500, 0])
def test_restart_outside_the_body_is_refused(line: int) -> None:
    with pytest.raises(FramingError, match="no block") as info:
        restart_lines(PROGRAM, line)
    assert info.value.line == line


def test_block_times_follow_t_equals_s_over_v() -> None:
    times = block_times(PROGRAM.decode(), rapid=6000.0)
    assert times[9] == pytest.approx(1.0)  # G4 P1: seconds by default
    assert times[10] == pytest.approx(math.hypot(10, 10) / 100.0)  # rapid 6000 mm/min = 100 mm/s
    assert times[11] == pytest.approx(40 / 20.0)  # 40 mm at 1200 mm/min
    assert times[13] == pytest.approx(10 / 20.0)  # G91 X10
    # From (60, 10) clockwise around (60, 15) to (60, 20): half a circle of radius 5 at 800 mm/min.
    assert times[15] == pytest.approx(5 * math.pi / (800 / 60.0))
    assert 2 not in times and 4 not in times  # no motion, no time
    assert block_times("G4 P500\n", dwell_ms=True)[1] == pytest.approx(0.5)


def test_arcs_by_centre_and_radius_and_full_circles() -> None:
    # Quarter circle of radius 10 at 600 mm/min (10 mm/s): 15.708 mm.
    times = block_times(
        "G1 X10 Y0 F600\nG3 X0 Y10 I-10 J0\nG2 X10 Y0 R10\nG2 X10 Y0 I-10 J0\nG2 X0 Y10 R-10\n"
    )
    assert times[2] == pytest.approx(math.pi * 10 / 2 / 10)
    assert times[3] == pytest.approx(math.pi * 10 / 2 / 10)
    assert times[4] == pytest.approx(2 * math.pi * 10 / 10)
    assert times[5] == pytest.approx(3 * math.pi * 10 / 2 / 10)


def test_units_inverse_time_and_what_cannot_be_timed() -> None:
    times = block_times("G20 G1 X1 F10\nG93 G1 X2 F2\nG95 G1 X3 F0.1\nG94\nG1 X4 F100\n(bad # line\n")
    assert times[1] == pytest.approx(6.0)  # 1 inch at 10 in/min
    assert times[2] == pytest.approx(30.0)  # G93: 1/F minutes
    assert 3 not in times  # feed per revolution: unknown, 0
    assert times[5] == pytest.approx(25.4 / (100 * 25.4 / 60))
    with pytest.raises(ValueError, match="rapid"):
        block_times("G0 X1\n", rapid=0)


def test_feed_per_revolution_is_timed_with_the_spindle_speed() -> None:
    # Mill: G95 F0.1 mm/rev at S2000 rpm is 200 mm/min; 10 mm take 3 s. Without S it cannot be timed.
    times = block_times("G21 G95 F0.1\nG1 X10\nS2000 M3\nG1 X20\nG20\nG91 G1 X1 F0.01\n")
    assert 2 not in times  # no spindle speed yet: 0 s, the short side
    assert times[4] == pytest.approx(10 / (0.1 * 2000 / 60))
    # G20: 1 inch at 0.01 in/rev, 2000 rpm = 20 in/min: 3 s.
    assert times[6] == pytest.approx(3.0)
    # Mill G98/G99 are canned-cycle return levels, not feed modes.
    assert block_times("G99 G1 X10 F600\n")[1] == pytest.approx(1.0)


def test_a_lathe_program_in_feed_per_revolution_and_constant_surface_speed() -> None:
    # Fanuc T, G-code system A: X is a diameter, W incremental Z, G99 feed per revolution, G50 S clamps.
    program = "\n".join(
        [
            "G50 S3000",  # 1: the spindle's top speed under G96
            "G97 S1000 M3",  # 2: 1000 rpm
            "G99 G0 X40 Z0",  # 3: rapid to radius 20 (diameter 40), 20 mm at 10,000 mm/min
            "G1 W-10 F0.2",  # 4: 10 mm along Z at 0.2 mm/rev x 1000 rpm = 200 mm/min: 3 s
            "G96 S120",  # 5: 120 m/min surface speed
            "G1 X20 W-10",  # 6: diameter 40 -> 20, fastest at radius 10: 120000 / (2 pi 10) rpm
            "G1 X0",  # 7: facing to the centre: the G50 clamp
            "G98 G1 Z10 F300",  # 8: back to feed per minute: Z -20 -> 10, 30 mm at 300 mm/min
        ]
    )
    times = block_times(program, lathe=True)
    assert times[3] == pytest.approx(20 / (10_000 / 60))
    assert times[4] == pytest.approx(3.0)
    rpm = 120_000 / (2 * math.pi * 10)
    assert times[6] == pytest.approx(math.hypot(10, 10) / (0.2 * rpm / 60))
    assert times[7] == pytest.approx(10 / (0.2 * 3000 / 60))
    assert times[8] == pytest.approx(30 / 5.0)


def test_arcs_in_the_zx_plane() -> None:
    # G18: a half circle in Z/X of radius 5 (I is X's centre offset, K Z's) at 600 mm/min.
    times = block_times("G18 G1 X0 Z0 F600\nG2 X0 Z10 I0 K5\n")
    assert times[2] == pytest.approx(math.pi * 5 / 10)
