"""Delivery over the controller's FTP program store, as the gateway's FTP client sees it (aioftp).

The one module that imports aioftp's client side. `FtpProgramStore` is one FTP
session (a `ProgramStore`: list, get, put, delete, size); `FtpTransport` is the
`DeliveryTransport` built on it. Every aioftp, socket and timeout error becomes
a DeliveryError (or ProgramNotFound) here, with the server's own reply when it
gave one, so the queue can record "550 disk full" rather than a stack trace;
`553` (name not allowed) is permanent.

Uploads go to a temporary name and are renamed into place, so the controller
never sees half a program under its real name; controllers whose FTP server
cannot rename use `upload: direct`. After an upload, the program is checked by
its size (SIZE, or a listing) or, with `verify: hash`, downloaded back and hashed.
"""

from __future__ import annotations

import asyncio
import hashlib
import io
import ssl
from collections.abc import Awaitable, Callable
from pathlib import Path, PurePosixPath
from typing import BinaryIO, Literal, Self, TypeVar

import aioftp

from gateway.errors import DeliveryError, ProgramNotFound
from gateway.transports.base import Program, Progress, RemoteFile, ReportProgress
from gateway.transports.ftp.config import ControllerFtp

BLOCK = 64 * 1024
Sent = Callable[[int], None]  # bytes sent so far
T = TypeVar("T")


def reply_of(exc: aioftp.StatusCodeError) -> str:
    """'550 path does not exist' from aioftp's exception."""
    code = str(exc.received_codes[-1]) if exc.received_codes else "???"
    info = exc.info if isinstance(exc.info, list) else [str(exc.info)]
    text = " ".join(str(line).strip(" -") for line in info if str(line).strip())
    return f"{code} {text}".strip()


def _code(exc: aioftp.StatusCodeError) -> str:
    return str(exc.received_codes[-1]) if exc.received_codes else ""


class FtpProgramStore:
    """One FTP session with a controller: `async with FtpProgramStore(cfg) as store: await store.list()`."""

    def __init__(self, config: ControllerFtp, *, what: str = "controller") -> None:
        self.config = config
        self.what = what
        self.folder = PurePosixPath(config.folder)
        self._client: aioftp.Client | None = None

    @property
    def address(self) -> str:
        return f"ftp://{self.config.host}:{self.config.port}{self.config.folder}"

    def path(self, name: str) -> PurePosixPath:
        check_remote_name(name)
        return self.folder / name

    # --- session ---------------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        cfg = self.config
        passive = {"auto": ("epsv", "pasv"), "epsv": ("epsv",), "pasv": ("pasv",)}[cfg.passive]
        context = _tls_context(cfg.tls_verify) if cfg.tls != "none" else None
        client = aioftp.Client(
            socket_timeout=cfg.timeout,
            connection_timeout=cfg.timeout,
            write_speed_limit=int(cfg.rate_limit) if cfg.rate_limit else None,
            passive_commands=passive,
            ssl=context if cfg.tls == "implicit" else None,
            encoding="utf-8",
        )
        try:
            await client.connect(cfg.host, cfg.port)
            if cfg.tls == "explicit":
                await client.upgrade_to_tls(context)
            password = cfg.password.get_secret_value() if cfg.password is not None else ""
            await client.login(cfg.user, password)
        except aioftp.StatusCodeError as exc:
            client.close()
            raise DeliveryError(
                f"{self.what} {self.address} refused the login: {reply_of(exc)}", reply=reply_of(exc)
            ) from None
        except (OSError, EOFError, TimeoutError, ssl.SSLError, aioftp.AIOFTPException) as exc:
            client.close()
            raise DeliveryError(f"{self.what} {self.address} is unreachable: {_describe(exc)}") from None
        self._client = client
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        try:
            async with asyncio.timeout(self.config.timeout):
                await client.quit()
        except (OSError, EOFError, TimeoutError, aioftp.AIOFTPException):
            pass
        finally:
            client.close()

    @property
    def client(self) -> aioftp.Client:
        if self._client is None:
            raise DeliveryError(f"not connected to {self.address}")
        return self._client

    async def _call(self, what: str, coro: Awaitable[T], *, missing: str | None = None) -> T:
        """Run one client operation, translating its errors."""
        try:
            return await coro
        except aioftp.StatusCodeError as exc:
            reply = reply_of(exc)
            if missing is not None and _code(exc) in ("550", "450"):
                raise ProgramNotFound(f"{missing} is not in {self.address} ({reply})", reply=reply) from None
            raise DeliveryError(
                f"{what}: {self.what} answered {reply}", reply=reply, permanent=_code(exc) == "553"
            ) from None
        except (OSError, EOFError, TimeoutError, aioftp.AIOFTPException) as exc:
            raise DeliveryError(f"{what}: connection to {self.address} failed: {_describe(exc)}") from None

    # --- operations ------------------------------------------------------------------------------

    async def list(self) -> list[RemoteFile]:
        """The programs in the folder (files only), sorted by name."""

        async def collect() -> list[RemoteFile]:
            out = []
            for path, info in await self.client.list(self.folder):
                if info.get("type") != "file":
                    continue
                size = info.get("size")
                out.append(
                    RemoteFile(
                        PurePosixPath(path).name,
                        int(size) if size not in (None, "") else None,
                        info.get("modify"),
                    )
                )
            return sorted(out, key=lambda f: f.name)

        return await self._call(f"listing {self.config.folder}", collect())

    async def size(self, name: str) -> int | None:
        """The size of a program, None if there is none of that name. SIZE first, a listing if unsupported."""
        path = self.path(name)
        try:
            _, info = await self.client.command(f"SIZE {path}", "213")
            return int(info[-1].strip())
        except aioftp.StatusCodeError as exc:
            if _code(exc) in ("550", "450"):
                return None
            if not _code(exc).startswith("50"):
                raise DeliveryError(
                    f"SIZE {name}: {self.what} answered {reply_of(exc)}", reply=reply_of(exc)
                ) from None
        except ValueError:
            pass  # an odd SIZE reply: fall back to the listing
        except (OSError, EOFError, TimeoutError, aioftp.AIOFTPException) as exc:
            raise DeliveryError(
                f"SIZE {name}: connection to {self.address} failed: {_describe(exc)}"
            ) from None
        for remote in await self.list():
            if remote.name == name:
                return remote.size
        return None

    async def get(self, name: str, *, limit: int | None = None) -> bytes:
        """A program's content. `limit` refuses programs larger than that many bytes."""
        path = self.path(name)

        async def download() -> bytes:
            chunks: list[bytes] = []
            total = 0
            async with self.client.download_stream(path) as stream:
                async for block in stream.iter_by_block(BLOCK):
                    total += len(block)
                    if limit is not None and total > limit:
                        raise DeliveryError(f"{name} is larger than {limit} bytes", permanent=True)
                    chunks.append(block)
            return b"".join(chunks)

        return await self._call(f"downloading {name}", download(), missing=name)

    async def sha256(self, name: str) -> str:
        path = self.path(name)

        async def digest() -> str:
            h = hashlib.sha256()
            async with self.client.download_stream(path) as stream:
                async for block in stream.iter_by_block(BLOCK):
                    h.update(block)
            return h.hexdigest()

        return await self._call(f"reading back {name}", digest(), missing=name)

    async def delete(self, name: str) -> None:
        await self._call(f"deleting {name}", self.client.remove_file(self.path(name)), missing=name)

    async def upload(self, name: str, source: Path, *, progress: Sent | None = None) -> None:
        """Store a local file under `name`: via a temporary name and a rename, unless configured `direct`."""
        with source.open("rb") as f:
            await self._store(name, f, progress)

    async def put(self, name: str, data: bytes) -> None:
        """Store `data` under `name`, the same way as `upload`."""
        await self._store(name, io.BytesIO(data), None)

    async def _store(self, name: str, f: BinaryIO, progress: Sent | None) -> None:
        final = self.path(name)
        temp = self.path(self.temp_name(name)) if self.config.upload == "temp-rename" else final

        async def send() -> None:
            sent = 0
            async with self.client.upload_stream(temp) as stream:
                while block := f.read(BLOCK):
                    await stream.write(block)
                    sent += len(block)
                    if progress is not None:
                        progress(sent)

        await self._call(f"uploading {name}", send())
        if temp != final:
            await self._call(f"renaming {temp.name} to {name}", self.client.rename(temp, final))

    async def remove_temp(self, name: str) -> bool:
        """Delete a leftover temporary upload of `name` (after a crash); True if there was one."""
        if self.config.upload != "temp-rename":
            return False
        try:
            await self.delete(self.temp_name(name))
        except ProgramNotFound:
            return False
        return True

    def temp_name(self, name: str) -> str:
        return name + self.config.temp_suffix


