"""The sending side of a DNC transfer: which bytes may go now, and what the controller said.

A sans-I/O state machine. The transport feeds it what it read from the port
(`feed`, giving events) and asks what it may write (`next_chunk`, nothing while
the controller holds it back), then says how much it really wrote (`sent`). The
sender counts the characters that went out after a DC3 had been received: the
controller tolerates only a few (Fanuc raises alarm 087, buffer overflow, after
about ten), so that count is the measure of an honest sender.

A DC1 or DC3 is obeyed whatever its bit 7 (see `feed`): a flow-control character
taken for junk would let the sender run past the controller's DC3.

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
        self.parity_errors = 0  # other characters with a wrong parity bit (software parity)
        #: DC1/DC3 whose bit 7 was not what the settings expect (obeyed all the same; see `format_hint`).
        self.flow_wrong_bit7 = 0

    # --- what the controller says ----------------------------------------------------------------

    def feed(self, data: bytes) -> list[SenderEvent]:
        """Bytes read from the port. DC1 and DC3 change the state whatever their bit 7; anything else is
        junk, counted.

        A flow-control character is never junk: a 7-bit device server hands the controller's characters
        to TCP with bit 7 clear (its UART checked and dropped the parity bit), a transparent port hands
        them with the parity bit in bit 7, and a sender that took one kind for the other must still stop
        at the controller's DC3. Such characters are counted (`flow_wrong_bit7`) so that the line can say
        which setting to check (`format_hint`).
        """
        events: list[SenderEvent] = []
        junk = bytearray()
        reasons: set[str] = set()
        soft = self.settings.software_parity
        for byte in data:
            char = byte & 0x7F
            wrong_bit7 = byte not in self._good if soft else byte > 0x7F and self.settings.seven_bit
            if char in (DC1, DC3) and self._xonxoff:
                if junk:
                    events.append(self._junk(junk, reasons))
                    junk, reasons = bytearray(), set()
                self.flow_wrong_bit7 += wrong_bit7
                events.append(self._resume() if char == DC1 else self._pause())
                continue
            if soft and wrong_bit7:
                self.parity_errors += 1
                reasons.add(f"parity error(s): is the controller's character format {self.settings.format}?")
                junk.append(byte)
                continue
            junk.append(char if soft else byte)
            if char in (DC1, DC3):
                reasons.add(
                    f"{'DC1' if char == DC1 else 'DC3'} while the handshake is {self.settings.handshake}"
                )
            elif self.settings.seven_bit and byte > 0x7F:
                reasons.add("bytes above 0x7F on a 7-bit line (wrong baud rate or character format?)")
            else:
                reasons.add("characters other than DC1/DC3 while sending (wrong baud rate, or line noise?)")
        if junk:
            events.append(self._junk(junk, reasons))
        return events

    def format_hint(self) -> str | None:
        """What the flow-control characters say of the line's settings, None when they fit them.

        With software parity on, a DC3 that comes as 0x13 (its even parity bit missing) while DC1 (0x11,
        even already) fits means a device server whose own UART does the parity: software parity must
        be off. Without it, a DC1 or DC3 with bit 7 set on a 7-bit line means a transparent port that
        passes the parity bit on as bit 7: software parity must be on (or the port set to the format).
        """
        if not self.flow_wrong_bit7:
            return None
        fmt = self.settings.format
        if self.settings.software_parity:
            return (
                f"{self.flow_wrong_bit7} DC1/DC3 came without the parity bit software parity expects: the "
                f"device server's UART seems to do the {fmt} parity itself (a 7-bit port): set "
                "software_parity: false"
            )
        if self.settings.seven_bit:
            return (
                f"{self.flow_wrong_bit7} DC1/DC3 came with bit 7 set: the device server seems to pass the "
                f"parity bit on (a transparent 8-bit port): set its serial port to {fmt}, or "
                "software_parity: true"
            )
        return (
            f"{self.flow_wrong_bit7} DC1/DC3 came with bit 7 set on an 8-bit line: the controller sends "
            f"7 data bits and a parity bit; check its character format against {fmt}"
        )

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
