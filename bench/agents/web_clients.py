"""N live-socket clients of the web console, as N browsers on one machine page (bench scenario `web`).

Each opens /api/live and sends the machine page's own subscription (every variable of the machine,
and the job and alarm events), then reads what the console pushes. Prints `ready` once every client
has its first batch, and at the end (stdin closed) one JSON line: messages and bytes received. Messages
are counted, not parsed: a browser parses on its own machine, while this process shares the gateway's.

    python -m bench.agents.web_clients URL MACHINE CLIENTS
"""

from __future__ import annotations

import asyncio
import json
import sys

import aiohttp


async def client(url: str, machine: str, counts: list[int], first: asyncio.Event, ready: list[int]) -> None:
    async with aiohttp.ClientSession() as session, session.ws_connect(url + "api/live") as ws:
        await ws.send_str(json.dumps({"watch": [{"machine": machine, "paths": None}], "events": True}))
        seen = False
        async for msg in ws:
            counts[0] += 1
            counts[1] += len(msg.data)
            if not seen:
                seen = True
                ready[0] += 1
                if ready[0] == ready[1]:
                    first.set()


async def main() -> None:
    url, machine, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    counts, ready, first = [0, 0], [0, n], asyncio.Event()
    tasks = [asyncio.create_task(client(url, machine, counts, first, ready)) for _ in range(n)]
    await first.wait()
    print("ready", flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    print(json.dumps({"messages": counts[0], "bytes": counts[1]}), flush=True)


if __name__ == "__main__":
    asyncio.run(main())
