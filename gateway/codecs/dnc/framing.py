"""A program's wire form: leader, `%`, the blocks with the line's end of block, `%`.

The input is a program as the job validator passed it (bytes, LF or CRLF line
ends, with or without its own `%` lines). The output keeps an index from byte
offset to the program's own line number, so that a sender can say which block
it has reached and a restart can name the block to start from.

Programs that cannot travel are refused, with the line: a DC1/DC2/DC3/DC4 byte
would be taken for flow control by the controller (the article's "wrong
handshake"), a NUL inside would look like leader, and a byte above 0x7F has no
place on a 7-bit line.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

from gateway.codecs.dnc.line import CONTROL_BYTES, NUL, LineSettings
from gateway.errors import CodecError

#: The line number given to blocks the gateway generated (a restart's modal block).
GENERATED = 0

_CONTROL_NAMES = {0x11: "DC1 (XON)", 0x12: "DC2", 0x13: "DC3 (XOFF)", 0x14: "DC4"}


class FramingError(CodecError):
    """A program that cannot be sent over a serial DNC line, located by line (1-based)."""

    def __init__(self, line: int, reason: str) -> None:
        self.line = line
        self.reason = reason
        super().__init__(f"line {line}: {reason}" if line else reason)


@dataclass(frozen=True, slots=True)
class SourceLine:
    """One block as it will be sent: the program's line number and its text, without a line end."""

    number: int
    text: bytes


@dataclass(frozen=True, slots=True)
class ProgramLines:
    """A program split for sending: its own start-marker line (`%O1234`, `%_N_PART_MPF`) if it had
    one with text, and its blocks between the markers."""

    lines: tuple[SourceLine, ...]
    header: bytes | None = None

    def text(self) -> bytes:
        """The program as a file: `%` lines around the blocks, LF line ends."""
        start = self.header if self.header is not None else b"%"
        return start + b"\n" + b"".join(line.text + b"\n" for line in self.lines) + b"%\n"


@dataclass(frozen=True, slots=True)
class WireProgram:
    """The bytes to send, and where each block starts in them.

    `starts[i]` is the offset of block i's first byte and `numbers[i]` its line in
    the source program (GENERATED for blocks the gateway added). `body_start` is
    the offset just after the leader and the opening `%` line; `body_end` the
    offset of the closing `%` (len(data) without markers).
    """

    data: bytes
    starts: tuple[int, ...]
    numbers: tuple[int, ...]
    body_start: int
    body_end: int

    def __len__(self) -> int:
        return len(self.data)

    @property
    def blocks(self) -> int:
        return len(self.starts)

    def blocks_complete(self, offset: int) -> int:
        """How many blocks have all their bytes (line end included) before `offset`."""
        if offset >= self.body_end:
            return len(self.starts)
        # Block i is complete once block i+1 has started (its line end precedes it).
        return max(0, bisect.bisect_right(self.starts, offset) - 1)

    def line_reached(self, offset: int) -> int | None:
        """The source line of the last block sent whole once `offset` bytes are out, None before the first."""
        done = self.blocks_complete(offset)
        return self.numbers[done - 1] if done else None

    def block_of(self, offset: int) -> int | None:
        """The source line of the block that holds byte `offset`, None for leader and markers."""
        if offset < self.body_start or offset >= self.body_end:
            return None
        return self.numbers[bisect.bisect_right(self.starts, offset) - 1]


def split_program(program: bytes) -> ProgramLines:
    """The blocks of a program between its `%` lines, numbered like the source file (first line 1).

    Leading blank lines and a first `%` line are dropped (a `%` line with text is
    kept as the header); the next `%` line ends the program and everything after
    it is dropped, as controllers do. Raises FramingError for bytes that cannot
    travel (see the module's docstring) or a CR inside a line.
    """
    _check_bytes(program)
    raw_lines = program.split(b"\n")
    if raw_lines and raw_lines[-1] == b"":
        raw_lines.pop()
    lines: list[SourceLine] = []
    header: bytes | None = None
    started = False  # past the first `%` line or the first content
    for number, raw in enumerate(raw_lines, start=1):
        text = raw.removesuffix(b"\r")
        if b"\r" in text:
            raise FramingError(number, "carriage return inside a line (only CR LF or LF end a block)")
        stripped = text.strip(b" \t")
        if stripped.startswith(b"%"):
            if started or lines:
                break  # the end marker: controllers ignore what follows
            started = True
            rest = stripped[1:].strip(b" \t")
            header = stripped if rest else None
            continue
        if not started and not stripped:
            continue  # blank lines before the program
        started = True
        lines.append(SourceLine(number, text))
    return ProgramLines(tuple(lines), header)


def frame_program(program: bytes | ProgramLines, settings: LineSettings) -> WireProgram:
    """The program's wire form for `settings`: leader, `%` line, blocks with the EOB, closing `%`.

    Returns characters, not port bytes: `settings.encode` adds software parity.
    """
    parts = program if isinstance(program, ProgramLines) else split_program(program)
    eob = settings.eob_bytes
    chunks: list[bytes] = [b"\x00" * settings.leader]
    if settings.markers:
        chunks.append((parts.header if parts.header is not None else b"%") + eob)
    body_start = sum(len(c) for c in chunks)
    starts: list[int] = []
    numbers: list[int] = []
    offset = body_start
    for source in parts.lines:
        starts.append(offset)
        numbers.append(source.number)
        chunks.append(source.text)
        chunks.append(eob)
        offset += len(source.text) + len(eob)
    body_end = offset
    if settings.markers:
        chunks.append(b"%")
    data = b"".join(chunks)
    if settings.seven_bit and max(data, default=0) > 0x7F:
        where = next((ln.number for ln in parts.lines if max(ln.text, default=0) > 0x7F), 0)
        raise FramingError(where, "a byte above 0x7F cannot travel on a 7-bit line (ISO code is 7-bit)")
    return WireProgram(data, tuple(starts), tuple(numbers), body_start, body_end)


def _check_bytes(program: bytes) -> None:
    for value, what in ((NUL, "NUL"), *((c, _CONTROL_NAMES[c]) for c in sorted(CONTROL_BYTES))):
        at = program.find(bytes((value,)))
        if at >= 0:
            line = program.count(b"\n", 0, at) + 1
            if value == NUL:
                reason = "a NUL byte inside the program (NUL is leader on a DNC line)"
            else:
                reason = f"a {what} byte inside the program would be taken for flow control"
            raise FramingError(line, reason)
