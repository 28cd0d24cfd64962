"""The agent's HTTP face: the one module that imports aiohttp's server side.

Every GET goes to `Agent.answer()` (probe, current, sample, assets, errors), except
requests with `interval=`, which stream: `multipart/x-mixed-replace`, one MTConnectStreams
document per part (http://…/sample?from=…&interval=…), at most one part per `interval`
ms, and an empty document after `heartbeat` ms of silence so that the client knows the
agent is alive. A client that falls so far behind that the ring overwrote what it has
not read yet gets an OUT_OF_RANGE MTConnectError part and the stream ends: a stream
never goes on past a gap it did not report.

A client that goes away is noticed at the next part (at the latest a heartbeat later);
stopping the agent cancels every stream. Connections are capped and slow ones closed by the listener both
HTTP faces share (gateway/sinks/http_listener.py, `mtconnect.connections`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from collections import OrderedDict
from typing import Self

from aiohttp import web

from gateway.codecs.mtconnect.buffer import ObservationBuffer
from gateway.codecs.mtconnect.documents import streams_xml
from gateway.codecs.mtconnect.errors import ErrorCode, OutOfRange, RequestError
from gateway.codecs.mtconnect.json_documents import streams_json
from gateway.codecs.mtconnect.multipart import encode_part, part_head
from gateway.codecs.mtconnect.queries import MAX_TARGET, Request
from gateway.sinks.http_listener import Limits, Listener
from gateway.sinks.mtconnect.agent import JSON, XML, Agent, Answer

log = logging.getLogger("gateway.sinks.mtconnect")

CHUNKS_KEPT = 32
MAX_LINE = MAX_TARGET + 1024  # a long request line is answered with INVALID_URI, not aiohttp's bare 400


class AgentServer:
    """aiohttp's server around an Agent; `async with AgentServer(agent, host, port) as server:`."""

    def __init__(
        self, agent: Agent, host: str, port: int, *, max_streams: int = 64, limits: Limits | None = None
    ) -> None:
        self.agent = agent
        self.host = host
        self.port = port
        self.max_streams = max_streams
        self.streams: set[asyncio.Task[object]] = set()
        self.parts_sent = 0
        self.parts_shared = 0  # chunks rendered once for several streams at the same place
        # The last chunks rendered, by (items, from, to, count, format): streams that follow the
        # agent together ask for the same chunk, and render it once between them.
        self.chunks: OrderedDict[tuple[object, ...], tuple[bytes, int, bool]] = OrderedDict()
        self.listener = Listener(
            name="the MTConnect agent",
            limits=limits or Limits(),
            shutdown_timeout=0.5,
            max_line_size=MAX_LINE,
        )

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "", "::") else self.host
        return f"http://{host}:{self.port}"

    async def __aenter__(self) -> Self:
        app = web.Application()
        app.router.add_route("*", "/{tail:.*}", self.handle)
        await self.listener.start(app, self.host, self.port)
        self.port = self.listener.port
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        for task in list(self.streams):
            task.cancel()
        await self.listener.stop()

    async def handle(self, request: web.Request) -> web.StreamResponse:
        agent = self.agent
        target = request.raw_path
        accept = request.headers.get("Accept", "")
        if request.method not in ("GET", "HEAD"):
            refusal = RequestError(
                ErrorCode.UNSUPPORTED, f"{request.method[:20]} is not supported: the agent is read-only"
            )
            return _response(agent.error([refusal], "xml", status=405))
        try:
            parsed = agent.request(target, accept)
            if parsed.interval is not None and parsed.kind in ("sample", "current"):
                return await self.stream(request, parsed)
        except RequestError as exc:
            return _response(agent.error([exc], "json" if "format=json" in target.lower() else "xml"))
        return _response(agent.answer(target, accept))

    async def stream(self, http: web.Request, request: Request) -> web.StreamResponse:
        """A streamed /sample or /current. Refusals before the first part are plain error documents."""
        agent = self.agent
        buffer = agent.buffer
        items = agent.items(request)
        start = buffer.next_sequence if request.from_ is None else request.from_
        if request.kind == "sample":
            buffer.sample(items, from_=start, count=request.count)  # refuses a bad from/count now
        if len(self.streams) >= self.max_streams:
            refusal = RequestError(ErrorCode.TOO_MANY, f"the agent serves {self.max_streams} streams at once")
            return _response(agent.error([refusal], request.format, status=503))
        boundary = secrets.token_hex(16)
        response = web.StreamResponse(
            headers={
                "Content-Type": f"multipart/x-mixed-replace;boundary={boundary}",
                "Cache-Control": "no-cache, no-store",
            }
        )
        await response.prepare(http)
        task = asyncio.current_task()
        assert task is not None
        self.streams.add(task)
        content_type = JSON if request.format == "json" else XML
        try:
            await _Stream(self, response, boundary, content_type, request, items, start).run()
        except (ConnectionError, asyncio.CancelledError):
            pass  # the client went away, or the agent stops
        finally:
            self.streams.discard(task)
        with contextlib.suppress(ConnectionError):
            await response.write_eof()
        return response


