"""The receiving side: a program punched by the controller (or sent to it), framed by `%`.

A sans-I/O state machine: `feed(bytes)` gives events. Leader (NUL, DEL, blank
lines) before the first `%` is skipped; DC1..DC4 anywhere are tape and flow
control, not data, and are dropped; other bytes before `%` are junk, counted.
The program is what lies between the `%` line and the closing `%`. A program
over `max_size` is refused (Overflow) and the rest of it skipped until its `%`.
When the line ends inside a program, the caller says so (`end_of_input`) and
gets `Unterminated` with what had arrived: nothing is stored silently.

The article counts the `%` markers to know when a transfer is complete; this is
the same rule. Without markers (`markers=False`) the caller decides where a
program ends (an idle timeout) and `end_of_input` hands it over.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum

from gateway.codecs.dnc.line import CONTROL_BYTES, CR, DEL, LF, NUL
from gateway.codecs.dnc.sender import JUNK_SAMPLE, Junk

DEFAULT_MAX_SIZE = 16 * 1024 * 1024
_LEADER = frozenset({NUL, DEL, LF, CR, 0x20, 0x09})
_DROP = bytes(sorted(CONTROL_BYTES))
_O_NUMBER = re.compile(rb"^\s*O\s*(\d{1,8})\s*(?:\(([^()]*)\))?", re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class ProgramStarted:
    """The opening `%` arrived. `header` is the text after it on its line (`O1234`, `_N_PART_MPF`), if any."""

    header: bytes = b""


@dataclass(frozen=True, slots=True)
class ProgramReceived:
    """A whole program: the blocks between the markers, as they came (line ends included).

    `number` is the first O-number (`O4711` -> 4711) and `name` the comment beside
    it, or the start marker's text (`%_N_PART_MPF`).
    """

    text: bytes
    number: int | None
    name: str | None
    header: bytes = b""


@dataclass(frozen=True, slots=True)
class Overflow:
    """The program passed `limit` bytes: refused, and the rest skipped until its closing `%`."""

    limit: int


@dataclass(frozen=True, slots=True)
class Unterminated:
    """The line ended inside a program: `text` is what had arrived (not a program: no closing `%`)."""

    text: bytes


ReceiverEvent = ProgramStarted | ProgramReceived | Overflow | Unterminated | Junk


class _State(Enum):
    IDLE = "idle"  # before a program: leader, junk
    HEADER = "header"  # after the opening `%`, up to its line end
    BODY = "body"
    SKIPPING = "skipping"  # an oversized program, until its `%`


class ProgramReceiver:
    """Collects `%`-framed programs from a byte stream, one after another."""

    def __init__(
        self, *, max_size: int = DEFAULT_MAX_SIZE, strip_parity: bool = False, markers: bool = True
    ) -> None:
        if max_size < 1:
            raise ValueError("max_size must be >= 1")
        self.max_size = max_size
        self.strip_parity = strip_parity
        self.markers = markers
        self._state = _State.IDLE if markers else _State.BODY
        self._header = bytearray()
        self._body = bytearray()
        self.junk_bytes = 0
        self.programs = 0

    @property
    def receiving(self) -> bool:
        """Inside a program (between its markers)."""
        return self._state is not _State.IDLE and (self.markers or bool(self._body))

    @property
    def received(self) -> int:
        """Bytes of the current program so far."""
        return len(self._body)

    def feed(self, data: bytes) -> list[ReceiverEvent]:
        if self.strip_parity:
            data = data.translate(_STRIP)
        data = data.translate(None, _DROP)
        events: list[ReceiverEvent] = []
        pos = 0
        end = len(data)
        while pos < end:
            state = self._state
            if state is _State.IDLE:
                pos = self._idle(data, pos, events)
            elif state is _State.HEADER:
                nl = data.find(b"\n", pos)
                stop = end if nl < 0 else nl
                self._header += data[pos:stop]
                if nl >= 0:
                    self._state = _State.BODY
                    header = bytes(self._header).strip(b" \t\r")
                    events.append(ProgramStarted(header))
                    pos = nl + 1
                else:
                    pos = end
                if len(self._header) > self.max_size:
                    events.append(Overflow(self.max_size))
                    self._header.clear()
                    self._state = _State.SKIPPING
            elif state is _State.BODY:
                pct = data.find(b"%", pos) if self.markers else -1
                stop = end if pct < 0 else pct
                room = self.max_size - len(self._body)
                if stop - pos > room:
                    events.append(Overflow(self.max_size))
                    self._body.clear()
                    self._header.clear()
                    self._state = _State.SKIPPING if self.markers else _State.BODY
                    pos = stop if self.markers else end
                    continue
                self._body += data[pos:stop]
                if pct >= 0:
                    events.append(self._finish())
                    pos = pct + 1
                else:
                    pos = end
            else:  # SKIPPING
                pct = data.find(b"%", pos)
                if pct < 0:
                    pos = end
                else:
                    self._state = _State.IDLE
                    pos = pct + 1
        return events

    def _idle(self, data: bytes, pos: int, events: list[ReceiverEvent]) -> int:
        pct = data.find(b"%", pos)
        stop = len(data) if pct < 0 else pct
        junk = bytes(b for b in data[pos:stop] if b not in _LEADER)
        if junk:
            self.junk_bytes += len(junk)
            reason = "characters before the opening % (wrong baud rate or format, or line noise?)"
            events.append(Junk(len(junk), junk[:JUNK_SAMPLE], reason))
        if pct < 0:
            return len(data)
        self._state = _State.HEADER
        self._header.clear()
        self._body.clear()
        return pct + 1

    def _finish(self) -> ProgramReceived:
        header = bytes(self._header).strip(b" \t\r")
        text = bytes(self._body)
        self._body.clear()
        self._header.clear()
        self._state = _State.IDLE if self.markers else _State.BODY
        self.programs += 1
        number, name = _identify(text, header)
        return ProgramReceived(text, number, name, header)

    def end_of_input(self) -> list[ReceiverEvent]:
        """The line ended (closed, dropped, idle too long). Inside a program: Unterminated, or, without
        markers, the program itself."""
        if not self.markers:
            if not self._body:
                return []
            return [self._finish()]
        state = self._state
        text = bytes(self._body)
        self._body.clear()
        self._header.clear()
        self._state = _State.IDLE
        if state in (_State.HEADER, _State.BODY):
            return [Unterminated(text)]
        return []


_STRIP = bytes(v & 0x7F for v in range(256))


def _identify(text: bytes, header: bytes) -> tuple[int | None, str | None]:
    """The O-number and name of a received program: `O4711 (BRACKET)`, or `%O4711`, `%_N_PART_MPF`."""
    for candidate in (header, *text.lstrip(b"\r\n \t").split(b"\n", 1)[:1]):
        match = _O_NUMBER.match(candidate)
        if match:
            name = match.group(2)
            return int(match.group(1)), (name.decode("ascii", "replace").strip() or None) if name else None
    if header:
        return None, header.decode("ascii", "replace")
    return None, None
