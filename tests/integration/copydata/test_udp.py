"""A udp target: one datagram per frame, a snapshot at start and periodically, replies back as feedback."""

from __future__ import annotations

import asyncio
import struct
from typing import Any

from gateway.codecs.copydata import pack_tcp, unpack_datagram
from tests.integration.copydata.conftest import RigFactory, single, targets
from tests.waiting import free_port, wait_until


class Datagrams(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.received: list[tuple[bytes, Any]] = []
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.received.append((data, addr))


async def test_udp_frames_snapshots_and_replies(make_rig: RigFactory) -> None:
    port = free_port()
    loop = asyncio.get_running_loop()
    transport, receiver = await loop.create_datagram_endpoint(Datagrams, local_addr=("127.0.0.1", port))
    try:
        rig = await make_rig(targets({
            "name": "nesting", "transport": "udp", "host": "127.0.0.1", "port": port,
            "snapshot_interval": 0.2, "max_rate": None,
        }), loop_program="demo.nc")  # fmt: skip
        emitter = rig.emitter()
        await rig.connected()

        def decoded() -> list[tuple[int, dict[str, Any]]]:
            out = []
            for data, _ in list(receiver.received):
                frame = unpack_datagram(data, emitter.layout)  # exactly one frame per datagram
                out.append(
                    (
                        frame.dwdata,
                        {
                            r.variable.name: r.value
                            for r in emitter.encoder.table.decode(frame, emitter.layout)
                        },
                    )
                )
            return out

        full = {v.name for v in emitter.encoder.table}
        await wait_until(lambda: sum(1 for dw, v in decoded() if dw == 2 and set(v) == full) >= 2,
                         message="periodic full snapshots")  # fmt: skip
        x = "Axes/X/Position"
        await wait_until(lambda: len({v[x] for _, v in decoded() if x in v}) > 5, message="positions moving")

        # A reply from the receiver's address comes back as feedback.
        events = rig.machine.tree.events.subscribe("test")
        _, gateway_addr = receiver.received[-1]
        assert receiver.transport is not None
        receiver.transport.sendto(pack_tcp(single(5, struct.pack("<I", 77)), emitter.layout), gateway_addr)
        receiver.transport.sendto(b"\x09\x00\x00\x00garbage", gateway_addr)  # dropped, with a logged reason
        event = await wait_until(lambda: next(iter(events.take()), None), message="the reply as feedback")
        assert event.payload["items"] == [{"id": 5, "path": "Program/Block", "value": 77}]
        await wait_until(lambda: emitter.transport.bad_replies == 1, message="the bad datagram counted")  # type: ignore[union-attr]
    finally:
        transport.close()
