"""COPYDATA over TCP: `dwData (u32 LE) | cbData (u32 LE) | lpData`, frames back to back.

`tcp-client`: the gateway connects to the nesting software's listener, and
reconnects with backoff whenever the connection cannot be made or is lost.
`tcp-server`: the nesting software connects to the gateway; each client gets
its own channel (and so its own snapshot and its own bounded queue), up to
`max_clients`. If the port cannot be bound (another program holds it), the
gateway keeps running and tries again with backoff: the OPC UA and MQTT mirrors
matter more than this one link.

Both read what the peer sends back with the incremental decoder. A stream that
does not follow the format cannot be resynchronised, so it is closed, with the
reason in the log; other connections are not affected.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket

from gateway.codecs.copydata import TCP_HEADER, CopydataError, FrameDecoder
from gateway.reconnect import Backoff, OutageLog
from gateway.sinks.copydata.channel import Channel, OutFrame
from gateway.sinks.copydata.port import TransportPort
from gateway.sinks.copydata.socket_errors import os_reason

log = logging.getLogger("gateway.sinks.copydata")

READ_CHUNK = 65536
STABLE_AFTER = 10.0  # s a connection must last before the reconnect backoff starts again from `initial`
CLOSE_GRACE = 1.0  # s to flush and close politely before the connection is aborted


def pack(frames: list[OutFrame]) -> bytes:
    header = TCP_HEADER.pack
    return b"".join(header(dwdata, len(lpdata)) + lpdata for dwdata, lpdata in frames)


def peer_name(writer: asyncio.StreamWriter) -> str:
    peer = writer.get_extra_info("peername")
    if isinstance(peer, tuple) and len(peer) >= 2:
        host = f"[{peer[0]}]" if ":" in str(peer[0]) else str(peer[0])
        return f"{host}:{peer[1]}"
    return str(peer or "?")


def tune_socket(writer: asyncio.StreamWriter, send_buffer: int | None) -> None:
    """Small frames should leave at once (no Nagle delay); dead peers are noticed by keepalive.

    `send_buffer` caps both the kernel's send buffer and what asyncio buffers above it:
    frames that wait there for a slow receiver are stale by the time it reads them.
    """
    if send_buffer is not None:
        writer.transport.set_write_buffer_limits(high=send_buffer)
    sock = writer.get_extra_info("socket")
    if sock is None:
        return
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        if send_buffer is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, send_buffer)


async def serve_connection(
    emitter: TransportPort, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str
) -> str:
    """Send this connection its frames and read its replies until either side ends; returns why it ended."""
    channel = emitter.open_channel(peer)
    send = asyncio.create_task(_send(channel, writer), name=f"copydata:{emitter.name}:{peer}:send")
    receive = asyncio.create_task(
        _receive(emitter, reader, peer), name=f"copydata:{emitter.name}:{peer}:receive"
    )
    try:
        done, _ = await asyncio.wait({send, receive}, return_when=asyncio.FIRST_COMPLETED)
        task = done.pop()
        try:
            reason = task.result()
        except (ConnectionError, OSError) as exc:
            reason = f"connection lost: {os_reason(exc)}"
        except Exception:  # a bug must cost this connection, not the gateway
            log.exception("copydata %s: internal error serving %s", emitter.name, peer)
            reason = "internal error"
    finally:
        for task in (send, receive):
            task.cancel()
        await asyncio.gather(send, receive, return_exceptions=True)
        emitter.close_channel(channel)
        await _close(writer)
    return reason


async def _send(channel: Channel, writer: asyncio.StreamWriter) -> str:
    while True:
        frames = await channel.next_frames()
        writer.write(pack(frames))
        channel.sent += len(frames)
        await writer.drain()  # a receiver that does not read stops us here; its channel bounds the rest


async def _receive(emitter: TransportPort, reader: asyncio.StreamReader, peer: str) -> str:
    decoder = FrameDecoder(emitter.layout)
    while True:
        data = await reader.read(READ_CHUNK)
        try:
            if not data:
                decoder.feed_eof()
                return "closed by the receiver"
            frames = decoder.feed(data)
        except CopydataError as exc:
            for frame in exc.frames:  # complete frames that came before the fault still count
                await emitter.on_frame(frame, peer)
            emitter.throttle.log(
                f"copydata {emitter.name} malformed", logging.WARNING,
                "copydata %s: closing the connection from %s: malformed frame (%s): %s",
                emitter.name, peer, exc.kind, exc,
            )  # fmt: skip
            return f"malformed frame ({exc.kind})"
        for frame in frames:
            await emitter.on_frame(frame, peer)


async def _close(writer: asyncio.StreamWriter) -> None:
    if writer.transport.get_write_buffer_size():
        writer.transport.abort()  # frames still waiting for a peer that does not read: stale, drop them
        return
    writer.close()
    try:
        async with asyncio.timeout(CLOSE_GRACE):
            await writer.wait_closed()
    except (TimeoutError, ConnectionError, OSError):
        writer.transport.abort()  # a peer that reads nothing would keep the buffered frames forever


class TcpClientTransport:
    """The gateway connects to the nesting software, and reconnects with backoff."""

    def __init__(self, emitter: TransportPort) -> None:
        self.emitter = emitter
        self.target = emitter.target
        self.connects = 0
        self.attempts = 0
        self._writer: asyncio.StreamWriter | None = None

    def describe(self) -> str:
        return f"tcp-client {self.target.host}:{self.target.port}"

    @property
    def buffered(self) -> int:
        """Bytes asyncio holds for the current connection (bounded by send_buffer plus one batch)."""
        writer = self._writer
        return writer.transport.get_write_buffer_size() if writer is not None else 0

    async def run(self) -> None:
        target, emitter = self.target, self.emitter
        assert target.host is not None and target.port is not None
        backoff = Backoff.of(target.backoff, stable_after=STABLE_AFTER)
        outage = OutageLog(log)
        last_reason = ""
        while True:
            emitter.set_state("connecting" + (f" ({last_reason})" if last_reason else ""))
            try:
                # asyncio.timeout, not wait_for: on 3.11 wait_for loses a cancellation that
                # arrives as the connection attempt fails, and shutdown would then hang.
                async with asyncio.timeout(target.timeout):
                    reader, writer = await asyncio.open_connection(target.host, target.port)
            except (OSError, TimeoutError) as exc:
                reason = last_reason = os_reason(exc)
                self.attempts += 1
                delay = backoff.next()
                outage.failed(reason, "copydata %s: cannot connect to %s:%s: %s; retrying in %.1f s",
                              emitter.name, target.host, target.port, reason, delay)  # fmt: skip
                emitter.set_state(f"connecting ({reason})")
                await asyncio.sleep(delay)
                continue
            self.connects += 1
            tune_socket(writer, target.send_buffer)
            peer = peer_name(writer)
            outage.recovered("copydata %s: connected to %s", emitter.name, peer)
            emitter.set_state("connected")
            backoff.connected()
            self._writer = writer
            try:
                reason = await serve_connection(emitter, reader, writer, peer)
            finally:
                self._writer = None
            log.warning("copydata %s: connection to %s ended: %s", emitter.name, peer, reason)
            last_reason = reason
            backoff.ended()
            emitter.set_state(f"connecting ({reason})")
            await asyncio.sleep(backoff.next())


class TcpServerTransport:
    """The nesting software connects to the gateway; every client gets its own snapshot and queue."""

    def __init__(self, emitter: TransportPort) -> None:
        self.emitter = emitter
        self.target = emitter.target
        self.port = self.target.listen_port  # the real one once bound (port 0: any free port)
        self.listening = asyncio.Event()
        self.accepted = 0
        self.refused = 0
        self.closed_malformed = 0
        self._clients: set[asyncio.Task[None]] = set()

    def describe(self) -> str:
        return f"tcp-server {self.target.listen_address}:{self.port}"

    def _listening(self) -> None:
        clients = len(self._clients)
        self.emitter.set_state(f"listening, {clients} client{'s' if clients != 1 else ''}")

    async def run(self) -> None:
        target, emitter = self.target, self.emitter
        backoff = Backoff.of(target.backoff)
        outage = OutageLog(log)
        while True:
            try:
                server = await asyncio.start_server(
                    self._client, target.listen_address, target.listen_port, reuse_address=True
                )
            except OSError as exc:
                reason = os_reason(exc)
                delay = backoff.next()
                outage.failed(reason, "copydata %s: cannot listen on %s:%s: %s; trying again in %.1f s",
                              emitter.name, target.listen_address, target.listen_port, reason, delay,
                              level=logging.ERROR)  # fmt: skip
                emitter.set_state(f"not listening ({reason})")
                await asyncio.sleep(delay)
                continue
            try:
                self.port = server.sockets[0].getsockname()[1]
                self.listening.set()
                self._listening()
                outage.recovered(
                    "copydata %s: listening on %s:%s", emitter.name, target.listen_address, self.port
                )
                await asyncio.Future()  # serve until cancelled
            finally:
                self.listening.clear()
                server.close()
                await self._stop_clients()
                with contextlib.suppress(TimeoutError, OSError):
                    async with asyncio.timeout(CLOSE_GRACE):
                        await server.wait_closed()

    async def _stop_clients(self) -> None:
        clients = list(self._clients)
        for task in clients:
            task.cancel()
        await asyncio.gather(*clients, return_exceptions=True)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        emitter = self.emitter
        peer = peer_name(writer)
        if len(self._clients) >= self.target.max_clients:
            self.refused += 1
            emitter.throttle.log(
                f"copydata {emitter.name} refused", logging.WARNING,
                "copydata %s: refusing %s: already serving max_clients=%d",
                emitter.name, peer, self.target.max_clients,
            )  # fmt: skip
            writer.transport.abort()
            return
        task.set_name(f"copydata:{emitter.name}:client:{peer}")
        self._clients.add(task)
        self.accepted += 1
        self._listening()
        tune_socket(writer, self.target.send_buffer)
        log.info("copydata %s: client %s connected", emitter.name, peer)
        try:
            reason = await serve_connection(emitter, reader, writer, peer)
            if reason.startswith("malformed"):
                self.closed_malformed += 1
            else:
                log.info("copydata %s: client %s left: %s", emitter.name, peer, reason)
        except asyncio.CancelledError:
            # Shutting down. This task belongs to asyncio's stream protocol, whose done-callback
            # (Python 3.11) logs a traceback for a cancelled task: end it normally instead.
            return
        finally:
            self._clients.discard(task)
            if self.listening.is_set():
                self._listening()
