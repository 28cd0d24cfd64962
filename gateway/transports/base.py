"""The seam between delivery and a controller: what a delivery transport (and a program store) must do,
and the spec each transport's folder exports (`TransportSpec`), with the narrow ports the core gives it.

The delivery worker (gateway/jobs/delivery/worker.py) owns jobs: queue order,
attempts and backoff, FAILED, auto-start, the record of what happened. A
transport owns one way of getting a program onto a controller: the controller's
FTP program store (ftp/), a serial DNC line (dnc/: load, drip-feed) or FOCAS2
(focas/). The worker talks to a `DeliveryTransport` only; registry.py picks the
spec of each machine's `jobs.controller` by its `type`, and the spec assembles
that transport's machines (`Deliveries`) from what the core passes in.

Two protocols, because not every way of delivering is a store: an FTP server
can list, fetch and delete programs (the machine's `Programs` methods and
`cnc-gateway programs`), a serial line can only send. A transport that has no
`ProgramStore` leaves the machine with `Programs.Put` alone.

Failures are `DeliveryError` (gateway/errors.py): `permanent=True` for a refusal
that retrying cannot cure (the job is FAILED at once), anything else is retried
with backoff up to the machine's `max_attempts`. `reply` carries the
controller's own words when it gave some.
"""

from __future__ import annotations

import builtins
from collections.abc import Awaitable, Callable, Mapping, Sequence
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, Self, TypeVar

from gateway.model.tree import Machine
from gateway.settings.base import Strict

M = TypeVar("M")


@dataclass(frozen=True, slots=True)
class Program:
    """A validated program, ready to go: its file in the spool and what the queue knows of it."""

    name: str  # the file name on the controller (the job's file name)
    path: Path  # the validated program (spool/<id>.program); the transport only reads it
    size: int  # bytes in `path`
    sha256: str  # hex digest of `path`
    number: str | None = None  # the program name the validator found in it (an O-number), if any
    user: str = ""  # who submitted it (for a transport's own records: the DNC transfer log)


@dataclass(frozen=True, slots=True)
class Progress:
    """How far a delivery has come. Transports report `sent` at least; a drip-feed can say more."""

    sent: int  # bytes the controller has taken so far
    block: int | None = None  # the block (line) the controller is executing, when the transport knows it
    lead: float | None = None  # seconds of program the controller holds ahead of the block it executes
    remaining: float | None = None  # seconds of program left to run from that block (drip-feed)
    held: str = ""  # why nothing goes out now (drip-feed): "DC3", "waiting for DC1", "paused", or ""


#: Called by a transport as the program goes out; cheap, never blocks, never raises.
ReportProgress = Callable[[Progress], None]


class DeliveryTransport(Protocol):
    """One machine's way of receiving programs. Each call opens (and closes) its own connection."""

    async def deliver(self, program: Program, progress: ReportProgress) -> str:
        """Put `program` on the controller, checked as far as the transport can check, and say where it
        went, for the job's record (`/DATA/Programs/part.nc`). Raises DeliveryError."""
        ...

    async def holds(self, program: Program) -> bool:
        """After a crash, for a job left SENDING: does the controller hold this program already, complete?

        True makes the job DELIVERED without sending it again (and without starting it).
        Whatever an interrupted delivery left behind (a temporary upload) is removed either
        way. A transport that cannot look answers False, and the program is sent again.
        Raises DeliveryError when the controller cannot be asked (the worker asks again later).
        """
        ...


@dataclass(frozen=True, slots=True)
class RemoteFile:
    """A program in a controller's program store."""

    name: str
    size: int | None
    modified: str | None  # the store's own time text (FTP: YYYYMMDDhhmmss from MLSD, or the listing's date)


class ProgramStore(Protocol):
    """One session with a controller's program store: list, fetch, store and delete programs by name.

    Opened with `async with open_store() as store:` (an `OpenStore`). Names are plain
    file names in the store's one program folder; a name that is not one raises a
    permanent DeliveryError, a missing program ProgramNotFound.
    """

    @property
    def address(self) -> str:
        """Where the store is, for messages: `ftp://10.0.0.5:21/DATA/Programs`."""
        ...

    async def list(self) -> list[RemoteFile]:
        """The programs, sorted by name."""
        ...

    async def get(self, name: str, *, limit: int | None = None) -> bytes:
        """A program's content; `limit` refuses (permanently) programs larger than that many bytes."""
        ...

    async def put(self, name: str, data: bytes) -> None:
        """Store `data` as `name`, replacing a program of that name."""
        ...

    async def delete(self, name: str) -> None: ...

    async def size(self, name: str) -> int | None:
        """The size of a program in bytes, or None if there is none of that name."""
        ...


#: Opens a session with one machine's program store.
OpenStore = Callable[[], AbstractAsyncContextManager[ProgramStore]]


# --- the spec and its ports ------------------------------------------------------------------------


class ControllerSettings(Protocol):
    """What the core reads of any transport's settings (the mapping's `jobs.controller`)."""

    @property
    def type(self) -> str: ...

    def model_copy(self, *, update: Mapping[str, Any] | None = None, deep: bool = False) -> Self:
        """The settings with some keys changed (pydantic's; the demo points a machine at its simulator)."""
        ...


