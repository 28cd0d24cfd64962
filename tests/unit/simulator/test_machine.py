from __future__ import annotations

import math

import pytest

from gateway.errors import InvalidArgument, InvalidState, OutOfRange
from simulator.alarms import PROGRAM_ERROR, PROGRAM_NOT_FOUND, SOFT_LIMIT
from simulator.machine import AMBIENT, GAS_ON, OVERRIDE_LIMIT, RAPID, Machine, MachineState, Mode
from simulator.store import MemoryStore

Idle, Running, Paused, Alarm = (
    MachineState.IDLE,
    MachineState.RUNNING,
    MachineState.PAUSED,
    MachineState.ALARM,
)


def machine_with(text: str, name: str = "p.nc") -> Machine:
    m = Machine(MemoryStore({name: text}))
    m.select_program(name)
    return m


def started(text: str) -> Machine:
    m = machine_with(text)
    m.start()
    return m


def run_to_end(m: Machine, dt: float = 0.05, limit: float = 10_000.0) -> float:
    """Step until the program is no longer running; return the simulated time it took."""
    t = 0.0
    while m.state is Running:
        m.step(dt)
        t += dt
        assert t < limit, "program did not end"
    return t


def pos(m: Machine) -> tuple[float, float, float]:
    return (m.axes[0].actual, m.axes[1].actual, m.axes[2].actual)


def approx(*values: float) -> object:
    return pytest.approx(values, abs=1e-6)


# --- motion ------------------------------------------------------------------------------------


def test_straight_g1_takes_length_over_feed() -> None:
    m = started("G21 G90\nG1 X100 F600\nM30\n")  # 100 mm at 10 mm/s
    m.step(5.0)
    assert pos(m) == approx(50.0, 0.0, 0.0)
    assert m.axes[0].velocity == pytest.approx(600.0) and m.axes[1].velocity == pytest.approx(0.0)
    assert m.feed_rate == pytest.approx(600.0)
    assert m.axes[0].commanded == pytest.approx(100.0)  # end point of the current block
    assert m.program.progress == pytest.approx(50.0)
    m.step(4.999)
    assert m.state is Running
    m.step(0.002)
    assert m.state is Idle and pos(m) == approx(100.0, 0.0, 0.0)
    assert m.program.run_time == pytest.approx(10.0)
    assert m.feed_rate == 0.0 and m.axes[0].velocity == 0.0


def test_g2_full_circle_path_is_two_pi_r_and_runs_clockwise() -> None:
    m = started("G0 X100 Y100\nG2 I50 F600\nM30\n")  # centre (150, 100), r = 50
    rapid = math.hypot(100, 100) / 30000 * 60
    circle = 2 * math.pi * 50 / 10  # s at 10 mm/s
    m.step(rapid + circle / 4)
    assert pos(m)[:2] == pytest.approx((150.0, 150.0), abs=1e-6)  # clockwise from the left: up first
    m.step(circle / 4)
    assert pos(m)[:2] == pytest.approx((200.0, 100.0), abs=1e-6)
    run_to_end(m, dt=0.001)
    assert pos(m) == approx(100.0, 100.0, 0.0)
    assert m.program.run_time == pytest.approx(rapid + circle, abs=2e-3)


@pytest.mark.parametrize(("radius", "sweep"), [(50, math.pi / 2), (-50, 3 * math.pi / 2)])
def test_r_arcs_positive_minor_negative_major(radius: float, sweep: float) -> None:
    m = started(f"G0 X100 Y100\nG3 X150 Y150 R{radius} F600\nM30\n")
    rapid = math.hypot(100, 100) / 500
    duration = 50 * sweep / 10
    m.step(rapid + duration / 2)
    # Counter-clockwise from 100,100 to 150,150: the minor arc turns about 100,150 and is
    # half done at 135.36,114.64; the major one turns about 150,100 and swings out to 185.36,64.64.
    h = 50 * math.sqrt(0.5)
    expected = (100 + h, 150 - h) if radius > 0 else (150 + h, 100 - h)
    assert pos(m)[:2] == pytest.approx(expected, abs=1e-6)
    run_to_end(m, dt=0.001)
    assert pos(m)[:2] == pytest.approx((150.0, 150.0), abs=1e-9)
    assert m.program.run_time == pytest.approx(rapid + duration, abs=2e-3)


def test_g91_incremental_moves_add_up() -> None:
    m = started("G91 G0 X10 Y10\nX10\nG1 X5 Z-2 F600\nM0\nG90 G0 X1\nM30\n")
    run_to_end(m)
    assert m.state is Paused and pos(m) == approx(25.0, 10.0, -2.0)
    m.resume()
    run_to_end(m)
    assert pos(m) == approx(1.0, 10.0, -2.0)


