"""Path segments in machine coordinates: straight lines and XY arcs (optionally helical).

A segment answers what the executor and the soft-limit check need: its length,
the point and the unit tangent at a distance along it, and the box it sweeps.
The arc geometry itself (centre, sweep, length, the points it passes) is the
gateway's, gateway/codecs/arcs.py, so the simulator runs the arcs the job
estimator timed; only the 3-D walk, the tangent and the box are kept here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gateway.codecs import arcs
from gateway.codecs.arcs import ArcProblem, PlaneArc

Point = tuple[float, float, float]

#: Arc words that describe no arc; the message is shown in a program-error alarm.
ArcError = ArcProblem


@dataclass(frozen=True, slots=True)
class Line:
    start: Point
    end: Point

    @property
    def length(self) -> float:
        return math.dist(self.start, self.end)

    def at(self, s: float) -> Point:
        f = 0.0 if self.length == 0 else min(max(s / self.length, 0.0), 1.0)
        (x0, y0, z0), (x1, y1, z1) = self.start, self.end
        return (x0 + (x1 - x0) * f, y0 + (y1 - y0) * f, z0 + (z1 - z0) * f)

    def tangent(self, s: float) -> Point:
        length = self.length
        if length == 0:
            return (0.0, 0.0, 0.0)
        (x0, y0, z0), (x1, y1, z1) = self.start, self.end
        return ((x1 - x0) / length, (y1 - y0) / length, (z1 - z0) / length)

    def bounds(self) -> tuple[Point, Point]:
        (x0, y0, z0), (x1, y1, z1) = self.start, self.end
        return (min(x0, x1), min(y0, y1), min(z0, z1)), (max(x0, x1), max(y0, y1), max(z0, z1))


@dataclass(frozen=True, slots=True)
class Arc:
    """An arc in the XY plane from `start` to `end`, Z changing linearly (a helix): `plane` in 3-D.

    The radius may change linearly from `plane.r0` to `plane.r1` (an end point a
    hair off the circle, within tolerance).
    """

    start: Point
    end: Point
    plane: PlaneArc

    @property
    def center(self) -> tuple[float, float]:
        return self.plane.center

    @property
    def sweep(self) -> float:
        return self.plane.sweep

    @property
    def clockwise(self) -> bool:
        return self.plane.clockwise

    @property
    def length(self) -> float:
        return self.plane.length

    def at(self, s: float) -> Point:
        length = self.length
        f = 1.0 if length == 0 else min(max(s / length, 0.0), 1.0)
        if f >= 1.0:
            return self.end
        x, y = self.plane.point_at(f)
        return (x, y, self.start[2] + (self.end[2] - self.start[2]) * f)

    def tangent(self, s: float) -> Point:
        length = self.length
        if length == 0:
            return (0.0, 0.0, 0.0)
        plane = self.plane
        f = min(max(s / length, 0.0), 1.0)
        a, r = plane.angle_at(f), plane.radius_at(f)
        dtheta = (-plane.sweep if plane.clockwise else plane.sweep) / length
        dr = (plane.r1 - plane.r0) / length
        dz = (self.end[2] - self.start[2]) / length
        return (dr * math.cos(a) - r * math.sin(a) * dtheta, dr * math.sin(a) + r * math.cos(a) * dtheta, dz)

    def bounds(self) -> tuple[Point, Point]:
        plane = self.plane
        r = max(plane.r0, plane.r1)  # the larger radius all round: the soft-limit check errs outward
        xs = [self.start[0], self.end[0]]
        ys = [self.start[1], self.end[1]]
        for angle, _ in plane.crossings():
            xs.append(plane.center[0] + r * math.cos(angle))
            ys.append(plane.center[1] + r * math.sin(angle))
        zs = [self.start[2], self.end[2]]
        return (min(xs), min(ys), min(zs)), (max(xs), max(ys), max(zs))


Segment = Line | Arc


def arc_from_center(start: Point, end: Point, i: float, j: float, clockwise: bool) -> Arc:
    """An arc by centre offsets I/J from the start (LinuxCNC/Fanuc incremental I/J)."""
    center = (start[0] + i, start[1] + j)
    plane = arcs.arc_from_center(start[:2], end[:2], center, clockwise, dw=end[2] - start[2])
    if plane.off_circle:
        raise ArcError(f"arc end point is {plane.mismatch:.4f} mm off the circle (radius {plane.r0:.4f} mm)")
    return Arc(start, end, plane)


def arc_from_radius(start: Point, end: Point, radius: float, clockwise: bool) -> Arc:
    """An arc by radius: R > 0 takes the minor arc (<= 180 deg), R < 0 the major arc."""
    return Arc(start, end, arcs.arc_from_radius(start[:2], end[:2], radius, clockwise, dw=end[2] - start[2]))
