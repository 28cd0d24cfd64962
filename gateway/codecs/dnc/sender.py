"""The sending side of a DNC transfer: which bytes may go now, and what the controller said.

A sans-I/O state machine. The transport feeds it what it read from the port
(`feed`, giving events) and asks what it may write (`next_chunk`, nothing while
the controller holds it back), then says how much it really wrote (`sent`). The
sender counts the characters that went out after a DC3 had been received: the
controller tolerates only a few (Fanuc raises alarm 087, buffer overflow, after
about ten), so that count is the measure of an honest sender.

By default the sender waits for the controller's first DC1 before sending
anything (`wait_for_dc1`): a Fanuc sends DC1 when the operator starts the read
(EDIT + READ, or cycle start in RMT mode). With `handshake: rtscts` or `none`
the port does the flow control (or nothing does): DC1/DC3 are not acted on.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.codecs.dnc.framing import WireProgram
from gateway.codecs.dnc.line import DC1, DC3, LineSettings

#: Junk bytes kept in one event; the count covers every byte.
JUNK_SAMPLE = 32


@dataclass(frozen=True, slots=True)
class Resume:
    """DC1: the controller can take data."""


@dataclass(frozen=True, slots=True)
class Pause:
    """DC3: the controller's buffer is nearly full; stop within a few characters."""


@dataclass(frozen=True, slots=True)
class Junk:
    """Bytes that cannot come from a controller reading a program at this setting.

    `count` bytes in all, `sample` the first of them; `reason` says why (wrong
    baud rate and wrong character format both look like this).
    """

    count: int
    sample: bytes
    reason: str


SenderEvent = Resume | Pause | Junk


class DncSender:
    """Sends one framed program, honouring DC1/DC3. Not thread-safe; one per transfer."""

    def __init__(self, program: WireProgram, settings: LineSettings, *, wait_for_dc1: bool = True) -> None:
        self.program = program
        self.settings = settings
        self._wire = settings.encode(program.data)
        self._xonxoff = settings.handshake == "xonxoff"
        self._good = frozenset(settings.encode(bytes(range(128))))  # port bytes with a right parity bit
        self.offset = 0
        #: True while DC3 holds the sender (and, with wait_for_dc1, until the first DC1).
        self.paused = self._xonxoff and wait_for_dc1
        self.waiting_for_dc1 = self.paused
        self._after_dc3: int | None = None  # characters sent in the current DC3 episode, None outside one
        self.after_dc3_last = 0
        self.after_dc3_max = 0
        self.after_dc3_total = 0
        self.pauses = 0
        self.resumes = 0
        self.junk_bytes = 0
        self.parity_errors = 0

    # --- what the controller says ----------------------------------------------------------------

    def feed(self, data: bytes) -> list[SenderEvent]:
        """Bytes read from the port. DC1 and DC3 change the state; anything else is counted as junk."""
        chars, errors = self.settings.decode(data)
        events: list[SenderEvent] = []
        junk = bytearray()
        reasons: set[str] = set()
        bad_positions: set[int] = set()
        if errors:
            self.parity_errors += errors
            reasons.add(
                f"{errors} parity error(s): is the controller's character format {self.settings.format}?"
            )
            bad_positions = {i for i, b in enumerate(data) if b not in self._good}
        for index, char in enumerate(chars):
            if index in bad_positions:
                junk.append(data[index])
                continue
            if char in (DC1, DC3) and self._xonxoff:
                if junk:
                    events.append(self._junk(junk, reasons))
                    junk, reasons = bytearray(), set()
                events.append(self._resume() if char == DC1 else self._pause())
                continue
            junk.append(char)
            if char in (DC1, DC3):
                reasons.add(
                    f"{'DC1' if char == DC1 else 'DC3'} while the handshake is {self.settings.handshake}"
                )
            elif self.settings.seven_bit and char > 0x7F:
                reasons.add("bytes above 0x7F on a 7-bit line (wrong baud rate or character format?)")
            else:
                reasons.add("characters other than DC1/DC3 while sending (wrong baud rate, or line noise?)")
        if junk:
            events.append(self._junk(junk, reasons))
        return events

    def _junk(self, junk: bytearray, reasons: set[str]) -> Junk:
        self.junk_bytes += len(junk)
        return Junk(len(junk), bytes(junk[:JUNK_SAMPLE]), "; ".join(sorted(reasons)))

    def _resume(self) -> Resume:
        self.resumes += 1
        self.waiting_for_dc1 = False
        if self.paused and self._after_dc3 is not None:
            self.after_dc3_last = self._after_dc3
        self.paused = False
        self._after_dc3 = None
        return Resume()

    def _pause(self) -> Pause:
        if not self.paused or self._after_dc3 is None:
            self.pauses += 1
            self._after_dc3 = 0
        self.paused = True
        return Pause()

    # --- what may be sent -----------------------------------------------------------------------

    @property
    def total(self) -> int:
        return len(self._wire)

    @property
    def remaining(self) -> int:
        return len(self._wire) - self.offset

    @property
    def done(self) -> bool:
        return self.offset >= len(self._wire)

    @property
    def line(self) -> int | None:
        """The source line of the last block sent whole (progress, and where a restart would start)."""
        return self.program.line_reached(self.offset)

    @property
    def blocks_sent(self) -> int:
        return self.program.blocks_complete(self.offset)

    def next_chunk(self, max_bytes: int | None = None) -> bytes:
        """Port bytes that may be written now (at most `chunk_size`, or `max_bytes`): empty while paused.

        Does not advance: call `sent(n)` with what the port really took.
        """
        if self.paused or self.done:
            return b""
        size = self.settings.chunk_size if max_bytes is None else min(max_bytes, self.settings.chunk_size)
        return self._wire[self.offset : self.offset + max(0, size)]

    def sent(self, count: int) -> int:
        """`count` more bytes went to the port now. Returns how many of them went after a DC3."""
        if count < 0 or count > self.remaining:
            raise ValueError(f"sent {count} bytes, but {self.remaining} remain")
        self.offset += count
        if self._after_dc3 is None:
            return 0
        self._after_dc3 += count
        self.after_dc3_total += count
        self.after_dc3_last = self._after_dc3
        self.after_dc3_max = max(self.after_dc3_max, self._after_dc3)
        return count

    def take(self, max_bytes: int | None = None) -> bytes:
        """`next_chunk` and `sent` in one, for callers whose writes never fall short."""
        chunk = self.next_chunk(max_bytes)
        self.sent(len(chunk))
        return chunk
