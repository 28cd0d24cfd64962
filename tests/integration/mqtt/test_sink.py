"""The MQTT sink against a real Mosquitto: retained state, quality, liveness, `/set`, outages.

The controller side is the tree itself, fed with `Machine.ingest` / `invalidate`;
the simulator end-to-end tests are in test_end_to_end.py.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from gateway.config.mapping import MachineMapping
from gateway.errors import SinkError
from gateway.model.tree import Machine
from gateway.sinks.mqtt.config import MqttConfig
from gateway.sinks.mqtt.sink import MqttSink
from tests.integration.mqtt.conftest import Mosquitto, Recorder, mqtt_config, subscriber
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until

MAPPING = {
    "machine": "m1",
    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
    "variables": [
        {"path": "Axes/X/Position", "source": "x", "type": "Double", "unit": "mm"},
        {
            "path": "Feed/Override",
            "source": "o",
            "type": "UInt16",
            "unit": "%",
            "access": "readwrite",
            "range": {"min": 0, "max": 150},
            "mqtt": {"writable": True},
        },
        {"path": "Program/Name", "source": "p", "type": "String", "access": "readwrite"},
        {
            "path": "Laser/Power",
            "source": "lp",
            "type": "Double",
            "mqtt": {"payload": "raw", "topic": "laser/watts"},
        },
        {"path": "Laser/Secret", "source": "ls", "type": "Double", "mqtt": {"publish": False}},
    ],
}
NOW = datetime(2026, 5, 6, 7, 8, 9, tzinfo=UTC)


def make_tree(**machine: Any) -> MappedTree:
    return MappedTree([MachineMapping.model_validate({**MAPPING, **machine})])


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


def ingest(machine: Machine, path: str, value: Any) -> None:
    machine.ingest(machine.nodes[path], value, datetime.now(UTC))


async def test_values_are_retained_for_a_late_subscriber(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    m = tree.machines["m1"]
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        ingest(m, "Axes/X/Position", 1.0)
        ingest(m, "Axes/X/Position", 12.5)
        ingest(m, "Laser/Power", 2000.0)
        ingest(m, "Laser/Secret", 1.0)
        await wait_until(lambda: sink.settled, message="everything acknowledged")
        late = subscriber(recorders, mosquitto.port)
        await wait_until(lambda: late.last("cnc/m1/axes/x/position") and late.last("cnc/m1/laser/watts"))
        pos = late.last("cnc/m1/axes/x/position")
        assert pos.retain and pos.json()["value"] == 12.5 and pos.json()["unit"] == "mm"
        assert pos.json()["quality"] == "good"
        assert late.last("cnc/m1/laser/watts").payload == b"2000.0"  # raw payload, own topic
        assert not any("secret" in r.topic for r in late.messages)  # publish: false
        status = late.last_json("cnc/status")
        assert status["state"] == "online" and status["machines"] == ["m1"]
        machine_status = late.last_json("cnc/m1/status")
        assert machine_status["state"] == "disconnected" and machine_status["dropped"] == 0
        assert not any(r.topic.startswith("cnc/m1/status/") for r in late.messages)  # one status topic
        assert m.nodes["Status/MqttState"].sample.value == "connected"


async def test_events_go_out_as_json_retained_state_and_an_ordered_stream(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    from gateway.model.events import Event

    tree = make_tree()
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        live = subscriber(recorders, mosquitto.port, topics=["cnc/m1/jobs/#"])
        for state in ("QUEUED", "SENDING", "DELIVERED"):
            tree.events.publish(
                Event("m1", "jobs/J000007", {"id": "J000007", "state": state, "at": NOW}, retain=True)
            )
            tree.events.publish(Event("m1", "jobs/events", {"id": "J000007", "to": state}))
        await wait_until(lambda: sink.settled and len(live.on("cnc/m1/jobs/events")) == 3, message="3 events")
        assert [r.json()["to"] for r in live.on("cnc/m1/jobs/events")] == ["QUEUED", "SENDING", "DELIVERED"]
        late = subscriber(recorders, mosquitto.port, topics=["cnc/m1/jobs/#"])
        await wait_until(lambda: late.last("cnc/m1/jobs/J000007"), message="the retained job record")
        record = late.last("cnc/m1/jobs/J000007")
        assert record.retain and record.json()["state"] == "DELIVERED"
        assert record.json()["at"] == "2026-05-06T07:08:09.000Z" and "ts" in record.json()
        assert late.on("cnc/m1/jobs/events") == []  # the stream is not retained


async def test_a_machine_another_shard_serves_publishes_nothing_here(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    """shard: lease: while the machine is on standby (Machine.served false) neither its values, nor its status
    document, nor its events leave this sink, and no sample marked as a standby's does even once it is
    served; once served, everything does, and the gateway's status document lists it."""
    from gateway.model.events import Event
    from gateway.model.status import STANDBY_STATUS

    tree = make_tree()
    m = tree.machines["m1"]
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online, message="the sink to connect")
        live = subscriber(recorders, mosquitto.port, topics=["cnc/#"])
        m.served = False  # (no value arrives on standby: the machine's source does not run)
        m.invalidate(STANDBY_STATUS, "served by another shard")
        m.status.standby("served by another shard")
        tree.events.publish(Event("m1", "alarms/active", [], retain=True))
        m.served = True  # as gateway/sources/leased.py does when the lease arrives
        m.status.error("")
        m.status.connecting()
        m.invalidate(STANDBY_STATUS, "served by another shard")  # queued as the lease arrives: not sent
        ingest(m, "Axes/X/Position", 8.0)
        tree.events.publish(Event("m1", "alarms/active", [{"id": "1001"}], retain=True))
        await wait_until(lambda: live.on("cnc/m1/alarms/active") and live.on("cnc/m1/axes/x/position"),
                         timeout=10, message="the served machine's messages")  # fmt: skip
        await wait_until(lambda: any("m1" in (r.json().get("machines") or []) for r in live.on("cnc/status")),
                         timeout=10, message="the status document listing the machine again")  # fmt: skip
        await wait_until(lambda: sink.settled, message="everything acknowledged")
        assert [r.json()["value"] for r in live.on("cnc/m1/axes/x/position")] == [8.0]
        assert [r.json() for r in live.on("cnc/m1/alarms/active")] == [[{"id": "1001"}]]
        leaked = [r for r in live.messages if b"another shard" in r.payload or b"standby" in r.payload]
        assert leaked == []