class _Stream:
    def __init__(
        self,
        server: AgentServer,
        response: web.StreamResponse,
        boundary: str,
        content_type: str,
        request: Request,
        items: frozenset[str] | None,
        start: int,
    ) -> None:
        self.server = server
        self.agent = server.agent
        self.response = response
        self.boundary = boundary
        self.content_type = content_type
        self.request = request
        self.items = items
        self.next = start

    async def send(self, body: str) -> None:
        await self.send_bytes(body.encode("utf-8"))

    async def send_bytes(self, body: bytes) -> None:
        if len(body) < 65536:
            await self.response.write(encode_part(self.boundary, body, self.content_type))
        else:  # a large shared chunk goes out as it is, not copied into one part per stream
            await self.response.write(part_head(self.boundary, len(body), self.content_type))
            await self.response.write(body)
            await self.response.write(b"\r\n")
        self.server.parts_sent += 1

    def chunk(self, buffer: ObservationBuffer) -> tuple[bytes, int, bool]:
        """The next chunk from `self.next`: (document, next sequence, whether it has observations)."""
        request = self.request
        key = (buffer.instance_id, self.items, self.next, buffer.next_sequence, request.count, request.format)
        cache = self.server.chunks
        found = cache.get(key)
        if found is not None:
            self.server.parts_shared += 1
            return found
        result = buffer.sample(self.items, from_=self.next, count=request.count)
        nxt = result.window.next_sequence
        made = (self.document(list(result.entries), nxt).encode("utf-8"), nxt, bool(result.entries))
        cache[key] = made
        while len(cache) > CHUNKS_KEPT:
            cache.popitem(last=False)
        return made

    def document(self, entries: list[object], next_sequence: int) -> str:
        buffer: ObservationBuffer = self.agent.buffer
        window = buffer.window(next_sequence)
        render = streams_json if self.request.format == "json" else streams_xml
        return render(self.agent.catalog, entries, window, self.agent.info())  # type: ignore[arg-type]

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        request = self.request
        interval = (request.interval or 0) / 1000.0
        heartbeat = request.heartbeat / 1000.0
        buffer = self.agent.buffer
        last = -1e9
        if request.kind == "current":
            while True:
                await self.send(self.agent.current(request).body)
                await asyncio.sleep(max(interval, 0.01))
        while True:
            wake = self.agent.changed()
            first = buffer.first_sequence
            if self.next < first:
                gap = OutOfRange(
                    "from", self.next, first, buffer.next_sequence,
                    f"the client fell behind: sequences {self.next} to {first - 1} were overwritten before "
                    "they could be sent; start again from /current",
                )  # fmt: skip
                await self.send(self.agent.error([gap], request.format).body)
                return
            now = loop.time()
            if self.next < buffer.next_sequence:
                body, self.next, full = self.chunk(buffer)
                if full or now - last >= heartbeat:
                    await self.send_bytes(body)
                    last = now
                if interval > 0:  # on a grid: streams of one interval wake together and share their chunks
                    await asyncio.sleep(interval - loop.time() % interval)
                else:
                    await asyncio.sleep(0)
                continue
            left = heartbeat - (now - last)
            if left <= 0:
                await self.send(self.document([], self.next))
                last = now
                continue
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(wake.wait(), left)


def _response(answer: Answer) -> web.Response:
    return web.Response(status=answer.status, body=answer.body.encode("utf-8"), content_type=None,
                        headers={"Content-Type": answer.content_type})  # fmt: skip
