"""Every gateway type, scalar and array, both ways over a real broker: tree → DBIRTH/DDATA → host, and
host → DCMD → the write path → the controller, read back and shown again."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest

from tests.integration.mqtt.conftest import Mosquitto
from tests.integration.sparkplug.conftest import TYPES, sink_rig, sparkplug_config, start_host, typed_mapping
from tests.integration.sparkplug.host import SparkplugHost
from tests.waiting import wait_until

WHEN = datetime(2024, 5, 6, 7, 8, 9, 123000, tzinfo=UTC)
# (value published, value written back) per type
VALUES: dict[str, tuple[Any, Any]] = {
    "Boolean": (True, False),
    "SByte": (-128, 127),
    "Byte": (255, 7),
    "Int16": (-32768, 32767),
    "UInt16": (65535, 1),
    "Int32": (-(2**31), 2**31 - 1),
    "UInt32": (2**32 - 1, 3),
    "Int64": (-(2**63), 2**63 - 1),
    "UInt64": (2**64 - 1, 2**63 + 5),
    "Float": (1.5, -0.25),
    "Double": (3.141592653589793, -1e300),
    "String": ("Grüße ✓", ""),
    "DateTime": (WHEN, datetime(1969, 12, 31, 23, 59, 59, 1000, tzinfo=UTC)),
}
# Sparkplug datatype numbers, from the specification's table: scalar, array
DATATYPES = {
    "Boolean": (11, 32),
    "SByte": (1, 22),
    "Byte": (5, 26),
    "Int16": (2, 23),
    "UInt16": (6, 27),
    "Int32": (3, 24),
    "UInt32": (7, 28),
    "Int64": (4, 25),
    "UInt64": (8, 29),
    "Float": (9, 30),
    "Double": (10, 31),
    "String": (12, 33),
    "DateTime": (13, 34),
}


def array_of(name: str, value: Any) -> list[Any]:
    if name == "Boolean":
        return [True, False, True, True, False, False, False, False, True]  # nine: two bytes of bits
    if name == "String":
        return ["a", "", "Grüße"]
    return [value, value]


async def test_every_type_round_trips_both_ways(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(mosquitto.port)) as rig:
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        birth = host.last("DBIRTH", "m1")
        assert birth is not None
        for name in TYPES:
            scalar, array = DATATYPES[name]
            assert birth.metric(f"T/{name}").datatype == scalar  # type: ignore[union-attr]
            assert birth.metric(f"A/{name}").datatype == array  # type: ignore[union-attr]
            assert birth.metric(f"T/{name}").is_null  # type: ignore[union-attr]  # no value yet: a null

        machine = rig.tree.machines["m1"]
        for name in TYPES:  # the tree to the host
            value = VALUES[name][0]
            machine.ingest(machine.nodes[f"T/{name}"], value, WHEN)
            machine.ingest(machine.nodes[f"A/{name}"], array_of(name, value), WHEN)
        await wait_until(lambda: host.value("m1", "T/DateTime") == WHEN, message="the values at the host")
        for name in TYPES:
            value = VALUES[name][0]
            assert host.value("m1", f"T/{name}") == value, name
            assert host.value("m1", f"A/{name}") == array_of(name, value), name
            assert host.quality("m1", f"T/{name}") == 192  # Good now, after a null

        for name in TYPES:  # the host to the controller, through the write path, and shown again
            value = VALUES[name][1]
            host.write("m1", f"T/{name}", value)
            host.write("m1", f"A/{name}", array_of(name, value))
        await wait_until(lambda: len(rig.controller.written) == 2 * len(TYPES), message="every write")
        written = dict(rig.controller.written)
        for name in TYPES:
            value = VALUES[name][1]
            assert written[f"T/{name}"] == value, name
            assert written[f"A/{name}"] == array_of(name, value), name
        await wait_until(
            lambda: all(host.value("m1", f"T/{n}") == VALUES[n][1] for n in TYPES),
            message="the written values, read back, at the host",
        )
        assert rig.sink.refusals == {} and rig.sink.requests is not None
        assert rig.sink.requests.accepted == 2 * len(TYPES)


async def test_a_value_its_type_cannot_carry_is_left_out_and_the_rest_goes_on(
    mosquitto: Mosquitto, hosts: list[SparkplugHost], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    host = start_host(hosts, mosquitto.port)
    async with sink_rig(tmp_path, typed_mapping(), sparkplug_config(mosquitto.port)) as rig:
        await wait_until(lambda: host.last("DBIRTH", "m1"), message="the DBIRTH")
        machine = rig.tree.machines["m1"]
        # A driver that hands a String variable a number, and a controller clock before 1970.
        machine.ingest(machine.nodes["T/String"], 5, WHEN)
        machine.ingest(machine.nodes["Axes/X/Position"], 1.25, datetime(1601, 1, 1, tzinfo=UTC))
        await wait_until(lambda: host.value("m1", "Axes/X/Position") == 1.25, message="the rest of the cycle")
        assert host.value("m1", "T/String") is None
        host.rebirth()
        await wait_until(lambda: len(host.of("DBIRTH", "m1")) == 2, message="the births again")
        string = host.last("DBIRTH", "m1").metric("T/String")  # type: ignore[union-attr]
        assert string is not None and string.is_null and string.properties["Quality"][1] == 0
        x = host.last("DBIRTH", "m1").metric("Axes/X/Position")  # type: ignore[union-attr]
        assert x is not None and x.value == 1.25 and x.timestamp == 0
        assert rig.sink.born and "T/String" in caplog.text
