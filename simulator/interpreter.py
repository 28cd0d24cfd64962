"""Turn a G-code program into a list of timed actions in machine coordinates.

The whole program is planned when it starts, so that progress can be measured
against its total path length. Planning follows the modal state (G90/G91,
G20/G21, G92 offsets, motion mode, F) block by block. A block that cannot run
(a lexing error, an unsupported code, a target beyond the soft limits) becomes
a `Fault` at its place in the list: the machine runs everything before it and
raises the alarm when it gets there, before that block moves anything.

Within a block the order is LinuxCNC's, simplified: modes (units, distance),
F, S, laser on/off (M3/M4/M5), dwell (G4), G92, motion, M0/M1, then M2/M30.
Every number in a block is read in the units that block selects.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from gateway.codecs.gcode import Block, GcodeError, Word, lex_line, lex_lines, split_lines
from simulator.alarms import Alarm, program_error, soft_limit
from simulator.geometry import ArcError, Line, Point, Segment, arc_from_center, arc_from_radius

AXES = "XYZ"
#: Soft limits of the simulated 3 m x 1.5 m laser, machine coordinates in mm.
SOFT_LIMITS: dict[str, tuple[float, float]] = {"X": (0.0, 3000.0), "Y": (0.0, 1500.0), "Z": (-5.0, 100.0)}
MAX_POWER = 6000.0  # W
INCH = 25.4

#: G codes the simulator runs. G17/G40/G49/G54/G80/G94 select what is already in
#: effect (XY plane, no compensation, first work offset, no canned cycle, feed per
#: minute), so common program preambles run unchanged.
SUPPORTED_G = frozenset(
    {0.0, 1.0, 2.0, 3.0, 4.0, 17.0, 20.0, 21.0, 40.0, 49.0, 54.0, 80.0, 90.0, 91.0, 92.0, 92.1, 94.0}
)
SUPPORTED_M = frozenset({0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 30.0})
KNOWN_LETTERS = frozenset("GMFSXYZIJRPO")
_GROUPS: tuple[tuple[str, frozenset[float]], ...] = (
    ("G", frozenset({0.0, 1.0, 2.0, 3.0, 4.0, 92.0, 92.1})),  # motion and the axis-word users
    ("G", frozenset({90.0, 91.0})),
    ("G", frozenset({20.0, 21.0})),
    ("M", frozenset({3.0, 4.0, 5.0})),
    ("M", frozenset({0.0, 1.0, 2.0, 30.0})),
)


# --- actions -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class BeginBlock:
    line: int
    text: str


@dataclass(frozen=True, slots=True)
class Move:
    segment: Segment
    feed: float | None  # mm/min as programmed; None for a rapid (G0)


@dataclass(frozen=True, slots=True)
class Dwell:
    seconds: float


@dataclass(frozen=True, slots=True)
class SetPower:
    watts: float


@dataclass(frozen=True, slots=True)
class SetLaser:
    on: bool


@dataclass(frozen=True, slots=True)
class ProgramStop:
    """M0: the machine pauses; Resume (or Start) continues."""


@dataclass(frozen=True, slots=True)
class ProgramEnd:
    """M2/M30 (count_part) or simply the last block (no part counted)."""

    count_part: bool


@dataclass(frozen=True, slots=True)
class Fault:
    alarm: Alarm


Action = BeginBlock | Move | Dwell | SetPower | SetLaser | ProgramStop | ProgramEnd | Fault


@dataclass(frozen=True, slots=True)
class Plan:
    actions: tuple[Action, ...]
    total_path: float  # mm, every move up to the end or the first fault


# --- planning ----------------------------------------------------------------------------------


class _BlockError(Exception):
    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class _LimitError(Exception):
    def __init__(self, alarm: Alarm) -> None:
        super().__init__(alarm.text)
        self.alarm = alarm


def plan_program(
    text: str,
    start: Point,
    *,
    limits: dict[str, tuple[float, float]] = SOFT_LIMITS,
    block_delete: bool = True,
) -> Plan:
    """Plan `text` from machine position `start`. Never raises for bad programs: they plan to a Fault."""
    return _Planner(start, limits, block_delete).run(text)


def _program_lines(text: str) -> Iterator[tuple[str, Block | GcodeError]]:
    """(raw text, lexed line) between the markers: a first `%` starts, the next `%` ends the program."""
    seen_content = False
    for raw, item in zip(split_lines(text), lex_lines(text), strict=True):
        if isinstance(item, Block) and item.marker:
            if seen_content:
                return
            seen_content = True
            continue
        if isinstance(item, GcodeError) or not item.is_blank:
            seen_content = True
        yield raw, item


class _Planner:
    def __init__(self, start: Point, limits: dict[str, tuple[float, float]], block_delete: bool) -> None:
        self.pos: list[float] = list(start)
        self.offset = [0.0, 0.0, 0.0]  # G92: machine = program + offset
        self.absolute = True
        self.unit = 1.0
        self.motion: float | None = None
        self.feed: float | None = None
        self.limits = limits
        self.block_delete = block_delete
        self.actions: list[Action] = []
        self.total = 0.0

    def run(self, text: str) -> Plan:
        end: Action = ProgramEnd(count_part=False)
        for raw, item in _program_lines(text):
            acts, stop = self.line(raw, item)
            self.actions.extend(acts)
            if stop is not None:
                end = stop
                break
        self.actions.append(end)
        return Plan(tuple(self.actions), self.total)

    def line(self, raw: str, item: Block | GcodeError) -> tuple[list[Action], Action | None]:
        """The actions of one line, and the action that ends the program there (a Fault, M2/M30), if any."""
        if isinstance(item, GcodeError):
            fault = Fault(program_error(item.line, f"{item.reason} (column {item.column})"))
            return [BeginBlock(item.line, raw.strip())], fault
        if item.is_blank or (item.block_delete and self.block_delete):
            return [], None
        acts: list[Action] = [BeginBlock(item.line, item.text.strip())]
        try:
            more, ended = self.block(item)
        except _BlockError as exc:
            return acts, Fault(program_error(item.line, exc.reason))
        except _LimitError as exc:
            return acts, Fault(exc.alarm)
        acts.extend(more)
        return acts, ProgramEnd(count_part=True) if ended else None

    def block(self, b: Block) -> tuple[list[Action], bool]:
        """The actions of one block, or _BlockError/_LimitError before any of them happens."""
        words = b.words
        if any(w.letter == "O" for w in words):
            if all(w.letter == "O" for w in words):
                return [], False  # program number line
            raise _BlockError("an O word (program number) must stand alone in its block")
        for w in words:
            if w.letter not in KNOWN_LETTERS:
                polar = " (polar coordinates are not supported)" if w.letter in "^@" else ""
                raise _BlockError(f"unsupported word {w.code}{polar}")
        gs = [w for w in words if w.letter == "G"]
        ms = [w for w in words if w.letter == "M"]
        for w in gs:
            if w.value not in SUPPORTED_G:
                raise _BlockError(f"unsupported code {w.code}")
        for w in ms:
            if w.value not in SUPPORTED_M:
                raise _BlockError(f"unsupported code {w.code}")
        _check_groups(words)
        values: dict[str, float] = {}
        for w in words:
            if w.letter in "GM":
                continue
            if w.letter in values:
                raise _BlockError(f"{w.letter} appears twice in one block")
            values[w.letter] = w.value
        g = {w.value for w in gs}
        m = {w.value for w in ms}
        used: set[str] = set()
        acts: list[Action] = []

        if 20.0 in g:
            self.unit = INCH
        if 21.0 in g:
            self.unit = 1.0
        if 90.0 in g:
            self.absolute = True
        if 91.0 in g:
            self.absolute = False
        if "F" in values:
            used.add("F")
            if values["F"] < 0:
                raise _BlockError("feed rate F must not be negative")
            self.feed = values["F"] * self.unit
        if "S" in values:
            used.add("S")
            if not 0 <= values["S"] <= MAX_POWER:
                raise _BlockError(f"laser power S{values['S']:g} is outside 0..{MAX_POWER:g} W")
            acts.append(SetPower(values["S"]))
        if m & {3.0, 4.0}:
            acts.append(SetLaser(True))
        if 5.0 in m:
            acts.append(SetLaser(False))
        if 4.0 in g:
            used.add("P")
            if "P" not in values or values["P"] < 0:
                raise _BlockError("G4 needs a dwell time P >= 0 (seconds)")
            acts.append(Dwell(values["P"]))
        axes = [a for a in AXES if a in values]
        if 92.0 in g:
            if not axes:
                raise _BlockError("G92 needs at least one axis word")
            for a in axes:
                i = AXES.index(a)
                self.offset[i] = self.pos[i] - values[a] * self.unit
            used.update(axes)
        elif 92.1 in g:
            self.offset = [0.0, 0.0, 0.0]
        motion = [w.value for w in gs if w.value in (0.0, 1.0, 2.0, 3.0)]
        if motion:
            self.motion = motion[0]
        arc_words = [k for k in "IJR" if k in values]
        if (axes and 92.0 not in g) or arc_words:
            acts.extend(self.motion_block(values, axes, arc_words, b.line))
            used.update(axes)
            if self.motion in (2.0, 3.0):
                used.update(arc_words)
        unused = [w.code for w in words if w.letter not in "GM" and w.letter not in used]
        if unused:
            raise _BlockError(f"{', '.join(unused)} has no use in this block")
        if 0.0 in m:
            acts.append(ProgramStop())
        return acts, bool(m & {2.0, 30.0})

    def motion_block(
        self, values: dict[str, float], axes: list[str], arc_words: list[str], line: int
    ) -> list[Action]:
        if self.motion is None:
            raise _BlockError("axis words without a motion mode (G0, G1, G2 or G3)")
        start: Point = (self.pos[0], self.pos[1], self.pos[2])
        target = list(self.pos)
        for a in axes:
            i = AXES.index(a)
            value = values[a] * self.unit
            target[i] = value + self.offset[i] if self.absolute else self.pos[i] + value
        end: Point = (target[0], target[1], target[2])
        segment: Segment
        if self.motion in (0.0, 1.0):
            if arc_words:
                return []  # reported as unused words by the caller
            segment = Line(start, end)
        else:
            if "R" in values and ("I" in values or "J" in values):
                raise _BlockError("an arc takes either I/J or R, not both")
            clockwise = self.motion == 2.0
            try:
                if "R" in values:
                    segment = arc_from_radius(start, end, values["R"] * self.unit, clockwise)
                elif "I" in values or "J" in values:
                    ci, cj = values.get("I", 0.0) * self.unit, values.get("J", 0.0) * self.unit
                    segment = arc_from_center(start, end, ci, cj, clockwise)
                else:
                    raise _BlockError(f"G{self.motion:g} needs I/J (centre) or R (radius)")
            except ArcError as exc:
                raise _BlockError(str(exc)) from None
        feed = None
        if self.motion != 0.0:
            if not self.feed:
                raise _BlockError(f"G{self.motion:g} needs a feed rate: no F word programmed")
            feed = self.feed
        self.check_limits(segment, line)
        self.pos = target
        if segment.length == 0:
            return []
        self.total += segment.length
        return [Move(segment, feed)]

    def check_limits(self, segment: Segment, line: int) -> None:
        lo, hi = segment.bounds()
        for i, axis in enumerate(AXES):
            low, high = self.limits[axis]
            if hi[i] > high + 1e-9:
                raise _LimitError(soft_limit(axis, "+", line))
            if lo[i] < low - 1e-9:
                raise _LimitError(soft_limit(axis, "-", line))


class StreamPlanner:
    """Plans a program line by line as it arrives (DNC drip feed), with the modal state carried over.

    Lines are numbered from 2: line 1 is the `%` that opened the program, as in the file it came from.
    """

    def __init__(
        self, start: Point, *, limits: dict[str, tuple[float, float]] = SOFT_LIMITS, block_delete: bool = True
    ) -> None:
        self._planner = _Planner(start, limits, block_delete)
        self._line = 1

    @property
    def total_path(self) -> float:
        return self._planner.total

    def feed(self, raw: str) -> tuple[list[Action], bool]:
        """The actions of the next line; True if they end the program (their last is ProgramEnd or Fault)."""
        self._line += 1
        item: Block | GcodeError
        try:
            item = lex_line(raw, self._line)
        except GcodeError as exc:
            item = exc
        acts, stop = self._planner.line(raw, item)
        if stop is None:
            return acts, False
        return [*acts, stop], True


def _check_groups(words: tuple[Word, ...]) -> None:
    for letter, group in _GROUPS:
        found = [w for w in words if w.letter == letter and w.value in group]
        if len(found) > 1:
            raise _BlockError(f"{found[0].code} and {found[1].code} cannot share a block")
