"""Path segments in machine coordinates: straight lines and XY arcs (optionally helical).

A segment answers what the executor and the soft-limit check need: its length,
the point and the unit tangent at a distance along it, and the box it sweeps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

Point = tuple[float, float, float]

TAU = 2.0 * math.pi


class ArcError(ValueError):
    """Arc words that describe no arc; the message is shown in a program-error alarm."""


@dataclass(frozen=True, slots=True)
class Line:
    start: Point
    end: Point

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def at(self, s: float) -> Point:
        f = 0.0 if self.length == 0 else min(max(s / self.length, 0.0), 1.0)
        return tuple(a + (b - a) * f for a, b in zip(self.start, self.end, strict=True))  # type: ignore[return-value]

    def tangent(self, s: float) -> Point:
        length = self.length
        if length == 0:
            return (0.0, 0.0, 0.0)
        return tuple((b - a) / length for a, b in zip(self.start, self.end, strict=True))  # type: ignore[return-value]

    def bounds(self) -> tuple[Point, Point]:
        lo = tuple(min(a, b) for a, b in zip(self.start, self.end, strict=True))
        hi = tuple(max(a, b) for a, b in zip(self.start, self.end, strict=True))
        return lo, hi  # type: ignore[return-value]


@dataclass(frozen=True, slots=True)
class Arc:
    """An arc in the XY plane around `center`, swept by `sweep` radians (> 0) from angle `a0`.

    The radius may change linearly from `r0` to `r1` (an end point a hair off the
    circle, within tolerance) and Z linearly from start to end (a helix).
    """

    start: Point
    end: Point
    center: tuple[float, float]
    clockwise: bool
    a0: float
    sweep: float
    r0: float
    r1: float

    @property
    def length(self) -> float:
        planar = 0.5 * (self.r0 + self.r1) * self.sweep
        return math.hypot(planar, self.end[2] - self.start[2])

    def _angle(self, f: float) -> float:
        return self.a0 - f * self.sweep if self.clockwise else self.a0 + f * self.sweep

    def at(self, s: float) -> Point:
        length = self.length
        f = 1.0 if length == 0 else min(max(s / length, 0.0), 1.0)
        if f >= 1.0:
            return self.end
        a = self._angle(f)
        r = self.r0 + (self.r1 - self.r0) * f
        z = self.start[2] + (self.end[2] - self.start[2]) * f
        return (self.center[0] + r * math.cos(a), self.center[1] + r * math.sin(a), z)

    def tangent(self, s: float) -> Point:
        length = self.length
        if length == 0:
            return (0.0, 0.0, 0.0)
        f = min(max(s / length, 0.0), 1.0)
        a = self._angle(f)
        r = self.r0 + (self.r1 - self.r0) * f
        dtheta = (-self.sweep if self.clockwise else self.sweep) / length
        dr = (self.r1 - self.r0) / length
        dz = (self.end[2] - self.start[2]) / length
        return (dr * math.cos(a) - r * math.sin(a) * dtheta, dr * math.sin(a) + r * math.cos(a) * dtheta, dz)

    def bounds(self) -> tuple[Point, Point]:
        r = max(self.r0, self.r1)
        xs = [self.start[0], self.end[0]]
        ys = [self.start[1], self.end[1]]
        # The arc reaches the circle's extreme in a direction if it sweeps past that angle.
        for k in range(4):
            angle = k * math.pi / 2
            offset = (self.a0 - angle) % TAU if self.clockwise else (angle - self.a0) % TAU
            if offset <= self.sweep:
                xs.append(self.center[0] + r * math.cos(angle))
                ys.append(self.center[1] + r * math.sin(angle))
        zs = [self.start[2], self.end[2]]
        return (min(xs), min(ys), min(zs)), (max(xs), max(ys), max(zs))


Segment = Line | Arc

#: How far (mm) an arc's end may lie off the circle through its start before it is an error.
ARC_TOLERANCE = 0.005
#: Start and end closer than this (mm) make a full circle (I/J arcs).
SAME_POINT = 1e-6


def arc_from_center(start: Point, end: Point, i: float, j: float, clockwise: bool) -> Arc:
    """An arc by centre offsets I/J from the start (LinuxCNC/Fanuc incremental I/J)."""
    cx, cy = start[0] + i, start[1] + j
    r0 = math.hypot(start[0] - cx, start[1] - cy)
    r1 = math.hypot(end[0] - cx, end[1] - cy)
    if r0 < SAME_POINT:
        raise ArcError("arc centre (I/J) coincides with its start point")
    if abs(r1 - r0) > max(ARC_TOLERANCE, 0.001 * r0):
        raise ArcError(f"arc end point is {abs(r1 - r0):.4f} mm off the circle (radius {r0:.4f} mm)")
    a0 = math.atan2(start[1] - cy, start[0] - cx)
    a1 = math.atan2(end[1] - cy, end[0] - cx)
    if math.hypot(end[0] - start[0], end[1] - start[1]) < SAME_POINT:
        sweep = TAU
    else:
        sweep = (a0 - a1) % TAU if clockwise else (a1 - a0) % TAU
    return Arc(start, end, (cx, cy), clockwise, a0, sweep, r0, r1)


def arc_from_radius(start: Point, end: Point, radius: float, clockwise: bool) -> Arc:
    """An arc by radius: R > 0 takes the minor arc (<= 180 deg), R < 0 the major arc."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    chord = math.hypot(dx, dy)
    r = abs(radius)
    if chord < SAME_POINT:
        raise ArcError("an R arc needs an end point different from its start (use I/J for a full circle)")
    if r < SAME_POINT:
        raise ArcError("arc radius R must not be 0")
    if chord > 2 * r + ARC_TOLERANCE:
        raise ArcError(f"arc radius R{radius:g} is too small for a chord of {chord:.4f} mm")
    h = math.sqrt(max(r * r - (chord / 2) ** 2, 0.0))
    # The centre of a minor arc lies left of the chord for G3 (counter-clockwise), right for G2.
    left = (-dy / chord, dx / chord)
    side = -1.0 if clockwise else 1.0
    if radius < 0:
        side = -side
    cx = start[0] + dx / 2 + side * h * left[0]
    cy = start[1] + dy / 2 + side * h * left[1]
    a0 = math.atan2(start[1] - cy, start[0] - cx)
    a1 = math.atan2(end[1] - cy, end[0] - cx)
    sweep = (a0 - a1) % TAU if clockwise else (a1 - a0) % TAU
    return Arc(start, end, (cx, cy), clockwise, a0, sweep, r, r)
