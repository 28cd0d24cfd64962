"""The punch desk: what a serial machine sends while no job is sending (an `IdleListener`).

- **A punched program** (the operator's PUNCH, framed by `%`) is stored under the
  state directory with its time, size and SHA-256 (`received.py`), optionally
  validated with the machine's rules and filed as a backup, shown in the
  machine's `Jobs/Dnc/...` variables and as a `dnc/received` event (MQTT), and
  recorded in the transfer log (direction receive; the line records the answer it sends).
- **A remote request** (`O9999 (PRG=O4711)`) is answered with the named program,
  looked for where `requests.from` says, in order: the configured folder, and
  the programs the machine's job queue accepted (the newest matching job; the
  service's `find_job`). `send: now` sends it back at once, load or drip as the
  line's mode says (`send: load`: always a load), once the machine's validation
  rules accept it (a queued program was validated when it arrived);
  `send: queue` submits it as a job, which the machine's transport delivers load
  or drip like any job. A name that is unknown or would leave the folder is
  answered with a short program whose comment says why (the operator reads it on
  the controller's screen). Every request is audited (`call Dnc.Request`, origin
  `dnc`): an answer changes the machine. The answer's send is logged with the
  job's submitter as the user when it came from the queue.
- **Refusals**: a punch without its closing `%` (the line went quiet for
  `idle_timeout` seconds, or was lost), or larger than `max_size`, is refused
  with its reason, counted (`Jobs/Dnc/RefusedCount`), logged, and what arrived is
  kept in `dnc/refused/`. Junk on the line is counted. Nothing here raises into
  the line owner.

`feed` runs on the event loop and never blocks on files: stores, validation and
log records are queued to `run()`, which does them one after another in a
thread. The one exception is reading a requested program from the folder when
`from` is only the folder (at most `requests.max_size` bytes, 1 MB by default),
because the answer is what `feed` returns. When `from` names the queue, the
request is answered in `run()` (a query of the queue file) and the answer handed
to the line with `send_answer`.
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import logging
import os
import time
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any, TypeVar

from gateway.codecs.dnc import (
    BadRequest,
    Junk,
    Overflow,
    ProgramReceived,
    ProgramReceiver,
    ProgramStarted,
    RemoteRequest,
    Unterminated,
    answer_program,
    not_found,
    parse_request,
)
from gateway.model.audit import AuditEntry, as_text
from gateway.model.events import Event
from gateway.model.sample import utcnow
from gateway.model.tree import Machine
from gateway.transports.base import FindJob, QueuedProgram, Submit, Validate
from gateway.transports.dnc.idle import SendAnswer
from gateway.transports.dnc.punch import PunchSettings, RemoteRequests
from gateway.transports.dnc.received import ReceivedProgram, ReceivedStore
from gateway.transports.dnc.transfers import Outcome, TransferLog, TransferRecord

log = logging.getLogger("gateway.jobs.dnc")

T = TypeVar("T")
Blocking = Callable[[Callable[[], T]], Awaitable[T]]
MAX_PENDING = 200  # stored punches waiting for the thread; beyond, refused and counted
ORIGIN = "dnc"
JUNK_LOG_EVERY = 60.0  # s between log lines about junk on an idle line


async def _in_thread(fn: Callable[[], T]) -> T:
    return await asyncio.to_thread(fn)


@dataclass(frozen=True, slots=True)
class Answer:
    """What became of a remote request: `program` goes back on the line (None: nothing, or queued)."""

    requested: str | None
    status: str  # "Good" or a Bad status name, for the audit trail
    reason: str  # short, as in the answer's comment; "" when answered with the program
    program: bytes | None
    file: str = ""  # the program's file in the folder, or the job's file name
    user: str | None = None  # named in the transfer log for the answer's send
    job: str = ""  # the job it came from (from: queue)
    queued: bytes | None = None  # to submit as a job (send: queue, found in the queue)

    @property
    def source(self) -> str:
        return f"{self.file} ({self.job})" if self.job else self.file


def find_program(requests: RemoteRequests, name: str) -> Path | None:
    """The requested program's file in the folder, or None; never a file outside it (symbolic links
    included: a link that points out of the folder is not found)."""
    if requests.folder is None:
        return None
    folder = Path(os.path.realpath(requests.folder))
    for ext in requests.extensions:
        candidate = Path(os.path.realpath(folder / f"{name}{ext}"))
        if candidate.parent == folder and candidate.is_file():
            return candidate
    return None


class PunchDesk:
    """One machine's idle line. Fits `gateway.transports.dnc.idle.IdleListener`."""

    def __init__(
        self,
        machine: Machine,
        settings: PunchSettings,
        *,
        store: ReceivedStore,
        transfers: TransferLog | None = None,
        validate: Validate | None = None,
        backups: Path | None = None,
        submit: Submit | None = None,
        find_job: FindJob | None = None,
        send_answer: SendAnswer | None = None,
        blocking: Blocking[Any] = _in_thread,
        strip_parity: bool = True,
    ) -> None:
        self.machine = machine
        self.name = machine.name
        self.settings = settings
        self.store = store
        self.transfers = transfers
        self.validate = validate if settings.validate_programs else None
        self.request_validate = validate  # what answers a request is what validation accepts, always
        self.backups = backups if settings.backup else None
        self.submit = submit
        self.find_job = find_job
        self.send_answer = send_answer
        self.blocking = blocking
        # What the line needs to send the answer `feed` returns (the IdleListener seam): who is named in
        # the transfer log, and whether to send it as a load whatever the line's mode.
        self.answer_user: str | None = None
        self.answer_load = False
        self.receiver = ProgramReceiver(max_size=settings.max_size, strip_parity=strip_parity)
        self.received = 0
        self.refused = 0
        self.junk_bytes = 0
        self._junk_logged = -JUNK_LOG_EVERY
        self.requests = 0
        self._started: datetime | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._work: deque[Callable[[], Awaitable[None]]] = deque()
        self._wake = asyncio.Event()
        add = machine.add_internal
        self.v_last = add("Jobs/Dnc/LastReceived", "String", "The last program punched: its stored file", "")
        self.v_last_at = add("Jobs/Dnc/LastReceivedAt", "DateTime", "When it was received", _NEVER)
        self.v_last_size = add("Jobs/Dnc/LastReceivedSize", "UInt32", "Its size in bytes", 0)
        self.v_last_sha = add("Jobs/Dnc/LastReceivedSha256", "String", "Its SHA-256", "")
        self.v_last_verdict = add(
            "Jobs/Dnc/LastReceivedVerdict",
            "String",
            "Its validation: accepted, rejected: reason, or empty when not validated",
            "",
        )
        self.v_count = add(
            "Jobs/Dnc/ReceivedCount", "UInt32", "Programs punched since the gateway started", 0
        )
        self.v_refused = add(
            "Jobs/Dnc/RefusedCount", "UInt32", "Punches refused since the start (no closing %, too large)", 0
        )
        self.v_refused_reason = add(
            "Jobs/Dnc/LastRefusedReason", "String", "Why the last one was refused", ""
        )
        self.v_request = add(
            "Jobs/Dnc/LastRequest", "String", "The last remote request: the name asked for and the answer", ""
        )
        self.v_junk = add(
            "Jobs/Dnc/JunkBytes", "UInt32", "Bytes outside any program (wrong baud rate or format?)", 0
        )

    # --- the IdleListener seam -----------------------------------------------------------------

    def feed(self, data: bytes) -> bytes | None:
        answer: bytes | None = None
        try:
            for event in self.receiver.feed(data):
                answer = self._event(event) or answer
        except Exception:  # a bug here must not take the line down; the punch is lost, said loudly
            log.exception("%s: the punch desk failed on %d bytes from the line", self.name, len(data))
            self.receiver = ProgramReceiver(
                max_size=self.settings.max_size, strip_parity=self.receiver.strip_parity
            )
        if data.translate(_SEVEN_BITS).translate(None, _NOT_PROGRESS) or not self.receiver.receiving:
            self._arm()  # flow control and tape feed alone are silence: a controller in READ sends DC1s
        return answer

    def line_lost(self, reason: str) -> None:
        self._cancel_timer()
        for event in self.receiver.end_of_input():
            self._event(event, why=f"the line was lost ({reason})")

    def idle_expired(self) -> None:
        """The line has been silent for `idle_timeout` inside a program: refuse it as unterminated."""
        self._timer = None
        for event in self.receiver.end_of_input():
            self._event(event, why=f"no closing % after {self.settings.idle_timeout:g} s of silence")

    # --- events --------------------------------------------------------------------------------

    def _event(self, event: object, why: str = "") -> bytes | None:
        if isinstance(event, ProgramStarted):
            self._started = utcnow()
        elif isinstance(event, ProgramReceived):
            started, self._started = self._started or utcnow(), None
            requests = self.settings.requests
            if requests is not None:
                request = parse_request(event.text, number=requests.number, key=requests.key)
                if request is not None:
                    return self._request(request, requests, event, started)
            if not event.text.strip(b" \t\r\n\x00"):
                self._refuse(
                    framed(event), "punch refused: an empty program (nothing between the % markers)", started
                )
            else:
                self._punched(event, started)
        elif isinstance(event, Unterminated):
            started, self._started = self._started or utcnow(), None
            self._refuse(event.text, f"punch refused: {why or 'no closing %'}", started)
        elif isinstance(event, Overflow):
            started, self._started = self._started or utcnow(), None
            self._refuse(b"", f"punch refused: larger than {event.limit} bytes (punch.max_size)", started)
        elif isinstance(event, Junk):
            self.junk_bytes += event.count
            self.machine.set_internal(self.v_junk, self.junk_bytes % 2**32)
            now = time.monotonic()
            if now - self._junk_logged >= JUNK_LOG_EVERY:  # a line at the wrong baud rate talks all day
                self._junk_logged = now
                log.warning(
                    "%s: %d bytes outside any program on the idle line (%d so far; e.g. %r): %s",
                    self.name,
                    event.count,
                    self.junk_bytes,
                    event.sample,
                    event.reason,
                )
        return None

    def _punched(self, event: ProgramReceived, started: datetime) -> None:
        text = framed(event)

        async def store() -> None:
            verdict = ""
            if self.validate is not None:
                validate = self.validate
                checked = await self.blocking(lambda: validate(text, "punch.nc"))
                verdict = "accepted" if checked.accepted else f"rejected: {checked.reason}"
            rec = await self.blocking(
                lambda: self.store.store(
                    self.name,
                    text,
                    at=started,
                    number=event.number,
                    name=event.name,
                    verdict=verdict,
                    backups=self.backups,
                )
            )
            self._stored(rec, started)

        self._queue(store)

    def _stored(self, rec: ReceivedProgram, started: datetime) -> None:
        self.received += 1
        m = self.machine
        m.set_internal(self.v_last, rec.file)
        m.set_internal(self.v_last_at, rec.received)
        m.set_internal(self.v_last_size, min(rec.size, 2**32 - 1))
        m.set_internal(self.v_last_sha, rec.sha256)
        m.set_internal(self.v_last_verdict, rec.verdict)
        m.set_internal(self.v_count, self.received % 2**32)
        m.tree.events.publish(Event(self.name, "dnc/received", rec.as_dict()))
        log.info(
            "%s: received %s (%d bytes, sha256 %s)%s",
            self.name,
            rec.file,
            rec.size,
            rec.sha256[:16],
            f", {rec.verdict}" if rec.verdict else "",
        )
        detail = f"stored as {rec.file}" + (f"; {rec.verdict}" if rec.verdict else "")
        self._log("receive", _program_name(rec.number, rec.name), rec.size, rec.sha256, started, "ok", detail)

    def _refuse(self, text: bytes, reason: str, started: datetime) -> None:
        self.refused += 1
        self.machine.set_internal(self.v_refused, self.refused % 2**32)
        self.machine.set_internal(self.v_refused_reason, reason)
        log.warning("%s: %s (%d bytes kept in dnc/refused/)", self.name, reason, len(text))
        sha = hashlib.sha256(text).hexdigest()
        self.machine.tree.events.publish(
            Event(self.name, "dnc/refused", {"reason": reason, "size": len(text), "sha256": sha})
        )

        async def keep() -> None:
            await self.blocking(
                lambda: self.store.refuse(self.name, text, at=started, what="unterminated", reason=reason)
            )

        self._queue(keep)
        self._log("receive", "?", len(text), sha, started, "refused", reason)

    # --- remote requests -----------------------------------------------------------------------

    def _request(
        self,
        request: RemoteRequest | BadRequest,
        requests: RemoteRequests,
        event: ProgramReceived,
        started: datetime,
    ) -> bytes | None:
        self.requests += 1
        if isinstance(request, RemoteRequest) and "queue" in requests.sources:

            async def later() -> None:  # the queue file is read off the loop; the line gets the answer
                answer = await self.answer_later(request, requests)
                self._answered(answer, requests, event, started)
                if answer.program is not None:
                    if self.send_answer is None:
                        log.warning("%s: no line to send the answer to %s", self.name, request.name)
                    else:
                        self.send_answer(answer.program, answer.user, requests.send == "load")

            self._queue(later)
            return None
        answer = self.answer(request, requests)
        self._answered(answer, requests, event, started)
        self.answer_user, self.answer_load = answer.user, requests.send == "load"
        return answer.program

    def _answered(
        self, answer: Answer, requests: RemoteRequests, event: ProgramReceived, started: datetime
    ) -> None:
        """Report, audit and log one answered request; submit it when it is to be queued."""
        name = answer.requested or "?"
        done = f"queued {answer.source}" if answer.program is None else f"sent {answer.source}"
        shown = f"{name}: " + (answer.reason or done)
        self.machine.set_internal(self.v_request, shown)
        self.machine.tree.events.publish(
            Event(
                self.name,
                "dnc/requests",
                {
                    "requested": answer.requested,
                    "status": answer.status,
                    "reason": answer.reason,
                    "file": answer.file,
                    "job": answer.job,
                },
            )
        )
        log.info(
            "%s: remote request for %s: %s",
            self.name,
            name,
            answer.reason or f"answered with {answer.source}",
        )
        self.machine.tree.audit(
            AuditEntry(
                started,
                "call",
                self.name,
                "Dnc.Request",
                ORIGIN,
                requests.user,
                None,
                None,
                as_text([name]),
                answer.status,
                answer.reason,
                (utcnow() - started).total_seconds(),
            )
        )
        outcome: Outcome = "ok" if answer.status == "Good" else "refused"
        detail = f"request for {name}: " + (
            answer.reason
            or ("queued as a job" if answer.program is None else f"answered with {answer.source}")
        )
        self._log(
            "receive",
            _program_name(event.number, event.name),
            len(framed(event)),
            hashlib.sha256(framed(event)).hexdigest(),
            started,
            outcome,
            detail,
            user=requests.user,
        )
        if answer.program is None and answer.status == "Good" and self.submit is not None:
            if answer.queued is not None:
                self._queue_job(answer, name)
            else:
                self._queue_submit(answer, requests, name)

    async def answer_later(self, request: RemoteRequest, requests: RemoteRequests) -> Answer:
        """The answer to a request looked for where `requests.from` says, in order (in `run()`)."""
        for source in requests.sources:
            if source == "folder":
                path = await self.blocking(lambda: find_program(requests, request.name))
                if path is not None:
                    answer: Answer = await self.blocking(
                        functools.partial(self._from_folder, request, requests, path)
                    )
                    return answer
            elif self.find_job is not None:
                job = await self.find_job(self.name, request.name)
                if job is not None:
                    return self._from_queue(request, requests, job)
        return self._not_found(request, requests)

    def _not_found(self, request: RemoteRequest, requests: RemoteRequests) -> Answer:
        return Answer(
            request.name,
            "BadNotFound",
            f"NOT FOUND {request.name}",
            not_found(request.name, number=requests.number),
        )

    def _from_queue(self, request: RemoteRequest, requests: RemoteRequests, job: QueuedProgram) -> Answer:
        """An accepted job's program: validated when it arrived, checked against its SHA-256 when read."""
        if requests.send == "queue":
            if self.submit is None:
                reason = "NO JOB QUEUE FOR REQUESTS"
                return Answer(
                    request.name, "BadInvalidState", reason, answer_program(reason, number=requests.number)
                )
            return Answer(request.name, "Good", "", None, job.file, job.user, job.job, job.data)
        if len(job.data) > requests.max_size:
            reason = f"TOO LARGE {request.name} {len(job.data)} BYTES"
            return Answer(
                request.name, "BadOutOfRange", reason, answer_program(reason, number=requests.number)
            )
        return Answer(request.name, "Good", "", job.data, job.file, job.user, job.job)

    def answer(self, request: RemoteRequest | BadRequest, requests: RemoteRequests) -> Answer:
        """The answer to one request from the folder (reads the program, for `send: now` or `load`)."""
        if isinstance(request, BadRequest):
            return Answer(
                request.name,
                "BadInvalidArgument",
                request.reason,
                answer_program(request.reason, number=requests.number),
            )
        path = find_program(requests, request.name)
        if path is None:
            return self._not_found(request, requests)
        return self._from_folder(request, requests, path)

    def _from_folder(self, request: RemoteRequest, requests: RemoteRequests, path: Path) -> Answer:
        if requests.send == "queue":
            if self.submit is None:
                reason = "NO JOB QUEUE FOR REQUESTS"
                return Answer(
                    request.name, "BadInvalidState", reason, answer_program(reason, number=requests.number)
                )
            return Answer(request.name, "Good", "", None, path.name, requests.user)
        try:
            size = path.stat().st_size
            if size > requests.max_size:
                reason = f"TOO LARGE {request.name} {size} BYTES"
                return Answer(
                    request.name, "BadOutOfRange", reason, answer_program(reason, number=requests.number)
                )
            data = path.read_bytes()
        except OSError as exc:
            reason = f"CANNOT READ {request.name}"
            log.warning("%s: remote request: cannot read %s: %s", self.name, path, exc)
            return Answer(
                request.name, "BadNotReadable", reason, answer_program(reason, number=requests.number)
            )
        if self.request_validate is not None:  # compiled reader: about 20 ms for 1 MB, so done here
            verdict = self.request_validate(data, path.name)
            if not verdict.accepted:
                first = verdict.reason
                log.warning(
                    "%s: remote request for %s refused by validation: %s", self.name, path.name, first
                )
                reason = f"REJECTED {request.name}"
                return Answer(
                    request.name,
                    "BadInvalidArgument",
                    f"{reason}: {first}",
                    answer_program(f"{reason} {first}", number=requests.number),
                )
            data = verdict.program
        return Answer(request.name, "Good", "", data, path.name, requests.user)

    def _queue_submit(self, answer: Answer, requests: RemoteRequests, name: str) -> None:
        submit = self.submit
        assert submit is not None
        folder = requests.folder

        async def go() -> None:
            path = find_program(requests, name)
            if path is None:  # gone since the request was answered
                log.warning("%s: remote request: %s left %s before it was queued", self.name, name, folder)
                return
            data = await self.blocking(path.read_bytes)
            reply = await submit(self.name, path.name, data, requests.user, ORIGIN)
            log.info("%s: remote request for %s queued: %s", self.name, name, reply)
            self.machine.set_internal(self.v_request, f"{name}: {reply}")

        self._queue(go)

    def _queue_job(self, answer: Answer, name: str) -> None:
        """Submit an accepted job's program again as a new job, in its submitter's name."""
        submit, data = self.submit, answer.queued
        assert submit is not None and data is not None
        user = answer.user or "?"

        async def go() -> None:
            reply = await submit(self.name, answer.file, data, user, ORIGIN)
            log.info("%s: remote request for %s queued from %s: %s", self.name, name, answer.job, reply)
            self.machine.set_internal(self.v_request, f"{name}: {reply}")

        self._queue(go)

    # --- the work queue ------------------------------------------------------------------------

    def _log(
        self,
        direction: str,
        program: str,
        size: int,
        sha256: str,
        started: datetime,
        outcome: Outcome,
        detail: str,
        *,
        user: str | None = None,
    ) -> None:
        transfers = self.transfers
        if transfers is None:
            return
        rec = TransferRecord(
            self.name,
            "send" if direction == "send" else "receive",
            program,
            size,
            sha256,
            started,
            utcnow(),
            outcome,
            user,
            detail,
        )

        async def write() -> None:
            await self.blocking(lambda: transfers.record(rec))

        self._queue(write)

    def _queue(self, job: Callable[[], Awaitable[None]]) -> None:
        if len(self._work) >= MAX_PENDING:
            self.refused += 1
            self.machine.set_internal(self.v_refused, self.refused % 2**32)
            log.error("%s: the punch desk is %d steps behind; one dropped", self.name, len(self._work))
            return
        self._work.append(job)
        self._wake.set()

    async def run(self) -> None:
        """Store, validate and log what `feed` took, in order, until cancelled."""
        try:
            while True:
                await self._wake.wait()
                self._wake.clear()
                while self._work:
                    job = self._work.popleft()
                    try:
                        await job()
                    except Exception:
                        log.exception("%s: the punch desk could not finish a step", self.name)
        finally:
            self._cancel_timer()

    async def drain(self) -> None:
        """Do what is queued now (tests, and a clean stop)."""
        while self._work:
            job = self._work.popleft()
            try:
                await job()
            except Exception:
                log.exception("%s: the punch desk could not finish a step", self.name)

    # --- the silence timer ---------------------------------------------------------------------

    def _arm(self) -> None:
        if not self.receiver.receiving:
            self._cancel_timer()
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # fed outside a loop (unit tests): idle_expired is called by hand
            return
        self._cancel_timer()
        self._timer = loop.call_later(self.settings.idle_timeout, self.idle_expired)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


_SEVEN_BITS = bytes(v & 0x7F for v in range(256))
_NOT_PROGRESS = bytes([0x00, 0x11, 0x12, 0x13, 0x14, 0x7F])  # NUL, DC1-DC4, DEL


def framed(event: ProgramReceived) -> bytes:
    """The program as the controller framed it, leader and control characters left out: `%` and its
    header line, the blocks, the closing `%`. What is stored, hashed and logged."""
    return b"%" + event.header + b"\n" + event.text + b"%\n"


def _program_name(number: int | None, name: str | None) -> str:
    if number is not None:
        return f"O{number:04d}" + (f" ({name})" if name else "")
    return name or "?"


_NEVER = datetime(1601, 1, 1, tzinfo=utcnow().tzinfo)
