"""Store-and-forward: nothing is published into the void. While the primary host is offline (or the broker
away) changes are stored; after the next births they arrive as historical DDATA, oldest first, each
message either all historical or all live; the NDEATH always matches its NBIRTH's bdSeq."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime
from pathlib import Path

from gateway.model.tree import Machine
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import sink_rig, sparkplug_config, start_host, typed_mapping
from tests.integration.sparkplug.host import Seen, SparkplugHost
from tests.waiting import wait_until

X = "Axes/X/Position"


async def change(machine: Machine, values: range) -> None:
    """One change a publishing cycle, each with its own source time."""
    for value in values:
        machine.ingest(machine.nodes[X], float(value), datetime.now(UTC))
        await asyncio.sleep(0.002)


def x_values(messages: list[Seen], *, historical: bool) -> list[float]:
    return [
        v for s in messages if s.kind == "DDATA" for (n, v, _, h) in s.values() if n == X and h == historical
    ]


def bdseq_of(seen: Seen | None) -> int:
    assert seen is not None
    metric = seen.metric("bdSeq")
    assert metric is not None
    return int(metric.value)


async def test_the_primary_hosts_state_gates_births_and_stored_data_goes_out_historical(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port, host_id="scada", online=False)
    config = sparkplug_config(mosquitto.port, primary_host_id="scada")
    async with sink_rig(tmp_path, typed_mapping(), config) as rig:
        sink, machine = rig.sink, rig.tree.machines["m1"]
        await wait_until(lambda: sink.connected, message="the broker connection")
        await change(machine, range(50))
        await wait_until(lambda: sink.changes_stored >= 50, message="50 changes stored")
        assert host.count() == 0 and not sink.born  # no STATE yet: nothing published

        host.publish_state(True)
        await wait_until(
            lambda: x_values(host.since(0), historical=True) == [float(v) for v in range(50)],
            message="the stored changes, historical, oldest first",
        )
        kinds = [s.kind for s in host.since(0)]
        assert kinds[:2] == ["NBIRTH", "DBIRTH"]  # births first, then the stored data
        first = host.of("NBIRTH")[0]
        assert host.of("DBIRTH", "m1")[0].metric(X).value == 49.0  # type: ignore[union-attr]
        await change(machine, range(50, 60))
        await wait_until(
            lambda: x_values(host.since(0), historical=False)[-1:] == [59.0], message="live data"
        )
        assert x_values(host.since(0), historical=False) == [float(v) for v in range(50, 60)]
        for seen in host.of("DDATA", "m1"):  # never mixed in one message
            assert len({m.is_historical for m in seen.payload.metrics}) == 1

        # The host goes offline: NDEATH with this session's bdSeq, a new connection, data stored again.
        mark = host.count()
        host.publish_state(False)
        await wait_until(lambda: host.of("NDEATH"), message="the NDEATH")
        assert bdseq_of(host.of("NDEATH")[0]) == bdseq_of(first)
        await wait_until(lambda: sink.connects == 2 and sink.connected, message="the next connection")
        stored = sink.changes_stored
        await change(machine, range(60, 70))
        await wait_until(lambda: sink.changes_stored >= stored + 10, message="stored while the host is away")
        host.publish_state(True)
        await wait_until(lambda: len(host.of("NBIRTH")) == 2, message="the births of the next session")
        assert bdseq_of(host.of("NBIRTH")[1]) == (bdseq_of(first) + 1) % 256
        await wait_until(
            lambda: x_values(host.since(mark), historical=True)[-1:] == [69.0],
            message="the second outage's changes",
        )
        assert x_values(host.since(mark), historical=True) == [float(v) for v in range(60, 70)]
        assert sink.backlog is not None and not sink.backlog


async def test_a_broker_outage_without_a_primary_host(
    queueing_broker: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    broker = queueing_broker
    host = start_host(hosts, broker.port, persistent=True)
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(broker.port)) as rig:
        sink, machine = rig.sink, rig.tree.machines["m1"]
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        await change(machine, range(10))
        await wait_until(lambda: x_values(host.since(0), historical=False)[-1:] == [9.0], message="live data")
        await asyncio.to_thread(broker.stop)
        await wait_until(lambda: not sink.connected, message="the loss, noticed")
        await change(machine, range(10, 40))
        await asyncio.to_thread(broker.start)
        await wait_until(
            lambda: len(host.of("NBIRTH")) == 2, timeout=20, message="the births after the outage"
        )
        first, second = host.of("NBIRTH")
        assert bdseq_of(second) == (bdseq_of(first) + 1) % 256  # the next CONNECT, the next bdSeq
        await wait_until(lambda: sink.settled, message="everything delivered")
        await wait_until(
            lambda: (
                39.0 in x_values(host.since(0), historical=True) + x_values(host.since(0), historical=False)
            ),
            message="the last change",
        )
    seen = x_values(host.since(0), historical=False) + x_values(host.since(0), historical=True)
    assert set(seen) == {float(v) for v in range(40)}  # every change, live or historical; none lost
    assert x_values(host.since(0), historical=True)[-1] == 39.0


async def test_bad_quality_while_reachable_is_a_property_change_not_a_death(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(mosquitto.port)) as rig:
        machine = rig.tree.machines["m1"]
        node = machine.nodes[X]
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        machine.ingest(node, 1.0, datetime.now(UTC))
        await wait_until(lambda: host.quality("m1", X) == 192, message="Good")
        machine.ingest(node, None, datetime.now(UTC), "BadNodeIdUnknown", "the controller lost the node")
        await wait_until(lambda: host.quality("m1", X) == 0, message="Bad, as a property")
        assert host.value("m1", X) == 1.0 and host.of("DDEATH") == []
        machine.ingest(node, 2.0, datetime.now(UTC))
        await wait_until(
            lambda: host.quality("m1", X) == 192 and host.value("m1", X) == 2.0, message="Good again"
        )
        assert len(host.of("DBIRTH")) == 1


async def test_a_clean_stop_publishes_the_ndeath_of_its_session(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    config = sparkplug_config(mosquitto.port)
    async with sink_rig(tmp_path, typed_mapping(), config):
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
    await wait_until(lambda: host.of("NDEATH"), message="the NDEATH")
    async with sink_rig(tmp_path, typed_mapping(), config):  # the same state directory: the next bdSeq
        await wait_until(lambda: len(host.of("NBIRTH")) == 2, message="the next session")
    first, second = host.of("NBIRTH")
    assert bdseq_of(host.of("NDEATH")[0]) == bdseq_of(first)
    assert bdseq_of(second) == bdseq_of(first) + 1
    kinds = [s.kind for s in host.since(0)]
    assert kinds.count("NDEATH") >= 1 and kinds.index("NDEATH") < kinds.index("NBIRTH", 1)
    assert host.of("NDEATH")[0].payload.seq is None  # an NDEATH carries no seq


async def test_stored_data_survives_a_restart_with_buffer_persist(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port, host_id="scada", online=False)
    config = sparkplug_config(mosquitto.port, primary_host_id="scada", buffer={"persist": True})
    async with sink_rig(tmp_path, typed_mapping(), config) as rig:
        await wait_until(lambda: rig.sink.connected, message="the broker connection")
        await change(rig.tree.machines["m1"], range(20))
        await wait_until(lambda: rig.sink.changes_stored >= 20, message="stored")
    assert (tmp_path / "state" / "sparkplug-backlog.sqlite3").exists()
    async with sink_rig(tmp_path, typed_mapping(), config) as rig:  # a new process, the same state directory
        assert rig.sink.backlog is not None and len(rig.sink.backlog) > 0
        await wait_until(lambda: rig.sink.connected, message="the broker connection")
        host.publish_state(True)
        await wait_until(
            lambda: x_values(host.since(0), historical=True)[-1:] == [19.0],
            message="the last run's changes, historical",
        )
        await wait_until(lambda: rig.sink.settled, message="delivered and fenced")
        assert not rig.sink.backlog
    assert x_values(host.since(0), historical=True) == [float(v) for v in range(20)]
