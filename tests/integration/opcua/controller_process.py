"""The test controller in a process of its own, so a test can freeze it (SIGSTOP) like a hung PLC.

Run as `python -m tests.integration.opcua.controller_process PORT`; prints `ready NS` once listening.
"""

from __future__ import annotations

import asyncio
import sys

from tests.integration.opcua.conftest import Controller


async def main(port: int) -> None:
    controller = Controller(port)
    await controller.build()
    await controller.start()
    print(f"ready {controller.ns}", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1])))
