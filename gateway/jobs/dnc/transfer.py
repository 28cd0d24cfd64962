"""One transfer over an open serial line: the blocking send loop that runs in the line's own thread.

It writes the framed program in slices of a few characters, paced a little
under the line's rate, and reads the port between two slices, so that a DC3 stops
it within a few characters even through a device server (whose buffer would
otherwise hold what was written too early, the article's alarm 087). The
operator's pause and abort (set from the event loop through `Control`) are looked
at between slices too. Progress goes back to the loop as `Position`s. A drip-feed
that is part of a fleet (fleet.py) writes only what the fleet's scheduler granted
it, and tells it of the controller's DC3s and DC1s.
"""

from __future__ import annotations

import bisect
import hashlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from gateway.codecs.dnc import DncSender, Junk, LineSettings, Pause, WireProgram
from gateway.errors import DeliveryError
from gateway.jobs.dnc.fleet import FleetLine
from gateway.jobs.dnc.port import SerialPort

SLICE = 8  # characters written at a time, at least (the sender sleeps until a slice is due)
AHEAD = 16  # characters a load may be ahead of the line: what can still go out after a DC3
DRIP_AHEAD = SLICE  # a drip-feed, which meets a DC3 every buffer's worth, keeps closer (the line rate
# is not what limits it: the machine's cutting is)
PACE = 0.98  # share of the line rate the sender keeps to, so that a device server's buffer stays empty
JUNK_LIMIT = 64  # characters that are neither DC1 nor DC3 before the transfer gives up (wrong baud/parity)
REPORT_EVERY = 0.25  # s between progress reports


