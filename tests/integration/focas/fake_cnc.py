"""A fake Fanuc for the corpus: answers like the simulator, except where a case says otherwise."""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import AsyncIterator
from typing import Any

from gateway.codecs.focas import functions as fn
from gateway.codecs.focas.commands import Reply, decode_request, response_frame
from gateway.codecs.focas.frame import SERVER_VERSION, Frame, FrameReader, Kind, encode_frame
from gateway.codecs.focas.values import VACANT
from simulator.focas.controller import FocasCnc
from simulator.machine import Machine
from simulator.store import MemoryStore


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


class FakeCnc:
    """Serves one corpus case to every connection (the driver reconnects after a drop)."""

    def __init__(self, case: dict[str, Any]) -> None:
        self.case = case
        self.cnc = FocasCnc(Machine(MemoryStore()))
        self.connections = 0
        self.polls = 0

    @contextlib.asynccontextmanager
    async def serving(self) -> AsyncIterator[int]:
        tasks: set[asyncio.Task[None]] = set()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            task = asyncio.current_task()
            assert task is not None
            tasks.add(task)
            try:
                await self._serve(reader, writer)
            except (ConnectionError, asyncio.CancelledError):
                pass
            finally:
                writer.transport.abort()
                tasks.discard(task)

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        try:
            yield server.sockets[0].getsockname()[1]
        finally:
            server.close()
            for task in list(tasks):
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        case = self.case
        frames = FrameReader()
        while data := await reader.read(65536):
            for frame in frames.feed(data):
                assert isinstance(frame, Frame)
                if frame.kind == Kind.OPEN:
                    if case.get("close_on_open"):
                        return
                    answer = case.get("open")
                    writer.write(
                        hexbytes(answer) if answer else encode_frame(Kind.OPEN_OK, bytes(4), SERVER_VERSION)
                    )
                elif frame.kind == Kind.CLOSE:
                    writer.write(encode_frame(Kind.CLOSE_OK, b"", SERVER_VERSION))
                    return
                elif frame.kind == Kind.REQUEST:
                    commands = decode_request(frame.payload)
                    if any(c.function == fn.SYSINFO for c in commands):  # the session learning: answer it
                        writer.write(response_frame([self.cnc.answer(c) for c in commands]))
                        continue
                    self.polls += 1
                    if case.get("silent"):
                        await asyncio.sleep(3600)
                    if "raw" in case:
                        writer.write(hexbytes(case["raw"]))
                        await writer.drain()
                        if case.get("close"):
                            return
                        await asyncio.sleep(3600)
                    replies = []
                    for c in commands:
                        code = case.get("errors", {}).get(c.function)
                        if code is not None:
                            replies.append(Reply(c.function, code, b"", c.device, c.path))
                        elif c.function == fn.MACRO_READ and c.args[0] in case.get("vacant", ()):
                            replies.append(Reply(c.function, 0, VACANT, c.device, c.path))
                        else:
                            replies.append(self.cnc.answer(c))
                    writer.write(response_frame(replies))


__all__ = ["FakeCnc", "hexbytes", "struct"]
