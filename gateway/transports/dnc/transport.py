"""Serial DNC delivery: load a program into the controller's memory, or drip-feed it while it runs.

One `SerialTransport` per machine owns its line (`jobs.controller` with
`type: serial`): the port (gateway/transports/dnc/port.py, pyserial) and the operator's
hold on a drip-feed (pause, resume, abort). Its transfers are stepped by the one
I/O thread that serves every serial line of the gateway (the fleet's, lineio.py),
so that a DC3 is acted on between two small writes (transfer.py); opening and
closing a port, which may wait, run in a worker thread of their own.
Between jobs it listens to the line for an `IdleListener` (the punch desk) when
one is attached, and keeps the port open for it; without one the port is open
only while a program goes out. The listener's answers (a remote request's
program) go out load or drip as the line's mode says; a dripped answer can be
paused, resumed and aborted like a job's drip-feed.

A drip-feed that stopped part way (a dropped line, an alarm, an abort, a gateway
restart) is never sent again on its own: its job is FAILED with the line to
resume at, and a `restart(job, line)` sends the program's header, the modal
state and the program from that line (gateway/codecs/dnc/restart.py). So that a
gateway restarted in the middle of a drip knows, the line writes a checkpoint
(`<state>/jobs/dnc/<machine>.json`) while it drips; `holds()` finds it and fails
the job for the operator instead of sending it again. Every transfer goes into
the DNC transfer log.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from gateway.codecs.dnc import (
    FramingError,
    WireProgram,
    block_times,
    frame_program,
    program_costs,
    restart_lines,
)
from gateway.errors import DeliveryError, InvalidState, StoreError
from gateway.transports.base import Program, Progress, ReportProgress
from gateway.transports.dnc.config import ControllerSerial
from gateway.transports.dnc.fleet import DripFleet, FleetLine
from gateway.transports.dnc.idle import IdleListener, SendAnswer
from gateway.transports.dnc.port import SerialPort, describe, line_settings
from gateway.transports.dnc.transfer import Control, Outcome, Position, Timing, Transfer, TransferFailed
from gateway.transports.dnc.transfers import TransferLog, TransferRecord

log = logging.getLogger("gateway.jobs.dnc")

CHECKPOINT_EVERY = 1.0  # s between checkpoint writes while dripping
LISTEN_EVERY = 0.05  # s between looks at an idle line
REOPEN_AFTER = 5.0  # s before an idle line that failed is opened again
ANSWER = "answer:"  # a progress file's `program` for a remote request's answer (not a job)


@dataclass(frozen=True, slots=True)
class Checkpoint:
    """A transfer in progress, as written to `<state>/jobs/dnc/<machine>.json` about once a second: where
    a drip-feed stopped after a restart (`holds`), and the progress `cnc-gateway jobs` shows."""

    program: str  # spool path of the job's program (its stem is the job id), or `answer:<name>`
    sha256: str
    drip: bool
    offset: int
    total: int
    resume_line: int | None
    line: int | None = None
    lead: float | None = None
    remaining: float | None = None
    held: str = ""

    def as_json(self) -> str:
        return json.dumps(dataclasses.asdict(self))

    @classmethod
    def parse(cls, text: str) -> Checkpoint:
        raw = json.loads(text)
        if not isinstance(raw, dict):
            raise ValueError("not an object")
        return cls(**{f.name: raw[f.name] for f in dataclasses.fields(cls) if f.name in raw})


def progress_path(state_dir: Path, machine: str) -> Path:
    return state_dir / "jobs" / "dnc" / f"{machine}.json"


def read_progress(state_dir: Path, machine: str) -> Checkpoint | None:
    """The transfer under way on `machine`'s line (or interrupted by a restart), None if none."""
    try:
        return Checkpoint.parse(progress_path(state_dir, machine).read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError):
        return None


@dataclass(slots=True)
class Drip:
    """The transfer under way, as the commands and the job's record see it."""

    program: Program
    control: Control
    position: Position | None = None


