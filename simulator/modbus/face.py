"""`ModbusFace`: Modbus TCP served from a `RegisterImage` (port 5502 by default: 502 needs privileges).

One task per client connection; requests are answered in order, each from the image as it is at that
moment. The unit id of a request must be the face's (`unit`), 0 or 255 (what TCP devices accept for
"this device"); any other is answered GATEWAY TARGET DEVICE FAILED TO RESPOND, as a Modbus gateway with
nothing behind that unit does. Bytes that are not Modbus TCP close the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Self

from gateway.codecs.modbus.frames import (
    ExceptionCode,
    FrameError,
    FrameReader,
    Refused,
    exception_response,
    frame,
    parse_request,
)
from simulator.errors import SimulatorError
from simulator.modbus.image import RegisterImage

log = logging.getLogger("simulator.modbus")

DEFAULT_PORT = 5502


class ModbusFace:
    def __init__(
        self, image: RegisterImage, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, unit: int = 1
    ) -> None:
        self.image = image
        self.host = host
        self.port = port
        self.unit = unit
        self.connections = 0
        self._server: asyncio.Server | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._writers: set[asyncio.StreamWriter] = set()

    @property
    def url(self) -> str:
        return f"modbus://{self.host}:{self.port}"

    async def __aenter__(self) -> Self:
        try:
            self._server = await asyncio.start_server(self._serve, self.host, self.port)
        except OSError as exc:
            raise SimulatorError(
                f"Modbus face cannot listen on {self.host}:{self.port}: {exc.strerror or exc}"
            ) from None
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.transport.abort()  # each client's read ends: its task finishes on its own
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=2)
        for task in list(self._tasks):
            task.cancel()
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    def respond(self, unit: int, pdu: bytes) -> bytes:
        """The response PDU to one request PDU."""
        if unit not in (self.unit, 0, 255):
            function = pdu[0] if pdu else 0
            return exception_response(function, ExceptionCode.GATEWAY_TARGET_NO_RESPONSE)
        try:
            return self.image.answer(parse_request(pdu))
        except Refused as refused:
            log.debug("Modbus request refused: %s", refused)
            return exception_response(refused.function, refused.code)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.add(writer)
        self.connections += 1
        peer = writer.get_extra_info("peername")
        frames = FrameReader()
        try:
            while data := await reader.read(4096):
                out = [frame(a.transaction, a.unit, self.respond(a.unit, a.pdu)) for a in frames.feed(data)]
                if out:
                    writer.write(b"".join(out))
        except FrameError as exc:
            log.info("Modbus client %s sent what is not Modbus TCP (%s); closing", peer, exc)
        except ConnectionError:
            pass
        finally:
            self._tasks.discard(task)
            self._writers.discard(writer)
            writer.transport.abort()
