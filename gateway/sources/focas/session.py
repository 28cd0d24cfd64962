"""One FOCAS session over asyncio: open, multi-command requests one at a time, close.

A Fanuc answers each request on a session in order and holds a few sessions only, so a session is
used by one caller at a time (`SessionPool` hands them out). Every failure to talk is a
`SourceError` with a reason users read; a refused open (the controller's session limit) is a
`SessionRefused`; an answer carrying a controller's error code is left to the caller, per command.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import Sequence

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.commands import Command, Reply, command, decode_response, request_frame
from gateway.codecs.focas.errors import EW_SOCKET, FocasError, describe
from gateway.codecs.focas.frame import SESSION_COMMANDS, Frame, FrameReader, Junk, Kind, encode_frame
from gateway.codecs.focas.plan import Context
from gateway.codecs.focas.values import SysInfo, decode_axis_names
from gateway.errors import SourceError

READ_SIZE = 65536


class SessionRefused(SourceError):
    """The controller would not open one more session (its limit), or closed it at once."""


class FocasSession:
    def __init__(self, host: str, port: int, timeout: float) -> None:
        self.host = host
        self.port = port
        self.timeout = timeout
        self.context = Context()
        self.sysinfo: SysInfo | None = None
        self.requests = 0  # round trips made
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._frames = FrameReader()
        self._pending: list[Frame] = []

    @property
    def endpoint(self) -> str:
        return f"focas://{self.host}:{self.port}"

    @property
    def is_open(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def open(self, kind: int = SESSION_COMMANDS) -> None:
        try:
            async with asyncio.timeout(self.timeout):
                self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        except (OSError, TimeoutError) as exc:
            raise SourceError(reason_of(exc)) from None
        try:
            answer = await self.exchange(encode_frame(Kind.OPEN, struct.pack(">H", kind)))
        except SourceError as exc:
            self.abort()
            raise SessionRefused(f"the controller closed the session as it opened ({exc.reason})") from None
        if answer.kind != Kind.OPEN_OK:
            self.abort()
            raise SourceError(f"the controller answered an open with frame type {answer.kind:#06x}")
        if len(answer.payload) >= 2 and struct.unpack_from(">h", answer.payload)[0] < 0:
            self.abort()
            code = struct.unpack_from(">h", answer.payload)[0]
            raise SessionRefused(f"the controller refused a session: {describe(code)}")

    async def learn(self) -> None:
        """Sysinfo and the axes' names, once per session (positions by axis name need them)."""
        replies = await self.request([command(fn.SYSINFO), command(fn.AXIS_NAMES)])
        if replies[0].error:
            raise SourceError(f"sysinfo refused: {describe(replies[0].error)}")
        try:
            self.sysinfo = SysInfo.decode(replies[0].data)
            names = decode_axis_names(replies[1].data) if not replies[1].error else []
        except FocasError as exc:
            raise SourceError(f"unreadable sysinfo: {exc.reason}") from None
        count = self.sysinfo.axis_count
        self.context = Context(tuple(n for n in names[:count] if n) or (), self.sysinfo.max_axis)

    async def request(self, commands: Sequence[Command]) -> list[Reply]:
        """One round trip: the commands' answers, in order (each with its own error code)."""
        frame = await self.exchange(request_frame(commands))
        self.requests += 1
        if frame.kind != Kind.RESPONSE:
            self.abort()
            raise SourceError(f"the controller answered a request with frame type {frame.kind:#06x}")
        try:
            replies = decode_response(frame.payload)
        except FocasError as exc:
            self.abort()
            raise SourceError(f"unreadable answer from the controller: {exc.reason}") from None
        if len(replies) != len(commands) or not all(
            r.answers(c) for r, c in zip(replies, commands, strict=False)
        ):
            self.abort()
            raise SourceError(
                f"the controller's answer does not match the request ({len(replies)} answers to "
                f"{len(commands)} commands)"
            )
        return replies

    async def exchange(self, data: bytes) -> Frame:
        """Send `data` and wait for the next frame."""
        self.send(data)
        return await self.next_frame()

    def send(self, data: bytes) -> None:
        if self._writer is None or self._writer.is_closing():
            raise SourceError("the session is closed")
        self._writer.write(data)

    async def drain(self) -> None:
        if self._writer is None:
            raise SourceError("the session is closed")
        try:
            async with asyncio.timeout(self.timeout):
                await self._writer.drain()
        except (OSError, TimeoutError) as exc:
            self.abort()
            raise SourceError(reason_of(exc)) from None

    async def next_frame(self) -> Frame:
        reader = self._reader
        if reader is None:
            raise SourceError("the session is closed")
        try:
            async with asyncio.timeout(self.timeout):
                while not self._pending:
                    data = await reader.read(READ_SIZE)
                    if not data:
                        raise SourceError("the controller closed the connection")
                    for event in self._frames.feed(data):
                        if isinstance(event, Junk):
                            raise SourceError(f"junk from the controller: {event.reason}")
                        self._pending.append(event)
        except SourceError:
            self.abort()
            raise
        except (OSError, TimeoutError) as exc:
            self.abort()
            raise SourceError(reason_of(exc)) from None
        return self._pending.pop(0)

    async def close(self) -> None:
        """Say goodbye (close frame) and close; never raises."""
        writer = self._writer
        if writer is None:
            return
        if not writer.is_closing():
            with contextlib.suppress(SourceError):
                self.send(encode_frame(Kind.CLOSE))
                async with asyncio.timeout(min(self.timeout, 0.5)):
                    await self.next_frame()
        self.abort()

    def abort(self) -> None:
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.transport.abort()


def reason_of(exc: BaseException) -> str:
    if isinstance(exc, TimeoutError):
        return "timed out"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, ConnectionResetError):
        return "connection reset"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


__all__ = ["EW_SOCKET", "FocasSession", "SessionRefused", "reason_of"]
