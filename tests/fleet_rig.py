"""`cnc-gateway fleet` as the tests run it, and uploads into a gateway's FTP inbox.

`write_fleet` writes the one gateway file every shard reads (its shard, state directory and ports from
the environment) and the fleet file; `Fleet` runs the supervisor as a process and keeps its output as it
comes, so that a test can wait for a line.
"""

from __future__ import annotations

import asyncio
import re
import sys
from pathlib import Path
from typing import Self

INBOX = "{host: 127.0.0.1, port: '${INBOX_PORT}'}"


def write_fleet(
    folder: Path,
    machines: list[str],
    ports: dict[str, int],
    *,
    shards: int = 2,
    inbox: str = INBOX,
    gateway: str = "",
    restart: str | None = "{initial: 0.2, max: 1}",
    shard: str = "${CNC_SHARD}",
) -> Path:
    """gateway.yaml (OPC UA, console and `inbox` on the shard's ports; `gateway` adds lines) and fleet.yaml,
    whose path is returned."""
    (folder / "gateway.yaml").write_text(
        f"machines: {machines}\n"
        f"shard: {shard}\n"
        "state_dir: ${CNC_STATE_DIR}\n"
        "opcua: {endpoint: 'opc.tcp://127.0.0.1:${OPCUA_PORT}/cnc-gateway', security: [None]}\n"
        "http: {host: 127.0.0.1, port: '${HTTP_PORT}'}\n"
        f"inbox: {inbox}\n" + gateway
    )
    given = ", ".join(f"{name}: {port}" for name, port in ports.items())
    path = folder / "fleet.yaml"
    path.write_text(
        f"gateway: gateway.yaml\nshards: {shards}\nports: {{{given}}}\nstate_dir: state\n"
        + (f"restart: {restart}\n" if restart else "")
    )
    return path


class Fleet:
    """`cnc-gateway fleet FILE` in a process of its own; `out` and `err` fill with its lines as they come."""

    def __init__(self, fleet_file: Path) -> None:
        self.file = fleet_file
        self.out: list[str] = []
        self.err: list[str] = []
        self._proc: asyncio.subprocess.Process | None = None
        self._readers: list[asyncio.Task[None]] = []

    @property
    def proc(self) -> asyncio.subprocess.Process:
        assert self._proc is not None, "enter the fleet first"
        return self._proc

    async def __aenter__(self) -> Self:
        self._proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "gateway.cli.main", "fleet", str(self.file),
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        self._readers = [
            asyncio.create_task(self._read(self._proc.stdout, self.out), name="test:fleet-stdout"),
            asyncio.create_task(self._read(self._proc.stderr, self.err), name="test:fleet-stderr"),
        ]
        return self

    @staticmethod
    async def _read(stream: asyncio.StreamReader | None, into: list[str]) -> None:
        assert stream is not None
        while line := await stream.readline():
            into.append(line.decode())

    async def __aexit__(self, *exc_info: object) -> None:
        if self.proc.returncode is None:
            self.proc.kill()
            await self.proc.wait()
        # The pipes close once every shard has ended too (they share them): a bounded wait, then let go.
        _, pending = await asyncio.wait(self._readers, timeout=30)
        for reader in pending:
            reader.cancel()
        await asyncio.gather(*self._readers, return_exceptions=True)

    def said(self, text: str) -> bool:
        return any(text in line for line in self.out + self.err)

    def pids(self) -> dict[int, int]:
        """Shard number → pid, from the status table printed once every shard has started."""
        return {int(k): int(p) for k, p in re.findall(r"shard (\d+)/\d+\s+pid (\d+)", "".join(self.out))}

    def starts(self, shard: int) -> list[int]:
        """The pids shard `shard` was started with, in order (from the supervisor's log)."""
        return [int(p) for p in re.findall(rf"shard {shard}/\d+ started \(pid (\d+)\)", "".join(self.err))]
