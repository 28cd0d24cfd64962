"""An SHDR adapter that sends as fast as its agent reads (its own process): the load of the SHDR bench.

    python -m bench.agents.shdr_adapter --keys 1000 --per-line 10

It listens on a free port (told in its ready line), answers `* PING` with `* PONG`, and
writes lines of `--per-line` changed key|value pairs, cycling through `--keys` keys with
an increasing value, whenever the socket can take more. `snap` answers the pairs sent.
"""

from __future__ import annotations

import argparse
import asyncio
from typing import Any

from bench.agents.protocol import serve, setup_logging

CHUNK = 200  # lines per write


class Adapter:
    def __init__(self, keys: int, per_line: int) -> None:
        self.keys = [f"k{n:05d}" for n in range(keys)]
        self.per_line = per_line
        self.sent = 0
        self.value = 0

    def lines(self) -> bytes:
        out: list[str] = []
        keys, n = self.keys, len(self.keys)
        for _ in range(CHUNK):
            pairs = []
            for _ in range(self.per_line):
                self.value += 1
                pairs.append(f"{keys[self.value % n]}|{self.value}")
            out.append("|" + "|".join(pairs) + "\n")
        self.sent += CHUNK * self.per_line
        return "".join(out).encode()

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        async def answer_pings() -> None:
            while line := await reader.readline():
                if line.startswith(b"* PING"):
                    writer.write(b"* PONG 10000\n")

        pings = asyncio.create_task(answer_pings())
        try:
            while True:
                writer.write(self.lines())
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            pings.cancel()
            writer.close()


async def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--keys", type=int, default=1000)
    p.add_argument("--per-line", type=int, default=10)
    args = p.parse_args()
    setup_logging()
    adapter = Adapter(args.keys, args.per_line)
    server = await asyncio.start_server(adapter.serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]

    def snap(_: dict[str, Any]) -> dict[str, Any]:
        return {"sent": adapter.sent}

    await serve({"snap": snap}, {"port": port})
    server.close()


if __name__ == "__main__":
    asyncio.run(main())
