"""Requests to another MTConnect agent: the one module that imports aiohttp's client side.

`AgentClient.get(path)` returns the body of any answer an agent gives (its errors are
MTConnectError documents, which the caller reads); `stream(path, idle)` yields the parts of
a `multipart/x-mixed-replace` answer, and gives up when nothing arrives for `idle`
seconds (the agent sends a heartbeat part well within that). Every failure of the
connection is a SourceError with a short reason (`connection refused`, `timed out`).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Self

import aiohttp

from gateway.codecs.mtconnect.multipart import MultipartReader, boundary_of
from gateway.errors import SourceError

MAX_BODY = 64 << 20


def _reason(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out"
    if isinstance(exc, aiohttp.ClientConnectorError):
        os_error = exc.os_error
        if isinstance(os_error, ConnectionRefusedError):
            return "connection refused"
        return os_error.strerror or str(os_error)
    if isinstance(exc, aiohttp.ServerDisconnectedError):
        return "the agent closed the connection"
    if isinstance(exc, aiohttp.ClientPayloadError):
        return "the answer was cut off"
    return str(exc) or type(exc).__name__


class AgentClient:
    def __init__(self, url: str, *, timeout: float = 5.0) -> None:
        self.url = url.rstrip("/")
        self.timeout = timeout
        self._session: aiohttp.ClientSession | None = None

    async def __aenter__(self) -> Self:
        self._session = aiohttp.ClientSession(
            timeout=aiohttp.ClientTimeout(total=None, connect=self.timeout, sock_read=None), trust_env=False
        )
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        session, self._session = self._session, None
        if session is not None:
            await session.close()

    @property
    def session(self) -> aiohttp.ClientSession:
        if self._session is None:
            raise SourceError("the agent client is not open")
        return self._session

    async def get(self, path: str) -> bytes:
        """The body of GET `path` (relative to the agent's base address), whatever its status."""
        try:
            async with asyncio.timeout(self.timeout):
                async with self.session.get(self.url + path) as response:
                    body = await response.content.read(MAX_BODY + 1)
        except (aiohttp.ClientError, TimeoutError, OSError) as exc:
            raise SourceError(f"{self.url}: {_reason(exc)}") from None
        if len(body) > MAX_BODY:
            raise SourceError(f"{self.url}{path}: the answer is larger than {MAX_BODY >> 20} MiB")
        return body

    async def stream(self, path: str, idle: float) -> AsyncIterator[bytes]:
        """The parts of a streamed answer; a plain (non-multipart) answer is yielded whole, once."""
        try:
            async with asyncio.timeout(self.timeout):
                response = await self.session.get(self.url + path)
        except (aiohttp.ClientError, TimeoutError, OSError) as exc:
            raise SourceError(f"{self.url}: {_reason(exc)}") from None
        try:
            boundary = boundary_of(response.headers.get("Content-Type", ""))
            if boundary is None:
                try:
                    async with asyncio.timeout(self.timeout):
                        yield await response.content.read(MAX_BODY)
                except (aiohttp.ClientError, TimeoutError, OSError) as exc:
                    raise SourceError(f"{self.url}: {_reason(exc)}") from None
                return
            reader = MultipartReader(boundary)
            while True:
                try:
                    async with asyncio.timeout(idle):
                        data = await response.content.readany()
                except TimeoutError:
                    raise SourceError(f"{self.url}: no data nor heartbeat for {idle:g} s") from None
                except (aiohttp.ClientError, OSError) as exc:
                    raise SourceError(f"{self.url}: {_reason(exc)}") from None
                if not data:
                    raise SourceError(f"{self.url}: the agent ended the stream")
                for part in reader.feed(data):
                    yield part
                if reader.failed is not None:
                    raise SourceError(f"{self.url}: unreadable stream: {reader.failed}")
        finally:
            response.close()
