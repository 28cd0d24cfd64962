"""A session as a host sees it: births after the connect and after a rebirth request, aliases, seq."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import (
    MACHINE,
    laser_sparkplug,
    sink_rig,
    sparkplug_config,
    start_host,
    typed_mapping,
)
from tests.integration.sparkplug.host import REBIRTH, Seen, SparkplugHost
from tests.unit.codecs.sparkplug import host as spec
from tests.waiting import wait_until

NODE_METRICS = {
    "Gateway/Version",
    "Gateway/Machines",
    "Gateway/MachinesConnected",
    "Gateway/MqttDropped",
    "Sparkplug/Dropped",
    "Sparkplug/Stored",
    "Sparkplug/CommandsRefused",
    "Jobs/QueueLength",
    "Jobs/Sending",
    "Jobs/FailedCount",
}


def online_birth(host: SparkplugHost) -> Seen | None:
    """The machine's latest DBIRTH if it was born with its controller connected."""
    birth = host.last("DBIRTH", MACHINE)
    connected = birth.metric("Status/Connected") if birth is not None else None
    return birth if connected is not None and connected.value is True else None


def seq_gaps(messages: list[object]) -> list[tuple[int, int]]:
    """(expected, got) wherever a message's seq is not the one after the previous (NBIRTH starts at 0)."""
    gaps = []
    previous: int | None = None
    for seen in messages:
        kind, seq = seen.kind, seen.seq  # type: ignore[attr-defined]
        if kind == "NDEATH":
            previous = None
            continue
        if kind == "NBIRTH":
            if seq != 0:
                gaps.append((0, seq))
            previous = 0
            continue
        if previous is not None and seq != (previous + 1) % 256:
            gaps.append(((previous + 1) % 256, seq))
        previous = seq
    return gaps


