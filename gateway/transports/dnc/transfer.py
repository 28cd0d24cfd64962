"""One transfer over an open serial line: a state machine the lines' I/O thread steps (lineio.py).

It writes the framed program in slices of a few characters, paced a little
under the line's rate, and reads the port before each slice and whenever the
port has something, so that a DC3 stops it within a few characters even through
a device server (whose buffer would otherwise hold what was written too early,
the article's alarm 087). The operator's pause and abort (set from the event loop
through `Control`, which wakes the thread) are looked at in every step. Progress
goes back to the loop as `Position`s. A drip-feed that is part of a fleet
(fleet.py) writes only what the fleet's scheduler granted it, and tells it of the
controller's DC3s and DC1s.
"""

from __future__ import annotations

import bisect
import hashlib
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

from gateway.codecs.dnc import DncSender, Junk, LineSettings, WireProgram
from gateway.errors import DeliveryError
from gateway.transports.dnc.fleet import FleetLine
from gateway.transports.dnc.lineio import GRACE
from gateway.transports.dnc.port import SerialPort

log = logging.getLogger("gateway.jobs.dnc")

SLICE = 8  # characters written at a time, at least (the sender sleeps until a slice is due)
AHEAD = 16  # characters a load may be ahead of the line: what can still go out after a DC3
DRIP_AHEAD = SLICE  # a drip-feed, which meets a DC3 every buffer's worth, keeps closer (the line rate
# is not what limits it: the machine's cutting is)
PACE = 0.98  # share of the line rate the sender keeps to, so that a device server's buffer stays empty
JUNK_LIMIT = 64  # characters that are neither DC1 nor DC3 before the transfer gives up (wrong baud/parity)
REPORT_EVERY = 0.25  # s between progress reports
PARITY_LOG_EVERY = 60.0  # s: a line's parity errors are logged at most this often
FULL_RETRY = 0.002  # s before writing again to a port that took nothing (its buffer full)
DRAIN_POLL = 0.01  # s between looks at what the OS still holds of a load's last bytes


class Control:
    """The operator's hold on a running transfer, set from the event loop, read by the lines' thread (which
    `wake` makes look at it at once)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.paused = False
        self.abort_reason: str | None = None
        self.wake: Callable[[], None] = lambda: None

    def pause(self) -> None:
        with self._lock:
            self.paused = True
        self.wake()

    def resume(self) -> None:
        with self._lock:
            self.paused = False
        self.wake()

    def abort(self, reason: str) -> None:
        with self._lock:
            self.abort_reason = reason
        self.wake()


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
    """A transfer's figures as the gateway saw them (the job's record and the transfer log)."""

    sent: int
    sha256: str  # of the characters sent (before software parity)
    after_dc3_max: int  # characters written after a DC3 had arrived, the most in one episode
    pauses: int  # DC3s
    after_dc3_total: int = 0
    parity_errors: int = 0  # characters other than DC1/DC3 with a wrong parity bit
    flow_wrong_bit7: int = 0  # DC1/DC3 that came with a bit 7 the settings did not expect (obeyed)
    hint: str | None = None  # what those say of the line's settings

    def describe(self) -> str:
        """`12 DC3, at most 3 characters after one` and what the line's characters say, for the record."""
        text = f"{self.pauses} DC3, at most {self.after_dc3_max} characters after one"
        if self.parity_errors:
            text += f"; {self.parity_errors} characters with a wrong parity bit"
        if self.hint is not None:
            text += f"; {self.hint}"
        return text


class TransferFailed(DeliveryError):
    """A transfer that stopped part way, with the position it reached (`offset`, and `resume_line`), and the
    figures so far (`outcome`)."""

    def __init__(
        self,
        reason: str,
        *,
        offset: int,
        resume_line: int | None,
        permanent: bool,
        outcome: Outcome | None = None,
    ) -> None:
        super().__init__(reason, permanent=permanent)
        self.offset = offset
        self.resume_line = resume_line
        self.outcome = outcome


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


