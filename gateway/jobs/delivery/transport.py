"""The seam between delivery and a controller: what a delivery transport (and a program store) must do.

The delivery worker (worker.py) owns jobs: queue order, attempts and backoff,
FAILED, auto-start, the record of what happened. A transport owns one way of
getting a program onto a controller: today the controller's FTP program store
(transports/ftp.py); serial DNC (RS-232: load, drip-feed) is the next. The
worker talks to a `DeliveryTransport` only, and transports/__init__.py picks
one per machine from its mapping's `jobs.controller`.

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

from collections.abc import Callable
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol


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
