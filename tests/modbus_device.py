"""A Modbus TCP device for the tests that is not pymodbus, with the oddities real devices have.

Written from the Modbus specification on the gateway's server-side frames codec
(gateway/codecs/modbus/frames.py, whose tests use the specification's own examples), so that the driver,
which speaks through pymodbus' client, is tested against another implementation. Its tables are sparse:
an address that was never given a value does not exist, and reading across it is ILLEGAL DATA ADDRESS,
as on devices with holes in their register map.

Quirks, each for the requests a predicate picks (by function and address) and optionally only a number
of times, make it answer as odd devices do:

- `wrong_tid`: echoes the transaction id plus one;
- `other_unit`: answers with another unit id;
- `short`: answers fewer registers (or bits) than asked, in a well-formed frame;
- `lying_count`: a byte count larger than the data that follows (the MBAP length is right);
- `truncated`: an MBAP length that promises more than is sent, then nothing;
- `garbage`: bytes that are not Modbus TCP;
- `silent`: no answer;
- `exception:N`: exception response N;
- `close`: closes the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Self

from gateway.codecs.modbus.address import Table
from gateway.codecs.modbus.frames import (
    ExceptionCode,
    FrameError,
    FrameReader,
    Read,
    Refused,
    Request,
    WriteBits,
    exception_response,
    frame,
    parse_request,
    read_bits_response,
    read_registers_response,
    write_response,
)

_READ = {1: Table.COIL, 2: Table.DISCRETE, 3: Table.HOLDING, 4: Table.INPUT}


@dataclass
class Quirk:
    kind: str
    picks: Callable[[Request], bool] = lambda _request: True
    times: int | None = None  # None: every time
    used: int = 0


@dataclass
class Seen:
    function: int
    address: int
    count: int
    unit: int


@dataclass
class OddDevice:
    unit: int = 1
    host: str = "127.0.0.1"
    port: int = 0
    tables: dict[Table, dict[int, int]] = field(default_factory=lambda: {t: {} for t in Table})
    read_only: set[tuple[Table, int]] = field(default_factory=set)
    quirks: list[Quirk] = field(default_factory=list)
    seen: list[Seen] = field(default_factory=list)
    connections: int = 0
    _server: asyncio.Server | None = None
    _writers: set[asyncio.StreamWriter] = field(default_factory=set)
    _tasks: set[asyncio.Task[None]] = field(default_factory=set)

    def set(self, table: Table, address: int, values: list[int]) -> None:
        for offset, value in enumerate(values):
            self.tables[table][address + offset] = value

    def get(self, table: Table, address: int, count: int = 1) -> list[int]:
        return [self.tables[table][a] for a in range(address, address + count)]

    def quirk(
        self, kind: str, picks: Callable[[Request], bool] = lambda _r: True, times: int | None = None
    ) -> Quirk:
        q = Quirk(kind, picks, times)
        self.quirks.append(q)
        return q

    def reads(self, function: int | None = None) -> list[Seen]:
        return [s for s in self.seen if function is None or s.function == function]

    async def __aenter__(self) -> Self:
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.stop()

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.transport.abort()
        if self._tasks:  # their reads end at once: nothing is left to be cancelled at the loop's end
            await asyncio.wait(list(self._tasks), timeout=2)
        if server is not None:
            with contextlib.suppress(Exception):
                await server.wait_closed()

    async def start(self) -> None:
        """Listen again on the same port (after stop(): the device restarted)."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)

    def _pick(self, request: Request) -> str | None:
        for q in self.quirks:
            if (q.times is None or q.used < q.times) and q.picks(request):
                q.used += 1
                return q.kind
        return None

    def _answer(self, request: Request) -> bytes:
        if isinstance(request, Read):
            table = _READ[request.function]
            values = self._values(request.function, table, request.address, request.count)
            if table.bits:
                return read_bits_response(request.function, [bool(v) for v in values])
            return read_registers_response(request.function, values)
        table = Table.COIL if isinstance(request, WriteBits) else Table.HOLDING
        addresses = range(request.address, request.address + len(request.values))
        self._values(request.function, table, request.address, len(request.values))
        if any((table, a) in self.read_only for a in addresses):
            raise Refused(request.function, ExceptionCode.ILLEGAL_DATA_ADDRESS, "read-only")
        self.set(table, request.address, [int(v) for v in request.values])
        return write_response(request)

    def _values(self, function: int, table: Table, address: int, count: int) -> list[int]:
        cells = self.tables[table]
        if any(a not in cells for a in range(address, address + count)):
            raise Refused(function, ExceptionCode.ILLEGAL_DATA_ADDRESS, "a hole in the map")
        return [cells[a] for a in range(address, address + count)]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        self._writers.add(writer)
        self.connections += 1
        frames = FrameReader()
        try:
            while data := await reader.read(4096):
                for adu in frames.feed(data):
                    out = self._respond(adu.transaction, adu.unit, adu.pdu)
                    if out == b"close":
                        return
                    if out:
                        writer.write(out)
        except (FrameError, ConnectionError):
            pass
        finally:
            self._tasks.discard(task)
            self._writers.discard(writer)
            writer.transport.abort()

    def _respond(self, tid: int, unit: int, pdu: bytes) -> bytes:
        try:
            request = parse_request(pdu)
        except Refused as refused:
            return frame(tid, unit, exception_response(refused.function, refused.code))
        count = request.count if isinstance(request, Read) else len(request.values)
        self.seen.append(Seen(request.function, request.address, count, unit))
        kind = self._pick(request)
        if kind == "silent":
            return b""
        if kind == "close":
            return b"close"
        if kind == "garbage":
            return b"HTTP/1.1 400 Bad Request\r\n\r\n"
        if kind is not None and kind.startswith("exception:"):
            return frame(tid, unit, exception_response(request.function, int(kind.split(":")[1])))
        try:
            answer = self._answer(request)
        except Refused as refused:
            return frame(tid, unit, exception_response(refused.function, refused.code))
        if kind == "wrong_tid":
            return frame(tid + 1, unit, answer)
        if kind == "other_unit":
            return frame(tid, unit + 1, answer)
        if kind == "short" and isinstance(request, Read):
            size = answer[1] - (2 if request.function in (3, 4) else 1)
            return frame(tid, unit, bytes((answer[0], size)) + answer[2 : 2 + size])
        if kind == "lying_count":
            return frame(tid, unit, bytes((answer[0], answer[1] + 8)) + answer[2:])
        if kind == "truncated":
            whole = frame(tid, unit, answer)
            return struct.pack(">HHH", tid, 0, len(answer) + 11) + whole[6:]
        return frame(tid, unit, answer)
