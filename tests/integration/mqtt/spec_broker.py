"""A broker written from the MQTT specification (3.1.1 and 5, the parts a publisher meets), for tests.

Not Mosquitto, and not our code: what it sees and answers follows the standard's
packet layouts (MQTT 3.1.1 §2-3, MQTT 5 §2-3), so that the gateway's own QoS 1
encoding and its reading of PUBACKs are checked against a second reading of the
spec. It records every PUBLISH as it arrived (flags, packet id, topic, payload,
which connection) and answers QoS 1 by policy: at once, all the PUBACKs of one
read in one write (`hold=False`); not until `release()` (`hold=True`); or with
the bytes a test chooses (`answer`), to send junk on the acknowledgement path.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Seen:
    connection: int
    topic: str
    payload: bytes
    qos: int
    retain: bool
    dup: bool
    packet_id: int | None


def varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | 0x80 if n else byte)
        if not n:
            return bytes(out)


def puback(packet_id: int, reason: int | None = None) -> bytes:
    """MQTT 3.1.1 §3.4 / MQTT 5 §3.4: the short form without a reason code, or with one."""
    body = packet_id.to_bytes(2, "big") + (bytes((reason,)) if reason is not None else b"")
    return b"\x40" + varint(len(body)) + body


@dataclass
class SpecBroker:
    v5: bool = False
    hold: bool = False
    receive_maximum: int | None = None  # MQTT 5: said in the CONNACK
    answer: Callable[[Seen], bytes | None] | None = None  # the bytes to answer a QoS 1 PUBLISH with
    seen: list[Seen] = field(default_factory=list)
    connections: int = 0
    port: int = 0
    held: list[int] = field(default_factory=list)
    _server: asyncio.Server | None = None
    _writers: list[asyncio.StreamWriter] = field(default_factory=list)

    async def start(self, port: int) -> SpecBroker:
        self._server = await asyncio.start_server(self._serve, "127.0.0.1", port)
        self.port = port
        return self

    async def stop(self) -> None:
        self.drop()
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    def drop(self) -> None:
        """End every connection at once, as a broker that dies does (no DISCONNECT)."""
        for writer in self._writers:
            writer.transport.abort()
        self._writers.clear()
        self.held.clear()

    def release(self) -> None:
        """Acknowledge every held PUBLISH, in one write, and stop holding."""
        self.hold = False
        if self._writers and self.held:
            self._writers[-1].write(b"".join(puback(pid) for pid in self.held))
        self.held.clear()

    def outstanding(self) -> int:
        return len(self.held)

    def published(self, topic: str) -> list[Seen]:
        return [s for s in self.seen if s.topic == topic]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        number = self.connections
        self._writers.append(writer)
        buf = bytearray()
        try:
            while True:
                data = await reader.read(65536)
                if not data:
                    return
                buf += data
                out = bytearray()
                while True:
                    packet = _split(buf)
                    if packet is None:
                        break
                    kind, flags, body = packet
                    out += self._handle(number, kind, flags, body)
                if out:
                    writer.write(bytes(out))
        except (ConnectionError, ValueError):
            return
        finally:
            with contextlib.suppress(ValueError):
                self._writers.remove(writer)
            writer.transport.abort()

    def _handle(self, number: int, kind: int, flags: int, body: bytes) -> bytes:
        if kind == 1:  # CONNECT → CONNACK: session present 0, accepted
            if not self.v5:
                return b"\x20\x02\x00\x00"
            props = b""
            if self.receive_maximum is not None:
                props = b"\x21" + self.receive_maximum.to_bytes(2, "big")  # Receive Maximum
            rest = b"\x00\x00" + varint(len(props)) + props
            return b"\x20" + varint(len(rest)) + rest
        if kind == 3:
            return self._publish(number, flags, body)
        if kind == 8:  # SUBSCRIBE → SUBACK granting QoS 1 to each filter
            pid, at = body[:2], 2
            if self.v5:
                length, at = _read_varint(body, at)
                at += length
            filters = 0
            while at < len(body):
                size = int.from_bytes(body[at : at + 2], "big")
                at += 2 + size + 1
                filters += 1
            rest = pid + (b"\x00" if self.v5 else b"") + b"\x01" * filters
            return b"\x90" + varint(len(rest)) + rest
        if kind == 10:  # UNSUBSCRIBE → UNSUBACK
            rest = body[:2] + (b"\x00" if self.v5 else b"")
            return b"\xb0" + varint(len(rest)) + rest
        if kind == 12:  # PINGREQ → PINGRESP
            return b"\xd0\x00"
        return b""

    def _publish(self, number: int, flags: int, body: bytes) -> bytes:
        qos = (flags >> 1) & 0x03
        size = int.from_bytes(body[:2], "big")
        topic = body[2 : 2 + size].decode("utf-8")
        at = 2 + size
        pid = None
        if qos:
            pid = int.from_bytes(body[at : at + 2], "big")
            at += 2
        if self.v5:
            length, at = _read_varint(body, at)
            at += length
        seen = Seen(number, topic, body[at:], qos, bool(flags & 0x01), bool(flags & 0x08), pid)
        self.seen.append(seen)
        if qos != 1 or pid is None:
            return b""
        if self.answer is not None:
            chosen = self.answer(seen)
            if chosen is not None:
                return chosen
        if self.hold:
            self.held.append(pid)
            return b""
        return puback(pid)


def _read_varint(buf: bytes | bytearray, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if at >= len(buf):
            raise ValueError("truncated variable byte integer")
        byte = buf[at]
        at += 1
        value |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return value, at
        shift += 7
        if shift > 21:
            raise ValueError("variable byte integer of more than 4 bytes")


def _split(buf: bytearray) -> tuple[int, int, bytes] | None:
    """The first whole packet of `buf` (taken out of it): type, flags, the rest; None until it is whole."""
    if len(buf) < 2:
        return None
    try:
        length, at = _read_varint(buf, 1)
    except ValueError:
        if len(buf) < 5:
            return None
        raise
    if len(buf) < at + length:
        return None
    first = buf[0]
    body = bytes(buf[at : at + length])
    del buf[: at + length]
    return first >> 4, first & 0x0F, body
