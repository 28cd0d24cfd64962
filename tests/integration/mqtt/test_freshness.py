"""Bounded freshness (issue 13): when the broker takes less than the machine changes, QoS 0 topics
coalesce per variable before anything queues, and QoS 1 topics still get every change.

The broker is made slow for real: Mosquitto is stopped (SIGSTOP) until the gateway's
socket buffers are full and paho holds what the socket will not take; then it runs on.
"""

from __future__ import annotations

import asyncio
import signal
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from pathlib import Path

from gateway.config.mapping import MachineMapping
from gateway.diagnostics import snapshot
from gateway.model.tree import Machine
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.mqtt.sink import MqttSink
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.trees import MappedTree
from tests.waiting import wait_until

MAPPING = {
    "machine": "m1",
    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
    "variables": [
        {"path": "Bulk", "source": "b", "type": "String"},  # large values: they fill the socket
        *({"path": f"Noise/v{i}", "source": f"n{i}", "type": "Double"} for i in range(5)),
        {"path": "Counter", "source": "c", "type": "Int32", "mqtt": {"qos": 1}},
    ],
}
BULK = "x" * 262_144
QOS0_TOPICS = [f"cnc/m1/noise/v{i}" for i in range(5)]


@asynccontextmanager
async def running(tree: MappedTree, cfg: MqttConfig, state_dir: Path) -> AsyncIterator[MqttSink]:
    sink = MqttSink(tree, cfg, state_dir, tree.mappings)
    async with sink:
        task = asyncio.create_task(sink.run(), name="test:mqtt")
        try:
            yield sink
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


def ingest(machine: Machine, path: str, value: object) -> None:
    machine.ingest(machine.nodes[path], value, datetime.now(UTC))


class Observed:
    def __init__(self, tree: MappedTree, sink: MqttSink) -> None:
        self.tree, self.sinks = tree, [sink]


async def test_a_stalled_broker_gets_the_latest_value_of_each_variable_and_every_qos1_change(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = MappedTree([MachineMapping.model_validate(MAPPING)])
    m = tree.machines["m1"]
    rec = subscriber(recorders, mosquitto.port)
    async with running(tree, mqtt_config(mosquitto.port, qos=0, keepalive=60), tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        assert mosquitto.proc is not None
        mosquitto.proc.send_signal(signal.SIGSTOP)
        try:
            # Large values until the kernel's buffers are full and paho holds a write the socket refused.
            for i in range(400):
                ingest(m, "Bulk", f"{i}{BULK}")
                await asyncio.sleep(0.01)  # the writer's turn (not a timing: the loop runs until it is full)
                if sink.socket_queue:
                    break
            assert sink.socket_queue, "the socket never filled"
            before = sink.coalesced
            for value in range(100):
                for i in range(5):
                    ingest(m, f"Noise/v{i}", float(value))
                ingest(m, "Counter", value)
                await asyncio.sleep(0)
            # Nothing went to paho meanwhile: the QoS 0 changes waited as one sample per variable.
            assert sink.coalesced - before >= 5 * 99
            assert snapshot(Observed(tree, sink))["sinks"]["mqtt"]["coalesced"] == sink.coalesced
        finally:
            mosquitto.proc.send_signal(signal.SIGCONT)
        await wait_until(
            lambda: all((rec.last_json(t) or {}).get("value") == 99.0 for t in QOS0_TOPICS),
            timeout=30,
            message="the latest value of every QoS 0 variable",
        )
        await wait_until(
            lambda: len(rec.on("cnc/m1/counter")) >= 100, timeout=30, message="every QoS 1 change"
        )
        assert [r.json()["value"] for r in rec.on("cnc/m1/counter")] == list(range(100))
        for topic in QOS0_TOPICS:  # each QoS 0 variable: a few values at most, the newest last
            values = [r.json()["value"] for r in rec.on(topic)]
            assert values[-1] == 99.0 and len(values) < 10
        await wait_until(
            lambda: m.nodes["Status/MqttCoalesced"].sample.value >= 5 * 99, message="Status/MqttCoalesced"
        )
        await wait_until(
            lambda: (rec.last_json("cnc/m1/status") or {}).get("coalesced", 0) >= 5 * 99,
            message="the count in the status document",
        )
