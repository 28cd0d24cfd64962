"""How long each block of a program runs: t = s / v, the patent's rule, block by block (pure).

The drip scheduler needs to know how many seconds of cutting a chunk of bytes
carries. The job estimator (gateway/jobs/estimate.py) answers for a whole
program and lives above the codecs, so this is its small sibling for single
blocks: straight moves and arcs in the XY plane (with a helical Z), rapids at a
configured rate, feeds in mm/min or in/min, G93 inverse time, and dwells.

Whatever it cannot time (G95 feed per revolution, canned cycles, splines, a
lexing error) counts as 0 s. An estimate that is too short only makes the
scheduler send earlier than needed, never too late, so every guess errs that way;
acceleration is ignored for the same reason.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from gateway.codecs.gcode import Block, lex_lines

DEFAULT_RAPID = 10_000.0  # mm/min: a cautious rapid for unknown machines (faster machines only help)
INCH = 25.4
_AXES = "XYZ"


def block_times(text: str, *, rapid: float = DEFAULT_RAPID, dwell_ms: bool = False) -> dict[int, float]:
    """Seconds each line of the program runs, by line number (1-based); lines that take no time are absent.

    `dwell_ms`: G4 P is in milliseconds (Fanuc) rather than seconds (LinuxCNC, the simulator).
    """
    if rapid <= 0:
        raise ValueError("rapid must be > 0 mm/min")
    return _Timer(rapid, dwell_ms).run(item for item in lex_lines(text) if isinstance(item, Block))


class _Timer:
    def __init__(self, rapid: float, dwell_ms: bool) -> None:
        self.rapid = rapid
        self.dwell_ms = dwell_ms
        self.pos = [0.0, 0.0, 0.0]  # mm
        self.absolute = True
        self.unit = 1.0  # mm per program unit
        self.motion: float | None = None
        self.feed: float | None = None  # mm/min, or 1/min under G93
        self.inverse = False
        self.per_rev = False

    def run(self, blocks: Iterable[Block]) -> dict[int, float]:
        times: dict[int, float] = {}
        for block in blocks:
            if block.marker or not block.words:
                continue
            seconds = self.block(block)
            if seconds > 0:
                times[block.line] = seconds
        return times

    def block(self, b: Block) -> float:
        gs = {w.value for w in b.words if w.letter == "G"}
        values = {w.letter: w.value for w in b.words if w.letter not in "GMN"}
        if 20.0 in gs:
            self.unit = INCH
        if 21.0 in gs:
            self.unit = 1.0
        if 90.0 in gs:
            self.absolute = True
        if 91.0 in gs:
            self.absolute = False
        if 93.0 in gs:
            self.inverse, self.per_rev = True, False
        if 94.0 in gs:
            self.inverse, self.per_rev = False, False
        if 95.0 in gs:
            self.inverse, self.per_rev = False, True
        if "F" in values:
            self.feed = values["F"] if self.inverse else values["F"] * self.unit
        seconds = 0.0
        if 4.0 in gs:
            dwell = values.get("P", values.get("X", 0.0))
            seconds += max(0.0, dwell / 1000.0 if self.dwell_ms and "P" in values else dwell)
            return seconds
        for code in (0.0, 1.0, 2.0, 3.0):
            if code in gs:
                self.motion = code
        if gs & {92.0, 92.1, 10.0, 28.0, 30.0, 53.0} or self.motion is None:
            return seconds  # position set (G92), homing, machine moves: not timed
        axes = [a for a in _AXES if a in values]
        if not axes and not ("I" in values or "J" in values or "R" in values):
            return seconds
        start = list(self.pos)
        end = list(self.pos)
        for a in axes:
            i = _AXES.index(a)
            value = values[a] * self.unit
            end[i] = value if self.absolute else self.pos[i] + value
        self.pos = end
        if self.motion in (2.0, 3.0):
            length = _arc_length(start, end, values, self.unit, clockwise=self.motion == 2.0)
        else:
            length = math.dist(start, end)
        if self.motion == 0.0:
            return seconds + length / (self.rapid / 60.0)
        if self.per_rev or not self.feed or self.feed <= 0:
            return seconds
        if self.inverse:
            return seconds + 60.0 / self.feed
        return seconds + length / (min(self.feed, self.rapid) / 60.0)


def _arc_length(
    start: list[float], end: list[float], values: dict[str, float], unit: float, *, clockwise: bool
) -> float:
    dz = end[2] - start[2]
    if "R" in values:
        r = abs(values["R"] * unit)
        chord = math.dist(start[:2], end[:2])
        if r <= 0 or chord > 2 * r:
            return math.dist(start, end)
        half = math.asin(min(1.0, chord / (2 * r)))
        sweep = 2 * half if values["R"] > 0 else 2 * math.pi - 2 * half
    else:
        cx = start[0] + values.get("I", 0.0) * unit
        cy = start[1] + values.get("J", 0.0) * unit
        r = math.hypot(start[0] - cx, start[1] - cy)
        if r <= 0:
            return math.dist(start, end)
        a0 = math.atan2(start[1] - cy, start[0] - cx)
        a1 = math.atan2(end[1] - cy, end[0] - cx)
        sweep = (a0 - a1) if clockwise else (a1 - a0)
        sweep %= 2 * math.pi
        if sweep < 1e-9:
            sweep = 2 * math.pi  # start == end: a full circle
    return math.hypot(r * sweep, dz)