async def test_quality_turns_bad_with_the_reason_and_the_status_follows(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    m = tree.machines["m1"]
    rec = subscriber(recorders, mosquitto.port)
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online)
        m.status.connected()
        ingest(m, "Axes/X/Position", 3.0)
        await wait_until(lambda: (rec.last_json("cnc/m1/status") or {}).get("state") == "connected")
        m.status.disconnected("controller unreachable: connection refused")
        m.invalidate("BadNotConnected", "controller unreachable: connection refused")
        await wait_until(lambda: (rec.last_json("cnc/m1/axes/x/position") or {}).get("quality") == "bad")
        doc = rec.last_json("cnc/m1/axes/x/position")
        assert doc["value"] == 3.0 and doc["status"] == "BadNotConnected"
        assert doc["reason"] == "controller unreachable: connection refused"
        await wait_until(lambda: (rec.last_json("cnc/m1/status") or {}).get("state") == "disconnected")
        status = rec.last_json("cnc/m1/status")
        assert status["reason"] == "controller unreachable: connection refused" and status["since"]


class _Writer:
    """The controller end of a write: records what reached it (the tree checked everything before)."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, Any]] = []

    async def write(self, node: Any, raw: Any) -> None:
        self.writes.append((node.path, raw))


SET = "cnc/m1/feed/override/set"


@pytest.mark.parametrize(
    ("topic", "payload", "status", "fragment"),
    [
        (SET, b'{"value": 5', "BadDecodingError", "malformed JSON"),
        (SET, b"fast", "BadTypeMismatch", "expected UInt16"),
        (SET, b'{"value": true}', "BadTypeMismatch", "expected UInt16"),
        (SET, b"200", "BadOutOfRange", "outside the range 0..150"),
        (SET, b"7" * 70_000, "BadRequestTooLarge", "more than the 65536 allowed"),
        ("cnc/m1/axes/x/position/set", b"1", "BadNotWritable", "read-only"),
        ("cnc/m1/program/name/set", b"x.nc", "BadUserAccessDenied", "not enabled"),
        ("cnc/m1/no/such/set", b"1", "BadNodeIdUnknown", "no variable"),
        ("cnc/m1/status/set", b"1", "BadNodeIdUnknown", "no variable"),
    ],
)
async def test_every_refused_write_gets_its_reason_and_nothing_is_written(
    mosquitto: Mosquitto,
    recorders: list[Recorder],
    tmp_path: Path,
    topic: str,
    payload: bytes,
    status: str,
    fragment: str,
) -> None:
    tree = make_tree()
    writer = tree.machines["m1"].writer = _Writer()
    rec = subscriber(
        recorders,
        mosquitto.port,
        topics=["cnc/+/+/+/set/result", "cnc/+/+/+/+/set/result", "cnc/+/+/set/result"],
    )
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: sink.online)
        await wait_until(rec.subscribed.is_set)
        await asyncio.sleep(0)  # the gateway's SUBACK: a first probe below is repeated until answered
        result = topic + "/result"

        def answered() -> Any:
            if not rec.on(result):
                rec.publish(topic, payload)
                return False
            return rec.last_json(result)

        doc = await wait_until(answered, interval=0.3, message=f"an answer on {result}")
        assert doc["ok"] is False and doc["status"] == status and fragment in doc["error"]
        assert writer.writes == []
        assert sink.writes.refused >= 1


async def test_an_accepted_write_reaches_the_controller_and_a_retained_request_is_never_replayed(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    writer = tree.machines["m1"].writer = _Writer()
    rec = subscriber(recorders, mosquitto.port)
    # A request left retained on the broker would be carried out again on every reconnect: refused.
    rec.publish(SET, b"60", retain=True)
    # Retained on the broker before the gateway subscribes (the recorder, subscribed to cnc/#, gets it back
    # once the broker has it): a gateway that subscribed first would get it live, not as a retained request.
    await wait_until(lambda: rec.on(SET), message="the retained request on the broker")
    async with running(tree, mqtt_config(mosquitto.port), tmp_path) as sink:
        await wait_until(lambda: rec.on(SET + "/result"), message="the answer to the retained request")
        doc = rec.last_json(SET + "/result")
        assert doc["ok"] is False and "retained" in doc["error"] and writer.writes == []
        rec.publish(SET, b"", retain=True)  # clear it from the broker

        def answered() -> Any:
            if len(rec.on(SET + "/result")) < 2:
                rec.publish(SET, b'{"value": 50}')
                return False
            return rec.last_json(SET + "/result")

        assert await wait_until(answered, interval=0.3) == {"ok": True}
        assert writer.writes[-1] == ("Feed/Override", 50) and sink.writes.accepted >= 1


async def test_mqtt5_response_topic_and_correlation_data_are_honoured(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    tree.machines["m1"].writer = _Writer()
    rec = subscriber(recorders, mosquitto.port, v5=True, topics=["replies/#", "cnc/+/+/+/set/result"])
    cfg = mqtt_config(mosquitto.port, protocol="5", response_topics=["replies/#"])  # outside the prefix
    async with running(tree, cfg, tmp_path) as sink:
        await wait_until(lambda: sink.online)
        props = Properties(PacketTypes.PUBLISH)
        props.ResponseTopic = "replies/me"
        props.CorrelationData = b"req-42"

        def answered() -> Any:
            if not rec.on("replies/me"):
                rec.publish(SET, b"250", properties=props)
                return False
            return rec.last("replies/me")

        reply = await wait_until(answered, interval=0.3)
        assert reply.json()["status"] == "BadOutOfRange"
        assert reply.properties.CorrelationData == b"req-42"
        assert not rec.on(SET + "/result")


async def test_a_flood_of_junk_leaves_the_gateway_serving(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    tree = make_tree()
    m = tree.machines["m1"]
    writer = m.writer = _Writer()
    rec = subscriber(recorders, mosquitto.port)
    async with running(tree, mqtt_config(mosquitto.port, max_set_payload=1024), tmp_path) as sink:
        await wait_until(lambda: sink.online)
        await asyncio.sleep(0.2)
        junk = [
            b"",
            b"\xff\xfe\x00",
            b"{",
            b'{"value": [[[[',
            b"[" * 5000,
            b"x" * 5000,
            b"nan",
            b"1e999",
            b"-1",
            b'{"value": {"a": 1}}',
            b"\x00" * 100,
        ]
        topics = [
            "cnc/m1/feed/override/set",
            "cnc/m1/axes/x/position/set",
            "cnc/m1/zz/set",
            "cnc/zz/zz/set",
            "cnc/m1/program/name/set",
            "cnc/m1/feed/set",
        ]
        sent = 0
        for i in range(3000):
            rec.publish(topics[i % len(topics)], junk[i % len(junk)], qos=i % 2)
            sent += 1
        # Still serving: values flow, and a good write goes through once the junk is answered.
        ingest(m, "Axes/X/Position", 42.0)
        await wait_until(
            lambda: (rec.last_json("cnc/m1/axes/x/position") or {}).get("value") == 42.0, timeout=20
        )
        await wait_until(
            lambda: sink.writes.received >= sent, timeout=20, message="every junk message handled"
        )
        assert sink.writes.accepted == 0 and writer.writes == []
        assert sink.online
        results = [r for r in rec.messages if r.topic.endswith("/set/result")]
        assert results and all(json.loads(r.payload)["ok"] is False for r in results)
        rec.publish("cnc/m1/feed/override/set", b"75")
        await wait_until(lambda: ("Feed/Override", 75) in writer.writes, timeout=10)


async def test_unreachable_broker_at_start_buffers_then_delivers_and_counts_drops(
    tmp_path: Path, recorders: list[Recorder]
) -> None:
    broker = Mosquitto(tmp_path / "late-broker", free_port())
    tree = make_tree()
    m = tree.machines["m1"]
    cfg = mqtt_config(broker.port, buffer={"limit": 20})
    async with running(tree, cfg, tmp_path / "state") as sink:
        await wait_until(lambda: sink.state == "disconnected" and "refused" in sink.last_error)
        assert "disconnected" in m.nodes["Status/MqttState"].sample.value
        for i in range(50):
            ingest(m, "Axes/X/Position", float(i))
        await wait_until(lambda: m.nodes["Status/MqttDropped"].sample.value > 0, message="the drop count")
        dropped = m.nodes["Status/MqttDropped"].sample.value
        assert dropped == sink.backlog.dropped["m1"] >= 30
        broker.start()
        try:
            rec = subscriber(recorders, broker.port, persistent=True)
            await wait_until(lambda: sink.online, timeout=10)
            await wait_until(lambda: (rec.last_json("cnc/m1/axes/x/position") or {}).get("value") == 49.0)
            got = [r.json()["value"] for r in rec.on("cnc/m1/axes/x/position")]
            assert got == sorted(got) and got[-1] == 49.0
            await wait_until(lambda: (rec.last_json("cnc/status") or {}).get("dropped") == dropped)
            assert (rec.last_json("cnc/m1/status") or {}).get("dropped") == dropped
        finally:
            broker.stop()


async def test_the_backlog_file_survives_a_gateway_restart(
    mosquitto: Mosquitto, recorders: list[Recorder], tmp_path: Path
) -> None:
    nowhere = free_port()
    state = tmp_path / "state"
    tree = make_tree()
    m = tree.machines["m1"]
    async with running(tree, mqtt_config(nowhere, buffer={"persist": True}), state) as sink:
        await wait_until(lambda: sink.state == "disconnected")
        for i in range(30):
            ingest(m, "Axes/X/Position", float(i))
        await wait_until(lambda: sink.backlog.counted >= 30)
    assert (state / "mqtt-backlog.sqlite3").exists()
    rec = subscriber(recorders, mosquitto.port)
    again = make_tree()
    async with running(again, mqtt_config(mosquitto.port, buffer={"persist": True}), state) as sink:
        await wait_until(lambda: len(rec.on("cnc/m1/axes/x/position")) >= 30, timeout=10)
        values = [r.json()["value"] for r in rec.on("cnc/m1/axes/x/position")]
        assert values == [float(i) for i in range(30)]
        await wait_until(lambda: sink.backlog.journal.count() == 0)


async def test_broker_refusal_is_reported_and_retried_with_backoff(tmp_path: Path) -> None:
    broker = Mosquitto(tmp_path / "strict", free_port(), anonymous=False)
    broker.start()
    try:
        tree = make_tree()
        cfg = mqtt_config(
            broker.port, reconnect={"initial": 0.2, "max": 0.4}, username="nobody", password="wrong"
        )
        async with running(tree, cfg, tmp_path / "state") as sink:
            await wait_until(lambda: "refused the connection" in sink.last_error, message="the refusal")
            assert "not authori" in sink.last_error.lower()
            value = tree.machines["m1"].nodes["Status/MqttState"].sample.value
            assert value.startswith("disconnected") and "refused" in value
            # It keeps trying, and waits longer each time (up to reconnect.max): no spinning.
            await wait_until(lambda: sink.attempts >= 3, message="retries")
            assert sink.last_delay >= 0.4 * 0.9 and sink.connects == 0
    finally:
        broker.stop()


def test_two_variables_on_one_topic_do_not_start(tmp_path: Path) -> None:
    tree = make_tree(
        variables=[
            {"path": "Axes/X", "source": "a", "type": "Double"},
            {"path": "Other", "source": "b", "type": "Double", "mqtt": {"topic": "axes/x"}},
        ]
    )
    with pytest.raises(SinkError, match="both publish to 'cnc/m1/axes/x'"):
        MqttSink(tree, MqttConfig(), tmp_path, tree.mappings)