def test_g20_converts_inches_including_feed() -> None:
    m = started("G20 G0 X1 Y2\nG1 X2 F10\nM30\n")  # 25.4 mm at 254 mm/min: 6 s
    run_to_end(m, dt=0.01)
    assert pos(m)[:2] == approx(50.8, 50.8)
    rapid = math.hypot(25.4, 50.8) / 500
    assert m.program.run_time == pytest.approx(rapid + 6.0, abs=1e-6)


def test_g92_sets_the_current_position() -> None:
    m = started("G0 X100 Y100\nG92 X0 Y0\nG0 X10 Y-5\nM0\nG92.1\nG0 X7\nM30\n")
    run_to_end(m)
    assert pos(m)[:2] == approx(110.0, 95.0)  # machine coordinates: program origin is at 100,100
    m.resume()
    run_to_end(m)
    assert pos(m)[:2] == approx(7.0, 95.0)


def test_g4_dwell_p_is_seconds() -> None:
    m = started("G4 P2.5\nM30\n")
    m.step(2.4)
    assert m.state is Running and m.program.block_text == "G4 P2.5" and m.program.block == 1
    m.step(0.2)
    assert m.state is Idle and m.program.run_time == pytest.approx(2.5)


@pytest.mark.parametrize(("override", "seconds"), [(50, 20.0), (100, 10.0), (200, 5.0)])
def test_override_scales_feed_but_not_rapids(override: int, seconds: float) -> None:
    m = machine_with("G0 X300\nG1 X400 F600\nM30\n")
    m.set_override(override)
    m.start()
    rapid = 300 / 500
    m.step(rapid + seconds / 2)
    assert m.axes[0].actual == pytest.approx(350.0)
    assert m.feed_rate == pytest.approx(600 * override / 100)
    run_to_end(m, dt=0.01)
    assert m.program.run_time == pytest.approx(rapid + seconds)


def test_an_override_beyond_the_knob_cuts_up_to_the_rapid() -> None:
    m = machine_with("G1 X100 F600\nM30\n")  # 10 s at F600
    with pytest.raises(OutOfRange, match=r"outside 0\.\.200"):
        m.set_override(800)  # the panel's knob
    m.set_override(800, limit=OVERRIDE_LIMIT)  # cnc-simulator --dnc-override 800
    m.start()
    run_to_end(m, dt=0.01)
    assert m.program.run_time == pytest.approx(10.0 / 8)
    fast = machine_with("G1 X100 F6000\nM30\n")  # 1 s at F6000; 8x would be 48,000 mm/min
    fast.set_override(800, limit=OVERRIDE_LIMIT)
    fast.start()
    fast.step(0.05)
    assert fast.feed_rate == pytest.approx(RAPID)  # capped at the rapid, 30,000 mm/min
    with pytest.raises(OutOfRange, match=r"outside 0\.\.1000"):
        m.set_override(1001, limit=OVERRIDE_LIMIT)


def test_override_zero_holds_the_path_while_running() -> None:
    m = started("G1 X100 F600\nM30\n")
    m.step(1.0)
    m.set_override(0)
    m.step(5.0)
    assert m.state is Running and m.axes[0].actual == pytest.approx(10.0) and m.feed_rate == 0.0
    m.set_override(100)
    m.step(1.0)
    assert m.axes[0].actual == pytest.approx(20.0)


def test_override_range_and_mode() -> None:
    m = Machine(MemoryStore())
    with pytest.raises(OutOfRange, match=r"outside 0\.\.200"):
        m.set_override(201)
    m.set_override(200)
    assert m.override == 200
    m.set_mode(2)
    assert (m.mode, m.mode.text) == (Mode.MDA, "MDA")
    with pytest.raises(OutOfRange) as info:
        m.set_mode(3)
    assert info.value.status == "BadOutOfRange"


# --- laser ---------------------------------------------------------------------------------------


def test_m3_s_and_m5_drive_the_laser() -> None:
    m = started("S3000 M3\nG4 P1\nM5\nG4 P3\nS1000 M4\nG4 P1\nM30\n")
    m.step(0.01)
    assert m.laser.on and m.laser.power_set == 3000.0 and 0 < m.laser.power_act < 3000.0
    m.step(0.98)
    assert m.laser.power_act == pytest.approx(3000.0, abs=1.0)
    assert m.laser.gas_pressure == pytest.approx(GAS_ON, abs=0.5)
    assert m.laser.head_temp > AMBIENT
    m.step(0.02)
    assert not m.laser.on and m.laser.power_act == 0.0
    gas_after_off = m.laser.gas_pressure
    m.step(2.9)
    assert 0 < m.laser.gas_pressure < gas_after_off
    m.step(0.2)
    assert m.laser.on and m.laser.power_set == 1000.0  # M4 is beam on too
    run_to_end(m)
    assert not m.laser.on and m.laser.power_set == 0.0  # program end switches the beam off