class FtpTransport:
    """Delivery to the controller's FTP program store: one FTP session per delivery (or check)."""

    def __init__(self, config: ControllerFtp, *, verify: Literal["size", "hash"] = "size") -> None:
        self.config = config
        self.verify = verify

    def store(self) -> FtpProgramStore:
        return FtpProgramStore(self.config)

    async def deliver(self, program: Program, progress: ReportProgress) -> str:
        async with self.store() as store:
            await store.upload(program.name, program.path, progress=lambda sent: progress(Progress(sent)))
            await self._verify(store, program)
        return f"{self.config.folder}/{program.name}"

    async def holds(self, program: Program) -> bool:
        async with self.store() as store:
            found = await self._on_controller(store, program)
            await store.remove_temp(program.name)
        return found

    async def _verify(self, store: FtpProgramStore, program: Program) -> None:
        name = program.name
        if self.verify == "hash":
            digest = await store.sha256(name)
            if digest != program.sha256:
                raise DeliveryError(f"verification failed: {name} on the controller has different content")
            return
        size = await store.size(name)
        if size != program.size:
            found = "no such file" if size is None else f"{size} bytes"
            raise DeliveryError(
                f"verification failed: {name} on the controller has {found}, expected {program.size}"
            )

    @staticmethod
    async def _on_controller(store: FtpProgramStore, program: Program) -> bool:
        size = await store.size(program.name)
        if size is None or size != program.size:
            return False
        return await store.sha256(program.name) == program.sha256


def check_remote_name(name: str) -> str:
    if not name or "/" in name or "\\" in name or name in (".", "..") or not name.isprintable():
        raise DeliveryError(f"{name!r} is not a plain program name", permanent=True)
    return name


def _tls_context(verify: bool) -> ssl.SSLContext:
    context = ssl.create_default_context()
    if not verify:
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
    return context


def _describe(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out"
    if isinstance(exc, ConnectionResetError) and not str(exc):
        return "the server closed the connection"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__
