"""Run-time estimate of a G-code program: path length over feed, block by block (pure).

The estimate is reported with every job, so that the shop sees how long a sheet
takes before it reaches the machine, and where the program goes (its extents).
It follows the modal state like a controller does: G20/G21 units, G90/G91
(and G90.1/G91.1 for arc centres), G17/G18/G19 planes, G92 offsets, G93/G94/G95
feed modes and the motion mode. Conventions, stated once:

- The program starts at the origin of its coordinates (0, 0, 0), in mm, G90, G17, G94,
  unless a G92 before the first move says where it starts (G92 X0 Y0 in many laser
  and plasma programs); a later G92 shifts the coordinates as usual.
- Rapids (G0) run in a straight line at the machine's rapid speed; no feed
  faster than it is counted (the controller would clamp it too). Acceleration is ignored.
- Arcs count their real length: r·θ in the plane, with the helical component.
  Full circles (start == end, I/J/K) and LinuxCNC's P turns are supported.
- G4 P is seconds (LinuxCNC and the simulator) or milliseconds (Fanuc, `dwell_p`);
  G4 X is seconds. G93 inverse time counts 1/F minutes per move.
- What it cannot know it says in `notes`, with the line, and sets `exact=False`:
  NURBS and splines, canned cycles, probing, threading, polar words, G95 feed per
  revolution, moves from an unknown position (after G28, say), moves without a
  feed. Everything else is still estimated.
- Extents are the min/max of X/Y/Z reached by the program (end points, arc
  extremes and, conservatively, NURBS control points), in mm, in the program's
  coordinates at its start (a later G92 shift moves the coordinates, not the extents' frame).
- Estimation stops at the first M2 or M30: nothing after it runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

from gateway.codecs.arcs import ArcProblem, PlaneArc, arc_from_center, arc_from_radius
from gateway.codecs.gcode import Program, format_number

AXES = "XYZ"
INCH = 25.4
#: Notes beyond this are summarised in one last note.
MAX_NOTES = 50

#: Plane -> (u, v, w) axis indices and the centre letters of u and v.
PLANES: dict[float, tuple[tuple[int, int, int], tuple[str, str]]] = {
    17.0: ((0, 1, 2), ("I", "J")),
    18.0: ((2, 0, 1), ("K", "I")),
    19.0: ((1, 2, 0), ("J", "K")),
}
CANNED = frozenset({73.0, 74.0, 76.0, 81.0, 82.0, 83.0, 84.0, 85.0, 86.0, 87.0, 88.0, 89.0})
#: Motion modes the estimator cannot time, by what they are.
UNTIMED_MOTION: dict[float, str] = {
    5.0: "cubic spline (G5)",
    5.1: "quadratic spline (G5.1)",
    5.2: "NURBS curve (G5.2)",
    33.0: "spindle-synchronised motion (G33)",
    33.1: "rigid tapping (G33.1)",
    38.2: "probing move (G38.2)",
    38.3: "probing move (G38.3)",
    38.4: "probing move (G38.4)",
    38.5: "probing move (G38.5)",
    **{code: f"canned cycle G{format_number(code)}" for code in CANNED},
}
MOTION = frozenset({0.0, 1.0, 2.0, 3.0}) | frozenset(UNTIMED_MOTION)
COORDINATE_SYSTEMS = frozenset({54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3, 54.1})
#: Codes that do not change lengths, times or positions as the estimator sees them.
NEUTRAL = frozenset(
    {9.0, 17.1, 18.1, 19.1, 40.0, 43.0, 43.1, 43.2, 49.0, 61.0, 61.1, 64.0, 80.0, 96.0, 97.0, 98.0, 99.0, 5.3}
) | frozenset({4.0, 10.0, 20.0, 21.0, 28.0, 28.1, 30.0, 30.1, 53.0, 90.0, 91.0, 90.1, 91.1})
NEUTRAL |= frozenset({17.0, 18.0, 19.0, 92.0, 92.1, 92.2, 92.3, 93.0, 94.0, 95.0}) | COORDINATE_SYSTEMS
#: Codes whose effect on geometry the estimator does not model, with what it means for the estimate.
UNMODELLED: dict[float, str] = {
    7.0: "lathe diameter mode (G7): X is read as a radius",
    8.0: "lathe radius mode (G8)",
    15.0: "polar coordinates off (G15)",
    16.0: "polar coordinates (G16): moves are not estimated correctly",
    50.0: "scaling off (G50)",
    51.0: "scaling (G51): lengths are not scaled",
    50.1: "mirror off (G50.1)",
    51.1: "mirror image (G51.1): extents are not mirrored",
    52.0: "local coordinate system (G52): later positions may be shifted",
    68.0: "coordinate rotation (G68): extents are not rotated",
    69.0: "rotation off (G69)",
    65.0: "macro call (G65): its moves are not estimated",
    66.0: "modal macro call (G66): its moves are not estimated",
    12.1: "polar interpolation (G12.1): moves are not estimated correctly",
    13.1: "polar interpolation off (G13.1)",
}
COMPENSATION = frozenset({41.0, 42.0, 41.1, 42.1})
EXTRA_AXES = "ABCUVW"
_EXTRA = frozenset(EXTRA_AXES)
_END = frozenset({2.0, 30.0})  # M2, M30
_NO_CODES: frozenset[float] = frozenset()
#: G codes that take a block's axis words for something other than a move (see `_Estimator.step`).
_SPECIAL = frozenset({4.0, 92.0, 10.0, 28.0, 28.1, 30.0, 30.1, 53.0})
_AXIS_INDEX = tuple(enumerate(AXES))


@dataclass(frozen=True, slots=True)
class Extents:
    """The box the program's moves reach, in mm."""

    min_x: float
    max_x: float
    min_y: float
    max_y: float
    min_z: float
    max_z: float

    def as_dict(self) -> dict[str, float]:
        return {
            "min_x": self.min_x,
            "max_x": self.max_x,
            "min_y": self.min_y,
            "max_y": self.max_y,
            "min_z": self.min_z,
            "max_z": self.max_z,
        }


