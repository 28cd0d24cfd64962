"""The raw copy the job benchmark compares with: an aioftp server that receives a file, and an
aioftp client in the same process that then uploads it to the controller's store. No checks,
no queue: the gateway's inbox → delivery path reduced to the two transfers."""

from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path
from typing import Any

import aioftp

from bench.agents.protocol import serve, setup_logging


async def main(args: argparse.Namespace) -> None:
    args.root.mkdir(parents=True, exist_ok=True)
    server = aioftp.Server([aioftp.User("bench", "bench", base_path=args.root, home_path="/")])
    await server.start("127.0.0.1", 0)
    port = server.server.sockets[0].getsockname()[1]

    async def relay(request: dict[str, Any]) -> dict[str, Any]:
        name = request["name"]
        started = time.perf_counter()
        async with aioftp.Client.context(
            "127.0.0.1", int(request["port"]), request["user"], request["password"]
        ) as client:
            await client.upload(args.root / name, f"{request['folder']}/{name}", write_into=True)
        return {"seconds": time.perf_counter() - started}

    try:
        await serve({"relay": relay}, {"port": port})
    finally:
        await server.close()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--root", type=Path, required=True)
    setup_logging()
    asyncio.run(main(parser.parse_args()))
