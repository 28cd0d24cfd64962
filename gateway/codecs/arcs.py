"""G2/G3 arc geometry by centre or by radius, in any plane (pure): the job estimator's and the simulator's.

Coordinates are plane coordinates (u, v), with w the axis normal to the plane
(G17: X, Y and Z; G18: Z, X and Y; G19: Y, Z and X), so one set of formulas
serves all three planes with the same sense of clockwise. The estimator
(gateway/jobs/validation/) needs an arc's length and the points where it reaches
its extremes; the simulator (simulator/geometry.py) also walks along it
(`angle_at`, `radius_at`, `point_at`) and keeps its own 3-D segment, its own
bounding box (the larger radius all round: a soft-limit check errs outward) and
its own tangent.

The arithmetic is the estimator's, operation by operation: the compiled reader
(gateway/jobs/validation/_plain.c) repeats it, and the two readers' estimates
agree to the bit. Change it there too, or the differential tests fail.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gateway.errors import CodecError

TAU = 2.0 * math.pi
#: Start and end closer than this (mm) make a full circle.
SAME_POINT = 1e-6
#: How far (mm) an end point may lie off the circle before the estimator says so.
TOLERANCE = 0.005

Point2 = tuple[float, float]


def distance(du: float, dv: float) -> float:
    """The length of (du, dv), computed plainly, not with `math.hypot`'s extra precision.

    The compiled plain-block reader (`_plain.c`) repeats this arithmetic
    operation by operation, so both readers give bit-identical estimates; for
    coordinates in millimetres the two formulas agree to the last digit or two.
    """
    return math.sqrt(du * du + dv * dv)


class ArcProblem(CodecError):
    """Arc words that describe no arc; the message becomes an estimator note, or a simulator alarm."""


@dataclass(frozen=True, slots=True)
class PlaneArc:
    """An arc around `center` swept by `sweep` radians (> 0) from angle `a0`.

    The radius may change linearly from r0 to r1 (an end point off the circle:
    the controller may refuse it, the estimator reads it as a spiral), and w
    changes linearly by `dw` (a helix).
    """

    center: Point2
    a0: float
    sweep: float
    clockwise: bool
    r0: float
    r1: float
    dw: float = 0.0

    @property
    def length(self) -> float:
        return distance(0.5 * (self.r0 + self.r1) * self.sweep, self.dw)

    @property
    def mismatch(self) -> float:
        """How far (mm) the end point lies off the circle through the start point."""
        return abs(self.r1 - self.r0)

    @property
    def off_circle(self) -> bool:
        """Whether the end point lies further off the circle than a controller tolerates (TOLERANCE, or
        0.1 % of the radius on large arcs)."""
        return self.mismatch > max(TOLERANCE, 0.001 * self.r0)

    def crossings(self) -> list[tuple[float, float]]:
        """The angles of the ±u and ±v directions (0, π/2, π, 3π/2) that the arc passes, each with the
        share of the sweep (0..1) at which it passes them."""
        out: list[tuple[float, float]] = []
        for k in range(4):
            angle = k * math.pi / 2
            offset = (self.a0 - angle) % TAU if self.clockwise else (angle - self.a0) % TAU
            if offset <= self.sweep:
                out.append((angle, offset / self.sweep if self.sweep else 0.0))
        return out

    def extremes(self) -> list[Point2]:
        """The points where the arc crosses the ±u and ±v directions from its centre."""
        out: list[Point2] = []
        for angle, f in self.crossings():
            r = self.r0 + (self.r1 - self.r0) * min(f, 1.0)
            out.append((self.center[0] + r * math.cos(angle), self.center[1] + r * math.sin(angle)))
        return out

    def angle_at(self, f: float) -> float:
        """The angle (radians) a share `f` (0..1) of the way along the sweep."""
        return self.a0 - f * self.sweep if self.clockwise else self.a0 + f * self.sweep

    def radius_at(self, f: float) -> float:
        return self.r0 + (self.r1 - self.r0) * f

    def point_at(self, f: float) -> Point2:
        """The (u, v) point a share `f` (0..1) of the way along the sweep."""
        a, r = self.angle_at(f), self.radius_at(f)
        return (self.center[0] + r * math.cos(a), self.center[1] + r * math.sin(a))


def _sweep(start: Point2, end: Point2, center: Point2, clockwise: bool, turns: int) -> tuple[float, float]:
    a0 = math.atan2(start[1] - center[1], start[0] - center[0])
    a1 = math.atan2(end[1] - center[1], end[0] - center[0])
    if distance(start[0] - end[0], start[1] - end[1]) < SAME_POINT:
        sweep = TAU
    else:
        sweep = (a0 - a1) % TAU if clockwise else (a1 - a0) % TAU
    return a0, sweep + TAU * (turns - 1)


def arc_from_center(
    start: Point2, end: Point2, center: Point2, clockwise: bool, *, turns: int = 1, dw: float = 0.0
) -> PlaneArc:
    """An arc by its centre (already absolute). Start == end is a full circle."""
    r0 = distance(start[0] - center[0], start[1] - center[1])
    r1 = distance(end[0] - center[0], end[1] - center[1])
    if r0 < SAME_POINT:
        raise ArcProblem("the arc centre coincides with its start point")
    a0, sweep = _sweep(start, end, center, clockwise, turns)
    return PlaneArc(center, a0, sweep, clockwise, r0, r1, dw)


def arc_from_radius(
    start: Point2, end: Point2, radius: float, clockwise: bool, *, turns: int = 1, dw: float = 0.0
) -> PlaneArc:
    """An arc by radius: R > 0 takes the arc of at most 180 degrees, R < 0 the longer one."""
    du, dv = end[0] - start[0], end[1] - start[1]
    chord = distance(du, dv)
    r = abs(radius)
    if chord < SAME_POINT:
        raise ArcProblem("an R arc cannot be a full circle: its end point must be different from its start")
    if r < SAME_POINT:
        raise ArcProblem("arc radius R must not be 0")
    if chord > 2 * r + TOLERANCE:
        raise ArcProblem(f"arc radius R{radius:g} is too small for a chord of {chord:.4f} mm")
    h = math.sqrt(max(r * r - (chord / 2) ** 2, 0.0))
    # The centre of the shorter arc lies left of the chord for G3 (counter-clockwise), right for G2.
    left = (-dv / chord, du / chord)
    side = -1.0 if clockwise else 1.0
    if radius < 0:
        side = -side
    center = (start[0] + du / 2 + side * h * left[0], start[1] + dv / 2 + side * h * left[1])
    a0, sweep = _sweep(start, end, center, clockwise, turns)
    return PlaneArc(center, a0, sweep, clockwise, r, r, dw)
