from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from simulator.geometry import ArcError, Line, arc_from_center, arc_from_radius


def flat(box: tuple[tuple[float, ...], tuple[float, ...]]) -> tuple[float, ...]:
    return box[0] + box[1]


def test_line_length_point_tangent_and_bounds() -> None:
    line = Line((0.0, 0.0, 0.0), (30.0, -40.0, 0.0))
    assert line.length == 50.0
    assert line.at(25.0) == pytest.approx((15.0, -20.0, 0.0))
    assert line.tangent(0.0) == pytest.approx((0.6, -0.8, 0.0))
    assert line.bounds() == ((0.0, -40.0, 0.0), (30.0, 0.0, 0.0))


def test_full_circle_from_center() -> None:
    arc = arc_from_center((10.0, 0.0, 0.0), (10.0, 0.0, 0.0), -10.0, 0.0, clockwise=False)
    assert arc.sweep == pytest.approx(2 * math.pi)
    assert arc.length == pytest.approx(20 * math.pi)
    assert flat(arc.bounds()) == pytest.approx((-10.0, -10.0, 0.0, 10.0, 10.0, 0.0))
    assert arc.at(arc.length / 4) == pytest.approx((0.0, 10.0, 0.0), abs=1e-9)  # counter-clockwise: up first


def test_helix_length_and_z() -> None:
    arc = arc_from_center((10.0, 0.0, 0.0), (10.0, 0.0, -3.0), -10.0, 0.0, clockwise=True)
    assert arc.length == pytest.approx(math.hypot(20 * math.pi, 3.0))
    assert arc.at(arc.length / 2)[2] == pytest.approx(-1.5)


def test_quarter_arc_bounds_only_cover_the_swept_quadrant() -> None:
    arc = arc_from_center((10.0, 0.0, 0.0), (0.0, 10.0, 0.0), -10.0, 0.0, clockwise=False)
    assert flat(arc.bounds()) == pytest.approx((0.0, 0.0, 0.0, 10.0, 10.0, 0.0))
    other_way = arc_from_center((10.0, 0.0, 0.0), (0.0, 10.0, 0.0), -10.0, 0.0, clockwise=True)
    assert other_way.sweep == pytest.approx(1.5 * math.pi)
    assert flat(other_way.bounds()) == pytest.approx((-10.0, -10.0, 0.0, 10.0, 10.0, 0.0))


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: arc_from_center((0.0, 0.0, 0.0), (5.0, 0.0, 0.0), 0.0, 0.0, True), "coincides"),
        (lambda: arc_from_center((0.0, 0.0, 0.0), (30.0, 0.0, 0.0), 10.0, 0.0, True), "off the circle"),
        (lambda: arc_from_radius((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 5.0, True), "different from its start"),
        (lambda: arc_from_radius((0.0, 0.0, 0.0), (30.0, 0.0, 0.0), 10.0, True), "too small"),
        (lambda: arc_from_radius((0.0, 0.0, 0.0), (3.0, 0.0, 0.0), 0.0, True), "must not be 0"),
    ],
)
def test_impossible_arcs(make: object, message: str) -> None:
    with pytest.raises(ArcError, match=message):
        make()  # type: ignore[operator]


@given(
    st.floats(1.0, 500.0),
    st.floats(0.0, 2 * math.pi),
    st.floats(0.01, 2 * math.pi - 0.01),
    st.booleans(),
    st.booleans(),
)
def test_r_arcs_end_where_asked_with_the_expected_sweep(
    r: float, start_angle: float, sweep: float, clockwise: bool, minor_sign: bool
) -> None:
    start = (r * math.cos(start_angle), r * math.sin(start_angle), 0.0)
    end_angle = start_angle - sweep if clockwise else start_angle + sweep
    end = (r * math.cos(end_angle), r * math.sin(end_angle), 0.0)
    radius = r if sweep <= math.pi else -r
    arc = arc_from_radius(start, end, radius, clockwise)
    assert arc.sweep == pytest.approx(sweep, abs=1e-6)
    assert arc.at(arc.length) == end
    assert arc.center == pytest.approx((0.0, 0.0), abs=1e-6 * r)
    lo, hi = arc.bounds()
    for s in (arc.length * k / 16 for k in range(17)):
        p = arc.at(s)
        assert lo[0] - 1e-9 <= p[0] <= hi[0] + 1e-9 and lo[1] - 1e-9 <= p[1] <= hi[1] + 1e-9
