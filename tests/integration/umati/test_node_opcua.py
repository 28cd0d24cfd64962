"""The umati view against an independent client: node-opcua (tests/node/umati_client.mjs), as a dashboard.

It finds the machine from Objects/Machines (Machinery namespace) by its MachineToolType, reads its
Identification, subscribes to ActiveProgram's state and the channel's ChannelState, and receives a
NotificationEventType event when the simulator raises an alarm. node-opcua is installed by `make test`
(Makefile: node-deps) from tests/node/package-lock.json; without npm the test is skipped, saying so.
"""

from __future__ import annotations

import asyncio
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from tests.integration.alarms.test_alarms import SOFT_LIMIT, raise_soft_limit
from tests.integration.laser_rig import MACHINE, laser_rig
from tests.waiting import wait_until

ROOT = Path(__file__).resolve().parents[3]
CLIENT = ROOT / "tests" / "node" / "umati_client.mjs"
INSTALLED = ROOT / "tests" / "node" / "node_modules" / "node-opcua-client"

pytestmark = pytest.mark.skipif(
    shutil.which("node") is None or not INSTALLED.is_dir(),
    reason="node-opcua is not installed: `make node-deps` (needs npm) puts it in tests/node/node_modules",
)


class NodeClient:
    """The node-opcua client process and the JSON lines it printed."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.lines: list[dict[str, Any]] = []

    async def read(self) -> None:
        assert self.proc.stdout is not None
        async for raw in self.proc.stdout:
            if raw.startswith(b"{"):  # node-opcua logs its own warnings to stdout too
                self.lines.append(json.loads(raw))

    def of(self, key: str) -> list[Any]:
        return [line[key] for line in self.lines if key in line]

    def failed(self) -> None:
        assert not self.of("error"), self.of("error")


async def test_node_opcua_finds_reads_subscribes_and_gets_the_alarm(tmp_path: Path) -> None:
    async with laser_rig(tmp_path) as rig:
        proc = await asyncio.create_subprocess_exec(
            "node", str(CLIENT), rig.endpoint, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE
        )
        node = NodeClient(proc)
        reader = asyncio.create_task(node.read(), name="test:node-opcua")
        try:

            def ready() -> bool:
                node.failed()
                return bool(node.of("ready"))

            await wait_until(ready, timeout=30, message="node-opcua to find the machine and subscribe")
            [machine] = node.of("machine")
            assert machine["name"] == MACHINE and machine["folder"] == "Machinery:Machines"
            identification = machine["identification"]
            assert identification["SerialNumber"] == "LS-SIM-0001"
            assert identification["Manufacturer"] == "cnc-gateway project"
            assert identification["ProductInstanceUri"].startswith("urn:cnc-gateway:simulator")
            client = await rig.client()
            await raise_soft_limit(rig, client)

            def alarm_seen() -> bool:
                node.failed()
                return any(e["identifier"] == "1001" for e in node.of("event"))

            await wait_until(alarm_seen, timeout=15, message="the NotificationEventType event at node-opcua")
            [event] = [e for e in node.of("event") if e["identifier"] == "1001"]
            assert event["message"] == SOFT_LIMIT and event["severity"] == 700 and event["source"] == MACHINE

            def states(what: str) -> list[Any]:
                return [v["value"] for v in node.of("value") if v["what"] == what]

            await wait_until(lambda: "Aborted" in states("CurrentState"), timeout=10, message="Aborted")
            assert "Running" in states("CurrentState")
            assert 0 in states("Channel1/ChannelState")  # Active while the program ran
        finally:
            assert proc.stdin is not None
            proc.stdin.close()
            await asyncio.wait_for(proc.wait(), timeout=20)
            reader.cancel()
            await asyncio.gather(reader, return_exceptions=True)
