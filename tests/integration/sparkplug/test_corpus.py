"""tests/corpus/sparkplug/commands.yaml over a real broker: each NCMD and DCMD reaches the edge node and
is refused, counted by its kind, and nothing is written, called or reborn; the node keeps going."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from google.protobuf.message import DecodeError

from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.config.mapping import MachineMapping
from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import sink_rig, sparkplug_config, start_host
from tests.integration.sparkplug.host import SparkplugHost
from tests.unit.codecs.sparkplug.test_corpus import CASES, payload_of
from tests.waiting import wait_until

# The births the corpus names (its header), by alias; the edge node binds its own numbers.
DEVICE_ALIASES = {
    10: "Axes/X/Position",
    11: "Feed/Override",
    12: "Laser/On",
    13: "Program/Name",
    14: "ActiveAlarms/Codes",
    15: "ActiveAlarms/Acked",
    16: "ActiveAlarms/Texts",
    17: "Program/Started",
}
TYPES = {
    "Axes/X/Position": "Double",
    "Feed/Override": "UInt16",
    "Laser/On": "Boolean",
    "Program/Name": "String",
    "ActiveAlarms/Codes": "Int32[]",
    "ActiveAlarms/Acked": "Boolean[]",
    "ActiveAlarms/Texts": "String[]",
    "Program/Started": "DateTime",
}
UNBOUND = 9_999  # an alias the edge node did not bind, for the corpus's unbound ones


def corpus_mapping() -> MachineMapping:
    return MachineMapping.model_validate(
        {
            "machine": "m1",
            "driver": {"endpoint": "opc.tcp://127.0.0.1:1"},
            "variables": [
                {"path": p, "source": p, "type": t, "access": "readwrite"} for p, t in TYPES.items()
            ],
            "mqtt": {"writable": True},
        }
    )


def translated(data: bytes, aliases: dict[int, int]) -> bytes:
    """The case with the corpus's aliases as the edge node bound them (bytes that are no protobuf: as is)."""
    try:
        payload = Payload.FromString(data)
    except DecodeError:
        return data
    if not any(m.HasField("alias") for m in payload.metrics):
        return data
    for m in payload.metrics:
        if m.HasField("alias"):
            m.alias = aliases.get(m.alias, UNBOUND)
    return payload.SerializeToString()


async def test_every_corpus_command_is_refused_over_the_broker(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with sink_rig(tmp_path, corpus_mapping(), sparkplug_config(mosquitto.port)) as rig:
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        nbirth = host.last("NBIRTH")
        assert nbirth is not None and nbirth.metric("Gateway/Version") is not None
        aliases = {corpus: host.alias("m1", name) for corpus, name in DEVICE_ALIASES.items()}
        aliases[1] = nbirth.metric("Gateway/Version").alias  # type: ignore[union-attr,assignment]
        requests = rig.sink.requests
        assert requests is not None
        births = len(host.of("NBIRTH"))
        for case in CASES:
            before = dict(requests.refusals)
            topic = (
                "spBv1.0/cnc/NCMD/cnc-gateway"
                if case["message"] == "NCMD"
                else "spBv1.0/cnc/DCMD/cnc-gateway/m1"
            )
            host.send(topic, translated(payload_of(case), aliases))
            kind = case["expect"]["kind"]
            await wait_until(
                lambda k=kind, b=before: requests.refusals[k] == b.get(k, 0) + 1,  # type: ignore[misc]
                message=f"{case['name']}: refused as {kind}",
            )
            assert sum(requests.refusals.values()) == sum(before.values()) + 1, case["name"]
        assert rig.controller.written == [] and requests.accepted == 0 and requests.rebirths == 0
        assert len(host.of("NBIRTH")) == births
        # Still the same session, still publishing.
        machine = rig.tree.machines["m1"]
        machine.ingest(machine.nodes["Axes/X/Position"], 4.5, datetime.now(UTC))
        await wait_until(lambda: host.value("m1", "Axes/X/Position") == 4.5, message="data after the junk")
        counted: dict[str, Any] = dict(requests.refusals)
        assert sum(counted.values()) == len(CASES)
