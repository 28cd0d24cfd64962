"""The run-time estimator: hand-computed programs, what it refuses to guess, and Hypothesis properties."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gateway.codecs.gcode import format_number, parse_program
from gateway.jobs.validation.estimate import MAX_NOTES, Estimate, Extents, estimate_program

RAPID = 6000.0  # mm/min: 100 mm/s, easy to compute by hand
FAST = 1e12  # a rapid speed that never clamps a feed in the properties


def est(text: str, *, rapid: float = RAPID, **kwargs: object) -> Estimate:
    return estimate_program(parse_program(text), rapid_feed_mm_min=rapid, **kwargs)  # type: ignore[arg-type]


def close(a: float | None, b: float, rel: float = 1e-9) -> bool:
    return a is not None and math.isclose(a, b, rel_tol=rel, abs_tol=1e-9)


def n(value: float) -> str:
    return format_number(value)


# --- by hand -------------------------------------------------------------------------------------


def test_lines_rapids_and_dwell_by_hand() -> None:
    e = est("G21 G90\nG0 X30 Y40\nG1 X60 Y80 F600\nG4 P1.5\nG1 Z-3\nM30\n")
    # rapid 50 mm at 100 mm/s; feed 50 mm + 3 mm at 10 mm/s; dwell 1.5 s
    assert e.rapid_mm == pytest.approx(50.0) and e.cut_mm == pytest.approx(53.0)
    assert e.dwell_s == 1.5
    assert e.seconds == pytest.approx(0.5 + 5.3 + 1.5)
    assert e.exact and e.notes == ()
    assert e.extents == Extents(30.0, 60.0, 40.0, 80.0, -3.0, 0.0)
    assert e.blocks == 6


def test_full_circle_by_ij_and_its_extents() -> None:
    e = est("G0 X10 Y0\nG2 X10 Y0 I-10 J0 F600\nM2\n")
    assert e.cut_mm == pytest.approx(2 * math.pi * 10)
    assert e.seconds == pytest.approx(0.1 + 2 * math.pi * 10 / 10)
    assert e.extents == Extents(-10.0, 10.0, -10.0, 10.0, 0.0, 0.0)


def test_quarter_arcs_by_r_minor_and_major() -> None:
    minor = est("G0 X10 Y0\nG3 X0 Y10 R10 F600\n")
    major = est("G0 X10 Y0\nG3 X0 Y10 R-10 F600\n")
    assert minor.cut_mm == pytest.approx(10 * math.pi / 2)
    assert major.cut_mm == pytest.approx(10 * 3 * math.pi / 2)
    # the counter-clockwise 270-degree arc from (10,0) to (0,10) turns round (10,10),
    # through (20,10) and (10,20)
    assert major.extents is not None
    assert major.extents.as_dict() == pytest.approx(Extents(0.0, 20.0, 0.0, 20.0, 0.0, 0.0).as_dict())
    assert minor.extents is not None and minor.extents.min_x == pytest.approx(0.0)


def test_helix_and_turns() -> None:
    e = est("G0 X5\nG17 G3 X5 Y0 Z-6 I-5 J0 P3 F600\n")
    planar = 3 * 2 * math.pi * 5
    assert e.cut_mm == pytest.approx(math.hypot(planar, 6.0))


def test_planes_g18_and_g19() -> None:
    xz = est("G0 X10\nG18 G2 X-10 Z0 I-10 K0 F600\n")
    yz = est("G0 Y10\nG19 G2 Y-10 Z0 J-10 K0 F600\n")
    assert xz.cut_mm == pytest.approx(10 * math.pi) and yz.cut_mm == pytest.approx(10 * math.pi)
    # a half circle in the XZ (YZ) plane reaches 10 mm along Z and stays in its plane
    assert xz.extents is not None and xz.extents.max_y == 0.0
    assert xz.extents.max_z - xz.extents.min_z == pytest.approx(10.0)
    assert yz.extents is not None and yz.extents.max_x == 0.0
    assert yz.extents.max_z - yz.extents.min_z == pytest.approx(10.0)


def test_inches_incremental_and_g92() -> None:
    e = est("G20 G91\nG1 X1 Y0 F10\nG1 X1\nG90 G92 X0 Y0\nG1 X1\nM30\n")
    # 2 in incremental, then G92 makes the current point (2 in, 0) the new zero: X1 moves 1 in further
    assert e.cut_mm == pytest.approx(3 * 25.4)
    assert e.seconds == pytest.approx(3 * 25.4 / (10 * 25.4) * 60)
    assert e.extents is not None and e.extents.max_x == pytest.approx(3 * 25.4)


def test_feed_carries_over_unit_changes_as_a_physical_speed() -> None:
    e = est("G21 G1 X25.4 F254\nG20 X2\n")  # 254 mm/min stays 254 mm/min after G20
    assert e.seconds == pytest.approx(2 * 25.4 / 254 * 60)


def test_dwell_units_and_fanuc_x_and_sinumerik_f() -> None:
    assert est("G4 P500\n", dwell_p="milliseconds").dwell_s == 0.5
    assert est("G4 P2\n").dwell_s == 2.0
    assert est("G4 X1.5\n").dwell_s == 1.5
    e = est("G1 X10 F600\nG4 F2\nG1 X20\n")
    assert e.dwell_s == 2.0 and e.seconds == pytest.approx(2.0 + 2.0)  # F2 is the dwell, not a new feed


def test_inverse_time_g93() -> None:
    e = est("G93 G1 X100 F2\nG1 X0\nG94\n")
    assert e.seconds == pytest.approx(30.0)
    assert not e.exact and any("line 2" in note and "G93" in note for note in e.notes)


def test_feed_per_revolution_is_noted_not_guessed() -> None:
    e = est("G95 G1 X10 F0.1\n")
    assert not e.exact and e.cut_mm == 10.0 and e.seconds is None
    assert e.notes == ("line 1: feed per revolution (G95) is not estimated",)


def test_move_without_feed_is_noted_or_uses_the_default() -> None:
    bare = est("G0 X10\nG1 X20\nG1 X30 F600\n")
    assert not bare.exact
    assert bare.notes == ("line 2: a feed move before any feed rate (F) is not estimated",)
    assert bare.seconds == pytest.approx(0.1 + 1.0) and bare.cut_mm == 20.0
    dflt = est("G0 X10\nG1 X20\nG1 X30 F600\n", default_feed_mm_min=300.0)
    assert dflt.seconds == pytest.approx(0.1 + 2.0 + 1.0)
    assert not dflt.exact and "default 300 mm/min" in dflt.notes[0]


def test_feed_above_rapid_is_clamped() -> None:
    e = est("G1 X100 F60000\n")
    assert e.seconds == pytest.approx(1.0) and e.exact
    assert "above the rapid speed" in e.notes[0]


def test_canned_cycle_nurbs_and_polar_are_noted_and_the_rest_estimated() -> None:
    text = (
        "G0 X0 Y0 Z5\n"  # 5 mm rapid
        "G81 X10 Y10 Z-2 R1 F100\n"  # line 2
        "X20\n"  # line 3: the cycle repeats at the new X
        "G80\n"
        "G0 Z5\n"  # Z is unknown after the cycle: not counted
        "G0 X0 Y0 Z5\n"  # known again from here
        "G5.2 X1 Y1 P1 L3\n"  # line 7
        "X2 Y-3 P1\n"
        "X3 Y0 P1\n"
        "G5.3\n"
        "G1 X13 F600\n"  # 10 mm cut
        "G1 @5 ^90\n"  # line 12: polar
        "M2\n"
    )
    e = est(text)
    assert not e.exact
    assert e.notes[0] == "line 2: canned cycle G81 is not estimated"
    assert e.notes[1] == "line 3: canned cycle G81 is not estimated"
    assert any(note.startswith("line 7: NURBS") for note in e.notes)
    assert "line 12: polar words (^ and @) are not estimated" in e.notes
    assert e.cut_mm == pytest.approx(10.0)
    assert (
        e.extents is not None and e.extents.min_z == -2.0 and e.extents.min_y == -3.0
    )  # cycle depth, control point


def test_unknown_position_after_g28_until_known_again() -> None:
    e = est("G1 X10 F600\nG28\nG1 X20\nG0 X0 Y0 Z0\nG1 X10\n")
    assert "line 3: a move from an unknown position (unknown since line 2) is not estimated" in e.notes
    assert e.cut_mm == pytest.approx(20.0)  # lines 1 and 5


def test_unknown_g_code_and_extra_axes_are_noted() -> None:
    e = est("G12.5 G1 X10 A90 F600\n")
    assert e.notes == (
        "line 1: unknown code G12.5: its effect is not estimated",
        "line 1: A axis motion is not included in the length",
    )
    assert e.cut_mm == 10.0 and not e.exact


def test_estimation_stops_at_the_end_code() -> None:
    e = est("G1 X10 F600\nM30\nG1 X1000\n")
    assert e.cut_mm == 10.0


def test_nothing_estimable_gives_none() -> None:
    e = est("G81 X1 Y1 Z-1 R1 F10\n")
    assert e.seconds is None and not e.exact


def test_empty_program_is_zero_with_no_extents() -> None:
    e = est("M3\nM5\n")
    assert e.seconds == 0.0 and e.extents is None and e.exact


def test_notes_are_capped() -> None:
    e = est("".join("G81 X1 Y1 Z-1 R1 F10\n" for _ in range(80)))
    assert len(e.notes) == MAX_NOTES + 1 and e.notes[-1] == "and 30 more notes"


def test_as_dict_is_json() -> None:
    e = est("G2 X0 Y0 I5 F100\nG5.2 X1 Y1 P1\nG5.3\n")
    d = json.loads(json.dumps(e.as_dict()))
    assert set(d) == {"seconds", "cut_mm", "rapid_mm", "dwell_s", "blocks", "extents", "exact", "notes"}
    assert d["extents"] == {
        "min_x": 0.0,
        "max_x": 10.0,
        "min_y": -5.0,
        "max_y": 5.0,
        "min_z": 0.0,
        "max_z": 0.0,
    }
    assert d["exact"] is False


def test_bad_arguments() -> None:
    with pytest.raises(ValueError):
        est("G1 X1\n", rapid=0)


# --- properties ----------------------------------------------------------------------------------

coord = st.floats(min_value=-2000, max_value=2000, allow_nan=False, allow_infinity=False)
feed = st.floats(min_value=0.5, max_value=50000, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord, coord)


@settings(max_examples=200, deadline=None)
@given(start=point, end=point, f=feed)
def test_straight_move_takes_its_length_over_its_feed(
    start: tuple[float, float, float], end: tuple[float, float, float], f: float
) -> None:
    # G92 declares where the tool is without moving it, so the estimate is this one move alone.
    text = (
        f"G92 X{n(start[0])} Y{n(start[1])} Z{n(start[2])}\n"
        f"G1 X{n(end[0])} Y{n(end[1])} Z{n(end[2])} F{n(f)}\n"
    )
    e = est(text, rapid=FAST)
    length = math.dist(start, end)
    assert close(e.cut_mm, length)
    assert close(e.seconds, length / f * 60.0)
    assert e.exact


@settings(max_examples=100, deadline=None)
@given(points=st.lists(st.tuples(st.booleans(), point), min_size=1, max_size=8), f=feed)
def test_absolute_and_incremental_give_the_same_estimate(
    points: list[tuple[bool, tuple[float, float, float]]], f: float
) -> None:
    absolute = [f"G90 F{n(f)}"]
    incremental = [f"G91 F{n(f)}"]
    here = (0.0, 0.0, 0.0)
    for rapid, p in points:
        g = "G0" if rapid else "G1"
        absolute.append(f"{g} X{n(p[0])} Y{n(p[1])} Z{n(p[2])}")
        d = [b - a for a, b in zip(here, p, strict=True)]
        incremental.append(f"{g} X{n(d[0])} Y{n(d[1])} Z{n(d[2])}")
        here = p
    a = est("\n".join(absolute), rapid=RAPID)
    i = est("\n".join(incremental), rapid=RAPID)
    assert close(i.seconds, a.seconds or 0.0, rel=1e-7)
    assert close(i.cut_mm, a.cut_mm, rel=1e-7) and close(i.rapid_mm, a.rapid_mm, rel=1e-7)


@settings(max_examples=100, deadline=None)
@given(points=st.lists(point, min_size=1, max_size=6), f=st.floats(min_value=0.1, max_value=1000))
def test_inch_and_mm_versions_agree(points: list[tuple[float, float, float]], f: float) -> None:
    inch = ["G20 G90"] + [f"G1 X{n(x)} Y{n(y)} Z{n(z)} F{n(f)}" for x, y, z in points]
    mm = ["G21 G90"] + [
        f"G1 X{n(x * 25.4)} Y{n(y * 25.4)} Z{n(z * 25.4)} F{n(f * 25.4)}" for x, y, z in points
    ]
    a, b = est("\n".join(inch), rapid=FAST), est("\n".join(mm), rapid=FAST)
    assert close(a.seconds, b.seconds or 0.0, rel=1e-7)
    assert a.extents is not None and b.extents is not None
    for key, value in a.extents.as_dict().items():
        assert math.isclose(value, b.extents.as_dict()[key], rel_tol=1e-9, abs_tol=1e-6)


@settings(max_examples=200, deadline=None)
@given(
    cx=st.floats(-500, 500),
    cy=st.floats(-500, 500),
    r=st.floats(0.5, 500),
    a0=st.floats(-math.pi, math.pi),
    theta=st.floats(0.05, 2 * math.pi - 0.05),
    clockwise=st.booleans(),
    by_radius=st.booleans(),
    f=feed,
)
def test_arc_takes_r_theta_over_feed(
    cx: float, cy: float, r: float, a0: float, theta: float, clockwise: bool, by_radius: bool, f: float
) -> None:
    a1 = a0 - theta if clockwise else a0 + theta
    sx, sy = cx + r * math.cos(a0), cy + r * math.sin(a0)
    ex, ey = cx + r * math.cos(a1), cy + r * math.sin(a1)
    assume(math.hypot(ex - sx, ey - sy) > 1e-3)
    centre = f"R{n(r if theta <= math.pi else -r)}" if by_radius else f"I{n(cx - sx)} J{n(cy - sy)}"
    g = "G2" if clockwise else "G3"
    text = f"G92 X{n(sx)} Y{n(sy)}\n{g} X{n(ex)} Y{n(ey)} {centre} F{n(f)}\n"
    e = est(text, rapid=FAST)
    assert close(e.cut_mm, r * theta, rel=1e-6)
    assert close(e.seconds, r * theta / f * 60.0, rel=1e-6)
    assert e.extents is not None
    assert cx - r - 1e-6 <= e.extents.min_x and e.extents.max_x <= cx + r + 1e-6


def test_g92_before_the_first_move_says_where_the_tool_starts() -> None:
    e = est("G92 X100 Y50\nG1 X110 F600\nG92 X0\nG1 X5\n")
    # the first G92 sets the start; the second (after a move) shifts coordinates: X5 is 5 mm further
    assert e.cut_mm == pytest.approx(15.0)
    assert e.extents is not None and (e.extents.min_x, e.extents.max_x) == (110.0, 115.0)


def test_arc_in_the_plane_is_estimated_while_the_normal_axis_is_unknown() -> None:
    e = est("G81 X0 Y0 Z-1 R1 F10\nG80\nG0 X10 Y0\nG2 X10 Y0 I-10 F600\n")
    # Z is unknown after the cycle, but neither the rapid nor the XY circle moves Z
    assert e.rapid_mm == pytest.approx(10.0)
    assert e.cut_mm == pytest.approx(2 * math.pi * 10)
    assert e.notes == ("line 1: canned cycle G81 is not estimated",)
