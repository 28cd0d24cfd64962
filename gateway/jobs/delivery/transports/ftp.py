"""The controller's FTP program store, as the gateway's FTP client sees it (aioftp).

The one module that imports aioftp's client side. Every aioftp, socket and
timeout error becomes a DeliveryError (or ProgramNotFound) here, with the
server's own reply when it gave one, so the queue can record "550 disk full"
rather than a stack trace.

Uploads go to a temporary name and are renamed into place, so the controller
never sees half a program under its real name; controllers whose FTP server
cannot rename use `upload: direct`.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import ssl
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Self

import aioftp

from gateway.config.jobs import ControllerFtp
from gateway.errors import DeliveryError, ProgramNotFound

log = logging.getLogger(__name__)

BLOCK = 64 * 1024
Progress = Callable[[int], None]


@dataclass(frozen=True, slots=True)
class RemoteFile:
    name: str
    size: int | None
    modified: str | None  # the server's YYYYMMDDhhmmss (MLSD) or listing date text


def reply_of(exc: aioftp.StatusCodeError) -> str:
    """'550 path does not exist' from aioftp's exception."""
    code = str(exc.received_codes[-1]) if exc.received_codes else "???"
    info = exc.info if isinstance(exc.info, list) else [str(exc.info)]
    text = " ".join(str(line).strip(" -") for line in info if str(line).strip())
    return f"{code} {text}".strip()


def _code(exc: aioftp.StatusCodeError) -> str:
    return str(exc.received_codes[-1]) if exc.received_codes else ""


class ProgramStore:
    """One FTP session with a controller: `async with ProgramStore(cfg) as store: await store.list()`."""

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
            raise DeliveryError(f"{self.what} {self.address} refused the login: {reply_of(exc)}", reply=reply_of(exc)) from None
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

    async def _call(self, what: str, coro: Any, *, missing: str | None = None) -> Any:
        """Run one client operation, translating its errors."""
        try:
            return await coro
        except aioftp.StatusCodeError as exc:
            reply = reply_of(exc)
            if missing is not None and _code(exc) in ("550", "450"):
                raise ProgramNotFound(f"{missing} is not in {self.address} ({reply})", reply=reply) from None
            raise DeliveryError(f"{what}: {self.what} answered {reply}", reply=reply, permanent=_code(exc) == "553") from None
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
                out.append(RemoteFile(PurePosixPath(path).name, int(size) if size not in (None, "") else None, info.get("modify")))
            return sorted(out, key=lambda f: f.name)

        return await self._call(f"listing {self.config.folder}", collect())

    async def size(self, name: str) -> int | None:
        """The size of a program, or None if there is none of that name. SIZE first, a listing if unsupported."""
        path = self.path(name)
        try:
            _, info = await self.client.command(f"SIZE {path}", "213")
            return int(info[-1].strip())
        except aioftp.StatusCodeError as exc:
            if _code(exc) in ("550", "450"):
                return None
            if not _code(exc).startswith("50"):
                raise DeliveryError(f"SIZE {name}: {self.what} answered {reply_of(exc)}", reply=reply_of(exc)) from None
        except ValueError:
            pass  # an odd SIZE reply: fall back to the listing
        except (OSError, EOFError, TimeoutError, aioftp.AIOFTPException) as exc:
            raise DeliveryError(f"SIZE {name}: connection to {self.address} failed: {_describe(exc)}") from None
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

    async def upload(self, name: str, source: Path, *, progress: Progress | None = None) -> None:
        """Store a local file under `name`: via a temporary name and a rename, unless configured `direct`."""
        final = self.path(name)
        temp = self.path(self.temp_name(name)) if self.config.upload == "temp-rename" else final

        async def send() -> None:
            sent = 0
            async with self.client.upload_stream(temp) as stream:
                with source.open("rb") as f:
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

    async def put_bytes(self, name: str, data: bytes, scratch: Path) -> None:
        """Upload bytes (the CLI's `programs put`) through a scratch file."""
        scratch.write_bytes(data)
        try:
            await self.upload(name, scratch)
        finally:
            scratch.unlink(missing_ok=True)


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
