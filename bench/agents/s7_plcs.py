"""S7 PLCs for the PLC bench (their own process): N python-snap7 servers, each with one data block.

    python -m bench.agents.s7_plcs --plcs 5 --reals 200 --ints 200

DB1 of each holds `--reals` REALs from byte 0, then `--ints` INTs; every 100 ms a tenth of each changes.
The ready line gives the ports; `snap` answers nothing but the process's CPU (the protocol adds it).
"""

from __future__ import annotations

import argparse
import asyncio
import struct
from typing import Any

import snap7
from snap7.type import SrvArea

from bench.agents.protocol import serve, setup_logging
from bench.procs import free_port


async def change(servers: list[snap7.Server], blocks: list[bytearray], reals: int, ints: int) -> None:
    step = 0
    while True:
        step += 1
        for server, block in zip(servers, blocks, strict=True):
            server.lock_area(SrvArea.DB, 1)
            try:
                for i in range(step % 10, reals, 10):
                    struct.pack_into(">f", block, 4 * i, step + i / 1000)
                for i in range(step % 10, ints, 10):
                    struct.pack_into(">h", block, 4 * reals + 2 * i, (step + i) & 0x7FFF)
            finally:
                server.unlock_area(SrvArea.DB, 1)
        await asyncio.sleep(0.1)


async def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--plcs", type=int, default=5)
    p.add_argument("--reals", type=int, default=200)
    p.add_argument("--ints", type=int, default=200)
    args = p.parse_args()
    setup_logging()
    servers, blocks, ports = [], [], []
    for _ in range(args.plcs):
        block = bytearray(4 * args.reals + 2 * args.ints)
        server = snap7.Server(log=False)
        server.register_area(SrvArea.DB, 1, block)
        port = free_port()
        server.start_to("127.0.0.1", port)
        servers.append(server)
        blocks.append(block)
        ports.append(port)
    changer = asyncio.create_task(change(servers, blocks, args.reals, args.ints))

    def snap(_: dict[str, Any]) -> dict[str, Any]:
        return {}

    try:
        await serve({"snap": snap}, {"ports": ports})
    finally:
        changer.cancel()
        for server in servers:
            server.stop()


if __name__ == "__main__":
    asyncio.run(main())
