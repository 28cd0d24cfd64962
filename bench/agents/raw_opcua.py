"""The asyncua ceiling: a plain asyncua Server with N Double variables, written as fast as it goes.

No gateway code: `Server`, `add_folder`/`add_variable` in folders of 200 (a flat
folder is quadratic), and `write_attribute_value` with a fresh DataValue per write
on cached node ids, yielding to the loop every 1,000 writes. `burst` writes flat
out for a fixed time and reports the rate; `run` writes in the background, flat
out or at a set rate (a subscribed client's notification rate peaks below flat
out, where the writer leaves the server no time to publish); `pause` stops it.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import time
from datetime import UTC, datetime
from typing import Any

from asyncua import Server, ua

from bench.agents.protocol import serve, setup_logging

URI = "urn:bench:raw"
PER_FOLDER = 200
CHUNK = 1000


class Writer:
    def __init__(self, server: Server, ids: list[ua.NodeId]) -> None:
        self.server = server
        self.ids = ids
        self.written = 0
        self.task: asyncio.Task[None] | None = None

    async def write(self, seconds: float, rate: float = math.inf) -> None:
        """Write for `seconds`, flat out or at `rate` writes/s (bursts every 5 ms)."""
        write = self.server.write_attribute_value
        ids, n = self.ids, len(self.ids)
        double = ua.VariantType.Double
        start = time.monotonic()
        end = start + seconds
        base = seq = self.written
        while time.monotonic() < end:
            due = CHUNK
            if math.isfinite(rate):
                due = min(CHUNK, int((time.monotonic() - start) * rate) - (seq - base))
                if due < 1:
                    await asyncio.sleep(0.005)
                    continue
            stamp = datetime.now(UTC)
            for _ in range(due):
                seq += 1
                dv = ua.DataValue(
                    ua.Variant(float(seq), double), SourceTimestamp=stamp, ServerTimestamp=stamp
                )
                await write(ids[(seq - 1) % n], dv)
            self.written = seq
            await asyncio.sleep(0)


async def main(args: argparse.Namespace) -> None:
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{args.port}")
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    ns = await server.register_namespace(URI)
    started = time.perf_counter()
    root = await server.nodes.objects.add_folder(ua.NodeId("Raw", ns), ua.QualifiedName("Raw", ns))
    ids: list[ua.NodeId] = []
    folder = root
    for i in range(args.variables):
        if i % PER_FOLDER == 0:
            name = f"g{i // PER_FOLDER:03d}"
            folder = await root.add_folder(ua.NodeId(name, ns), ua.QualifiedName(name, ns))
        node = await folder.add_variable(ua.NodeId(f"v{i:05d}", ns), ua.QualifiedName(f"v{i:05d}", ns), 0.0)
        ids.append(node.nodeid)
    build = time.perf_counter() - started
    await server.start()
    writer = Writer(server, ids)

    async def burst(request: dict[str, Any]) -> dict[str, Any]:
        before, t0 = writer.written, time.perf_counter()
        await writer.write(float(request["seconds"]))
        return {"writes": writer.written - before, "elapsed": time.perf_counter() - t0}

    async def run(request: dict[str, Any]) -> dict[str, Any]:
        await pause(request)
        rate = request.get("rate")
        writer.task = asyncio.create_task(
            writer.write(math.inf, math.inf if rate in (None, "max") else float(rate)), name="raw-writer"
        )
        return {"written": writer.written}

    async def pause(request: dict[str, Any]) -> dict[str, Any]:
        if writer.task is not None:
            writer.task.cancel()
            await asyncio.gather(writer.task, return_exceptions=True)
            writer.task = None
        return {"written": writer.written}

    def snap(request: dict[str, Any]) -> dict[str, Any]:
        return {"written": writer.written}

    try:
        await serve(
            {"burst": burst, "run": run, "pause": pause, "snap": snap},
            {"endpoint": f"opc.tcp://127.0.0.1:{args.port}", "build_seconds": build, "uri": URI},
        )
    finally:
        await pause({})
        await server.stop()


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--variables", type=int, required=True)
    parser.add_argument("--port", type=int, required=True)
    setup_logging()
    asyncio.run(main(parser.parse_args()))