@dataclass(frozen=True, slots=True)
class Estimate:
    """How long a program runs and where it goes; `notes` say plainly what is not counted."""

    seconds: float | None
    cut_mm: float
    rapid_mm: float
    dwell_s: float
    blocks: int
    extents: Extents | None
    exact: bool
    notes: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly, for job records and MQTT payloads."""
        return {
            "seconds": self.seconds,
            "cut_mm": self.cut_mm,
            "rapid_mm": self.rapid_mm,
            "dwell_s": self.dwell_s,
            "blocks": self.blocks,
            "extents": None if self.extents is None else self.extents.as_dict(),
            "exact": self.exact,
            "notes": list(self.notes),
        }


def estimate_program(
    program: Program,
    *,
    rapid_feed_mm_min: float,
    default_feed_mm_min: float | None = None,
    dwell_p: Literal["seconds", "milliseconds"] = "seconds",
) -> Estimate:
    """Estimate `program` on a machine whose rapids run at `rapid_feed_mm_min`.

    `default_feed_mm_min` is the feed for moves before any F word; without it such
    moves are noted and not timed.
    """
    running = RunningEstimate(
        rapid_feed_mm_min=rapid_feed_mm_min, default_feed_mm_min=default_feed_mm_min, dwell_p=dwell_p
    )
    for block in program.blocks:
        running.block(block.line, [(w.letter, w.value) for w in block.words], block.block_delete)
    return running.result()


class RunningEstimate:
    """`estimate_program` one block at a time, for programs too large to hold as Blocks.

    Feed every block of the program in order (as (letter, value) pairs), then ask
    for the `result()`; blocks after the end code are counted and not estimated.
    """

    def __init__(
        self,
        *,
        rapid_feed_mm_min: float,
        default_feed_mm_min: float | None = None,
        dwell_p: Literal["seconds", "milliseconds"] = "seconds",
    ) -> None:
        if not rapid_feed_mm_min > 0:
            raise ValueError("rapid_feed_mm_min must be > 0")
        if default_feed_mm_min is not None and not default_feed_mm_min > 0:
            raise ValueError("default_feed_mm_min must be > 0")
        self._estimator = _Estimator(rapid_feed_mm_min, default_feed_mm_min, dwell_p)
        self._blocks = 0
        self._ended = False

    def block(self, line: int, pairs: list[tuple[str, float]], block_delete: bool = False) -> None:
        self._blocks += 1
        if not self._ended:
            try:
                self._ended = self._estimator.step(line, pairs, block_delete)
            except (OverflowError, ValueError):  # numbers too large for the arithmetic of an arc
                self._estimator.skip(line, "numbers too large to estimate")
                self._estimator.lose(line)

    def result(self) -> Estimate:
        return self._estimator.result(self._blocks)


Position = list[float | None]


def _known(value: float | None) -> float:
    """A coordinate the caller has checked is known."""
    assert value is not None
    return value


class _Estimator:
    """The modal state of a controller, reduced to what lengths and times depend on."""

    def __init__(self, rapid: float, default_feed: float | None, dwell_p: str) -> None:
        self.rapid = rapid
        self.default_feed = default_feed
        self.dwell_scale = 0.001 if dwell_p == "milliseconds" else 1.0
        self.pos: Position = [0.0, 0.0, 0.0]  # in the frame at program start, mm; None = unknown
        self.offset: Position = [0.0, 0.0, 0.0]  # G92: frame = program coordinates + offset
        self.saved_offset: Position = [0.0, 0.0, 0.0]
        self.lost_at: int | None = None  # the line after which the position became unknown
        self.unit = 1.0
        self.absolute = True
        self.arc_absolute = False
        self.plane = 17.0
        self.feed_mode = 94.0
        self.motion: float | None = None
        self.feed: float | None = None  # mm/min (G94), or the raw F number (G93)
        self.system: float | None = None
        self.moved = False  # any axis words seen yet (a G92 before then declares the start point)
        self.cut_mm = self.rapid_mm = self.cut_s = self.rapid_s = self.dwell_s = 0.0
        self.timed = 0
        self.untimed = 0
        self.exact = True
        self.notes: list[str] = []
        self.extra_notes = 0
        self.once: set[str] = set()
        self.lo: list[float | None] = [None, None, None]
        self.hi: list[float | None] = [None, None, None]

    # --- bookkeeping ---------------------------------------------------------------------------

    def note(self, line: int | None, text: str, *, exact: bool = False, key: str | None = None) -> None:
        """Record what was not counted. `key` makes a note appear only once per program."""
        if key is not None:
            if key in self.once:
                return
            self.once.add(key)
        if not exact:
            self.exact = False
        if len(self.notes) < MAX_NOTES:
            self.notes.append(f"line {line}: {text}" if line is not None else text)
        else:
            self.extra_notes += 1

    def skip(self, line: int, text: str) -> None:
        """A block whose time is not counted."""
        self.untimed += 1
        self.note(line, text)

    def reach(self, point: Position) -> None:
        for i, value in enumerate(point):
            if value is None:
                continue
            lo, hi = self.lo[i], self.hi[i]
            self.lo[i] = value if lo is None or value < lo else lo
            self.hi[i] = value if hi is None or value > hi else hi

    def lose(self, line: int, axes: str = AXES) -> None:
        for a in axes:
            self.pos[AXES.index(a)] = None
        self.lost_at = line

    def result(self, blocks: int) -> Estimate:
        notes = list(self.notes)
        if self.extra_notes:
            notes.append(f"and {self.extra_notes} more notes")
        extents = None
        if all(v is not None for v in self.lo + self.hi):
            lo, hi = self.lo, self.hi
            extents = Extents(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])  # type: ignore[arg-type]
        elif any(v is not None for v in self.lo):
            missing = ", ".join(a for a, v in zip(AXES, self.lo, strict=True) if v is None)
            notes.append(f"no extents: the {missing} position is never known")
        seconds: float | None = self.rapid_s + self.cut_s + self.dwell_s
        if self.timed == 0 and self.untimed > 0:
            seconds = None
        cut, rapid, dwell = self.cut_mm, self.rapid_mm, self.dwell_s
        exact = self.exact
        totals = (cut, rapid, dwell, 0.0 if seconds is None else seconds)
        bounds = () if extents is None else tuple(extents.as_dict().values())
        if not all(map(math.isfinite, totals + bounds)):  # numbers beyond what a float holds
            notes.append("the program's numbers are too large to add up: no time, lengths or extents")
            seconds, cut, rapid, dwell, extents, exact = None, 0.0, 0.0, 0.0, None, False
        return Estimate(seconds, cut, rapid, dwell, blocks, extents, exact, tuple(notes))

    # --- the program ---------------------------------------------------------------------------

    def step(self, line: int, pairs: list[tuple[str, float]], block_delete: bool = False) -> bool:
        """Apply one block given as (letter, value) pairs in order; True when it ends the program.

        The hot loop of a job's validation (one call per line of the program), so it sorts
        the words in one pass and leaves the uncommon checks behind cheap tests.
        """
        words: dict[str, float] = {}
        gs: list[float] = []
        ms: set[float] = set()
        for letter, value in pairs:
            if letter == "G":
                gs.append(value)
            elif letter == "M":
                ms.add(value)
            elif letter not in words:
                words[letter] = value
        codes: set[float] | frozenset[float] = _NO_CODES
        if gs:
            self.modes(line, gs)
            codes = set(gs)
        # Sinumerik writes the dwell time as G4 F<seconds>; elsewhere F in a G4 block is the feed.
        dwell_by_f = 4.0 in codes and "F" in words and "P" not in words and "X" not in words
        if "F" in words and not dwell_by_f:
            f = words["F"]
            self.feed = f if self.feed_mode == 93.0 else f * self.unit
        if block_delete:
            self.note(line, "optional blocks (/) are counted as run", exact=True, key="block delete")
        has_axes = "X" in words or "Y" in words or "Z" in words
        if gs:
            if 80.0 in codes or (5.3 in codes and self.motion == 5.2):
                self.motion = None
            motion = [g for g in gs if g in MOTION]
            if motion:
                self.motion = motion[-1]  # modal, even when a non-modal code below takes the axis words
        if not gs or codes.isdisjoint(_SPECIAL):
            self.move(line, words, has_axes, 5.2 in codes)
        elif 4.0 in codes:
            self.dwell(line, words, dwell_by_f)
        elif 92.0 in codes:
            self.set_offsets(words, line)
        elif 10.0 in codes:
            self.note(line, "G10 changes offsets; the estimate assumes the current coordinates do not move")
        elif codes & {28.0, 28.1, 30.0, 30.1}:
            if codes & {28.0, 30.0}:
                self.skip(line, "return to a home position (G28/G30) is not estimated")
                self.lose(line)
                self.moved = True
        elif 53.0 in codes and has_axes:
            self.skip(line, "a move in machine coordinates (G53) is not estimated")
            self.lose(line, "".join(a for a in AXES if a in words))
            self.moved = True
        else:
            self.move(line, words, has_axes, 5.2 in codes)
        if not _EXTRA.isdisjoint(words):
            for a in EXTRA_AXES:
                if a in words and not (a == "U" and 4.0 in codes):
                    self.note(line, f"{a} axis motion is not included in the length", key=f"axis {a}")
        if ms:
            if 0.0 in ms or 1.0 in ms:
                self.note(line, "program stop (M0/M1): the wait for the operator is not counted", exact=True)
            return bool(ms & _END)
        return False

    def modes(self, line: int, gs: list[float]) -> None:
        for g in gs:
            if g == 20.0:
                self.unit = INCH
            elif g == 21.0:
                self.unit = 1.0
            elif g == 90.0:
                self.absolute = True
            elif g == 91.0:
                self.absolute = False
            elif g == 90.1:
                self.arc_absolute = True
            elif g == 91.1:
                self.arc_absolute = False
            elif g in PLANES:
                self.plane = g
            elif g in (93.0, 94.0, 95.0):
                if g != self.feed_mode:
                    self.feed = None  # a new feed mode needs a new F (LinuxCNC and Fanuc alike)
                self.feed_mode = g
            elif g in COORDINATE_SYSTEMS:
                if self.system is not None and g != self.system:
                    self.note(
                        line,
                        f"coordinate system G{format_number(g)}: its offset from the previous one is unknown",
                    )
                    self.lose(line)
                self.system = g
            elif g in COMPENSATION:
                self.note(
                    line,
                    "cutter compensation: lengths are those of the programmed path",
                    exact=True,
                    key="comp",
                )
            elif g in UNMODELLED:
                self.note(line, UNMODELLED[g])
            elif g == 92.1 or g == 92.2:
                self.offset = [0.0, 0.0, 0.0]
            elif g == 92.3:
                self.offset = list(self.saved_offset)
            elif g not in NEUTRAL and g not in MOTION:
                self.note(line, f"unknown code G{format_number(g)}: its effect is not estimated")

    def dwell(self, line: int, words: dict[str, float], by_f: bool) -> None:
        if "P" in words:
            seconds = words["P"] * self.dwell_scale
        elif "X" in words:
            seconds = words["X"]  # Fanuc: G4 X is seconds
        elif by_f:
            seconds = words["F"]  # Sinumerik: G4 F is seconds
        else:
            self.skip(line, "a dwell (G4) without a time (P, X or F) is not estimated")
            return
        if seconds < 0:
            self.skip(line, "a negative dwell time is not estimated")
            return
        self.dwell_s += seconds
        self.timed += 1

    def set_offsets(self, words: dict[str, float], line: int) -> None:
        """G92. Before any move it only says where the tool starts, so it sets the position instead."""
        for i, a in enumerate(AXES):
            if a in words:
                value = words[a] * self.unit
                if not self.moved:
                    self.pos[i] = value
                    continue
                here = self.pos[i]
                self.offset[i] = None if here is None else here - value
        self.saved_offset = list(self.offset)

    # --- motion --------------------------------------------------------------------------------

    def target(self, words: dict[str, float]) -> Position:
        t = list(self.pos)
        for i, a in enumerate(AXES):
            if a in words:
                value = words[a] * self.unit
                if self.absolute:
                    off = self.offset[i]
                    t[i] = None if off is None else value + off
                else:
                    here = self.pos[i]
                    t[i] = None if here is None else here + value
        return t

    def move(self, line: int, words: dict[str, float], has_axes: bool, nurbs_start: bool) -> None:
        polar = "^" in words or "@" in words
        if not (has_axes or polar):
            arc_words = "I" in words or "J" in words or "K" in words or "R" in words
            if not (self.motion in (2.0, 3.0) and arc_words):
                return
        self.moved = True
        if self.motion is None:
            self.skip(line, "axis words without a motion mode (G0, G1, G2 or G3) are not estimated")
            self.pos = self.target(words)
            return
        t = self.target(words)
        if self.motion in UNTIMED_MOTION:
            self.untimed_motion(line, words, t, polar, nurbs_start)
            return
        if polar:
            self.skip(line, "polar words (^ and @) are not estimated")
            self.lose(line, "XY")
            return
        pos = self.pos
        square = 0.0  # of the straight distance; a float product overflows to inf, never raises
        for i, axis in _AXIS_INDEX:
            if axis in words:
                end, start = t[i], pos[i]
                if end is None or start is None:
                    since = f" (unknown since line {self.lost_at})" if self.lost_at is not None else ""
                    self.skip(line, f"a move from an unknown position{since} is not estimated")
                    self.reach(t)
                    self.pos = t
                    return
                delta = end - start
                square += delta * delta
        if self.motion in (0.0, 1.0):
            self.reach(t)
            self.pos = t
            self.count(line, math.sqrt(square), rapid=self.motion == 0.0, words=words)
        else:
            self.arc(line, words, t)

    def untimed_motion(
        self, line: int, words: dict[str, float], t: Position, polar: bool, nurbs_start: bool
    ) -> None:
        """Splines, NURBS, cycles and probing: not timed; keep track of the position where we can."""
        assert self.motion is not None
        with_polar = " (with polar words)" if polar else ""
        if self.motion == 5.2:
            # Continuation lines carry control points; the curve stays inside their hull.
            if nurbs_start:
                self.skip(
                    line, "NURBS curve (G5.2 to G5.3) is not estimated; extents include its control points"
                )
            else:
                self.untimed += 1
        else:
            self.skip(line, f"{UNTIMED_MOTION[self.motion]}{with_polar} is not estimated")
        if polar or self.motion in (38.2, 38.3, 38.4, 38.5):
            self.lose(line)
        elif self.motion in CANNED:
            # The holes' X/Y are known in G90 without repeats; Z ends at R or the initial level.
            if self.absolute and "L" not in words:
                self.reach(t)
                self.pos = [t[0], t[1], None]
                self.lost_at = line
            else:
                self.lose(line)
        else:
            self.reach(t)
            self.pos = t

    def arc(self, line: int, words: dict[str, float], t: Position) -> None:
        (u, v, w), (cu_letter, cv_letter) = PLANES[self.plane]
        start = self.pos
        su, sv, eu, ev = start[u], start[v], t[u], t[v]
        if su is None or sv is None or eu is None or ev is None:
            self.skip(line, "an arc from an unknown position is not estimated")
            self.pos = t
            return
        s2, e2 = (su, sv), (eu, ev)
        # the helical axis moved only if named, and then move() made sure both ends are known
        dw = _known(t[w]) - _known(start[w]) if AXES[w] in words else 0.0
        clockwise = self.motion == 2.0
        turns = 1
        if "P" in words:
            p = words["P"]
            if not (p.is_integer() and p >= 1):
                self.skip(line, f"arc turns P{format_number(p)} must be a whole number >= 1; not estimated")
                self.pos = t
                return
            turns = int(p)
        try:
            if "R" in words:
                arc = arc_from_radius(s2, e2, words["R"] * self.unit, clockwise, turns=turns, dw=dw)
            elif cu_letter in words or cv_letter in words:
                cu = words[cu_letter] * self.unit if cu_letter in words else 0.0
                cv = words[cv_letter] * self.unit if cv_letter in words else 0.0
                if self.arc_absolute:
                    ou, ov = self.offset[u], self.offset[v]
                    if ou is None or ov is None:
                        raise ArcProblem("its absolute centre is in an unknown frame")
                    center = (cu + ou, cv + ov)
                else:
                    center = (s2[0] + cu, s2[1] + cv)
                arc = arc_from_center(s2, e2, center, clockwise, turns=turns, dw=dw)
            else:
                raise ArcProblem(f"it has neither centre words ({cu_letter}, {cv_letter}) nor R")
        except ArcProblem as exc:
            self.skip(line, f"arc not estimated: {exc}")
            self.reach(t)
            self.pos = t
            return
        if arc.off_circle:
            self.note(
                line,
                f"the arc's end point is {arc.mismatch:.4f} mm off its circle "
                "(the controller may refuse it); estimated as a spiral",
                exact=True,
            )
        self.reach_arc(arc, start, (u, v, w))
        self.reach(t)
        self.pos = t
        self.count(line, arc.length, rapid=False, words=words)

    def reach_arc(self, arc: PlaneArc, start: Position, axes: tuple[int, int, int]) -> None:
        u, v, _ = axes
        for pu, pv in arc.extremes():
            point: Position = list(start)
            point[u], point[v] = pu, pv
            self.reach(point)

    def count(self, line: int, length: float, *, rapid: bool, words: dict[str, float]) -> None:
        if rapid:
            self.rapid_mm += length
            self.rapid_s += length / self.rapid * 60.0
            self.timed += 1
            return
        self.cut_mm += length
        seconds = self.feed_seconds(line, length, words)
        if seconds is None:
            self.untimed += 1
        else:
            self.cut_s += seconds
            self.timed += 1

    def feed_seconds(self, line: int, length: float, words: dict[str, float]) -> float | None:
        if self.feed_mode == 95.0:
            self.note(line, "feed per revolution (G95) is not estimated")
            return None
        if self.feed_mode == 93.0:
            if "F" not in words or words["F"] <= 0:
                self.note(line, "an inverse-time (G93) move without its own F is not estimated")
                return None
            return 60.0 / words["F"]
        feed = self.feed
        if not feed:
            if self.default_feed is None:
                self.note(line, "a feed move before any feed rate (F) is not estimated")
                return None
            feed = self.default_feed
            self.note(
                line,
                f"no feed rate (F) yet: estimated at the default {format_number(feed)} mm/min",
                key="dflt",
            )
        if feed > self.rapid:
            self.note(
                line,
                f"feed {format_number(feed)} mm/min is above the rapid speed; counted at "
                f"{format_number(self.rapid)} mm/min",
                exact=True,
                key="clamp",
            )
            feed = self.rapid
        return length / feed * 60.0