def test_head_temperature_rises_with_power_and_cools_to_ambient() -> None:
    m = started("S6000 M3\nG4 P120\nM5\nM30\n")
    m.step(120.0)
    hot = m.laser.head_temp
    assert hot > AMBIENT + 20
    run_to_end(m)
    m.step(600.0)
    assert m.laser.head_temp == pytest.approx(AMBIENT)
    assert m.laser.power_table == (20.0, 40.0, 60.0, 80.0, 100.0)


# --- program flow --------------------------------------------------------------------------------


def test_m30_and_m2_count_parts_and_running_out_does_not() -> None:
    store = MemoryStore({"a.nc": "G0 X1\nM30\n", "b.nc": "G0 X2\nM2\n", "c.nc": "G0 X3\n"})
    m = Machine(store)
    for name, count in (("a.nc", 1), ("b.nc", 2), ("c.nc", 2), ("a.nc", 3)):
        m.select_program(name)
        m.start()
        run_to_end(m)
        assert (m.state, m.program.part_count, m.program.progress) == (Idle, count, 100.0)


def test_blocks_report_line_number_and_text() -> None:
    m = started("%\n(header)\n\nN10 G1 X10 F600 (cut)\nN20 G1 X20\nM30\n%\n")
    m.step(0.5)
    assert (m.program.block, m.program.block_text) == (4, "N10 G1 X10 F600 (cut)")
    m.step(1.0)
    assert (m.program.block, m.program.block_text) == (5, "N20 G1 X20")


def test_block_delete_skips_slashed_blocks() -> None:
    m = started("G0 X10\n/G0 X500\nM30\n")
    run_to_end(m)
    assert m.axes[0].actual == 10.0


def test_pause_holds_motion_and_resume_continues() -> None:
    m = started("S1000 M3\nG1 X100 F600\nM30\n")
    m.step(2.0)
    m.pause()
    assert m.state is Paused and not m.laser.on and m.feed_rate == 0.0
    m.step(10.0)
    assert m.axes[0].actual == pytest.approx(20.0) and m.program.run_time == pytest.approx(2.0)
    m.start()  # Start while paused resumes
    assert m.state is Running and m.laser.on
    run_to_end(m, dt=0.01)
    assert m.program.run_time == pytest.approx(10.0)


def test_m0_pauses_until_resume() -> None:
    m = started("G0 X10\nM0\nG0 X20\nM30\n")
    m.step(1.0)
    assert m.state is Paused and m.axes[0].actual == 10.0
    m.resume()
    run_to_end(m)
    assert m.axes[0].actual == 20.0


def test_stop_aborts_and_stays_harmless_when_idle() -> None:
    m = started("S500 M3\nG1 X100 F600\nM30\n")
    m.step(1.0)
    m.stop()
    assert m.state is Idle and not m.laser.on and m.axes[0].actual == pytest.approx(10.0)
    assert m.axes[0].commanded == m.axes[0].actual
    m.stop()
    assert m.state is Idle and m.program.part_count == 0


# --- alarms --------------------------------------------------------------------------------------


def test_soft_limit_alarm_is_raised_before_the_block_moves() -> None:
    m = started("G0 X2900 Y750\nG1 X3050 F6000\nM30\n")
    xs = []
    while m.state is Running:
        m.step(0.01)
        xs.append(m.axes[0].actual)
    assert m.state is Alarm
    assert [(a.id, a.text, int(a.severity)) for a in m.alarms] == [
        (SOFT_LIMIT, "Soft limit X+ exceeded at line 2", 3)
    ]
    assert max(xs) == 2900.0 and m.axes[0].actual == 2900.0


@pytest.mark.parametrize(("code", "alarm"), [("G3", True), ("G2", False)])
def test_soft_limit_covers_the_arc_extent(code: str, alarm: bool) -> None:
    # Same end points; counter-clockwise bulges to X 3000.5, clockwise away from the limit.
    m = started(f"G0 X2990 Y750\n{code} X2990 Y771 I0 J10.5 F3000\nM30\n")
    run_to_end(m)
    assert (m.state is Alarm) == alarm
    if alarm:
        assert m.alarms[0].text == "Soft limit X+ exceeded at line 2"


