"""Retained job records on a real Mosquitto: with `mqtt_retained_jobs: 2`, after four jobs are delivered
through the inbox, a fresh subscriber finds only the two newest `jobs/<id>` topics retained; and a
restart with a lower limit clears the records an earlier run left behind."""

from __future__ import annotations

import asyncio
import re
import uuid
from pathlib import Path

from gateway.config.gateway import GatewayConfig
from gateway.config.jobs import InboxConfig
from gateway.config.loader import Config, load_mapping
from gateway.jobs.queue.records import JobState
from gateway.jobs.service import JobService
from gateway.model.tree import VariableTree
from gateway.sinks.mqtt.sink import MqttSink
from tests.integration.jobs.conftest import Store, mapping_text, program
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.waiting import wait_until

JOBS = "cnc/laser/jobs/+"
RECORD = re.compile(r"^cnc/laser/jobs/J\d{6}$")


async def test_only_the_newest_ended_jobs_stay_retained(
    store: Store, harness, mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    live = subscriber(recorders, mosquitto.port, topics=[JOBS])
    extra = "  mqtt_retained_jobs: 2"
    async with harness([mapping_text("laser", store.port, extra=extra)]) as h:
        sink = MqttSink(h.tree, mqtt_config(mosquitto.port), tmp_path / "mqtt", h.tree.mappings)
        async with sink:
            task = asyncio.create_task(sink.run(), name="test:mqtt")
            try:
                await wait_until(lambda: sink.online, message="the sink to connect")
                for seq in range(1, 5):
                    reply = await h.stor("laser", f"part{seq}.nc", program(f"part {seq}"))
                    assert reply.startswith(f"226 J{seq:06d} queued"), reply
                    await h.wait_state(seq, JobState.DELIVERED)

                def withdrawn(topic: str) -> bool:  # an empty message: the broker drops the retained one
                    return any(m.payload == b"" for m in live.on(topic))

                await wait_until(
                    lambda: withdrawn("cnc/laser/jobs/J000001") and withdrawn("cnc/laser/jobs/J000002"),
                    message="the two oldest records withdrawn",
                )
                await wait_until(
                    lambda: (live.last_json("cnc/laser/jobs/J000004") or {}).get("state") == "DELIVERED",
                    message="the last record delivered",
                )
                await wait_until(lambda: sink.settled, message="everything acknowledged by the broker")

                fresh = subscriber(recorders, mosquitto.port, topics=[JOBS])
                # The broker sends retained messages right after SUBACK, before anything published later.
                marker = f"cnc/laser/jobs/marker-{uuid.uuid4().hex[:6]}"
                fresh.publish(marker, b"end", qos=1)
                await wait_until(lambda: fresh.on(marker), message="the marker after the retained messages")
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    retained = sorted(m.topic for m in fresh.messages if m.retain and RECORD.match(m.topic))
    assert retained == ["cnc/laser/jobs/J000003", "cnc/laser/jobs/J000004"]
    assert fresh.last_json("cnc/laser/jobs/J000004")["state"] == "DELIVERED"


async def test_a_restart_clears_records_an_earlier_run_left_retained(
    store: Store, harness, mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    live = subscriber(recorders, mosquitto.port, topics=[JOBS])
    async with harness([mapping_text("laser", store.port, extra="  mqtt_retained_jobs: 100")]) as h:
        sink = MqttSink(h.tree, mqtt_config(mosquitto.port), tmp_path / "mqtt", h.tree.mappings)
        async with sink:
            task = asyncio.create_task(sink.run(), name="test:mqtt")
            try:
                await wait_until(lambda: sink.online, message="the sink to connect")
                for seq in range(1, 4):
                    reply = await h.stor("laser", f"part{seq}.nc", program(f"part {seq}"))
                    assert reply.startswith(f"226 J{seq:06d} queued"), reply
                    await h.wait_state(seq, JobState.DELIVERED)
                await wait_until(
                    lambda: (live.last_json("cnc/laser/jobs/J000003") or {}).get("state") == "DELIVERED",
                    message="three records retained by the first run",
                )
                await wait_until(lambda: sink.settled, message="everything acknowledged by the broker")
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    # The second run, with a limit of 1, started in the gateway's order: the sink, then the job service.
    path = tmp_path / "machine0.yaml"
    path.write_text(mapping_text("laser", store.port, extra="  mqtt_retained_jobs: 1"))
    inbox = InboxConfig.model_validate({"host": "127.0.0.1", "port": 0, "accounts": []})
    config = Config(
        GatewayConfig(state_dir=str(h.state), inbox=inbox), (load_mapping(path, environ={}),), tmp_path
    )
    tree = VariableTree(config.definitions())
    sink = MqttSink(tree, mqtt_config(mosquitto.port), tmp_path / "mqtt", config.mappings)
    async with sink:
        task = asyncio.create_task(sink.run(), name="test:mqtt")
        try:
            async with JobService(config, tree, environ={}):

                def withdrawn(topic: str) -> bool:
                    return any(m.payload == b"" for m in live.on(topic))

                await wait_until(
                    lambda: withdrawn("cnc/laser/jobs/J000001") and withdrawn("cnc/laser/jobs/J000002"),
                    message="the second run to withdraw the two oldest records at start-up",
                )
                await wait_until(lambda: sink.settled, message="everything acknowledged by the broker")
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    fresh = subscriber(recorders, mosquitto.port, topics=[JOBS])
    marker = f"cnc/laser/jobs/marker-{uuid.uuid4().hex[:6]}"
    fresh.publish(marker, b"end", qos=1)
    await wait_until(lambda: fresh.on(marker), message="the marker after the retained messages")
    retained = sorted(m.topic for m in fresh.messages if m.retain and RECORD.match(m.topic))
    assert retained == ["cnc/laser/jobs/J000003"]