async def test_births_after_connect_and_again_after_a_rebirth_request(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with laser_sparkplug(tmp_path, sparkplug_config(mosquitto.port)) as laser:
        await wait_until(lambda: online_birth(host), message="the DBIRTH of the machine online")
        nbirth = host.of("NBIRTH")[0]
        assert nbirth.topic == "spBv1.0/cnc/NBIRTH/cnc-gateway" and nbirth.seq == 0
        bdseq = nbirth.metric("bdSeq")
        rebirth = nbirth.metric(REBIRTH)
        assert bdseq is not None and bdseq.datatype == spec.INT64 and bdseq.value == laser.sink.bdseq
        assert rebirth is not None and rebirth.value is False and rebirth.alias is None
        assert {m.name for m in nbirth.payload.metrics} == NODE_METRICS | {"bdSeq", REBIRTH}
        assert nbirth.metric("Gateway/Machines").value == 1  # type: ignore[union-attr]

        assert host.of("DBIRTH", MACHINE)[0].seq == 1  # right after the NBIRTH (a DDEATH after it if the
        dbirth = online_birth(host)  # simulator was not connected yet; then a DBIRTH again when it was)
        assert dbirth is not None and dbirth.topic == f"spBv1.0/cnc/DBIRTH/cnc-gateway/{MACHINE}"
        names = {m.name for m in dbirth.payload.metrics}
        assert set(laser.machine.nodes) <= names  # every variable, Status/* included
        assert {p for p in names if p.startswith("Status/")} >= {"Status/Connected", "Status/State"}
        assert {"Commands/start/Execute", "Commands/start/Result", "Commands/select-program/Execute"} <= names
        for m in dbirth.payload.metrics:  # name, alias, datatype, timestamp, and a value or a null
            assert m.alias is not None and m.datatype and m.timestamp and (m.value is not None or m.is_null)
        x = dbirth.metric("Axes/X/Position")
        assert x is not None and x.datatype == spec.DOUBLE
        assert x.properties["engUnit"] == (spec.STRING, "mm") and x.properties["Quality"][0] == spec.INT32
        await wait_until(lambda: host.quality(MACHINE, "Axes/X/Position") == 192, message="X, Good")
        override = dbirth.metric("Feed/Override")
        assert override is not None and override.datatype == spec.UINT16
        assert override.properties["engLow"] == (spec.DOUBLE, 0.0) and override.properties["engHigh"] == (
            spec.DOUBLE,
            150.0,
        )
        assert override.properties["readOnly"] == (spec.BOOLEAN, False)
        assert dbirth.metric("Laser/PowerTable").datatype == 31  # type: ignore[union-attr]  # DoubleArray
        assert dbirth.metric("Commands/start/Execute").datatype == spec.BOOLEAN  # type: ignore[union-attr]
        assert dbirth.metric("Commands/select-program/Execute").datatype == spec.STRING  # type: ignore[union-attr]
        aliases = {m.name: m.alias for m in dbirth.payload.metrics}

        mark = host.count()
        births = len(host.of("DBIRTH", MACHINE))
        host.rebirth()
        await wait_until(
            lambda: len(host.of("NBIRTH")) == 2 and len(host.of("DBIRTH", MACHINE)) > births,
            message="the births again",
        )
        again = host.of("NBIRTH")[1]
        assert again.seq == 0 and again.metric("bdSeq").value == bdseq.value  # type: ignore[union-attr]
        reborn = host.of("DBIRTH", MACHINE)[-1]
        assert reborn.seq == 1 and {m.name: m.alias for m in reborn.payload.metrics} == aliases
        assert reborn.metric("Status/Connected").value is True  # type: ignore[union-attr]
        after = [s.kind for s in host.since(mark)]
        assert after.index("NBIRTH") < after.index("DBIRTH") and "DDEATH" not in after
        assert laser.sink.requests is not None and laser.sink.requests.rebirths == 1


async def test_ddata_by_alias_as_the_birth_bound_them(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with laser_sparkplug(tmp_path, sparkplug_config(mosquitto.port), loop_program="demo.nc"):
        await wait_until(lambda: online_birth(host), message="the DBIRTH of the machine online")
        mark = host.count()
        await wait_until(
            lambda: sum(1 for s in host.since(mark) if s.kind == "DDATA") >= 20,
            timeout=30,
            message="20 DDATA of the running program",
        )
    birth = online_birth(host)
    assert birth is not None
    bound = {m.alias: (m.name, m.datatype) for m in birth.payload.metrics}
    ddata = [s for s in host.since(mark) if s.kind == "DDATA"]
    for seen in ddata:
        for m in seen.payload.metrics:
            assert m.name is None and m.alias in bound  # by alias only, one the birth bound
            assert m.datatype is not None and not m.is_historical and m.timestamp
        stamps = [m.timestamp for m in seen.payload.metrics]
        assert stamps == sorted(stamps)  # chronological within a message
    changed = {bound[m.alias][0] for s in ddata for m in s.payload.metrics}
    assert {"Axes/X/Position", "Program/Block"} <= changed
    assert isinstance(host.value(MACHINE, "Axes/X/Position"), float)


async def test_seq_runs_over_every_message_of_the_node_without_a_gap_across_wraps(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(mosquitto.port)) as rig:
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        machine = rig.tree.machines["m1"]
        x = machine.nodes["Axes/X/Position"]
        for i in range(600):  # one change per publishing cycle: one DDATA each
            machine.ingest(x, float(i), datetime.now(UTC))
            await wait_until(lambda: rig.sink.settled, interval=0.001, message="the change published")
            if i == 300:
                host.rebirth()  # a rebirth midway starts the count again at the NBIRTH
        await wait_until(lambda: host.value("m1", "Axes/X/Position") == 599.0, message="the last change")
    messages = host.since(0)
    assert len(messages) > 600 and seq_gaps(messages) == []
    assert sum(1 for s in messages if s.seq == 255) >= 2  # it wrapped, twice
    assert [s.kind for s in messages].count("NBIRTH") == 2
    values = [
        v for s in host.of("DDATA", "m1") for (name, v, _, _) in s.values() if name == "Axes/X/Position"
    ]
    assert values == [float(i) for i in range(600)]
