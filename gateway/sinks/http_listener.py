"""The listener both HTTP faces share (the web console and API, the MTConnect agent): aiohttp's server
behind a guard that caps connections and closes the slow ones.

Issue 23: with no cap and aiohttp's keep-alive of 3,630 s, 420 unfinished GETs to one face took the
process to its open-file limit, and every other door (OPC UA, the FTP inbox, the other HTTP face) stopped
accepting. The guard is an asyncio protocol in front of aiohttp's, one per TCP connection:

- a connection beyond `per_address` from one address is refused at once (503, closed);
- at `max` connections, the oldest connection that is *waiting* (no request yet, or idle between
  requests) is closed to make room: a slow-loris crowd keeps pushing itself out, while a client that
  sends its request at once gets through; only when every connection is busy is a new one refused;
- a new connection that has not sent its whole request line and headers (TLS handshake included) within
  `header_timeout` is closed (408); after a response, aiohttp's keep-alive timer gives the next request
  `keepalive` seconds, its headers included;
- a response the client stops reading (the socket's buffer full for `STALLED_SEND` seconds) is aborted.

`max` never exceeds a quarter of the process's open-file limit (`descriptor_share`), so the two HTTP faces
together hold at most half the descriptors and the other doors keep theirs; a larger configured value is
lowered, with a warning. TLS is done here, after a connection is admitted (asyncio's `start_tls`), so
that a crowd of unfinished handshakes is capped and timed out like the rest.

Busy and waiting are told apart by a middleware that each request passes through: a connection is busy
from the moment its handler starts until its response is written (WebSockets and MTConnect streams stay
busy for as long as they last).
"""

from __future__ import annotations

import asyncio
import logging
import os
import resource
import socket
import ssl
import time
from collections import Counter, OrderedDict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from aiohttp import web

from gateway.errors import SinkError
from gateway.sinks.http_limits import ConnectionLimits

log = logging.getLogger("gateway.http")

STALLED_SEND = 60.0  # s a response may wait for a client that does not read before the connection is aborted
BACKLOG = 32  # asyncio accepts up to this many at once, past the cap until the guard sees them
QUEUE = 1024  # the kernel's queue of connections not yet accepted (no descriptor of ours): absorbs bursts
SHARE = 4  # each HTTP face holds at most 1/SHARE of the open-file limit
MOST = 1024  # and at most this many connections when the limit is very high
REPORT_EVERY = 60.0  # s between the log's summaries of refused and closed connections
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain\r\nConnection: close\r\nRetry-After: 5\r\n"
    b"Content-Length: 31\r\n\r\ntoo many connections; try again"
)
TIMEOUT = b"HTTP/1.1 408 Request Timeout\r\nConnection: close\r\nContent-Length: 0\r\n\r\n"

Factory = Callable[[], asyncio.Protocol]


@dataclass(frozen=True, slots=True)
class Limits:
    """The guard's settings (the config's `connections:`); `max` None: `descriptor_share()`."""

    max: int | None = None
    per_address: int = 32
    header_timeout: float = 10.0
    keepalive: float = 30.0

    @classmethod
    def of(cls, config: ConnectionLimits) -> Limits:
        return cls(config.max, config.per_address, config.header_timeout, config.keepalive)


