"""Clients that send garbage to a tcp-server target get their connection closed with a logged reason;
the gateway and its other clients do not notice."""

from __future__ import annotations

import asyncio
import logging
import random
import struct

import pytest

from tests.integration.copydata.conftest import RigFactory, TcpReceiver, targets
from tests.waiting import wait_until

SEED = 20240501
MAX_CBDATA = 4096

# One of each way a stream can be wrong, then seeded random ones.
MALFORMED: list[tuple[str, bytes]] = [
    ("unknown dwData", struct.pack("<II", 7, 4) + b"\x01\x00\x00\x00"),
    ("cbData over max_cbdata", struct.pack("<II", 2, MAX_CBDATA + 1)),
    ("length past the end", struct.pack("<II", 2, 6) + b"\x01\x00\xff\x00\x00\x00"),
    ("dwData=1 with two items", struct.pack("<II", 1, 10) + b"\x01\x00\x01\x00\x01\x05\x00\x01\x00\x02"),
    ("truncated header", struct.pack("<II", 2, 3) + b"\x01\x00\x02"),
    ("empty lpData", struct.pack("<II", 2, 0)),
    ("stream ends inside a frame", struct.pack("<II", 1, 12) + b"\x01\x00"),
]


def random_streams(count: int) -> list[tuple[str, bytes]]:
    rng = random.Random(SEED)
    out = []
    for i in range(count):
        if i % 2:  # bytes of any kind
            data = rng.randbytes(rng.randint(1, 3000))
        else:  # a plausible header, then garbage: reaches the item parser
            cbdata = rng.randint(0, 200)
            data = struct.pack("<II", rng.choice((1, 2)), cbdata) + rng.randbytes(rng.randint(0, cbdata + 20))
        out.append((f"random stream {i}", data))
    return out


async def throw(port: int, data: bytes) -> bool:
    """Send, half-close, and report whether the gateway closed the connection (it must, soon)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        await writer.drain()
        writer.write_eof()
        async with asyncio.timeout(10):
            while await reader.read(65536):
                pass  # its snapshot and frames, until it closes
        return True
    except ConnectionError:
        return True  # reset: closed as well
    finally:
        writer.close()


async def test_a_flood_of_malformed_streams_leaves_the_gateway_and_other_clients_alone(
    make_rig: RigFactory, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="gateway.sinks.copydata")
    rig = await make_rig(targets({
        "name": "nesting", "transport": "tcp-server", "bind": "127.0.0.1", "port": 0, "max_rate": 50,
        "max_cbdata": MAX_CBDATA, "max_clients": 64,
    }), loop_program="demo.nc")  # fmt: skip
    emitter = rig.emitter()
    port = await rig.server_port()
    good = await TcpReceiver(emitter).connect(port)
    try:
        await wait_until(lambda: len(good.got.frames) > 3, message="frames for the well-behaved client")
        streams = MALFORMED + random_streams(60)
        results = []
        for start in range(0, len(streams), 16):  # 16 bad clients at a time
            batch = streams[start : start + 16]
            results += await asyncio.gather(*(throw(port, data) for _, data in batch))
        assert all(results), "every bad stream was closed by the gateway"

        transport = emitter.transport
        assert transport.closed_malformed >= len(MALFORMED) + 30  # type: ignore[union-attr]
        reasons = [r.getMessage() for r in caplog.records if "malformed frame" in r.getMessage()]
        assert reasons and all("Traceback" not in r for r in reasons)
        for kind in ("unknown_dwdata", "frame_too_large", "length_overrun", "item_count", "truncated_header"):
            assert any(f"({kind})" in r for r in reasons), kind
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR]

        # The gateway runs on, and the good client still gets the machine's values.
        before = len(good.got.frames)
        await wait_until(lambda: len(good.got.frames) > before + 5, message="frames after the flood")
        assert not good.closed.is_set()
        await wait_until(lambda: emitter.stats()["receivers"] == 1, message="every bad client to be gone")
    finally:
        await good.close()