class SerialTransport:
    """A DeliveryTransport over one serial line (see the module docstring)."""

    def __init__(
        self,
        settings: ControllerSerial,
        *,
        machine: str = "",
        state_dir: Path | None = None,
        transfer_log: TransferLog | None = None,
        fleet: DripFleet | None = None,
        alarm: Callable[[], str | None] | None = None,
        on_figures: Callable[[SerialTransport], None] | None = None,
        listener: Callable[[SendAnswer], IdleListener] | None = None,
    ) -> None:
        self.settings = settings
        #: The scheduler its drip-feeds take part in: the gateway's one (lines.py), or the line's own.
        self.fleet = fleet or DripFleet.for_lines([(machine, settings)])
        self.machine = machine
        self.line = line_settings(settings)
        self.port = SerialPort(settings)
        #: What the line listens for between jobs (the punch desk), made with the line's `send_answer`.
        self.listener: IdleListener | None = None if listener is None else listener(self.send_answer)
        self.transfer_log = transfer_log
        self.checkpoint_path = None if state_dir is None else progress_path(state_dir, machine or "line")
        self.current: Drip | None = None
        #: Says why the controller is in alarm, None when it is not (lines.py reads `alarm_when`).
        self.alarm = alarm
        self.last: Outcome | None = None  # the last complete transfer (its DC3 figures)
        self.parity_errors = 0  # characters from the controller with a wrong parity bit, since the start
        self.hint = ""  # what they say of the line's settings (empty: nothing to check)
        #: Called after each transfer with the line (its `parity_errors` and `hint`), in the event loop.
        self.on_figures = on_figures
        self._lock = asyncio.Lock()
        self._answers: set[asyncio.Task[None]] = set()  # answers waiting for the line (send_answer)
        self._stepping: Future[None] | None = None  # the transfer the I/O thread steps now
        self._files = asyncio.Lock()  # the progress file's writes and removal, in order
        self._pending: tuple[Program, Position, int | None, bool] | None = None
        self._saver: asyncio.Task[None] | None = None

    @property
    def where(self) -> str:
        return self.settings.where

    async def _open(self) -> None:
        """Open the port off the I/O thread (a connect or an RFC 2217 negotiation may take seconds)."""
        await asyncio.to_thread(self.port.open)

    async def _close(self) -> None:
        await asyncio.to_thread(self.port.close)

    async def _read(self) -> bytes:
        """What the idle line heard, read on the lines' I/O thread (which owns the port between opens)."""
        return await asyncio.wrap_future(self.fleet.io.call(self.port.read))

    def close(self) -> None:
        """The gateway is stopping: abort the transfer in hand, close the port once it has stopped."""
        if self.current is not None:
            self.current.control.abort("the gateway is stopping")
        for task in self._answers:
            task.cancel()
        stepping = self._stepping
        if stepping is not None and not stepping.done():
            # The I/O thread sees the abort at its next step; the port closes after it, on that thread.
            io = self.fleet.io
            stepping.add_done_callback(lambda _f: io.call(self.port.close))
        else:
            self.port.close()

    # --- control (the Commands methods, the CLI through the queue) --------------------------------

    def pause(self) -> str:
        drip = self._drip()
        drip.control.pause()
        return f"{drip.program.name} paused"

    def resume(self) -> str:
        drip = self._drip()
        drip.control.resume()
        return f"{drip.program.name} resumed"

    def abort(self, by: str) -> str:
        drip = self._drip()
        drip.control.abort(f"aborted by {by or 'an operator'}")
        return f"{drip.program.name} aborted"

    def _drip(self) -> Drip:
        if self.current is None:
            raise InvalidState("nothing is being sent on this line")
        return self.current

    # --- DeliveryTransport -------------------------------------------------------------------------

    async def holds(self, program: Program) -> bool:
        """A serial line cannot look into the controller. A drip-feed interrupted by a restart is not sent
        again: the job fails, saying where it stopped, and waits for an operator's restart at a line."""
        point = self._read_checkpoint()
        if point is not None and point.drip and point.program == str(program.path):
            self._clear_checkpoint()
            at = f" near line {point.resume_line}" if point.resume_line is not None else ""
            raise DeliveryError(
                f"a drip-feed interrupted by a gateway restart{at} after {point.offset} bytes: "
                "not sent again on its own; restart it at a line",
                permanent=True,
            )
        return False

    async def deliver(self, program: Program, progress: ReportProgress) -> str:
        data = await asyncio.to_thread(_read_checked, program)
        start = await asyncio.to_thread(take_restart, program.path)
        try:
            lines = restart_lines(data, start) if start is not None else data
            wire = frame_program(lines, self.line)
        except FramingError as exc:
            raise DeliveryError(f"cannot send over a serial line: {exc}", permanent=True) from None
        drip = self.settings.mode == "drip"
        timing = None
        member: FleetLine | None = None
        if drip:
            times = self._times(data)
            timing = Timing(wire, times, self.settings.buffer)
            member = self._join(program.name, wire, times)
        what = f"{program.name} from line {start}" if start is not None else program.name
        started = datetime.now(UTC)
        async with self._lock:
            outcome: Outcome | None = None
            error: DeliveryError | None = None
            try:
                outcome = await self._send(program, wire, timing, progress, what, member)
            except DeliveryError as exc:
                error = exc
            finally:
                if member is not None:
                    member.close()
            await self._log(program, wire, started, outcome, error, start, self.settings.mode)
        if error is not None:
            raise error
        assert outcome is not None
        self.last = outcome
        mode = "drip-fed" if drip else "loaded"
        return (
            f"{describe(self.where)} ({mode}{f' from line {start}' if start is not None else ''}: "
            f"{outcome.sent} bytes, sha256 {outcome.sha256[:12]}…; program sha256 {program.sha256[:12]}… "
            f"checked; {outcome.describe()})"
        )

    def _times(self, text: bytes) -> dict[int, float]:
        """The run time of each line, as the drip scheduler estimates it from the mapping's settings."""
        s = self.settings
        return block_times(text.decode("latin-1"), rapid=s.rapid, dwell_ms=s.dwell_p == "ms", lathe=s.lathe)

    def _join(self, name: str, wire: WireProgram, times: dict[int, float]) -> FleetLine:
        """A drip-feed's place in the gateway's drip scheduler."""
        try:
            return self.fleet.join(
                self.machine or self.where,
                rate=self.line.bytes_per_second,
                buffer_size=self.settings.buffer,
                blocks=program_costs(wire, times),
                link=self.settings.link,
                lead_time=self.settings.lead_time,
                flow_control=self.settings.handshake != "none",
            )
        except ValueError as exc:
            raise DeliveryError(f"cannot drip-feed {name}: {exc}", permanent=True) from None

    async def _send(
        self,
        program: Program,
        wire: WireProgram,
        timing: Timing | None,
        progress: ReportProgress,
        what: str,
        member: FleetLine | None = None,
    ) -> Outcome:
        drip = Drip(program, Control())
        self.current = drip
        report = self._reporter(drip, timing, progress)

        settings = self.settings
        opened_here = not self.port.is_open
        try:
            if opened_here:
                await self._open()
            log.info("%s: sending %s over %s (%s mode)", self.machine, what, self.where, settings.mode)
            outcome = await self._transfer(wire, drip.control, timing, report, self.alarm, member)
        except TransferFailed as exc:
            await self._clear()  # the job's reason says where it stopped
            if exc.outcome is not None:
                self._figures(exc.outcome)
            if exc.offset > wire.body_start or not exc.permanent:
                await self._close()  # a line in doubt is opened afresh next time
            raise
        except asyncio.CancelledError:
            drip.control.abort("the gateway is stopping")
            raise
        finally:
            self.current = None
        await self._clear()
        self._figures(outcome)
        if opened_here and self.listener is None:
            await self._close()
        return outcome

    def _figures(self, outcome: Outcome) -> None:
        """A transfer's figures for whoever shows them (the machine's Status, JobService)."""
        self.parity_errors += outcome.parity_errors + outcome.flow_wrong_bit7
        if outcome.hint is not None:
            self.hint = outcome.hint
        elif outcome.pauses and not outcome.flow_wrong_bit7:
            self.hint = ""  # DC3s came as the settings expect: the line is set up right
        if self.on_figures is not None:
            self.on_figures(self)

    def _reporter(
        self, drip: Drip, timing: Timing | None, progress: ReportProgress | None, *, answer: bool = False
    ) -> Callable[[Position], None]:
        """What a transfer's position goes to (called in the lines' I/O thread): the drip's record, the
        progress file about once a second (`jobs list`, and the restart guard), the job's progress."""
        loop = asyncio.get_running_loop()
        last_checkpoint = 0.0
        program = drip.program

        def report(pos: Position) -> None:
            nonlocal last_checkpoint
            drip.position = pos
            now = time.monotonic()
            if now - last_checkpoint >= CHECKPOINT_EVERY:
                last_checkpoint = now
                resume = None if timing is None else timing.resume_line(pos.sent)
                # Written off the I/O thread: a disk that stalls a write (a journal commit, a busy
                # SD card) must not stall every line's next slice (bench: 0.16 s steps, all lines dry).
                loop.call_soon_threadsafe(self._save_checkpoint, (program, pos, resume, answer))
            if progress is not None:
                loop.call_soon_threadsafe(
                    progress, Progress(pos.sent, pos.line, pos.lead, pos.remaining, pos.held)
                )

        return report

    async def _transfer(
        self,
        wire: WireProgram,
        control: Control,
        timing: Timing | None,
        report: Callable[[Position], None],
        alarm: Callable[[], str | None] | None,
        member: FleetLine | None,
    ) -> Outcome:
        """One transfer, stepped by the lines' I/O thread, with the line's settings."""
        settings = self.settings
        io = self.fleet.io
        transfer = Transfer(
            self.port,
            wire,
            self.line,
            wait_for_dc1=settings.start == "dc1",
            dc1_timeout=settings.dc1_timeout,
            stall_timeout=settings.stall_timeout,
            control=control,
            timing=timing,
            report=report,
            alarm=alarm,
            fleet=member,
            name=self.machine or self.where,
        )

        def wake() -> None:  # the operator's pause, resume or abort, from the event loop
            transfer.due = 0.0
            io.wake()

        control.wake = wake
        self._stepping = stepping = io.attach(transfer)
        try:
            await asyncio.wrap_future(stepping)
        except asyncio.CancelledError:
            control.abort("the gateway is stopping")
            raise
        finally:
            if stepping.done():
                self._stepping = None
        assert transfer.outcome is not None
        return transfer.outcome

    async def _log(
        self,
        program: Program,
        wire: WireProgram,
        started: datetime,
        outcome: Outcome | None,
        error: DeliveryError | None,
        start: int | None,
        mode: str,
    ) -> None:
        if self.transfer_log is None:
            return
        detail = mode + (f" from line {start}" if start is not None else "")
        if outcome is not None:
            detail = f"{detail}; {outcome.describe()}"
        if error is not None:
            detail = f"{detail}: {error.reason}"
        aborted = error is not None and "aborted by" in error.reason
        record = TransferRecord(
            machine=self.machine,
            direction="send",
            program=program.name,
            size=outcome.sent if outcome is not None else len(wire),
            sha256=outcome.sha256 if outcome is not None else hashlib.sha256(wire.data).hexdigest(),
            started=started,
            ended=datetime.now(UTC),
            outcome="ok" if error is None else "aborted" if aborted else "failed",
            user=program.user or None,
            detail=detail,
        )
        try:
            await asyncio.to_thread(self.transfer_log.record, record)
        except StoreError as exc:
            log.error("%s: transfer not logged: %s", self.machine, exc)

    # --- listening between jobs ----------------------------------------------------------------------

    async def run(self) -> None:
        """Until cancelled: while no job sends, read the line for the idle listener, send its answers."""
        if self.listener is None:
            return
        listener = self.listener
        while True:
            async with self._lock:
                answer: bytes | None = None
                try:
                    if not self.port.is_open:
                        await self._open()
                    data = await self._read()
                    if data:
                        answer = listener.feed(data)
                    if answer is not None:
                        await self._answer(answer, listener.answer_user, listener.answer_load)
                except DeliveryError as exc:
                    await self._close()
                    listener.line_lost(exc.reason)
                    log.debug("%s: idle line: %s", self.machine, exc.reason)
                    await asyncio.sleep(REOPEN_AFTER)
            await asyncio.sleep(LISTEN_EVERY)

    def send_answer(self, text: bytes, user: str | None, load: bool) -> None:
        """Send an answer the listener found later (off the line's read loop): as soon as the line is free."""
        task = asyncio.get_running_loop().create_task(self._send_answer(text, user, load))
        self._answers.add(task)
        task.add_done_callback(self._answers.discard)

    async def _send_answer(self, text: bytes, user: str | None, load: bool) -> None:
        async with self._lock:
            try:
                if not self.port.is_open:
                    await self._open()
                await self._answer(text, user, load)
            except DeliveryError as exc:
                await self._close()
                if self.listener is not None:
                    self.listener.line_lost(exc.reason)
                log.warning("%s: the answer was not sent: %s", self.machine, exc.reason)

    async def _answer(self, text: bytes, user: str | None, load: bool) -> None:
        """Send a listener's answer (the line's lock held), load or drip as the line's mode says."""
        try:
            wire = frame_program(text, self.line)
        except FramingError as exc:
            log.warning("%s: the answer cannot be sent: %s", self.machine, exc)
            return
        drip = self.settings.mode == "drip" and not load
        timing = None
        member: FleetLine | None = None
        name = text.lstrip(b"%\r\n \0").split(b"\n", 1)[0].decode("ascii", "replace").strip() or "?"
        if drip:
            times = self._times(text)
            timing = Timing(wire, times, self.settings.buffer)
            member = self._join(name, wire, times)
        answer = Program(
            name, Path(os.devnull), len(text), hashlib.sha256(text).hexdigest(), None, user or ""
        )
        started = datetime.now(UTC)
        error: DeliveryError | None = None
        outcome: Outcome | None = None
        try:
            outcome = await self._answer_transfer(answer, wire, timing, member)
        except DeliveryError as exc:
            error = exc
            raise
        finally:
            if member is not None:
                member.close()
            await self._log(
                answer, wire, started, outcome, error, None, f"answer, {'drip' if drip else 'load'}"
            )

    async def _answer_transfer(
        self, answer: Program, wire: WireProgram, timing: Timing | None, member: FleetLine | None
    ) -> Outcome:
        drip = Drip(answer, Control())
        self.current = drip  # pause, resume and abort reach a dripped answer too
        # A dripped answer writes the progress file too (`jobs list` shows it), never taken for a job's.
        report = self._reporter(drip, timing, None, answer=timing is not None)
        try:
            alarm = self.alarm if timing is not None else None
            result = await self._transfer(wire, drip.control, timing, report, alarm, member)
        except asyncio.CancelledError:
            drip.control.abort("the gateway is stopping")
            raise
        finally:
            self.current = None
            if timing is not None:
                await self._clear()
        return result

    # --- the checkpoint ----------------------------------------------------------------------------

    def _save_checkpoint(self, point: tuple[Program, Position, int | None, bool]) -> None:
        """In the event loop: write the newest position in a worker thread, one write at a time, in order
        with `_clear` (which waits for the write in hand, so that no late write outlives the transfer)."""
        self._pending = point
        if self._saver is None or self._saver.done():
            self._saver = asyncio.get_running_loop().create_task(self._save_pending(), name="dnc:checkpoint")

    async def _save_pending(self) -> None:
        while self._pending is not None:
            (program, pos, resume, answer), self._pending = self._pending, None
            async with self._files:
                await asyncio.to_thread(self._write_checkpoint, program, pos, resume, answer=answer)

    async def _clear(self) -> None:
        """Remove the progress file once the writes queued before have been made."""
        self._pending = None
        async with self._files:
            await asyncio.to_thread(self._clear_checkpoint)

    def _write_checkpoint(
        self, program: Program, pos: Position, resume: int | None, *, answer: bool = False
    ) -> None:
        path = self.checkpoint_path
        if path is None:
            return
        point = Checkpoint(
            f"{ANSWER}{program.name}" if answer else str(program.path),
            program.sha256,
            self.settings.mode == "drip",
            pos.sent,
            pos.total,
            resume,
            pos.line,
            None if pos.lead is None else round(pos.lead, 1),
            None if pos.remaining is None else round(pos.remaining, 1),
            pos.held,
        )
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(".tmp")
            tmp.write_text(point.as_json())
            os.replace(tmp, path)
        except OSError as exc:
            log.warning("%s: drip checkpoint not written: %s", self.machine, exc)

    def _read_checkpoint(self) -> Checkpoint | None:
        path = self.checkpoint_path
        if path is None:
            return None
        try:
            return Checkpoint.parse(path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.warning("%s: drip checkpoint %s unreadable (%s); ignored", self.machine, path, exc)
            return None

    def _clear_checkpoint(self) -> None:
        if self.checkpoint_path is not None:
            with contextlib.suppress(OSError):
                self.checkpoint_path.unlink(missing_ok=True)


def restart_file(program: Path) -> Path:
    """Where a restart at a line waits for the job's next delivery: beside its spooled program, so that
    `cnc-gateway jobs restart` (another process) and a gateway restart keep it."""
    return program.with_suffix(".restart")


def request_restart(program: Path, line: int) -> None:
    """The next delivery of `program` starts at source line `line` (header, modal state, line on)."""
    path = restart_file(program)
    tmp = path.with_suffix(".restart-tmp")
    tmp.write_text(f"{line}\n")
    os.replace(tmp, path)


def take_restart(program: Path) -> int | None:
    """The line a restart asked for (and forget it), None for the whole program."""
    path = restart_file(program)
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise DeliveryError(f"cannot read the restart request {path}: {exc.strerror or exc}") from None
    path.unlink(missing_ok=True)
    if not text.isdigit() or int(text) < 1:
        raise DeliveryError(f"the restart request {path} holds {text!r}, not a line number", permanent=True)
    return int(text)


def _read_checked(program: Program) -> bytes:
    """The validated program, checked byte for byte against what validation saw (size and SHA-256)."""
    try:
        data = program.path.read_bytes()
    except OSError as exc:
        raise DeliveryError(f"cannot read {program.path}: {exc.strerror or exc}", permanent=True) from None
    digest = hashlib.sha256(data).hexdigest()
    if len(data) != program.size or (program.sha256 and digest != program.sha256):
        raise DeliveryError(
            f"{program.path} is not the program validated ({len(data)} bytes, sha256 {digest[:12]}…; "
            f"expected {program.size} bytes, {program.sha256[:12]}…)",
            permanent=True,
        )
    return data
