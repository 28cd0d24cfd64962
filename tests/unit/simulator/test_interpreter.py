from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from simulator.interpreter import BeginBlock, Dwell, Fault, Move, ProgramEnd, SetLaser, SetPower, plan_program
from simulator.machine import Machine, MachineState
from simulator.store import MemoryStore

ORIGIN = (0.0, 0.0, 0.0)


def test_total_path_counts_every_move() -> None:
    plan = plan_program("G0 X30 Y40\nG1 X30 Y0 F100\nG2 X30 Y0 I0 J10\nM30\n", ORIGIN)
    assert plan.total_path == pytest.approx(50 + 40 + 2 * math.pi * 10)
    assert isinstance(plan.actions[-1], ProgramEnd) and plan.actions[-1].count_part


def test_common_preamble_codes_are_accepted() -> None:
    plan = plan_program("G17 G21 G40 G49 G54 G80 G90 G94\nM30\n", ORIGIN)
    assert not any(isinstance(a, Fault) for a in plan.actions)


def test_order_within_a_block_puts_the_laser_before_the_motion() -> None:
    plan = plan_program("G1 X10 F100 S2000 M3\nG4 P0.5 M5\nM30\n", ORIGIN)
    kinds = [type(a).__name__ for a in plan.actions]
    assert kinds == [
        "BeginBlock",
        "SetPower",
        "SetLaser",
        "Move",
        "BeginBlock",
        "SetLaser",
        "Dwell",
        "BeginBlock",
        "ProgramEnd",
    ]
    assert plan.actions[1] == SetPower(2000.0) and plan.actions[2] == SetLaser(True)
    assert plan.actions[6] == Dwell(0.5)


def test_planning_stops_at_the_first_fault_and_lines_after_the_end_marker_are_ignored() -> None:
    plan = plan_program("%\nG0 X10\nG0 X20\n%\nG5.2 (never read)\n", ORIGIN)
    assert plan.total_path == 20.0 and isinstance(plan.actions[-1], ProgramEnd)
    plan = plan_program("G0 X10\nG0 Y5000\nG0 X20\n", ORIGIN)
    assert isinstance(plan.actions[-1], Fault) and plan.total_path == 10.0
    assert plan.actions[-1].alarm.text == "Soft limit Y+ exceeded at line 2"


def test_begin_block_carries_line_and_stripped_text() -> None:
    plan = plan_program("\n  N5 G0 X1 (go)  \nM30\n", ORIGIN)
    assert plan.actions[0] == BeginBlock(2, "N5 G0 X1 (go)")


def test_modal_motion_and_feed_carry_over() -> None:
    plan = plan_program("G1 X10 F300\nX20\nY10\nM30\n", ORIGIN)
    moves = [a for a in plan.actions if isinstance(a, Move)]
    assert [m.feed for m in moves] == [300.0, 300.0, 300.0]
    assert moves[-1].segment.end == (20.0, 10.0, 0.0)


def test_o_word_lines_are_program_numbers() -> None:
    plan = plan_program("O1234 (PART)\nG0 X1\nM30\n", ORIGIN)
    assert not any(isinstance(a, Fault) for a in plan.actions)
    plan = plan_program("O1234 G0 X1\n", ORIGIN)
    assert isinstance(plan.actions[-1], Fault) and "O word" in plan.actions[-1].alarm.text


def test_limits_are_configurable() -> None:
    limits = {"X": (0.0, 100.0), "Y": (0.0, 100.0), "Z": (0.0, 10.0)}
    plan = plan_program("G0 X150\n", ORIGIN, limits=limits)
    assert isinstance(plan.actions[-1], Fault) and "X+" in plan.actions[-1].alarm.text


gcode_like = st.text(alphabet="GMXYZIJRFSPNO0123456789.- \n()%;/", max_size=200)


@given(st.one_of(gcode_like, st.text(max_size=100)))
@settings(max_examples=300)
def test_any_text_plans_to_an_end_or_a_fault_and_runs_without_crashing(text: str) -> None:
    plan = plan_program(text, (10.0, 10.0, 0.0))
    assert isinstance(plan.actions[-1], (ProgramEnd, Fault))
    assert not any(isinstance(a, (ProgramEnd, Fault)) for a in plan.actions[:-1])
    m = Machine(MemoryStore({"p.nc": text}))
    m.select_program("p.nc")
    m.start()
    for _ in range(50):
        m.step(50.0)
        if m.state is MachineState.PAUSED:
            m.resume()
    assert all(math.isfinite(a.actual) for a in m.axes)
