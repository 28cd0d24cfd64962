"""Delivery over FOCAS2 (`jobs.controller: {type: focas}`): programs into a Fanuc's memory or data server.

`FocasProgramStore` is one command session with the control (a `ProgramStore`: list and delete by
the folder's file functions, get and put by upload and download on a transfer session of their
own); `FocasTransport` is the `DeliveryTransport` built on it. After a download the program is
checked by the folder listing's size, or with `verify: hash` uploaded back and hashed. The
controller's refusals are DeliveryErrors with its code (EW_DATA, EW_PROT, EW_OVRFLOW: permanent; the
rest, and a lost connection, are retried).
"""

from __future__ import annotations

import hashlib
import re
from typing import Literal, Self

from gateway.codecs.focas.errors import EW_DATA, EW_LENGTH, EW_OVRFLOW, EW_PROT
from gateway.errors import DeliveryError, ProgramNotFound, SourceError
from gateway.sources.focas import transfer
from gateway.sources.focas.session import FocasSession
from gateway.sources.focas.transfer import TransferRefused
from gateway.transports.base import Program, Progress, RemoteFile, ReportProgress
from gateway.transports.focas.config import ControllerFocas

NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,31}$")  # a 30i-series file name
PERMANENT = frozenset({EW_DATA, EW_LENGTH, EW_OVRFLOW, EW_PROT})


def _delivery_error(exc: SourceError, what: str) -> DeliveryError:
    if isinstance(exc, TransferRefused):
        return DeliveryError(f"{what}: {exc.reason}", reply=exc.reason, permanent=exc.code in PERMANENT)
    return DeliveryError(f"{what}: {exc.reason}")


def check_name(name: str) -> str:
    if not NAME.match(name):
        raise DeliveryError(
            f"{name!r} is not a Fanuc file name (1-32 letters, digits, '_', '.', '-')", permanent=True
        )
    return name


class FocasProgramStore:
    """One FOCAS session with a control's program folder."""

    def __init__(self, config: ControllerFocas) -> None:
        self.config = config
        self._session: FocasSession | None = None

    @property
    def address(self) -> str:
        return self.config.address

    async def __aenter__(self) -> Self:
        session = FocasSession(self.config.host, self.config.port, self.config.timeout)
        try:
            await session.open()
        except SourceError as exc:
            raise _delivery_error(exc, f"cannot reach {self.address}") from None
        self._session = session
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        session, self._session = self._session, None
        if session is not None:
            await session.close()

    def _open(self) -> FocasSession:
        if self._session is None or not self._session.is_open:
            raise DeliveryError(f"the session with {self.address} is closed")
        return self._session

    async def list(self) -> list[RemoteFile]:
        try:
            entries = await transfer.list_folder(self._open(), self.config.folder)
        except SourceError as exc:
            raise _delivery_error(exc, f"listing {self.address}") from None
        files = [e for e in entries if e.is_file]
        return sorted(
            (
                RemoteFile(e.name, e.size, "{:04d}{:02d}{:02d}{:02d}{:02d}{:02d}".format(*e.stamp))
                for e in files
            ),
            key=lambda f: f.name,
        )

    async def size(self, name: str) -> int | None:
        check_name(name)
        return next((f.size for f in await self.list() if f.name == name), None)

    async def get(self, name: str, *, limit: int | None = None) -> bytes:
        check_name(name)
        c = self.config
        try:
            return await transfer.upload(c.host, c.port, c.timeout, c.folder + name, limit)
        except TransferRefused as exc:
            if exc.code == EW_DATA:
                raise ProgramNotFound(f"{name} is not in {self.address}") from None
            raise _delivery_error(exc, f"fetching {name}") from None
        except SourceError as exc:
            raise _delivery_error(exc, f"fetching {name}") from None

    async def put(self, name: str, data: bytes, progress: ReportProgress | None = None) -> None:
        check_name(name)
        c = self.config

        def sent(n: int) -> None:
            if progress is not None:
                progress(Progress(n))

        try:
            await transfer.download(c.host, c.port, c.timeout, c.folder + name, data, sent)
        except SourceError as exc:
            raise _delivery_error(exc, f"storing {name}") from None

    async def delete(self, name: str) -> None:
        check_name(name)
        try:
            await transfer.delete_file(self._open(), self.config.folder + name)
        except TransferRefused as exc:
            if exc.code == EW_DATA:
                raise ProgramNotFound(f"{name} is not in {self.address}") from None
            raise _delivery_error(exc, f"deleting {name}") from None
        except SourceError as exc:
            raise _delivery_error(exc, f"deleting {name}") from None


class FocasTransport:
    def __init__(self, config: ControllerFocas, *, verify: Literal["size", "hash"] = "size") -> None:
        self.config = config
        self.verify = verify

    def store(self) -> FocasProgramStore:
        return FocasProgramStore(self.config)

    async def deliver(self, program: Program, progress: ReportProgress) -> str:
        name = check_name(program.name)
        data = program.path.read_bytes()
        async with self.store() as store:
            await store.put(name, data, progress)
            if self.verify == "hash":
                back = await store.get(name, limit=program.size + 1)
                if hashlib.sha256(back).hexdigest() != program.sha256:
                    raise DeliveryError(
                        f"{name}: the control holds other bytes than were sent (SHA-256 differs)"
                    )
            else:
                size = await store.size(name)
                if size != program.size:
                    raise DeliveryError(f"{name}: the control holds {size} bytes, {program.size} were sent")
        return self.config.address + name

    async def holds(self, program: Program) -> bool:
        async with self.store() as store:
            return await store.size(check_name(program.name)) == program.size