class Transfer:
    """Sends `wire` over an open `port`, stepped by the lines' I/O thread (`LineLoop.attach`).

    `step` is called when the port has something to read, when `due` has come, or when woken; it returns
    True when the program is out (`outcome`), and raises TransferFailed with the position reached.
    """

    def __init__(
        self,
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
        name: str = "",
    ) -> None:
        self.port = port
        self.wire = wire
        self.line = line
        self.sender = DncSender(wire, line, wait_for_dc1=wait_for_dc1)
        self.dc1_timeout = dc1_timeout
        self.stall_timeout = stall_timeout
        self.control = control
        self.timing = timing
        self.report = report
        self.alarm = alarm
        self.fleet = fleet
        self.name = name or port.where
        self.rate = line.bytes_per_second * PACE
        self.ahead = float(DRIP_AHEAD if timing is not None else AHEAD)
        self.tokens = self.ahead
        self.last: float | None = None
        self.due = 0.0
        self.outcome: Outcome | None = None
        self._fd = port.fileno()
        self._held_since: float | None = None
        self._reported = -math.inf
        self._digest = hashlib.sha256()
        self._junk = 0
        self._dc3 = False  # the controller's DC3 as the fleet was last told
        self._cutting = False  # the fleet was told the controller takes the program
        self._draining_since: float | None = None  # all written; the OS is passing the last bytes on
        self._parity_logged = -math.inf
        self._parity_seen = 0
        if fleet is not None:
            fleet.on_grant = self._granted

    def fileno(self) -> int | None:
        return self._fd

    def _granted(self) -> None:
        self.due = 0.0  # another line's step granted this one something: look at once

    # --- the step -------------------------------------------------------------------------------------

    def step(self, now: float, readable: bool) -> bool:
        try:
            return self._step(now, readable)
        except TransferFailed:
            raise
        except DeliveryError as exc:  # the line dropped (port.LineLost), or the port failed
            raise self._fail(exc.reason) from None

    def _step(self, now: float, readable: bool) -> bool:
        sender = self.sender
        if self.control.abort_reason is not None:
            raise self._fail(self.control.abort_reason, permanent=True)
        if readable:
            self._take(self.port.read())
        self._tell_fleet()
        held = self._held()
        if now - self._reported >= REPORT_EVERY:
            self._reported = now
            self.report(self._where(held))
            why = self.alarm() if self.alarm is not None else None
            if why is not None:
                raise self._fail(f"the controller is in alarm ({why})")
            self._log_parity(now)
        if sender.done:
            return self._drained(now)
        if self.last is None:
            self.last = now
        if held:
            return self._hold(now, held)
        self._held_since = None
        # A step that came late (a loaded machine) leaves up to `ahead` characters due, not more.
        self.tokens = min(self.ahead, self.tokens + (now - self.last) * self.rate)
        self.last = now
        # Lines stepped together (due within lineio.GRACE) write together: a step may borrow that much.
        if self.tokens + self.rate * GRACE < SLICE and sender.remaining > self.tokens:
            self.due = now + (SLICE - self.tokens) / self.rate
            return False
        allowed = max(int(self.tokens), min(SLICE, sender.remaining))
        if self.fleet is not None:
            allowance = self.fleet.allowance()
            if allowance <= 0:
                self.due = now + self.fleet.wait_seconds()
                return False
            allowed = min(allowed, allowance)
        if not readable:
            # The last look at the port may be a few hundred microseconds old (other lines were stepped
            # since): a DC3 that came meanwhile must stop this slice, not the next one.
            self._take(self.port.read())
            self._tell_fleet()
            if self._held():
                self.due = now
                return False
        chunk = sender.next_chunk(allowed)
        written = self.port.write(chunk)
        self._digest.update(self.wire.data[sender.offset : sender.offset + written])
        sender.sent(written)
        self.tokens -= written
        if self.fleet is not None:
            self.fleet.wrote(written)
        if written < len(chunk):
            self.due = now + FULL_RETRY  # the port's buffer is full: it is slower than the pacing thought
        elif sender.done:
            self.due = now
        else:
            self.due = now + max(0.0, SLICE - self.tokens) / self.rate
        return False

    def _take(self, data: bytes) -> None:
        if not data:
            return
        for event in self.sender.feed(data):
            if isinstance(event, Junk):
                self._junk += event.count
                if self._junk > JUNK_LIMIT:
                    raise self._fail(f"garbage from the controller: {event.reason}", permanent=True)

    def _tell_fleet(self) -> None:
        fleet = self.fleet
        if fleet is None:
            return
        sender = self.sender
        if not self._cutting and not sender.waiting_for_dc1:
            self._cutting = True
            fleet.started()
        if sender.paused != self._dc3:
            self._dc3 = sender.paused
            fleet.held(self._dc3, sender.offset)

    def _held(self) -> str:
        """Why nothing may go out now: "paused", "waiting for DC1", "DC3", or ""."""
        if self.control.paused:
            return "paused"
        if self.sender.waiting_for_dc1:
            return "waiting for DC1"
        return "DC3" if self.sender.paused else ""

    def _hold(self, now: float, held: str) -> bool:
        if self._held_since is None:
            self._held_since = now
        waited = now - self._held_since
        if held == "waiting for DC1" and waited > self.dc1_timeout:
            raise self._fail(
                f"no DC1 from the controller within {self.dc1_timeout:g} s (is it reading? "
                "EDIT + READ, or cycle start in RMT/DNC mode)",
                permanent=self.sender.offset > self.wire.body_start,
            )
        if held == "DC3" and waited > self.stall_timeout:
            raise self._fail(f"the controller held the line with DC3 for over {self.stall_timeout:g} s")
        self.tokens = min(self.tokens, self.ahead)
        self.last = now
        limit = {"waiting for DC1": self.dc1_timeout, "DC3": self.stall_timeout}.get(held, math.inf)
        # The port wakes the step when the controller says something; the clock, for the next report.
        self.due = min(self._held_since + limit + 1e-3, self._reported + REPORT_EVERY)
        return False

    def _drained(self, now: float) -> bool:
        """All written: done once the OS has passed it on (a load's last bytes must not be lost to a port
        closed too early). A port that holds them longer than the stall timeout has stalled."""
        if self._draining_since is None:
            self._draining_since = now
        if self.port.unsent() > 0:
            if now - self._draining_since > self.stall_timeout:
                raise self._fail(f"the port passed nothing on for over {self.stall_timeout:g} s")
            self.due = now + DRAIN_POLL
            return False
        self.report(self._where(""))
        self.outcome = self._outcome()
        return True

    def _log_parity(self, now: float) -> None:
        errors = self.sender.parity_errors + self.sender.flow_wrong_bit7
        if errors > self._parity_seen and now - self._parity_logged >= PARITY_LOG_EVERY:
            self._parity_logged = now
            self._parity_seen = errors
            hint = self.sender.format_hint()
            log.warning(
                "%s: %d characters from the controller with a wrong parity bit so far (%d of them DC1/DC3, "
                "obeyed)%s",
                self.name,
                errors,
                self.sender.flow_wrong_bit7,
                f"; {hint}" if hint is not None else "",
            )

    # --- what it reports ---------------------------------------------------------------------------------

    def _where(self, held: str) -> Position:
        sender = self.sender
        if self.timing is not None:
            return self.timing.position(sender.offset, held)
        return Position(sender.offset, sender.total, self.wire.line_reached(sender.offset), None, None, held)

    def _outcome(self) -> Outcome:
        sender = self.sender
        return Outcome(
            sender.offset,
            self._digest.hexdigest(),
            sender.after_dc3_max,
            sender.pauses,
            sender.after_dc3_total,
            sender.parity_errors,
            sender.flow_wrong_bit7,
            sender.format_hint(),
        )

    def _fail(self, reason: str, *, permanent: bool | None = None) -> TransferFailed:
        sender, wire, timing = self.sender, self.wire, self.timing
        offset = sender.offset
        body_started = offset > wire.body_start
        resume = timing.resume_line(offset) if timing is not None else None
        if body_started and timing is not None:
            at = f" at line {resume}" if resume is not None else ""
            reason = f"{reason}; stopped{at} after {offset} of {sender.total} bytes (resume at a line)"
        elif body_started:
            reason = f"{reason}; after {offset} of {sender.total} bytes"
        outcome = self._outcome()
        if outcome.pauses or outcome.parity_errors or outcome.hint:
            reason = f"{reason} ({outcome.describe()})"
        # A drip that started must not be sent again without an operator; a load may be.
        lasting = body_started and timing is not None if permanent is None else permanent
        return TransferFailed(reason, offset=offset, resume_line=resume, permanent=lasting, outcome=outcome)
