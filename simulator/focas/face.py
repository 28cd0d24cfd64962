"""`FocasFace`: the simulator as a Fanuc on TCP 8193. Async context manager.

Sessions: a client opens one with an open frame (payload 2: commands, 1: program transfer), and the
face keeps at most `sessions` open at once, as a Fanuc does; one more is answered with EW_SOCKET in
the open answer and closed. Command requests are answered by `FocasCnc` (controller.py), each in one
write. A transfer session takes a download into the program store (the name from the start frame,
or from the program's own O-number or <name> line when the start names only the folder) or sends a
program out. Junk on a connection (bytes that are not FOCAS frames, malformed requests) closes it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import struct
from typing import Protocol, Self

from gateway.codecs.focas.commands import decode_request, response_frame
from gateway.codecs.focas.errors import EW_DATA, EW_OVRFLOW, EW_SOCKET, FocasError
from gateway.codecs.focas.frame import SERVER_VERSION, Frame, FrameReader, Junk, Kind, encode_frame
from gateway.codecs.focas.program import CHUNK, read_start, result_frame
from simulator.errors import ProgramNotFound, SimulatorError
from simulator.focas.controller import FOLDER, FocasCnc
from simulator.machine import Machine
from simulator.store import check_name

log = logging.getLogger("simulator.focas")

DEFAULT_PORT = 8193
DEFAULT_SESSIONS = 5  # what a 0i-F allows by default (parameter 20 ... ; 30i-series: more)
MAX_PROGRAM = 16 << 20  # bytes a download may bring
READ_SIZE = 65536
_HEADER_NAME = re.compile(rb"^\s*%?\s*(?:<(?P<name>[A-Za-z0-9_.\-]{1,32})>|(?P<o>O[0-9]{1,8}))")


class WritableStore(Protocol):
    def exists(self, name: str) -> bool: ...

    def read(self, name: str) -> str: ...

    def write(self, name: str, data: bytes) -> None: ...

    def read_bytes(self, name: str) -> bytes: ...


class FocasFace:
    def __init__(
        self,
        machine: Machine,
        store: WritableStore,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        sessions: int = DEFAULT_SESSIONS,
    ) -> None:
        self.cnc = FocasCnc(machine)
        self.store = store
        self.host = host
        self.port = port
        self.max_sessions = sessions
        self.sessions = 0
        self.refused = 0  # sessions refused at the limit
        self.requests = 0  # command requests answered (one per round trip)
        self.junk = 0  # connections closed for junk
        self.downloads = 0
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: set[asyncio.StreamWriter] = set()

    @property
    def url(self) -> str:
        return f"focas://{self.host}:{self.port}"

    async def __aenter__(self) -> Self:
        try:
            self._server = await asyncio.start_server(self._serve, self.host, self.port)
        except OSError as exc:
            raise SimulatorError(
                f"FOCAS face cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.transport.abort()
        if self._tasks:  # the aborted connections end their handlers; cancel what is left
            await asyncio.wait(list(self._tasks), timeout=0.5)
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(self._tasks)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.add(writer)
        peer = writer.get_extra_info("peername")
        session = _Session()
        try:
            frames = FrameReader()
            while True:
                data = await reader.read(READ_SIZE)
                if not data:
                    return
                for event in frames.feed(data):
                    if isinstance(event, Junk):
                        self.junk += 1
                        log.info("FOCAS client %s sent junk (%s); closing", peer, event.reason)
                        return
                    if not await self._frame(event, session, writer):
                        return
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            if session.open:
                self.sessions -= 1
            self._writers.discard(writer)
            self._tasks.discard(task)
            writer.transport.abort()

    async def _frame(self, frame: Frame, s: _Session, writer: asyncio.StreamWriter) -> bool:
        """Answer one frame; False to close the connection."""
        kind = frame.kind
        if kind == Kind.OPEN:
            if s.open:
                return False
            if self.sessions >= self.max_sessions:
                self.refused += 1
                log.info("FOCAS session refused: %d of %d in use", self.sessions, self.max_sessions)
                writer.write(encode_frame(Kind.OPEN_OK, struct.pack(">hh", EW_SOCKET, 0), SERVER_VERSION))
                await writer.drain()
                return False
            self.sessions += 1
            s.open = True
            s.transfer = frame.payload == b"\x00\x01"
            writer.write(encode_frame(Kind.OPEN_OK, struct.pack(">hh", 0, self.max_sessions), SERVER_VERSION))
            return True
        if not s.open:
            log.info("FOCAS frame %#06x before an open; closing", kind)
            self.junk += 1
            return False
        if kind == Kind.CLOSE:
            writer.write(encode_frame(Kind.CLOSE_OK, b"", SERVER_VERSION))
            await writer.drain()
            return False
        if kind == Kind.REQUEST and not s.transfer:
            try:
                commands = decode_request(frame.payload)
            except FocasError as exc:
                self.junk += 1
                log.info("FOCAS request unreadable (%s); closing", exc.reason)
                return False
            self.requests += 1
            writer.write(response_frame([self.cnc.answer(c) for c in commands]))
            return True
        if s.transfer:
            return await self._transfer(frame, s, writer)
        self.junk += 1
        log.info("FOCAS frame %#06x not expected on a command session; closing", kind)
        return False

    async def _transfer(self, frame: Frame, s: _Session, writer: asyncio.StreamWriter) -> bool:
        kind = frame.kind
        if kind == Kind.DOWNLOAD_START and s.download is None:
            try:
                s.target = read_start(frame.payload)
            except FocasError:
                writer.write(result_frame(Kind.DOWNLOAD_START_OK, EW_DATA))
                return False
            s.download = bytearray()
            writer.write(result_frame(Kind.DOWNLOAD_START_OK, 0))
            return True
        if kind == Kind.DOWNLOAD_DATA and s.download is not None:
            if len(s.download) + len(frame.payload) > MAX_PROGRAM:
                s.overflow = True
            else:
                s.download += frame.payload
            return True
        if kind == Kind.DOWNLOAD_END and s.download is not None:
            code = EW_OVRFLOW if s.overflow else self._store(s.target, bytes(s.download))
            s.download, s.overflow = None, False
            writer.write(result_frame(Kind.DOWNLOAD_END_OK, code))
            return True
        if kind == Kind.UPLOAD_START:
            try:
                name = _upload_name(read_start(frame.payload))
                text = self.store.read_bytes(name)
            except (FocasError, ProgramNotFound, OSError):
                writer.write(result_frame(Kind.UPLOAD_START_OK, EW_DATA))
                return True
            writer.write(result_frame(Kind.UPLOAD_START_OK, 0))
            for at in range(0, len(text), CHUNK):
                writer.write(encode_frame(Kind.UPLOAD_DATA, text[at : at + CHUNK], SERVER_VERSION))
                await writer.drain()
            writer.write(encode_frame(Kind.UPLOAD_END, b"", SERVER_VERSION))
            return True
        if kind == Kind.UPLOAD_END_OK:
            return True
        self.junk += 1
        log.info("FOCAS transfer frame %#06x out of turn; closing", kind)
        return False

    def _store(self, target: str, text: bytes) -> int:
        name = _download_name(target, text)
        if name is None:
            log.info("FOCAS download into %r has no program name", target)
            return EW_DATA
        try:
            check_name(name)
            self.store.write(name, text)
        except (ValueError, OSError) as exc:
            log.info("FOCAS download of %s refused: %s", name, exc)
            return EW_DATA
        self.downloads += 1
        log.info("FOCAS download stored %s (%d bytes)", name, len(text))
        return 0


class _Session:
    __slots__ = ("download", "open", "overflow", "target", "transfer")

    def __init__(self) -> None:
        self.open = False
        self.transfer = False
        self.download: bytearray | None = None
        self.target = ""
        self.overflow = False


def _download_name(target: str, text: bytes) -> str | None:
    """The file a download lands in: the start frame's name after the folder, else the program's own."""
    rest = target.removeprefix(FOLDER)
    rest = rest.removeprefix("N:")
    if rest and not rest.endswith("/") and "/" not in rest:
        return rest
    m = _HEADER_NAME.match(text)
    if m is None:
        return None
    return (m["name"] or m["o"]).decode("ascii")


def _upload_name(requested: str) -> str:
    name = requested.removeprefix(FOLDER)
    first, dash, last = name.partition("-")
    if dash and first == last:  # O1234-O1234: a range of one
        name = first
    return name
