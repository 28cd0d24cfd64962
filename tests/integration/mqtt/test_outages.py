"""Outages: the broker restarted mid-stream (nothing lost at QoS 1), and the gateway killed (last will)."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from gateway.config.mapping import MachineMapping
from tests.integration.mqtt.conftest import Mosquitto, Recorder, env_without_proxy, mqtt_config, subscriber
from tests.integration.mqtt.test_sink import running
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until, wait_until_sync

MAPPING = {
    "machine": "m1",
    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
    "variables": [
        {"path": "Axes/X/Position", "source": "x", "type": "Double", "unit": "mm"},
        {"path": "Axes/Y/Position", "source": "y", "type": "Double", "unit": "mm"},
    ],
}


def first_occurrences(values: list[Any]) -> list[Any]:
    """QoS 1 is at least once: a message in flight when the broker died may come twice."""
    seen: set[Any] = set()
    out = []
    for v in values:
        if v not in seen:
            seen.add(v)
            out.append(v)
    return out


async def test_broker_restart_mid_stream_loses_nothing_at_qos1(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = MappedTree([MachineMapping.model_validate(MAPPING)])
    m = tree.machines["m1"]
    nodes = [m.nodes["Axes/X/Position"], m.nodes["Axes/Y/Position"]]
    capture = tree.hub.subscribe("test-capture", every_change=True)
    # A persistent session (clean_session=False) on a broker with persistence: while the subscriber is
    # away (the broker restarting, then the subscriber reconnecting after the gateway), the broker queues.
    rec = subscriber(recorders, mosquitto.port, persistent=True, topics=["cnc/m1/axes/#"])
    produced = 0
    running_flag = True

    async def produce() -> None:
        nonlocal produced
        while running_flag:
            produced += 1
            m.ingest(nodes[produced % 2], float(produced), datetime.now(UTC))
            await asyncio.sleep(0.003)

    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online)
        producer = asyncio.create_task(produce())
        try:
            await wait_until(lambda: len(rec.messages) >= 50, message="the stream to flow")
            await asyncio.to_thread(mosquitto.stop)
            await wait_until(lambda: not sink.online, message="the sink to notice")
            mark = produced
            await wait_until(lambda: produced >= mark + 200, message="changes while the broker is down")
            assert len(sink.backlog) > 0
            await asyncio.to_thread(mosquitto.start)
            await wait_until(lambda: sink.online, timeout=10, message="the sink to reconnect")
            mark = produced
            await wait_until(lambda: produced >= mark + 100)
        finally:
            running_flag = False
            await producer
        expected: dict[str, list[float]] = {}
        for node, sample in capture.take():
            if node in nodes:
                topic = f"cnc/m1/{node.path.lower()}"
                expected.setdefault(topic, []).append(sample.value)
        assert sum(len(v) for v in expected.values()) == produced

        def received(topic: str) -> list[float]:
            return first_occurrences([r.json()["value"] for r in rec.on(topic)])

        for topic, values in expected.items():
            await wait_until(
                lambda t=topic, v=values: len(received(t)) >= len(v),
                timeout=20,
                message=f"every change on {topic}",
            )
            assert received(topic) == values  # all of them, in order
        assert sink.backlog.dropped_total == 0
        assert rec.resumed >= 1  # the subscriber came back to its persisted session
        # The retained topics hold the latest values for a newcomer.
        late = subscriber(recorders, mosquitto.port, topics=["cnc/m1/axes/#"])
        for topic, values in expected.items():
            await wait_until(lambda t=topic: late.last(t))
            assert late.last(topic).retain and late.last_json(topic)["value"] == values[-1]


GATEWAY_FILE = """
opcua: {{endpoint: "opc.tcp://127.0.0.1:{opcua}/cnc-gateway"}}
state_dir: state
log_level: info
mqtt:
  port: {mqtt}
  client_id: will-test
  keepalive: 5
machines: [m1.yaml]
"""

MACHINE_FILE = """
machine: m1
driver: {{endpoint: "opc.tcp://127.0.0.1:{controller}", reconnect: {{initial: 0.5, max: 2}}}}
variables:
  - {{path: Axes/X/Position, source: "ns=2;s=x", type: Double}}
"""


def test_last_will_says_offline_when_the_gateway_is_killed(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    (tmp_path / "gateway.yaml").write_text(GATEWAY_FILE.format(opcua=free_port(), mqtt=mosquitto.port))
    (tmp_path / "m1.yaml").write_text(MACHINE_FILE.format(controller=free_port()))
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/status"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli.main", "run", str(tmp_path / "gateway.yaml")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env_without_proxy(),
    )
    try:
        wait_until_sync(
            lambda: (rec.last_json("cnc/status") or {}).get("state") == "online",
            timeout=60,
            message="the gateway's online status",
        )
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        wait_until_sync(
            lambda: rec.last_json("cnc/status")["state"] == "offline", timeout=15, message="the last will"
        )
        doc = rec.last_json("cnc/status")
        assert doc["reason"] == "connection to the gateway lost" and doc["version"]
        late = subscriber(recorders, mosquitto.port, topics=["cnc/status"])
        wait_until_sync(lambda: late.last("cnc/status"))
        assert late.last("cnc/status").retain and late.last_json("cnc/status")["state"] == "offline"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()


def test_a_clean_stop_says_offline_without_the_will(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    (tmp_path / "gateway.yaml").write_text(GATEWAY_FILE.format(opcua=free_port(), mqtt=mosquitto.port))
    (tmp_path / "m1.yaml").write_text(MACHINE_FILE.format(controller=free_port()))
    rec = subscriber(recorders, mosquitto.port, topics=["cnc/status"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "gateway.cli.main", "run", str(tmp_path / "gateway.yaml")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env_without_proxy(),
    )
    try:
        wait_until_sync(lambda: (rec.last_json("cnc/status") or {}).get("state") == "online", timeout=60)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0
        wait_until_sync(lambda: rec.last_json("cnc/status")["state"] == "offline", timeout=10)
        assert rec.last_json("cnc/status")["reason"] == "gateway stopped"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()
