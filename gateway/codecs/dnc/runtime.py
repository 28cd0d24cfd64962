"""How long each block of a program runs: t = s / v, the patent's rule, block by block (pure).

The drip scheduler needs to know how many seconds of cutting a chunk of bytes
carries. The job estimator (gateway/jobs/estimate.py) answers for a whole
program and lives above the codecs, so this is its small sibling for single
blocks: straight moves and arcs in the selected plane (G17/G18/G19, with a helical
third axis), rapids at the mapping's `rapid`, feeds in mm/min or in/min (G20/G21),
G93 inverse time, feed per revolution (G95 on a mill, G99 on a lathe) with the
spindle speed (G97 S in rpm, or G96 constant surface speed from the diameter,
clamped by G50 S on a lathe / G92 S on a mill), and dwells.

Which way to err. The estimate decides which drip-fed line is served first when
lines compete for a shared link (gateway/codecs/dnc/schedule.py): a line that
looks about to run dry goes first. So every guess errs short: whatever cannot be
timed (feed per revolution with no spindle speed, canned cycles, splines, a
lexing error) counts as 0 s, acceleration is ignored, and under constant surface
speed the spindle's fastest speed over the move is taken. A block estimated too
short only makes its line look hungrier and be served earlier; one estimated too
long would let its machine run dry while the scheduler thinks it still cuts.
The controller's DC1/DC3 then correct the per-line rate (schedule.py learns it).

`lathe=True` reads a Fanuc lathe's program (G-code system A): X is a diameter, U
and W are incremental X and Z, G98/G99 are feed per minute/per revolution, G18 is
the default plane and G50 S clamps the spindle speed. On a mill G98/G99 are the
canned cycles' return levels and are ignored here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from gateway.codecs.gcode import Block, lex_lines

DEFAULT_RAPID = 10_000.0  # mm/min: the mapping's `rapid` default (a machine faster than this is learned)
INCH = 25.4
FOOT = 304.8  # mm: G96's surface speed is in ft/min under G20
_AXES = "XYZ"
# The plane's two axes (indices into _AXES) and their arc-centre words: G17 XY (I J), G18 ZX (K I),
# G19 YZ (J K).
_PLANES = {17.0: ((0, 1), ("I", "J")), 18.0: ((2, 0), ("K", "I")), 19.0: ((1, 2), ("J", "K"))}


def block_times(
    text: str, *, rapid: float = DEFAULT_RAPID, dwell_ms: bool = False, lathe: bool = False
) -> dict[int, float]:
    """Seconds each line of the program runs, by line number (1-based); lines that take no time are absent.

    `dwell_ms`: G4 P is in milliseconds (Fanuc) rather than seconds (LinuxCNC, the simulator).
    `lathe`: a lathe's program (see the module docstring).
    """
    if rapid <= 0:
        raise ValueError("rapid must be > 0 mm/min")
    timer = _Timer(rapid, dwell_ms, lathe)
    return timer.run(item for item in lex_lines(text) if isinstance(item, Block))


class _Timer:
    def __init__(self, rapid: float, dwell_ms: bool, lathe: bool) -> None:
        self.rapid = rapid
        self.dwell_ms = dwell_ms
        self.lathe = lathe
        self.pos = [0.0, 0.0, 0.0]  # mm; on a lathe X is the radius here (the program's X is a diameter)
        self.absolute = True
        self.unit = 1.0  # mm per program unit
        self.motion: float | None = None
        self.plane = 18.0 if lathe else 17.0
        self.feed: float | None = None  # as programmed (program units per min or per rev, or 1/min)
        self.feed_unit = 1.0  # mm per program unit when the feed was programmed
        self.inverse = False
        self.per_rev = False
        self.spindle: float | None = None  # S as programmed: rpm (G97), or surface speed (G96)
        self.css = False
        self.spindle_max: float | None = None  # G50 S (lathe), G92 S (mill)

    def run(self, blocks: Iterable[Block]) -> dict[int, float]:
        times: dict[int, float] = {}
        for block in blocks:
            if block.marker or not block.words:
                continue
            seconds = self.block(block)
            if seconds > 0:
                times[block.line] = seconds
        return times

    def _modes(self, gs: set[float], values: dict[str, float]) -> None:
        if 20.0 in gs:
            self.unit = INCH
        if 21.0 in gs:
            self.unit = 1.0
        if 90.0 in gs:
            self.absolute = True
        if 91.0 in gs:
            self.absolute = False
        for plane in _PLANES:
            if plane in gs:
                self.plane = plane
        per_minute, per_rev = (98.0, 99.0) if self.lathe else (94.0, 95.0)
        if 93.0 in gs:
            self.inverse, self.per_rev = True, False
        if per_minute in gs:
            self.inverse, self.per_rev = False, False
        if per_rev in gs:
            self.inverse, self.per_rev = False, True
        if 96.0 in gs:
            self.css = True
        if 97.0 in gs:
            self.css = False
        clamp = 50.0 if self.lathe else 92.0
        if "S" in values:
            if clamp in gs:
                self.spindle_max = values["S"] if values["S"] > 0 else None
            else:
                self.spindle = values["S"]
        if "F" in values:
            self.feed = values["F"]
            self.feed_unit = self.unit

    def block(self, b: Block) -> float:
        gs = {w.value for w in b.words if w.letter == "G"}
        values = {w.letter: w.value for w in b.words if w.letter not in "GMN"}
        self._modes(gs, values)
        if 4.0 in gs:
            dwell = values.get("P", values.get("X", values.get("U", 0.0)))
            return max(0.0, dwell / 1000.0 if self.dwell_ms and "P" in values else dwell)
        for code in (0.0, 1.0, 2.0, 3.0):
            if code in gs:
                self.motion = code
        position_set = {50.0} if self.lathe else {92.0, 92.1}
        if gs & (position_set | {10.0, 28.0, 30.0, 53.0}) or self.motion is None:
            return 0.0  # position set, homing, machine moves: not timed
        start = list(self.pos)
        end = self._target(values)
        if end is None:
            return 0.0
        self.pos = end
        if self.motion in (2.0, 3.0):
            length = self._arc_length(start, end, values, clockwise=self.motion == 2.0)
        else:
            length = math.dist(start, end)
        if self.motion == 0.0:
            return length / (self.rapid / 60.0)
        feed = self._feed(start, end)
        if feed is None:
            return 0.0
        if self.inverse:
            return 60.0 / feed
        return length / (min(feed, self.rapid) / 60.0)

    def _target(self, values: dict[str, float]) -> list[float] | None:
        """Where the block moves to (mm, X as a radius on a lathe), None when it names no axis or arc."""
        end = list(self.pos)
        moved = False
        for i, axis in enumerate(_AXES):
            scale = self.unit / 2.0 if self.lathe and axis == "X" else self.unit
            if axis in values:
                value = values[axis] * scale
                end[i] = value if self.absolute else self.pos[i] + value
                moved = True
            incremental = {"X": "U", "Z": "W"}.get(axis) if self.lathe else None
            if incremental is not None and incremental in values:
                end[i] += values[incremental] * scale
                moved = True
        if not moved and not any(k in values for k in ("I", "J", "K", "R")):
            return None
        return end

    def _feed(self, start: list[float], end: list[float]) -> float | None:
        """The feed in mm/min (1/min under G93), None when it cannot be told (the move is not timed)."""
        if not self.feed or self.feed <= 0:
            return None
        if self.inverse:
            return self.feed
        if not self.per_rev:
            return self.feed * self.feed_unit
        rpm = self._rpm(min(abs(start[0]), abs(end[0])))
        return None if rpm is None else self.feed * self.feed_unit * rpm

    def _rpm(self, radius: float) -> float | None:
        """The spindle's speed over a move, its fastest where it varies (constant surface speed)."""
        if not self.spindle or self.spindle <= 0:
            return None
        if not self.css:
            return self.spindle
        surface = self.spindle * (FOOT if self.unit == INCH else 1000.0)  # mm/min
        rpm = surface / (2.0 * math.pi * radius) if radius > 0 else math.inf
        if self.spindle_max is not None:
            rpm = min(rpm, self.spindle_max)
        return None if math.isinf(rpm) else rpm

    def _arc_length(
        self, start: list[float], end: list[float], values: dict[str, float], *, clockwise: bool
    ) -> float:
        (a, b), (ca, cb) = _PLANES[self.plane]
        normal = 3 - a - b
        dn = end[normal] - start[normal]
        if "R" in values:
            r = abs(values["R"] * self.unit)
            chord = math.hypot(end[a] - start[a], end[b] - start[b])
            if r <= 0 or chord > 2 * r:
                return math.dist(start, end)
            half = math.asin(min(1.0, chord / (2 * r)))
            sweep = 2 * half if values["R"] > 0 else 2 * math.pi - 2 * half
        else:
            centre_a = start[a] + values.get(ca, 0.0) * self.unit
            centre_b = start[b] + values.get(cb, 0.0) * self.unit
            r = math.hypot(start[a] - centre_a, start[b] - centre_b)
            if r <= 0:
                return math.dist(start, end)
            a0 = math.atan2(start[b] - centre_b, start[a] - centre_a)
            a1 = math.atan2(end[b] - centre_b, end[a] - centre_a)
            sweep = (a0 - a1) if clockwise else (a1 - a0)
            sweep %= 2 * math.pi
            if sweep < 1e-9:
                sweep = 2 * math.pi  # start == end: a full circle
        return math.hypot(r * sweep, dn)
