"""Sources connect while the sinks start (gateway/app.py): no sink misses a value that arrived meanwhile.

The sources' tasks start before the sinks are entered, so a controller's initial values reach the tree while
the OPC UA server is still being built and before the MQTT sink has subscribed to the hub. Each sink
subscribes before it reads the tree's samples; these tests hold the gateway to it with a source that changes
every variable at each turn of the event loop from the moment its task starts, and check that both sinks
end with its last values (MQTT through Mosquitto, OPC UA through a client's Read).
"""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path
from typing import Any, Self

import pytest

from gateway.app import Gateway
from gateway.config.loader import load_mapping
from gateway.errors import SinkError
from gateway.model.sample import utcnow
from gateway.model.tree import Machine, VariableNode
from tests.integration.mqtt.conftest import Mosquitto, Recorder, gateway_config, mqtt_config, subscriber
from tests.opcua_client import Client
from tests.waiting import free_port, wait_until

VARIABLES = 40
AFTER = 50  # turns of the event loop the source goes on changing every variable once the gateway has started


def noise_mapping(folder: Path) -> Any:
    lines = [
        f"  - {{path: Noise/v{i:02d}, source: 'ns=2;s=v{i:02d}', type: Double}}" for i in range(VARIABLES)
    ]
    path = folder / "eager.yaml"
    path.write_text(
        "machine: eager\ndriver: {type: opcua, endpoint: 'opc.tcp://127.0.0.1:1'}\nvariables:\n"
        + "\n".join(lines)
        + "\n"
    )
    return load_mapping(path)


class EagerSource:
    """A controller whose values arrive from the first moment: every variable changes at each turn of the
    event loop, from before the task's first await until AFTER turns after the gateway has started."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self.rounds = 0
        self.rounds_before_started: int | None = None  # set when the gateway's __aenter__ has returned
        self.done = asyncio.Event()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        return None

    async def run(self) -> None:
        self.machine.status.connected()
        nodes = list(self.machine.mapped)
        while self.rounds_before_started is None or self.rounds < self.rounds_before_started + AFTER:
            self.rounds += 1
            now = utcnow()
            for node in nodes:
                self.machine.ingest(node, float(self.rounds), now)
            await asyncio.sleep(0)
        self.done.set()
        await asyncio.Event().wait()

    async def write(self, node: VariableNode, raw: Any) -> None:
        raise NotImplementedError


async def test_sinks_get_every_value_a_source_brings_while_they_start(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/eager/noise/#"])
    opcua_port = free_port()
    config = gateway_config(
        noise_mapping(tmp_path), tmp_path / "state", mqtt_config(mosquitto.port), opcua_port
    )
    gw = Gateway(config)
    source = EagerSource(gw.tree.machines["eager"])
    gw.sources = [source]
    async with gw:
        source.rounds_before_started = source.rounds
        task = asyncio.create_task(gw.run(), name="test:gateway")
        try:
            assert source.rounds_before_started > 0  # the source's values came while the sinks started
            await asyncio.wait_for(source.done.wait(), timeout=20)
            last = float(source.rounds)
            topics = [f"cnc/eager/noise/v{i:02d}" for i in range(VARIABLES)]
            await wait_until(
                lambda: all((rec.last_json(t) or {}).get("value") == last for t in topics),
                timeout=20,
                message="MQTT to carry every variable's last value",
            )
            async with Client(f"opc.tcp://127.0.0.1:{opcua_port}/cnc-gateway", timeout=5) as client:
                nodes = [client.get_node(f"ns=2;s=eager/Noise/v{i:02d}") for i in range(VARIABLES)]
                assert await client.read_values(nodes) == [last] * VARIABLES
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


async def test_a_sink_that_cannot_start_leaves_no_source_or_sink_task_running(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        opcua_port = taken.getsockname()[1]
        config = gateway_config(
            noise_mapping(tmp_path), tmp_path / "state", mqtt_config(mosquitto.port), opcua_port
        )
        gw = Gateway(config)
        source = EagerSource(gw.tree.machines["eager"])
        gw.sources = [source]
        with pytest.raises(SinkError, match="cannot listen"):
            async with gw:
                pass
    assert not [t for t in asyncio.all_tasks() if t.get_name().startswith(("source:", "sink:"))]
