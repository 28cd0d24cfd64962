"""QoS 1 on the sink's packet path (issue 28), against a broker written from the MQTT specification.

The sink encodes QoS 1 PUBLISH packets itself and reads their PUBACKs out of the
receive buffer; tests/integration/mqtt/spec_broker.py is the other side, written
from the standard, not from the sink: it records each PUBLISH's flags and packet
id and answers by policy. What the sink must do: every change once and in order,
never more unacknowledged than its window (or the broker's Receive Maximum), the
unacknowledged ones sent again with DUP after the connection drops, a refusal
counted and not re-sent, junk on the acknowledgement path refused without a
traceback (tests/corpus/mqtt/acks.yaml).
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.config.mapping import MachineMapping
from gateway.sinks.mqtt.sink import MqttSink
from tests.integration.mqtt.conftest import mqtt_config
from tests.integration.mqtt.spec_broker import Seen, SpecBroker
from tests.trees import MappedTree
from tests.waiting import free_port, wait_until

CORPUS = Path(__file__).parents[2] / "corpus" / "mqtt" / "acks.yaml"
MAPPING = {
    "machine": "m1",
    "driver": {"endpoint": "opc.tcp://127.0.0.1:4841"},
    "variables": [
        {"path": "Axes/X/Position", "source": "x", "type": "Double"},
        {"path": "Axes/Y/Position", "source": "y", "type": "Double"},
    ],
}
START = datetime(2026, 11, 28, 12, 0, tzinfo=UTC)


@asynccontextmanager
async def running(
    broker: SpecBroker, tmp_path: Path, **mqtt: Any
) -> AsyncIterator[tuple[MqttSink, MappedTree]]:
    tree = MappedTree([MachineMapping.model_validate(MAPPING)])
    cfg = mqtt_config(broker.port, qos=1, retain=False, protocol="5" if broker.v5 else "3.1.1", **mqtt)
    sink = MqttSink(tree, cfg, tmp_path / "state", tree.mappings)
    async with sink:
        task = asyncio.create_task(sink.run(), name="test:mqtt")
        try:
            await wait_until(lambda: sink.online, timeout=10, message="the sink to connect")
            yield sink, tree
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)


@asynccontextmanager
async def spec_broker(**kwargs: Any) -> AsyncIterator[SpecBroker]:
    broker = await SpecBroker(**kwargs).start(free_port())
    try:
        yield broker
    finally:
        await broker.stop()


def feed(tree: MappedTree, path: str, values: range) -> list[float]:
    """Distinct changes of one variable (each value a new float, each a later source time)."""
    machine = tree.machines["m1"]
    node = machine.nodes[path]
    out = []
    for i in values:
        machine.ingest(node, float(i), START + timedelta(milliseconds=i))
        out.append(float(i))
    return out


def values(seen: list[Seen]) -> list[float]:
    return [json.loads(s.payload)["value"] for s in seen]


def topic_of(sink: MqttSink, tree: MappedTree, path: str) -> str:
    return sink.routes.by_node[tree.machines["m1"].nodes[path]].topic


@pytest.mark.parametrize("v5", [False, True], ids=["3.1.1", "5"])
async def test_every_change_once_in_order_and_acknowledged_in_bulk(tmp_path: Path, v5: bool) -> None:
    async with spec_broker(v5=v5) as broker, running(broker, tmp_path) as (sink, tree):
        topic = topic_of(sink, tree, "Axes/X/Position")
        sent = feed(tree, "Axes/X/Position", range(2000))
        await wait_until(lambda: len(broker.published(topic)) >= len(sent), timeout=15, message="all changes")
        await wait_until(lambda: sink.settled, timeout=10, message="every PUBACK taken")
        got = broker.published(topic)
        assert values(got) == sent
        assert all(s.qos == 1 and not s.dup and not s.retain for s in got)
        assert sink.in_flight == 0 and sink.resent == 0 and sink.refused == 0


async def test_never_more_unacknowledged_than_the_window(tmp_path: Path) -> None:
    async with spec_broker(hold=True) as broker, running(broker, tmp_path, max_inflight=10) as (sink, tree):
        topic = topic_of(sink, tree, "Axes/X/Position")
        sent = feed(tree, "Axes/X/Position", range(50))
        await wait_until(lambda: broker.outstanding() == 10, timeout=10, message="a full window")
        # The sink has taken (nearly) every change and kept the rest back, not sent it.
        await wait_until(lambda: len(sink.backlog or ()) >= 40, timeout=10, message="the rest kept back")
        assert broker.outstanding() == 10 and sink.in_flight == 10
        # Acknowledged a window at a time: the rest follow, still in order, never more than 10 out.
        while len(broker.published(topic)) < len(sent):
            broker.hold = True
            mark = len(broker.seen)
            broker.release()
            broker.hold = True
            await wait_until(lambda m=mark: len(broker.seen) > m, timeout=10, message="the next window")
            assert broker.outstanding() <= 10
        broker.release()
        assert values(broker.published(topic)) == sent


async def test_the_brokers_receive_maximum_caps_the_window(tmp_path: Path) -> None:
    async with (
        spec_broker(v5=True, hold=True, receive_maximum=3) as broker,
        running(broker, tmp_path, max_inflight=100) as (sink, tree),
    ):
        feed(tree, "Axes/X/Position", range(20))
        await wait_until(lambda: broker.outstanding() == 3, timeout=10, message="the broker's window filled")
        await wait_until(lambda: len(sink.backlog or ()) >= 17, timeout=10, message="the rest kept back")
        assert broker.outstanding() == 3 and sink.in_flight == 3


async def test_unacknowledged_changes_are_sent_again_with_dup_after_a_drop(tmp_path: Path) -> None:
    async with spec_broker(hold=True) as broker, running(broker, tmp_path, max_inflight=20) as (sink, tree):
        topic = topic_of(sink, tree, "Axes/X/Position")
        sent = feed(tree, "Axes/X/Position", range(60))
        await wait_until(lambda: broker.outstanding() == 20, timeout=10, message="a full window")
        first = broker.published(topic)
        unacked = len(first)
        broker.hold = False
        broker.drop()
        await wait_until(lambda: broker.connections == 2 and sink.online, timeout=10, message="reconnected")
        await wait_until(lambda: sink.settled, timeout=10, message="everything acknowledged")
        again = [s for s in broker.published(topic) if s.connection == 2]
        # The unacknowledged come first, marked as re-deliveries; the rest were never sent, so not marked.
        assert values(again) == sent
        assert [s.dup for s in again] == [True] * unacked + [False] * (len(sent) - unacked)
        assert sink.resent >= unacked  # and the status message that was in flight too
        assert sink.health().figures()["resent"] == sink.resent  # what /metrics shows


async def test_a_refusal_is_counted_and_not_sent_again(tmp_path: Path) -> None:
    def refuse_y(seen: Seen) -> bytes | None:
        if seen.topic.endswith("y/position") and seen.packet_id is not None:
            return b"\x40\x03" + seen.packet_id.to_bytes(2, "big") + b"\x87"  # Not authorized
        return None

    async with spec_broker(v5=True, answer=refuse_y) as broker, running(broker, tmp_path) as (sink, tree):
        y = topic_of(sink, tree, "Axes/Y/Position")
        feed(tree, "Axes/Y/Position", range(5))
        await wait_until(lambda: sink.refused == 5, timeout=10, message="five refusals")
        await wait_until(lambda: sink.settled, timeout=10, message="the window free again")
        assert len(broker.published(y)) == 5 and broker.connections == 1


def corpus() -> list[dict[str, Any]]:
    cases: list[dict[str, Any]] = yaml.safe_load(CORPUS.read_text())
    return cases


@pytest.mark.parametrize("case", corpus(), ids=lambda c: c["name"])
async def test_junk_on_the_acknowledgement_path(
    tmp_path: Path, case: dict[str, Any], caplog: pytest.LogCaptureFixture
) -> None:
    """Each answer of tests/corpus/mqtt/acks.yaml to the first change's PUBLISH: the connection is kept or
    ended as the case says, no traceback, and every change still reaches the broker in the end."""
    answered: list[int] = []

    def answer(seen: Seen) -> bytes | None:
        if seen.topic.endswith("x/position") and not answered and seen.packet_id is not None:
            answered.append(seen.packet_id)
            return reply(case, seen.packet_id)
        return None

    caplog.set_level(logging.DEBUG)
    v5 = bool(case.get("v5"))
    async with spec_broker(v5=v5, answer=answer) as broker, running(broker, tmp_path) as (sink, tree):
        topic = topic_of(sink, tree, "Axes/X/Position")
        sent = feed(tree, "Axes/X/Position", range(3))
        await wait_until(lambda: answered, timeout=10, message="the first change at the broker")
        if case["expect"]["connection"] == "ended":
            await wait_until(lambda: broker.connections >= 2, timeout=10, message="a new connection")
        for later in range(3, 6):  # the link still carries changes afterwards
            sent += feed(tree, "Axes/X/Position", range(later, later + 1))
        await wait_until(
            lambda: set(sent) <= set(values(broker.published(topic))), timeout=15, message="every change"
        )
        if case["expect"]["connection"] == "kept":
            assert broker.connections == 1
    assert not [r for r in caplog.records if r.exc_info], "a traceback in the log"


def reply(case: dict[str, Any], packet_id: int) -> bytes:
    template: str = case["hex"]
    return bytes.fromhex(
        template.replace("{id}", f"{packet_id:04x}").replace("{other}", f"{packet_id ^ 0x5555:04x}")
    )


async def test_unacknowledged_changes_survive_a_gateway_restart_in_the_journal(tmp_path: Path) -> None:
    """buffer.persist: what the broker had not acknowledged when the gateway stopped is sent by the next
    start, in order, before anything newer."""
    persist = {"buffer": {"persist": True}}
    async with spec_broker(hold=True) as broker:
        async with running(broker, tmp_path, max_inflight=20, **persist) as (sink, tree):
            topic = topic_of(sink, tree, "Axes/X/Position")
            sent = feed(tree, "Axes/X/Position", range(30))
            await wait_until(lambda: broker.outstanding() == 20, timeout=10, message="a full window")
            await wait_until(lambda: len(sink.backlog or ()) >= 10, timeout=10, message="the rest kept back")
        assert broker.published(topic) and all(s.connection == 1 for s in broker.published(topic))
        broker.hold = False
        broker.drop()
        async with running(broker, tmp_path, max_inflight=20, **persist) as (sink, tree):
            await wait_until(lambda: sink.settled, timeout=10, message="the kept changes acknowledged")
        second = [s for s in broker.published(topic) if s.connection > 1]
        assert values(second) == sent