def descriptor_share() -> int:
    """The most connections one HTTP face may hold: a quarter of the open-file limit, at most MOST."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return MOST
    return max(8, min(MOST, soft // SHARE - BACKLOG))


class _Connection(asyncio.Protocol):
    """One TCP connection: admitted or refused by the guard, then handed to aiohttp's protocol."""

    def __init__(self, guard: Guard) -> None:
        self.guard = guard
        self.inner: asyncio.Protocol | None = None
        self.raw: asyncio.Transport | None = None
        self.transport: asyncio.Transport | None = None  # what aiohttp writes to (the TLS one, with TLS)
        self.address = ""
        self.busy = 0
        self.admitted = False
        self.timer: asyncio.TimerHandle | None = None
        self.stall: asyncio.TimerHandle | None = None
        self.handshake: asyncio.Task[None] | None = None
        self.early: list[bytes] = []

    # --- asyncio's side ---------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.raw = transport
        peer = transport.get_extra_info("peername")
        self.address = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        refusal = self.guard.admit(self)
        if refusal is not None:
            if self.guard.tls is None:
                transport.write(BUSY)
            transport.close()
            return
        self.admitted = True
        loop = asyncio.get_running_loop()
        self.timer = loop.call_later(self.guard.limits.header_timeout, self._timed_out)
        if self.guard.tls is None:
            self._open(transport)
        else:
            self.handshake = loop.create_task(self._start_tls(transport, self.guard.tls))

    def data_received(self, data: bytes) -> None:
        if self.inner is not None:
            self.inner.data_received(data)
        elif self.admitted:  # TLS hands over what came with the handshake's end before start_tls returns
            self.early.append(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received() if self.inner is not None else None

    def pause_writing(self) -> None:
        self.stall = asyncio.get_running_loop().call_later(STALLED_SEND, self._stalled)
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None
        if self.inner is not None:
            self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        self._release()
        if self.inner is not None:
            self.inner.connection_lost(exc)

    # --- the guard's side -------------------------------------------------------------------------

    def _open(self, transport: asyncio.Transport) -> None:
        self.transport = transport
        self.inner = self.guard.factory()
        self.guard.by_transport[transport] = self
        self.inner.connection_made(transport)
        early, self.early = self.early, []
        for data in early:
            self.inner.data_received(data)

    async def _start_tls(self, raw: asyncio.Transport, context: ssl.SSLContext) -> None:
        loop = asyncio.get_running_loop()
        try:
            # asyncio's own handshake timeout only backs up the guard's (which fires first, and counts it)
            timeout = self.guard.limits.header_timeout + 5.0
            tls = await loop.start_tls(raw, self, context, server_side=True, ssl_handshake_timeout=timeout)
        except (OSError, ssl.SSLError, TimeoutError, ConnectionError):
            self._release()  # start_tls closed the socket; the TLS protocol never tells us it was lost
            return
        except asyncio.CancelledError:
            raw.abort()
            self._release()
            raise
        if tls is None:  # pragma: no cover - the handshake ended with the connection
            self._release()
            return
        self._open(tls)

    def _timed_out(self) -> None:
        self.timer = None
        if self.busy or not self.admitted:
            return
        self.guard.count("header timeouts", self.address)
        transport = self.transport
        if transport is not None:
            transport.write(TIMEOUT)
            transport.close()
        else:  # still in its TLS handshake
            self.close()

    def _stalled(self) -> None:
        self.stall = None
        self.guard.count("stalled sends", self.address)
        self.close()

    def close(self) -> None:
        """Close now: nothing this connection still waits to send matters."""
        if self.handshake is not None and not self.handshake.done():
            self.handshake.cancel()
        for transport in (self.transport, self.raw):
            if transport is not None:
                transport.abort()

    def _release(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None
        if self.admitted:
            self.admitted = False
            self.guard.release(self)


class Guard:
    """The connections of one face: admission, the waiting ones in age order, and what was refused."""

    def __init__(self, name: str, limits: Limits, tls: ssl.SSLContext | None = None) -> None:
        self.name = name
        self.limits = limits
        self.tls = tls
        self.max = descriptor_share() if limits.max is None else min(limits.max, descriptor_share())
        self.factory: Factory = _no_factory
        self.open: set[_Connection] = set()
        self.waiting: OrderedDict[_Connection, None] = OrderedDict()  # no request under way, oldest first
        self.per_address: Counter[str] = Counter()
        self.by_transport: dict[asyncio.BaseTransport, _Connection] = {}
        self.counts: Counter[str] = Counter()  # since start: refused, evicted, timed out, by kind
        self.peak = 0
        self._recent: Counter[str] = Counter()
        self._addresses: Counter[str] = Counter()
        self._reported = 0.0
        if limits.max is not None and limits.max > self.max:
            log.warning(
                "%s: connections.max %d is lowered to %d, a quarter of this process's open-file limit "
                "(ulimit -n), so that the other doors keep their descriptors",
                name,
                limits.max,
                self.max,
            )

    def protocol(self, factory: Factory) -> Factory:
        """The protocol factory to listen with, in front of aiohttp's `factory`."""
        self.factory = factory
        return lambda: _Connection(self)

    def admit(self, conn: _Connection) -> str | None:
        """None when `conn` may stay, else why not (it is then closed)."""
        if self.per_address[conn.address] >= self.limits.per_address:
            self.count("refused: per-address cap", conn.address)
            return "per-address cap"
        if len(self.open) >= self.max:
            if not self.waiting:
                self.count("refused: every connection busy", conn.address)
                return "full"
            oldest = next(iter(self.waiting))
            self.count("closed to make room", oldest.address)
            self.release(oldest)
            oldest.close()
        self.open.add(conn)
        self.waiting[conn] = None
        self.per_address[conn.address] += 1
        self.peak = max(self.peak, len(self.open))
        return None

    def release(self, conn: _Connection) -> None:
        if conn not in self.open:
            return
        self.open.discard(conn)
        self.waiting.pop(conn, None)
        for transport in (conn.transport, conn.raw):
            if transport is not None:
                self.by_transport.pop(transport, None)
        self.per_address[conn.address] -= 1
        if self.per_address[conn.address] <= 0:
            del self.per_address[conn.address]

    def started(self, transport: asyncio.BaseTransport | None) -> _Connection | None:
        """A request's handler starts: its connection is busy (not to be closed for room, nor timed out)."""
        conn = self.by_transport.get(transport) if transport is not None else None
        if conn is None:
            return None
        conn.busy += 1
        self.waiting.pop(conn, None)
        if conn.timer is not None:
            conn.timer.cancel()
            conn.timer = None
        return conn

    def finished(self, conn: _Connection) -> None:
        """A request's response is written: its connection waits for the next (aiohttp times that)."""
        conn.busy -= 1
        if conn.busy == 0 and conn in self.open:
            self.waiting[conn] = None

    def count(self, what: str, address: str) -> None:
        self.counts[what] += 1
        self._recent[what] += 1
        self._addresses[address] += 1
        now = time.monotonic()
        if now - self._reported >= REPORT_EVERY:
            self.report(now)

    def report(self, now: float | None = None) -> None:
        """One log line for what was refused or closed since the last one."""
        if not self._recent:
            return
        top = ", ".join(f"{a} ({n})" for a, n in self._addresses.most_common(3))
        log.warning(
            "%s: %s (%d connections open, cap %d, %d per address); most from %s",
            self.name,
            ", ".join(f"{n} {what}" for what, n in self._recent.items()),
            len(self.open),
            self.max,
            self.limits.per_address,
            top,
        )
        self._recent.clear()
        self._addresses.clear()
        self._reported = time.monotonic() if now is None else now

    def close_all(self) -> None:
        for conn in list(self.open):
            conn.close()
            self.release(conn)


def _no_factory() -> asyncio.Protocol:  # pragma: no cover - replaced by protocol() before listening
    raise RuntimeError("the guard has no protocol factory")


Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class _Site(web.BaseSite):
    """aiohttp's TCPSite, listening through the guard (TLS is the guard's too)."""

    def __init__(self, runner: web.BaseRunner, host: str, port: int, guard: Guard) -> None:
        super().__init__(runner, backlog=BACKLOG)
        self._host = host
        self._port = port
        self._guard = guard

    @property
    def name(self) -> str:
        return f"{'https' if self._guard.tls else 'http'}://{self._host}:{self._port}"

    async def start(self) -> None:
        await super().start()
        server = self._runner.server
        assert server is not None
        self._server = await asyncio.get_running_loop().create_server(
            self._guard.protocol(server), self._host, self._port, backlog=BACKLOG, reuse_address=True
        )
        for listening in self._server.sockets:
            # asyncio's backlog is both the kernel's queue and how many it accepts in one go; a longer
            # queue, set again on the same socket, keeps a burst of connections from dropping a
            # client's SYN (a one-second retransmit) without letting asyncio accept more at once.
            with socket.socket(fileno=os.dup(listening.fileno())) as sock:
                sock.listen(QUEUE)


class Listener:
    """aiohttp's runner for an app, behind a Guard that lasts across restarts. `port`: the bound port."""

    def __init__(
        self, *, name: str, limits: Limits, tls: ssl.SSLContext | None = None, **runner: Any
    ) -> None:
        self.guard = Guard(name, limits, tls)
        self.name = name
        self._runner_args = runner
        self._runner: web.AppRunner | None = None
        self.port = 0

    @web.middleware
    async def _busy(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        conn = self.guard.started(request.transport)
        if conn is not None:
            task = asyncio.current_task()  # aiohttp's task for this request, which also writes the response
            if task is not None:
                task.add_done_callback(lambda _: self.guard.finished(conn))
            else:  # pragma: no cover - aiohttp always runs a handler in a task
                self.guard.finished(conn)
        return await handler(request)

    async def start(self, app: web.Application, host: str, port: int) -> None:
        """Serve `app` (a new one per start: aiohttp freezes an app once it runs); SinkError if it cannot."""
        app.middlewares.append(self._busy)
        runner = web.AppRunner(
            app,
            access_log=None,
            handle_signals=False,
            keepalive_timeout=self.guard.limits.keepalive,
            **self._runner_args,
        )
        await runner.setup()
        site = _Site(runner, host, port, self.guard)
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise SinkError(f"{self.name} cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self._runner = runner
        for address in runner.addresses:
            if isinstance(address, tuple):
                self.port = int(address[1])
                break
        else:  # pragma: no cover - a TCP site always has an address
            self.port = port

    async def stop(self) -> None:
        runner, self._runner = self._runner, None
        if runner is not None:
            self.guard.report()
            await runner.cleanup()
        self.guard.close_all()
