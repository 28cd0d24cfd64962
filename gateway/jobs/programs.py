"""The machine's `Programs` methods: list, fetch, back up, delete and put controller programs.

Registered on each machine with a `jobs:` section (gateway.model.methods), so
OPC UA shows them as Method nodes under the machine's `Programs` object. They
talk to the controller's program store directly (the `ProgramStore` of the
machine's delivery transport), except `Put`, which goes through validation and
the queue like an inbox upload: no back door. A transport with no store (a
serial line cannot list) leaves `Put` alone.

The job service passes in what the methods use (the store, its `submit_bytes`,
the backups shelf), so this module does not import the service. Delete, Put and
Backup need the operator role; Backup's copies are bounded by the shelf
(gateway/jobs/backups.py: a rate, a retention, and a reply that names the copy,
not the server's path).
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from gateway.errors import (
    ControllerRefused,
    ControllerUnavailable,
    DeliveryError,
    InvalidArgument,
    NotFound,
    PathRefused,
    ProgramNotFound,
    RequestError,
)
from gateway.jobs.backups import BackupShelf
from gateway.jobs.inbox.inbox import UploadReply
from gateway.jobs.inbox.paths import check_file_name
from gateway.model.methods import Argument, Method
from gateway.model.types import TypeSpec
from gateway.transports.base import OpenStore

if TYPE_CHECKING:
    from gateway.model.context import WriteContext

OBJECT = "Programs"
GET_LIMIT = 16 * 1024 * 1024  # bytes a Get may return through OPC UA

STRING = TypeSpec.parse("String")
NAME = Argument("Name", STRING, "Program file name in the controller's program folder")


def as_write_error(exc: DeliveryError) -> RequestError:
    """A program store error, as the status code a method call answers with."""
    if isinstance(exc, ProgramNotFound):
        return NotFound(exc.reason)
    if exc.reply is None:
        return ControllerUnavailable(exc.reason)
    return ControllerRefused(exc.reason)


def _name(value: Any) -> str:
    try:
        return check_file_name(str(value))
    except PathRefused as exc:
        raise InvalidArgument(exc.reason) from None


class SubmitProgram(Protocol):
    """Queues a program for a machine as if it had been uploaded (JobService.submit_bytes)."""

    async def __call__(
        self, machine: str, filename: str, data: bytes, *, user: str, origin: str
    ) -> UploadReply: ...


def program_methods(
    machine: str, *, store: OpenStore | None, submit: SubmitProgram, backups: BackupShelf
) -> list[Method]:
    """The methods for one machine: `store` opens its program store (None: Put only), `submit` queues a
    program, `backups` is where Backup copies programs (its folder, retention and rate)."""
    methods = _store_methods(store, backups) if store is not None else []
    return [*methods, _put_method(machine, submit)]


def _store_methods(store: OpenStore, backups: BackupShelf) -> list[Method]:
    """List, Get, Backup and Delete: straight to the controller's program store."""

    async def listing(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        try:
            async with store() as session:
                files = await session.list()
        except DeliveryError as exc:
            raise as_write_error(exc) from None
        return [[f.name for f in files], [f.size if f.size is not None else 0 for f in files]]

    async def fetch(name: str) -> bytes:
        try:
            async with store() as session:
                return await session.get(name, limit=GET_LIMIT)
        except DeliveryError as exc:
            raise as_write_error(exc) from None

    async def get(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        data = await fetch(_name(args[0]))
        return [data.decode("utf-8", errors="replace")]

    async def backup(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        name = _name(args[0])
        backups.admit()
        data = await fetch(name)
        return [await asyncio.to_thread(backups.store, name, data)]

    async def delete(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        name = _name(args[0])
        try:
            async with store() as session:
                await session.delete(name)
        except DeliveryError as exc:
            raise as_write_error(exc) from None
        return []

    return [
        Method(
            OBJECT,
            "List",
            "The programs in the controller's program folder, with their sizes in bytes",
            (),
            (Argument("Names", TypeSpec.parse("String[]")), Argument("Sizes", TypeSpec.parse("UInt64[]"))),
            listing,
        ),
        Method(OBJECT, "Get", "A program's text", (NAME,), (Argument("Content", STRING),), get),
        Method(
            OBJECT,
            "Backup",
            "Copy a program into the gateway's backups folder (backups/<machine>/); returns the copy's name",
            (NAME,),
            (Argument("File", STRING, "The copy's file name in the backups folder"),),
            backup,
            role="operator",
        ),
        Method(
            OBJECT, "Delete", "Delete a program from the controller", (NAME,), (), delete, role="operator"
        ),
    ]


def _put_method(machine: str, submit: SubmitProgram) -> Method:
    """Put: through validation and the queue, like an inbox upload."""

    async def put(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
        name = _name(args[0])
        content = str(args[1]).encode("utf-8")
        user = ctx.user or ctx.origin
        reply = await submit(machine, name, content, user=user, origin=ctx.origin)
        if reply.job_id is None and not reply.ok:
            raise InvalidArgument(reply.message)
        return [reply.job_id or "", reply.message]  # a rejection is a job too: its id and the reason

    job = Argument("JobId", STRING, "The job that will deliver it")
    return Method(
        OBJECT,
        "Put",
        "Queue a program for delivery: validated and delivered like an inbox upload",
        (NAME, Argument("Content", STRING, "The program text")),
        (job, Argument("Message", STRING, "queued, or why it was rejected")),
        put,
        role="operator",
    )
