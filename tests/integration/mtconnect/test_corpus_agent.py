"""tests/corpus/mtconnect/responses.yaml over HTTP: junk from an "agent" is a reported error, never a crash.

A fake agent (aiohttp) answers the gateway's MTConnect driver with one corpus case; the
driver must report the case's reason as its last error and keep its variables Bad. Then
the same fake agent turns good, and the driver must read it: junk did not break it.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest
from aiohttp import web

from gateway.config.mapping import MachineMapping
from gateway.model.tree import VariableTree
from gateway.sources.mtconnect.agent_source import MTConnectSource
from tests.unit.codecs.mtconnect.test_corpus import cases
from tests.waiting import wait_until

PROBE = (
    '<MTConnectDevices><Header instanceId="1"/><Devices><Device id="d" name="d" uuid="u"><DataItems>'
    '<DataItem category="EVENT" id="avail" type="AVAILABILITY"/>'
    '<DataItem category="CONDITION" id="sys" type="SYSTEM"/>'
    "</DataItems></Device></Devices></MTConnectDevices>"
)
CURRENT = (
    '<MTConnectStreams><Header instanceId="1" nextSequence="3" firstSequence="1" lastSequence="2"/><Streams>'
    '<DeviceStream name="d" uuid="u"><ComponentStream component="Device" componentId="d"><Events>'
    '<Availability dataItemId="avail" sequence="1" timestamp="2024-05-01T12:00:00Z">'
    "AVAILABLE</Availability>"
    '</Events><Condition><Normal dataItemId="sys" type="SYSTEM" sequence="2" '
    'timestamp="2024-05-01T12:00:00Z"/>'
    "</Condition></ComponentStream></DeviceStream></Streams></MTConnectStreams>"
)


class FakeAgent:
    def __init__(self) -> None:
        self.case: dict[str, Any] | None = None

    async def handle(self, request: web.Request) -> web.StreamResponse:
        case, path = self.case, request.path
        if path.endswith("/probe"):
            body = case["body"] if case is not None and not case.get("probe") else PROBE
        elif path.endswith("/current"):
            body = case["body"] if case is not None and case.get("probe") else CURRENT
        else:  # /sample: a stream that only heartbeats
            response = web.StreamResponse(headers={"Content-Type": "multipart/x-mixed-replace;boundary=B"})
            await response.prepare(request)
            empty = (
                CURRENT.replace("<Streams>", "<Streams/>").split("<Streams/>")[0]
                + "<Streams/></MTConnectStreams>"
            )
            while True:
                part = empty.encode()
                await response.write(
                    b"--B\r\nContent-type: text/xml\r\nContent-length: %d\r\n\r\n%s\r\n" % (len(part), part)
                )
                await asyncio.sleep(0.1)
        return web.Response(body=body.encode(), headers={"Content-Type": "text/xml"})


@pytest.fixture
async def agent() -> AsyncIterator[tuple[FakeAgent, int]]:
    fake = FakeAgent()
    app = web.Application()
    app.router.add_get("/{tail:.*}", fake.handle)
    runner = web.AppRunner(app, access_log=None, shutdown_timeout=0.2)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    port = runner.addresses[0][1]
    try:
        yield fake, port
    finally:
        await runner.cleanup()


@pytest.mark.parametrize("case", cases("responses.yaml"), ids=lambda c: c["name"])
async def test_junk_from_an_agent_is_reported_and_the_driver_recovers(
    agent: tuple[FakeAgent, int], case: dict[str, Any]
) -> None:
    fake, port = agent
    fake.case = case
    mapping = MachineMapping.model_validate({
        "machine": "far",
        "driver": {"type": "mtconnect", "url": f"http://127.0.0.1:{port}", "heartbeat": 500,
                   "reconnect": {"initial": 0.05, "max": 0.2}},
        "variables": [{"path": "Avail", "source": "avail", "type": "String"},
                      {"path": "System", "source": "sys", "type": "String[]"}],
    })  # fmt: skip
    tree = VariableTree([mapping.definition()])
    machine = tree.machines["far"]
    async with MTConnectSource(machine, mapping) as source:
        task = asyncio.create_task(source.run())
        try:
            await wait_until(
                lambda: case["error"] in machine.status.last_error, timeout=10, message=case["error"]
            )
            assert not tree.find("far", "Avail").sample.good
            fake.case = None  # the agent gets well: the driver must read it
            avail = tree.find("far", "Avail")
            await wait_until(
                lambda: avail.sample.good and avail.sample.value == "AVAILABLE", message="recovered"
            )
            assert tree.find("far", "System").sample.value == []
            assert not task.done()
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