class JobsSection(Protocol):
    """What a transport reads of its machine's `jobs:` section (gateway/config/jobs.py `JobsConfig`)."""

    @property
    def controller(self) -> ControllerSettings: ...

    @property
    def verify(self) -> Literal["size", "hash"]: ...

    @property
    def punch(self) -> object:
        """Serial DNC's `jobs.punch` (gateway/transports/dnc/punch.py), which that transport narrows."""
        ...


@dataclass(frozen=True, slots=True)
class ProgramVerdict:
    """What the machine's validation rules say of a program (a transport checking what it answers with)."""

    accepted: bool
    reason: str  # the first rejection's reason; "" when accepted
    program: bytes  # what would be delivered (the input, less what the rules strip)


@dataclass(frozen=True, slots=True)
class QueuedProgram:
    """A validated program of an accepted job, found for a request (the job service reads the spool)."""

    data: bytes
    file: str  # the job's file name
    user: str  # who submitted the job
    job: str  # its id, J000042


#: Runs a blocking call, `fn(*args, **kwargs)`, in one of the job service's threads.
RunIn = Callable[..., Awaitable[Any]]
#: (file name, program) -> the machine's validation rules' verdict (blocking: CPU for large programs).
Validate = Callable[[bytes, str], ProgramVerdict]
#: (machine, file name, program bytes, user, origin) -> a reply whose text says what became of it.
Submit = Callable[[str, str, bytes, str, str], Awaitable[str]]
#: (machine, requested name) -> the newest accepted job's program that a request for it names, or None.
FindJob = Callable[[str, str], Awaitable[QueuedProgram | None]]
#: (job id, line, user) -> the job's record, queued again to start at that line; raises RequestError.
Restart = Callable[[str, int, str], Awaitable[dict[str, Any]]]


@dataclass(frozen=True, slots=True)
class MachineJobs:
    """One machine whose `jobs.controller` is a transport's, and the core's ports for it."""

    name: str
    machine: Machine  # its variables and methods (a transport may add its own)
    jobs: JobsSection
    validate: Validate  # with the machine's validation rules
    restart: Restart  # a FAILED job of this machine queued again, to start at a line


@dataclass(frozen=True, slots=True)
class CorePorts:
    """What the core gives every transport's machines together."""

    state_dir: Path
    backups_dir: Path  # backups/<machine>/ are each machine's
    work: RunIn  # the service's worker threads (files, CPU)
    queue_thread: RunIn  # the queue's one thread (SQLite files the service opens)
    submit: Submit  # into a machine's job queue, as an upload would be
    find_job: FindJob


@dataclass(frozen=True, slots=True)
class Delivery:
    """One machine's delivery, assembled: its transport and what else the core offers through it."""

    transport: DeliveryTransport
    store: OpenStore | None = None  # its program store (`Programs` methods), None where it has none
    folder: str = ""  # the program folder auto-start's `select_value: path` names ("": none)
    #: Marks a FAILED job's spooled program to start at a line on its next delivery (drip-feed only).
    restart_at: Callable[[Path, int], None] | None = None
    keep_delivered: int = 0  # delivered programs the spool keeps for the transport (remote requests)


class Deliveries(Protocol):
    """A transport's machines, assembled: entered once the job queue is open, left before it closes;
    `run()` (a task of the job service) runs what they need beyond deliveries, until cancelled."""

    @property
    def machines(self) -> Mapping[str, Delivery]: ...

    async def __aenter__(self) -> Self: ...

    async def __aexit__(self, *exc_info: object) -> None: ...

    async def run(self) -> None: ...


class EachMachine:
    """`Deliveries` of a transport whose machines need nothing beyond their own transport (FTP, FOCAS)."""

    def __init__(self, machines: Mapping[str, Delivery]) -> None:
        self.machines = machines

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        return None

    async def run(self) -> None:
        return None


@dataclass(frozen=True, slots=True)
class TransportSpec:
    """One delivery transport, as gateway/transports/registry.py lists it.

    `assemble` is called once, when the job service is built, with every machine whose
    `jobs.controller.type` is `type` (never with none); it builds each machine's transport with what
    it needs passed in. `store` opens a program store from settings alone (`cnc-gateway programs`).
    """

    type: str  # `jobs.controller: {type: ...}` in a mapping file
    settings: builtins.type[Strict]  # the `controller:` model (its folder's config.py), `type: Literal`
    assemble: Callable[[Sequence[MachineJobs], CorePorts], Deliveries]
    summary: str  # one line, for docs/architecture.md's table
    store: Callable[[Any], OpenStore] | None = None  # None: the transport has no program store
    # `cnc-gateway` verbs this transport adds, as (verb, module): as DriverSpec.commands.
    commands: tuple[tuple[str, str], ...] = ()


def settings_of(settings: object, model: builtins.type[M]) -> M:
    """A machine's `jobs.controller` as the transport's own model (the registry picked the transport by
    its type, so anything else is a programming error)."""
    if not isinstance(settings, model):
        raise TypeError(f"a {type(settings).__name__}, not {model.__name__}")
    return settings
