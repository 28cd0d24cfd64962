"""MTConnect streaming clients (aiohttp, a process of their own): follow /sample streams, count observations.

    python -m bench.agents.mtconnect_client --url http://127.0.0.1:5000 --streams 5

Each stream starts at the agent's nextSequence and reads `multipart/x-mixed-replace` parts;
every `sequence="` in a part is one observation. `snap` answers the total so far and the
errors (MTConnectError parts, dropped streams).
"""

from __future__ import annotations

import argparse
import asyncio
import re
from typing import Any

import aiohttp

from bench.agents.protocol import serve, setup_logging
from gateway.codecs.mtconnect.multipart import MultipartReader, boundary_of

NEXT = re.compile(rb'nextSequence="(\d+)"')


class Streams:
    def __init__(self) -> None:
        self.observations = 0
        self.parts = 0
        self.errors = 0

    async def follow(self, url: str, query: str) -> None:
        async with aiohttp.ClientSession() as session:
            async with session.get(f"{url}/current") as r:
                found = NEXT.search(await r.read())
            start = int(found.group(1)) if found else 1
            async with session.get(f"{url}/sample?from={start}&{query}") as response:
                boundary = boundary_of(response.headers.get("Content-Type", "")) or "x"
                reader = MultipartReader(boundary)
                async for data in response.content.iter_any():
                    for part in reader.feed(data):
                        self.parts += 1
                        if b"<MTConnectError" in part:
                            self.errors += 1
                            return
                        self.observations += part.count(b'sequence="')


async def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--url", required=True)
    p.add_argument("--streams", type=int, default=1)
    p.add_argument("--query", default="interval=0&count=10000&heartbeat=1000")
    args = p.parse_args()
    setup_logging()
    streams = Streams()
    tasks = [asyncio.create_task(streams.follow(args.url, args.query)) for _ in range(args.streams)]

    def snap(_: dict[str, Any]) -> dict[str, Any]:
        dropped = sum(1 for t in tasks if t.done())
        return {"observations": streams.observations, "parts": streams.parts, "errors": streams.errors,
                "dropped": dropped}  # fmt: skip

    await serve({"snap": snap}, {"streams": args.streams})
    for task in tasks:
        task.cancel()


if __name__ == "__main__":
    asyncio.run(main())
