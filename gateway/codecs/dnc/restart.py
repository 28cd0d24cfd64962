"""Restart a program at block N: its set-up header, the modal state at N, then block N onwards.

A drip feed that stopped (alarm, broken line, tool change) resumes without
running the part again from the top. What the controller needs before block N:

- the header: the blocks before the first motion, which name the program
  (O-number), select units, distance mode, plane, work offset, tool, spindle or
  laser set-up, and the comments. Blocks that must not run twice are left out:
  program stops and ends (M0, M1, M2, M30, M98, M99), dwells (G4), position
  set-ups (G92, G10) and homing (G28, G30, G53);
- one generated block with the modal state in force at N, as the lines before N
  left it: units (G20/G21), distance (G90/G91), plane, work offset, motion mode
  and feed, with a comment saying where the restart is;
- block N and everything after it.

Spindle and laser on/off are not restored: a restart in the middle of a cut
leaves the beam or spindle as the header set it until the program's next M3/M4.
The machine moves from where it stands to block N's end point in the modal
motion mode; the operator positions it, or restarts at a block that starts a
contour (after its rapid). Restarting at or before the first motion block sends
the whole program.
"""

from __future__ import annotations

from gateway.codecs.dnc.framing import GENERATED, FramingError, ProgramLines, SourceLine, split_program
from gateway.codecs.gcode import Block, GcodeError, format_number, lex_line

_AXIS_LETTERS = frozenset("XYZABCUVW")
_MOTION_CODES = frozenset({0.0, 1.0, 2.0, 3.0, 28.0, 30.0, 33.0}) | frozenset(
    {73.0, 74.0, 76.0, 81.0, 82.0, 83.0, 84.0, 85.0, 86.0, 87.0, 88.0, 89.0}
)
_NOT_MOTION = frozenset({4.0, 10.0, 92.0, 92.1, 92.2, 92.3, 53.0})  # axis words here do not move the path
_DROP_G = frozenset({4.0, 10.0, 28.0, 30.0, 53.0, 92.0, 92.1, 92.2, 92.3})
_DROP_M = frozenset({0.0, 1.0, 2.0, 30.0, 98.0, 99.0})
_OFFSETS = frozenset({54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 54.1, 59.1, 59.2, 59.3})


def _lex(line: SourceLine) -> Block | None:
    try:
        return lex_line(line.text.decode("latin-1"), line.number)
    except GcodeError:
        return None


def _is_motion(block: Block | None) -> bool:
    if block is None:
        return False
    gs = {w.value for w in block.all("G")}
    if gs & _NOT_MOTION:
        return False
    return bool(gs & _MOTION_CODES) or any(w.letter in _AXIS_LETTERS for w in block.words)


def _keep_in_header(block: Block | None) -> bool:
    if block is None:
        return True  # the controller's business: sent as the program had it
    if {w.value for w in block.all("G")} & _DROP_G:
        return False
    return not {w.value for w in block.all("M")} & _DROP_M


def restart_lines(program: bytes, line: int) -> ProgramLines:
    """The program to send for a restart at source line `line` (see the module docstring).

    Raises FramingError when `line` is not a line of the program's body.
    """
    parts = split_program(program)
    index = next((i for i, ln in enumerate(parts.lines) if ln.number == line), None)
    if index is None:
        raise FramingError(line, "no block of the program is on this line (restart needs a line of the body)")
    blocks = [_lex(ln) for ln in parts.lines]
    first_motion = next((i for i, b in enumerate(blocks) if _is_motion(b)), len(blocks))
    if index <= first_motion:
        return parts
    header = [
        ln
        for ln, b in zip(parts.lines[:first_motion], blocks[:first_motion], strict=True)
        if _keep_in_header(b)
    ]
    modal = _modal_block(blocks[:index], line)
    return ProgramLines((*header, SourceLine(GENERATED, modal), *parts.lines[index:]), parts.header)


def _modal_block(before: list[Block | None], line: int) -> bytes:
    """One block restoring the modal state the blocks before the restart left in force."""
    units = distance = plane = offset = motion = None
    feed: float | None = None
    for block in before:
        if block is None:
            continue
        for word in block.all("G"):
            value = word.value
            if value in (20.0, 21.0):
                units = value
            elif value in (90.0, 91.0):
                distance = value
            elif value in (17.0, 18.0, 19.0):
                plane = value
            elif value in _OFFSETS:
                offset = value
            elif value in (0.0, 1.0, 2.0, 3.0):
                motion = value
            elif value == 80.0:
                motion = None
        f = block.get("F")
        if f is not None:
            feed = f.value
    words = [f"G{format_number(v)}" for v in (units, distance, plane, offset, motion) if v is not None]
    if feed is not None:
        words.append(f"F{format_number(feed)}")
    words.append(f"(RESTART AT LINE {line})")
    return " ".join(words).encode("ascii")
