"""The fast path of validation's one-pass reading, for the plain blocks that make up nearly every program.

A nesting or CAM program is millions of blocks like `G1 X12.5 Y30` and `G3 X1 Y2 I0 J5`.
Lexing each into words and stepping the general estimator costs microseconds a
block; here one regex over the whole text splits lines into plain blocks (each
word's number in its own group) and everything else, and plain blocks are
estimated inline with the estimator's state in local variables.

A block takes the fast path only when the answer is bound to be the general
path's: upper-case words in the order G X Y Z I J R F M S, each at most once, G0 to
G3, numbers of the lexer's form, M codes that end nothing, stop nothing and are not
forbidden, and a plain modal state (G90, G94, G17, G91.1, known position, a feed,
extents begun). Anything else, or anything unusual during the block (an arc the
estimator would comment on, a feed above the rapid speed not yet noted), goes to
the general path (`lex_compact` and `Reading.read`) with the state as it was. The
differential tests run both paths over generated programs and compare verdicts.

Where the compiled reader (`_plain.c`, built by setup.py) is available and the text
is ASCII, it reads runs of plain blocks with the same arithmetic, about thirty
times faster, and hands every line it is not certain of back to `_FastReader.rows`.
Without a C compiler the regex path below does all the work, with the same verdicts.
"""

# ruff: noqa: FURB136 - `b if b < a else a` is the estimator's own comparison, without a call per axis

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING, Any

from gateway.codecs.arcs import ArcProblem, PlaneArc, arc_from_center, arc_from_radius
from gateway.codecs.gcode import format_number, lex_compact
from gateway.jobs.validation import compiled

if TYPE_CHECKING:
    from gateway.jobs.validation.reading import Reading

#: Off only in tests, to compare the fast path with the general one.
_ENABLED = True
#: Off only in tests, to compare the compiled reader with the regex path.
_COMPILED = True
#: Lines the regex path reads at most between two tries of the compiled reader.
_MAX_RUN = 4096

_NUM = r"(-?+(?:[0-9]{1,30}+(?:\.[0-9]*+)?+|\.[0-9]++))"  # at most 30 integer digits: never overflows
_ROW = re.compile(
    rf"^(?:(?:G([0-3]))?(?: ?X{_NUM})?(?: ?Y{_NUM})?(?: ?Z{_NUM})?(?: ?I{_NUM})?(?: ?J{_NUM})?"
    rf"(?: ?R{_NUM})?(?: ?F{_NUM})?(?: ?M([0-9]{{1,9}}))?(?: ?S{_NUM})?\r?$|(.*))",
    re.MULTILINE,
)
_BLANK = ("",) * 11
_CHUNK = 1 << 20  # characters per findall
_MOTION = {"0": 0.0, "1": 1.0, "2": 2.0, "3": 3.0}
_STOPS = frozenset({0.0, 1.0, 2.0, 30.0})  # M codes the estimator notes or stops at


def read_text(reading: Reading, text: str, line: int = 1) -> None:
    """Read the lexed `text`, whose first line is `line`, into `reading`: the same outcome as
    `reading.read(lex_compact(text, line))`."""
    if not _ENABLED:
        reading.read(lex_compact(text, line))
        return
    fast = _FastReader(reading)
    if compiled.plain is not None and _COMPILED and text.isascii():
        _read_compiled(fast, text, line)
        return
    start, end = 0, len(text)
    while start < end:
        stop = text.find("\n", start + _CHUNK)
        stop = end if stop < 0 else stop + 1
        rows = _ROW.findall(text, start, stop)
        if text[stop - 1] == "\n":
            rows.pop()  # the empty "line" after the chunk's last line end
        fast.rows(rows, line)
        line += len(rows)
        start = stop


def read_ascii(reading: Reading, data: bytes, line: int = 1) -> None:
    """`read_text(reading, data.decode("ascii"), line)` for clean ASCII bytes, without decoding them all:
    the compiled reader reads the bytes themselves, and only the lines it leaves are decoded."""
    if compiled.plain is None or not _COMPILED or not _ENABLED:
        read_text(reading, data.decode("ascii"), line)
        return
    _read_compiled(_FastReader(reading), data, line)


def _read_compiled(fast: _FastReader, text: str | bytes, line: int) -> None:
    """The compiled reader takes runs of plain blocks; `fast.rows` reads the lines it leaves.

    After the compiled reader leaves a line, the regex path reads one line; when
    the compiled reader then reads nothing again, twice as many (up to _MAX_RUN),
    so that a program it cannot help with costs no more than the regex path alone.
    """
    assert compiled.plain is not None
    read_rows = compiled.plain.read_rows
    newline = "\n" if isinstance(text, str) else b"\n"
    pos, end, run = 0, len(text), 1
    while pos < end:
        if fast.simple():
            state = list(fast.load())
            pos, line, n, first, last, moved = read_rows(text, pos, line, fast.params(), state)
            if n:
                fast.store(n, first, last, moved, *state)
                run = 1
            else:
                run = min(2 * run, _MAX_RUN)
            if pos >= end:
                break
        stop = pos
        for _ in range(run):
            stop = text.find(newline, stop) + 1 or end  # type: ignore[arg-type]
            if stop >= end:
                break
        chunk = text[pos:stop]
        lines = chunk if isinstance(chunk, str) else chunk.decode("ascii")
        rows = _ROW.findall(lines)
        if lines.endswith("\n"):
            rows.pop()  # the empty "line" after the last line end
        fast.rows(rows, line)
        line += len(rows)
        pos = stop


