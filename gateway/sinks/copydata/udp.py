"""COPYDATA over UDP: one datagram per frame, `dwData | cbData | lpData`, to one receiver.

UDP has no connection, so the gateway cannot tell when a receiver starts:
a snapshot goes out when the transport starts and then every
`snapshot_interval` (5 s unless configured). Frames are limited to what one
datagram holds (larger snapshots are split). Datagrams coming back from the
receiver's address are replies; one that does not hold exactly one valid frame
is dropped with a logged reason. If the socket's buffer is full, frames are
dropped and counted, never queued without bound.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from gateway.codecs.copydata import TCP_HEADER, CopydataError, Frame, unpack_datagram
from gateway.reconnect import Backoff, OutageLog
from gateway.sinks.copydata.port import TransportPort
from gateway.sinks.copydata.socket_errors import os_reason

log = logging.getLogger("gateway.sinks.copydata")

REPLY_QUEUE = 100  # replies waiting to be handled; more are dropped (a flood must not grow memory)
BUFFER_LIMIT = 256 * 1024  # bytes asyncio may hold for the socket before frames are dropped


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, owner: UdpTransport) -> None:
        self.owner = owner

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.owner.received(data, addr)

    def error_received(self, exc: Exception) -> None:
        self.owner.error(exc)


class UdpTransport:
    def __init__(self, emitter: TransportPort) -> None:
        self.emitter = emitter
        self.target = emitter.target
        self.errors = 0  # e.g. ICMP port unreachable: nothing listens there (yet)
        self.overflows = 0
        self.bad_replies = 0
        self.replies_dropped = 0
        self._replies: asyncio.Queue[tuple[Frame, str]] = asyncio.Queue(REPLY_QUEUE)
        self._transport: asyncio.DatagramTransport | None = None
        self._last_error = ""

    def describe(self) -> str:
        return f"udp {self.target.host}:{self.target.port}"

    async def run(self) -> None:
        target, emitter = self.target, self.emitter
        assert target.host is not None and target.port is not None
        loop = asyncio.get_running_loop()
        backoff = Backoff.of(target.backoff)
        outage = OutageLog(log)
        while True:
            try:
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _Protocol(self), remote_addr=(target.host, target.port)
                )
                break
            except OSError as exc:
                delay, reason = backoff.next(), os_reason(exc)
                outage.failed(
                    reason, "copydata %s: cannot open a UDP socket to %s:%s: %s; retrying in %.1f s",
                    emitter.name, target.host, target.port, reason, delay,
                )  # fmt: skip
                emitter.set_state(f"not sending ({reason})")
                await asyncio.sleep(delay)
        if outage.down:
            outage.recovered("copydata %s: sending to %s:%s", emitter.name, target.host, target.port)
        self._transport = transport
        channel = emitter.open_channel(f"{target.host}:{target.port}")
        emitter.set_state("sending")
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._replies_worker(), name=f"copydata:{emitter.name}:replies")
                while True:
                    frames = await channel.next_frames()
                    for dwdata, lpdata in frames:
                        # Selector transports have it; typeshed's DatagramTransport does not say so.
                        buffered = transport.get_write_buffer_size()  # type: ignore[attr-defined]
                        if buffered > BUFFER_LIMIT:
                            self.overflows += 1
                            channel.dropped += 1
                            continue
                        transport.sendto(TCP_HEADER.pack(dwdata, len(lpdata)) + lpdata)
                        channel.sent += 1
        finally:
            emitter.close_channel(channel)
            transport.close()
            self._transport = None

    # --- from the protocol (event loop callbacks, never blocking) --------------------------------

    def received(self, data: bytes, addr: Any) -> None:
        peer = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else str(addr)
        emitter = self.emitter
        try:
            frame = unpack_datagram(data, emitter.layout)
        except CopydataError as exc:
            self.bad_replies += 1
            emitter.throttle.log(
                f"copydata {emitter.name} malformed", logging.WARNING,
                "copydata %s: dropping a datagram from %s: malformed frame (%s): %s",
                emitter.name, peer, exc.kind, exc,
            )  # fmt: skip
            return
        try:
            self._replies.put_nowait((frame, peer))
        except asyncio.QueueFull:
            self.replies_dropped += 1

    def error(self, exc: Exception) -> None:
        self.errors += 1
        reason = os_reason(exc)
        if reason != self._last_error:
            self._last_error = reason
            log.info("copydata %s: %s:%s: %s (is the receiver running?)",
                     self.emitter.name, self.target.host, self.target.port, reason)  # fmt: skip

    async def _replies_worker(self) -> None:
        while True:
            frame, peer = await self._replies.get()
            await self.emitter.on_frame(frame, peer)
