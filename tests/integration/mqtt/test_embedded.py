"""The demo's embedded broker (amqtt): started only when nothing answers on the configured port."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path

from gateway.cli.demo import _ensure_broker
from gateway.config.gateway import GatewayConfig
from gateway.config.loader import Config
from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.mqtt.embedded import broker_reachable
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.integration.mqtt.test_sink import MAPPING, ingest, running
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until


def demo_config(port: int) -> Config:
    gateway = GatewayConfig(mqtt=MqttConfig(port=port))
    return Config(gateway, (MachineMapping.model_validate(MAPPING),), Path.cwd())


async def test_the_demo_starts_an_embedded_broker_only_when_none_answers(
    tmp_path: Path, recorders: list[Recorder]
) -> None:
    port = free_port()
    async with contextlib.AsyncExitStack() as stack:
        assert await _ensure_broker(demo_config(port), stack) == "embedded amqtt, started by the demo"
        assert await asyncio.to_thread(broker_reachable, "127.0.0.1", port)
        rec = await asyncio.to_thread(subscriber, recorders, port)
        tree = MappedTree([MachineMapping.model_validate(MAPPING)])
        async with running(tree, mqtt_config(port), tmp_path) as sink:
            await wait_until(lambda: sink.online)
            ingest(tree.machines["m1"], "Axes/X/Position", 3.25)
            await wait_until(lambda: (rec.last_json("cnc/m1/axes/x/position") or {}).get("value") == 3.25)
        for r in recorders:
            r.stop()
    assert not await asyncio.to_thread(broker_reachable, "127.0.0.1", port)


async def test_the_demo_uses_a_broker_that_is_already_there(mosquitto: Mosquitto) -> None:
    async with contextlib.AsyncExitStack() as stack:
        assert await _ensure_broker(demo_config(mosquitto.port), stack) == "already running"