class Control:
    """The operator's hold on a running transfer, set from the event loop, read by the line's thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.paused = False
        self.abort_reason: str | None = None

    def pause(self) -> None:
        with self._lock:
            self.paused = True

    def resume(self) -> None:
        with self._lock:
            self.paused = False

    def abort(self, reason: str) -> None:
        with self._lock:
            self.abort_reason = reason


@dataclass(frozen=True, slots=True)
class Position:
    """Where a transfer is: bytes out, and (drip) the estimated block running, lead and time left."""

    sent: int
    total: int
    line: int | None  # the source line the controller is estimated to execute (drip), or the last sent
    lead: float | None  # seconds of cutting estimated in the controller's buffer (drip)
    remaining: float | None  # seconds of cutting estimated left (drip)
    held: str = ""  # why nothing is going out now: "DC3", "waiting for DC1", "paused", ""


@dataclass(frozen=True, slots=True)
class Outcome:
    sent: int
    sha256: str  # of the characters sent (before software parity)
    after_dc3_max: int
    pauses: int


class TransferFailed(DeliveryError):
    """A transfer that stopped part way, with the position it reached (`offset`, and `resume_line`)."""

    def __init__(self, reason: str, *, offset: int, resume_line: int | None, permanent: bool) -> None:
        super().__init__(reason, permanent=permanent)
        self.offset = offset
        self.resume_line = resume_line


class Timing:
    """Run time per block of a wire program, to estimate the block running, the lead and the time left."""

    def __init__(self, wire: WireProgram, times: dict[int, float], buffer: int) -> None:
        self.wire = wire
        self.buffer = buffer
        seconds = [times.get(n, 0.0) if n else 0.0 for n in wire.numbers]
        self._after = [0.0] * (len(seconds) + 1)  # _after[i]: seconds of blocks i..end
        for i in range(len(seconds) - 1, -1, -1):
            self._after[i] = self._after[i + 1] + seconds[i]

    def running_index(self, offset: int) -> int | None:
        """The block the controller may still be on after `offset` bytes: at most `buffer` bytes behind."""
        starts = self.wire.starts
        if not starts or offset <= self.wire.body_start:
            return None
        behind = max(self.wire.body_start, offset - self.buffer)
        return max(0, bisect.bisect_right(starts, behind) - 1)

    def position(self, offset: int, held: str) -> Position:
        index = self.running_index(offset)
        total = len(self.wire)
        if index is None:
            return Position(offset, total, None, 0.0, self._after[0], held)
        done = self.wire.blocks_complete(offset)
        lead = max(0.0, self._after[index] - self._after[max(index, done)])
        return Position(offset, total, self.wire.numbers[index], lead, self._after[index], held)

    def resume_line(self, offset: int) -> int | None:
        """Where a resume starts after a stop at `offset`: one block before any the controller may not have
        run (it holds up to `buffer` bytes, and the block it was on when it stopped)."""
        index = self.running_index(offset)
        if index is None:
            return None
        numbers = self.wire.numbers
        index = max(0, index - 1)
        while index > 0 and not numbers[index]:
            index -= 1  # a generated block (a restart's modal block) has no line of its own
        return numbers[index] or None


def run_transfer(
    port: SerialPort,
    wire: WireProgram,
    line: LineSettings,
    *,
    wait_for_dc1: bool,
    dc1_timeout: float,
    stall_timeout: float,
    control: Control,
    timing: Timing | None,
    report: Callable[[Position], None],
    alarm: Callable[[], str | None] | None = None,
    fleet: FleetLine | None = None,
) -> Outcome:
    """Send `wire` over `port` (blocking). Raises TransferFailed with the position reached."""
    sender = DncSender(wire, line, wait_for_dc1=wait_for_dc1)
    rate = line.bytes_per_second * PACE
    started = time.monotonic()
    ahead = float(DRIP_AHEAD if timing is not None else AHEAD)
    tokens = ahead
    last = started
    held_since: float | None = None
    reported = 0.0
    digest = hashlib.sha256()
    junk = 0
    held = "waiting for DC1" if sender.waiting_for_dc1 else ""
    granted = True  # a fleet's line: whether it has something granted to write (else it waits for it)
    dc3 = False  # the controller's DC3 as the fleet was last told
    cutting = False  # the fleet was told the controller takes the program
    look = True  # whether the controller may have sent something since the port was last read

    def where(held: str) -> Position:
        if timing is not None:
            return timing.position(sender.offset, held)
        return Position(sender.offset, sender.total, wire.line_reached(sender.offset), None, None, held)

    def fail(reason: str, *, permanent: bool | None = None) -> TransferFailed:
        offset = sender.offset
        body_started = offset > wire.body_start
        resume = timing.resume_line(offset) if timing is not None else None
        if body_started and timing is not None:
            at = f" at line {resume}" if resume is not None else ""
            reason = f"{reason}; stopped{at} after {offset} of {sender.total} bytes (resume at a line)"
        elif body_started:
            reason = f"{reason}; after {offset} of {sender.total} bytes"
        # A drip that started must not be sent again without an operator; a load may be.
        lasting = body_started and timing is not None if permanent is None else permanent
        return TransferFailed(reason, offset=offset, resume_line=resume, permanent=lasting)

    try:
        while not sender.done:
            if control.abort_reason is not None:
                raise fail(control.abort_reason, permanent=True)
            if held:
                data = port.wait()
            elif not granted and fleet is not None:
                data = port.wait(fleet.wake_fd, fleet.wait_seconds())
                fleet.drain()
            elif look:
                data = port.read()
            else:
                data = b""  # the pause just before watched the port: nothing came
            look = True
            if data:
                for event in sender.feed(data):
                    if isinstance(event, Junk):
                        junk += event.count
                        if junk > JUNK_LIMIT:
                            raise fail(f"garbage from the controller: {event.reason}", permanent=True)
                    elif isinstance(event, Pause):
                        pass
            if fleet is not None:
                if not cutting and not sender.waiting_for_dc1:
                    cutting = True
                    fleet.started()
                if sender.paused != dc3:
                    dc3 = sender.paused
                    fleet.held(dc3)
            now = time.monotonic()
            held = (
                "paused"
                if control.paused
                else "waiting for DC1"
                if sender.waiting_for_dc1
                else "DC3"
                if sender.paused
                else ""
            )
            if now - reported >= REPORT_EVERY:
                reported = now
                report(where(held))
                why = alarm() if alarm is not None else None
                if why is not None:
                    raise fail(f"the controller is in alarm ({why})")
            if held:
                if held_since is None:
                    held_since = now
                if held == "waiting for DC1" and now - held_since > dc1_timeout:
                    raise fail(
                        f"no DC1 from the controller within {dc1_timeout:g} s (is it reading? "
                        "EDIT + READ, or cycle start in RMT/DNC mode)",
                        permanent=sender.offset > wire.body_start,
                    )
                if held == "DC3" and now - held_since > stall_timeout:
                    raise fail(f"the controller held the line with DC3 for over {stall_timeout:g} s")
                tokens = min(tokens, ahead)
                last = now
                continue  # the next look at the port waits for the controller (port.wait)
            held_since = None
            # A sleep that overran (a loaded machine) leaves up to AHEAD characters due, not more.
            tokens = min(ahead, tokens + (now - last) * rate)
            last = now
            if tokens < SLICE and sender.remaining > tokens:
                # A whole slice at a time: fewer, larger writes, and a thread that waits in between,
                # on the port: a DC3 meanwhile is read at once.
                look = port.pause((SLICE - tokens) / rate)
                continue
            allowed = int(tokens)
            if fleet is not None:
                granted = (allowance := fleet.allowance()) > 0
                if not granted:
                    continue  # the next look at the port also waits for a grant
                allowed = min(allowed, allowance)
            chunk = sender.next_chunk(allowed)
            written = port.write(chunk)
            digest.update(wire.data[sender.offset : sender.offset + written])
            sender.sent(written)
            tokens -= written
            if fleet is not None:
                fleet.wrote(written)
        port.flush()
    except TransferFailed:
        raise
    except DeliveryError as exc:  # the line dropped (port.LineLost), or the port failed
        raise fail(exc.reason) from None
    report(where(""))
    return Outcome(sender.offset, digest.hexdigest(), sender.after_dc3_max, sender.pauses)