class _FastReader:
    def __init__(self, reading: Reading) -> None:
        self.reading = reading
        self.running = reading.estimate
        self.est = reading.estimate._estimator
        codes = reading.end_codes | reading.forbid_codes
        self.g_ok = {g: f"G{g}" not in codes for g in "0123"}
        self.m_ok: dict[str, bool] = {}
        self.codes = codes
        self.g_table = bytes(self.g_ok[g] for g in "0123")
        self.m_table: bytes | None = None

    def params(self) -> tuple[bytes, bytes, float, float, float, float, float, bool]:
        """What the compiled reader needs of the rules and the modal state (see `_plain.read_rows`)."""
        if self.m_table is None:
            self.m_table = bytes(self.m_allowed(str(m)) for m in range(100))
        est = self.est
        ox, oy, oz = _known(est.offset)
        return (self.g_table, self.m_table, est.unit, ox, oy, oz, est.rapid, "clamp" in est.once)

    def m_allowed(self, m: str) -> bool:
        ok = self.m_ok.get(m)
        if ok is None:
            value = float(m)
            ok = self.m_ok[m] = value not in _STOPS and "M" + format_number(value) not in self.codes
        return ok

    def simple(self) -> bool:
        """Whether plain blocks can be read inline in the current state."""
        r, est = self.reading, self.est
        return (
            not r.assembler.end
            and not self.running._ended
            and r.end_block is None
            and est.feed_mode == 94.0
            and est.absolute
            and est.plane == 17.0
            and not est.arc_absolute
            and None not in est.pos
            and None not in est.offset
            and None not in est.lo
            and None not in est.hi
        )

    def general(self, lines: list[str], line: int) -> None:
        self.reading.read(lex_compact("\n".join(lines) + "\n", line))

    def rows(self, rows: list[tuple[str, ...]], line: int) -> None:
        """Read `rows` (`_ROW.findall` of whole lines), the first of them at `line`."""
        reading, est = self.reading, self.est
        g_ok, m_allowed = self.g_ok, self.m_allowed
        rapid = est.rapid
        pending: list[str] = []  # lines for the general path, from pending_line on
        pending_line = line
        n = first = last = 0  # fast blocks since the last store, and their first and last lines
        moved = False
        simple = self.simple()
        unit, (ox, oy, oz) = est.unit, _known(est.offset)  # known (not None) whenever `simple`
        (px, py, pz, lox, loy, loz, hix, hiy, hiz,
         motion, feed, cut_mm, rapid_mm, cut_s, rapid_s, timed) = self.load()  # fmt: skip
        for row in rows:
            g, x, y, z, i, j, rr, f, m, _s, other = row
            plain = not other and row != _BLANK
            if plain and simple and not pending and (not g or g_ok[g]) and (not m or m_allowed(m)):
                mo = _MOTION[g] if g else motion
                fe = float(f) * unit if f else feed
                if not (x or y or z) and (not (i or j or rr) or mo is None or mo < 2.0):
                    # no move: only the motion mode and the feed change
                    motion, feed = mo, fe
                    n += 1
                    first = first or line
                    last = line
                    line += 1
                    continue
                done = mo is not None and mo <= 3.0  # G0 to G3, not a spline or cycle mode
                if done:
                    tx = float(x) * unit + ox if x else px
                    ty = float(y) * unit + oy if y else py
                    tz = float(z) * unit + oz if z else pz
                    if mo != 0.0:
                        if not fe or (fe > rapid and "clamp" not in est.once):
                            done = False  # the general path notes what it assumes
                        elif fe > rapid:
                            fe = rapid
                if done and mo < 2.0:
                    square = 0.0
                    if x:
                        d = tx - px
                        square += d * d
                    if y:
                        d = ty - py
                        square += d * d
                    if z:
                        d = tz - pz
                        square += d * d
                    length = math.sqrt(square)
                    if mo == 0.0:
                        rapid_mm += length
                        rapid_s += length / rapid * 60.0
                    else:
                        cut_mm += length
                        cut_s += length / fe * 60.0
                elif done:
                    try:
                        arc = _arc(mo, (px, py, pz), (tx, ty, tz), bool(z), i, j, rr, unit)
                        extremes, length = (arc.extremes(), arc.length) if arc is not None else ((), 0.0)
                    except (ArcProblem, OverflowError, ValueError):
                        arc = None
                    if arc is None:
                        done = False
                    else:
                        for pu, pv in extremes:
                            lox = pu if pu < lox else lox
                            hix = pu if pu > hix else hix
                            loy = pv if pv < loy else loy
                            hiy = pv if pv > hiy else hiy
                            loz = pz if pz < loz else loz
                            hiz = pz if pz > hiz else hiz
                        cut_mm += length
                        cut_s += length / fe * 60.0
                if done:
                    lox = tx if tx < lox else lox
                    hix = tx if tx > hix else hix
                    loy = ty if ty < loy else loy
                    hiy = ty if ty > hiy else hiy
                    loz = tz if tz < loz else loz
                    hiz = tz if tz > hiz else hiz
                    px, py, pz = tx, ty, tz
                    motion, feed = mo, fe
                    timed += 1
                    moved = True
                    n += 1
                    first = first or line
                    last = line
                    line += 1
                    continue
            # The general path, with the state as it was before this row.
            if n:
                self.store(n, first, last, moved, px, py, pz, lox, loy, loz, hix, hiy, hiz,
                           motion, feed, cut_mm, rapid_mm, cut_s, rapid_s, timed)  # fmt: skip
                n, moved = 0, False
            if not plain:
                if not pending:
                    pending_line = line
                pending.append(other)
                line += 1
                continue
            if pending:
                self.general(pending, pending_line)
                pending = []
            reading.read([(line, None, _pairs(row), False)])
            line += 1
            simple = self.simple()
            if simple:
                unit, (ox, oy, oz) = est.unit, _known(est.offset)
                (px, py, pz, lox, loy, loz, hix, hiy, hiz,
                 motion, feed, cut_mm, rapid_mm, cut_s, rapid_s, timed) = self.load()  # fmt: skip
        if n:
            self.store(n, first, last, moved, px, py, pz, lox, loy, loz, hix, hiy, hiz,
                       motion, feed, cut_mm, rapid_mm, cut_s, rapid_s, timed)  # fmt: skip
        if pending:
            self.general(pending, pending_line)

    def load(self) -> tuple[Any, ...]:
        """The state `rows` keeps in locals (placeholders when the positions are not all known)."""
        est = self.est
        points = (*est.pos, *est.lo, *est.hi)
        if None in points:
            points = (0.0,) * 9
        return (*points, est.motion, est.feed, est.cut_mm, est.rapid_mm, est.cut_s, est.rapid_s, est.timed)

    def store(self, n: int, first: int, last: int, moved: bool, *state: Any) -> None:
        """Write the locals of `rows` back: n fast blocks read, lines first to last."""
        est, asm, reading = self.est, self.reading.assembler, self.reading
        (px, py, pz, lox, loy, loz, hix, hiy, hiz,
         est.motion, est.feed, est.cut_mm, est.rapid_mm,
         est.cut_s, est.rapid_s, est.timed) = state  # fmt: skip
        est.pos = [px, py, pz]
        est.lo = [lox, loy, loz]
        est.hi = [hix, hiy, hiz]
        est.moved = est.moved or moved
        self.running._blocks += n
        asm.lines += n
        out = asm.out
        out.first_line = out.first_line or first
        out.last_line = last
        asm.seen_content = asm.seen_words = True
        reading.any_words = True


