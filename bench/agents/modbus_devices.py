"""Modbus TCP devices for the PLC bench (their own process): N simulator faces, each with R holding registers.

    python -m bench.agents.modbus_devices --devices 20 --registers 500 --change 50

Each device is the simulator's Modbus face (simulator/modbus/face.py) on a free port; every 100 ms a
task changes `--change` registers of every device (a rotating window, each value incremented), so that a
poller has changes to carry. The ready line gives the ports; `snap` answers the reads served.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
from typing import Any

from bench.agents.protocol import serve, setup_logging
from gateway.codecs.modbus.address import Table
from simulator.modbus import ModbusFace, RegisterImage


async def change(images: list[RegisterImage], registers: int, per_tick: int) -> None:
    at = 0
    while True:
        for image in images:
            values = image.tables[Table.HOLDING]
            for offset in range(per_tick):
                address = (at + offset) % registers
                values[address] = (values[address] + 1) & 0xFFFF
        at = (at + per_tick) % registers
        await asyncio.sleep(0.1)


async def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--devices", type=int, default=20)
    p.add_argument("--registers", type=int, default=500)
    p.add_argument("--change", type=int, default=50, help="registers changed per device every 100 ms")
    args = p.parse_args()
    setup_logging()
    images = [RegisterImage(holding=args.registers) for _ in range(args.devices)]
    async with contextlib.AsyncExitStack() as stack:
        faces = [await stack.enter_async_context(ModbusFace(image, port=0)) for image in images]
        changer = asyncio.create_task(change(images, args.registers, args.change))

        def snap(_: dict[str, Any]) -> dict[str, Any]:
            return {"reads": sum(i.reads for i in images), "connections": sum(f.connections for f in faces)}

        await serve({"snap": snap}, {"ports": [f.port for f in faces]})
        changer.cancel()


if __name__ == "__main__":
    asyncio.run(main())
