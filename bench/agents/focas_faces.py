"""Simulated Fanucs for the FOCAS bench (their own process): `--count` FOCAS faces of the laser model.

    python -m bench.agents.focas_faces --count 20

Each face answers from its own machine model (running the demo program, stepped every 20 ms, so
positions and the feed change) on a free port, told in the ready line. `snap` answers the command
requests and commands served per face.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from pathlib import Path
from typing import Any

from bench.agents.protocol import serve, setup_logging
from simulator.focas import FocasFace
from simulator.machine import Machine
from simulator.store import DirectoryStore


async def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--count", type=int, default=20)
    p.add_argument("--store", type=Path, required=True)
    args = p.parse_args()
    setup_logging()
    store = DirectoryStore(args.store)
    store.prepare()
    async with contextlib.AsyncExitStack() as stack:
        faces = []
        for _ in range(args.count):
            machine = Machine(store)
            machine.select_program("demo.nc")
            machine.start()
            faces.append(await stack.enter_async_context(FocasFace(machine, store, port=0, sessions=5)))

        async def step() -> None:
            last = time.monotonic()
            while True:
                await asyncio.sleep(0.02)
                now = time.monotonic()
                for face in faces:
                    m = face.cnc.machine
                    m.step(now - last)
                    if m.state.name == "IDLE":
                        m.start()
                last = now

        stepper = asyncio.create_task(step())

        def snap(_: dict[str, Any]) -> dict[str, Any]:
            return {"requests": [f.requests for f in faces], "commands": [f.cnc.commands for f in faces]}

        await serve({"snap": snap}, {"ports": [f.port for f in faces]})
        stepper.cancel()


if __name__ == "__main__":
    asyncio.run(main())