Point3 = tuple[float, float, float]


def _known(offset: list[float | None]) -> tuple[float, float, float]:
    """The G92 offsets for the inline reader. They are all known whenever `simple()` holds, the only
    state in which the reader uses them; an unknown one (after G28, say) reads as NaN, never used."""
    ox, oy, oz = (math.nan if v is None else v for v in offset)
    return ox, oy, oz


def _arc(
    mo: float, start: Point3, end: Point3, helix: bool, i: str, j: str, rr: str, unit: float
) -> PlaneArc | None:
    """`_Estimator.arc`'s arc in G17 with relative centres, or None where it would note or skip something."""
    s2, e2 = (start[0], start[1]), (end[0], end[1])
    dw = end[2] - start[2] if helix else 0.0
    clockwise = mo == 2.0
    if rr:
        arc = arc_from_radius(s2, e2, float(rr) * unit, clockwise, turns=1, dw=dw)
    elif i or j:
        cu = float(i) * unit if i else 0.0
        cv = float(j) * unit if j else 0.0
        arc = arc_from_center(s2, e2, (s2[0] + cu, s2[1] + cv), clockwise, turns=1, dw=dw)
    else:
        return None
    if arc.off_circle:
        return None
    return arc


def _pairs(row: tuple[str, ...]) -> list[tuple[str, float]]:
    """A plain row's words, as `lex_compact` gives them."""
    return [(letter, float(value)) for letter, value in zip("GXYZIJRFMS", row, strict=False) if value]