def test_soft_limit_below_zero() -> None:
    m = started("G0 X10 Y10\nG1 Y-0.001 F600\nM30\n")
    run_to_end(m)
    assert m.alarms[0].text == "Soft limit Y- exceeded at line 2"


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("G5.2 X20", "unsupported code G5.2"),
        ("G81 X20 Z-1 R2", "unsupported code G81"),
        ("M8", "unsupported code M8"),
        ("G1 ^45 @10 F100", "unsupported word ^45 (polar coordinates are not supported)"),
        ("G1 X20", "G1 needs a feed rate: no F word programmed"),
        ("G1 X20 (oops", "unterminated comment: '(' without ')' (column 8)"),
        ("G0 G1 X20", "G0 and G1 cannot share a block"),
        ("X20 X30", "X appears twice in one block"),
        ("G0 X20 P2", "P2 has no use in this block"),
        ("S7000", "laser power S7000 is outside 0..6000 W"),
        ("G2 X20 R1 F100", "arc radius R1 is too small"),
        ("T1", "unsupported word T1"),
    ],
)
def test_program_error_alarm_names_the_line_and_stops(line: str, reason: str) -> None:
    m = started(f"G0 X10\n{line}\nG0 X50\nM30\n")
    run_to_end(m)
    assert m.state is Alarm and m.axes[0].actual == 10.0
    assert len(m.alarms) == 1 and m.alarms[0].id == PROGRAM_ERROR
    assert m.alarms[0].text.startswith(f"Program error at line 2: {reason}")
    assert m.program.block == 2


def test_reset_clears_alarms_and_returns_to_idle() -> None:
    m = started("G5.2\n")
    run_to_end(m)
    assert m.state is Alarm
    with pytest.raises(InvalidState, match="reset first"):
        m.start()
    m.reset()
    assert m.state is Idle and m.alarms == []
    m.start()
    assert m.state is Running


# --- command refusals ----------------------------------------------------------------------------


def test_start_with_nothing_selected_is_refused() -> None:
    m = Machine(MemoryStore({"a.nc": "M30\n"}))
    with pytest.raises(InvalidState, match="no program selected") as info:
        m.start()
    assert info.value.status == "BadInvalidState" and m.state is Idle


def test_start_while_running_and_select_while_running_are_refused() -> None:
    m = started("G4 P10\nM30\n")
    with pytest.raises(InvalidState):
        m.start()
    with pytest.raises(InvalidState):
        m.select_program("p.nc")


@pytest.mark.parametrize("name", ["missing.nc", "", "../p.nc", "DATA/p.nc"])
def test_select_of_a_program_not_in_the_store_is_refused(name: str) -> None:
    m = Machine(MemoryStore({"p.nc": "M30\n"}))
    with pytest.raises(InvalidArgument) as info:
        m.select_program(name)
    assert info.value.status == "BadInvalidArgument" and m.program.name == ""


def test_start_of_a_program_deleted_after_selection() -> None:
    store = MemoryStore({"p.nc": "M30\n"})
    m = Machine(store)
    m.select_program("p.nc")
    del store.programs["p.nc"]
    with pytest.raises(InvalidState, match="no longer in the program store"):
        m.start()
    assert m.state is Alarm and [a.id for a in m.alarms] == [PROGRAM_NOT_FOUND]


def test_pause_and_resume_refused_when_nothing_runs() -> None:
    m = Machine(MemoryStore())
    with pytest.raises(InvalidState):
        m.pause()
    with pytest.raises(InvalidState):
        m.resume()


def test_ignore_start_accepts_and_does_nothing() -> None:
    m = machine_with("G0 X10\nM30\n")
    m.ignore_start = True
    m.start()
    m.step(1.0)
    assert m.state is Idle and m.axes[0].actual == 0.0


def test_program_is_read_afresh_at_each_start() -> None:
    store = MemoryStore({"p.nc": "G0 X10\nM30\n"})
    m = Machine(store)
    m.select_program("p.nc")
    m.start()
    run_to_end(m)
    store.programs["p.nc"] = "G0 X20\nM30\n"
    m.start()
    run_to_end(m)
    assert m.axes[0].actual == 20.0


def test_step_rejects_negative_time() -> None:
    with pytest.raises(ValueError):
        Machine(MemoryStore()).step(-1.0)


def test_axes_are_referenced_at_power_on() -> None:
    assert all(a.referenced for a in Machine(MemoryStore()).axes)
