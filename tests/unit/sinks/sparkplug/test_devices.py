"""A machine as a Sparkplug device: metrics, aliases, quality as a property, commands as metrics."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from gateway.codecs.sparkplug import Aliases, Quality, SparkplugType
from gateway.config.mapping import MachineMapping
from gateway.errors import InvalidArgument, TooManyArguments
from gateway.model.context import WriteContext
from gateway.model.methods import Argument, Method
from gateway.model.sample import Sample
from gateway.model.types import TypeSpec
from gateway.sinks.sparkplug.devices import Device, dcmd_writable, millis, value_of
from tests.trees import MappedTree

T = TypeSpec.parse
MAPPING = MachineMapping.model_validate(
    {
        "machine": "m1",
        "driver": {"endpoint": "opc.tcp://127.0.0.1:1"},
        "mqtt": {"writable": True, "commands": True},
        "variables": [
            {
                "path": "Axes/X/Position",
                "source": "x",
                "type": "Double",
                "unit": "mm",
                "description": "X",
                "range": {"min": -10, "max": 3000},
            },
            {"path": "Feed/Override", "source": "o", "type": "UInt16", "access": "readwrite"},
            {
                "path": "Feed/Locked",
                "source": "l",
                "type": "Boolean",
                "access": "readwrite",
                "mqtt": {"writable": False},
            },
            {"path": "ActiveAlarms/Codes", "source": "c", "type": "Int32[]"},
        ],
    }
)


async def _handler(ctx: WriteContext, args: Sequence[Any]) -> Sequence[Any]:
    return ("done", 1.0)


def method(name: str, *types: str) -> Method:
    inputs = tuple(Argument(f"a{i}", T(t)) for i, t in enumerate(types))
    return Method("Commands", name, f"run {name}", inputs, (), _handler)


def device(aliases: Aliases | None = None) -> Device:
    tree = MappedTree([MAPPING])
    machine = tree.machines["m1"]
    machine.add_method(method("start"))
    machine.add_method(method("select", "String"))
    machine.add_method(method("move", "Double", "Double"))
    return Device(machine, "cnc", "cnc-gateway", aliases or Aliases(), tree.mappings["m1"])


def test_topics_and_one_alias_per_metric_unique_across_the_node() -> None:
    aliases = Aliases()
    node_alias = aliases.alias(None, "Gateway/Version")
    d = device(aliases)
    assert (d.ddata, d.dbirth, d.ddeath) == (
        "spBv1.0/cnc/DDATA/cnc-gateway/m1",
        "spBv1.0/cnc/DBIRTH/cnc-gateway/m1",
        "spBv1.0/cnc/DDEATH/cnc-gateway/m1",
    )
    numbers = list(d.by_name.values())
    assert len(set(numbers)) == len(numbers) and node_alias not in numbers
    assert {"Axes/X/Position", "Status/Connected", "Commands/start/Execute", "Commands/move/Result"} <= set(
        d.by_name
    )
    assert d.table.by_alias(d.by_name["Feed/Override"]).name == "Feed/Override"  # type: ignore[union-attr]


def test_the_birth_has_every_metric_with_its_properties() -> None:
    d = device()
    metrics = {m.name: m for m in d.birth_metrics()}
    assert set(metrics) == set(d.by_name)
    x = metrics["Axes/X/Position"]
    assert x.value is None  # no value yet: a null
    props = {k: p.value for k, p in x.properties.items()}
    assert props == {
        "engUnit": "mm",
        "engLow": -10.0,
        "engHigh": 3000.0,
        "documentation": "X",
        "readOnly": True,
        "Quality": int(Quality.BAD),
    }
    assert metrics["Feed/Override"].properties["readOnly"].value is False
    assert (
        metrics["Feed/Locked"].properties["readOnly"].value is True
    )  # the mapping keeps it from MQTT writes
    assert metrics["ActiveAlarms/Codes"].datatype is SparkplugType.Int32Array
    assert metrics["Commands/start/Execute"].datatype is SparkplugType.Boolean
    assert metrics["Commands/start/Execute"].value is False
    assert metrics["Commands/select/Execute"].datatype is SparkplugType.String
    assert metrics["Commands/move/Execute"].datatype is SparkplugType.String  # a JSON object of the arguments
    assert metrics["Commands/move/Result"].properties["readOnly"].value is True


def test_quality_goes_with_a_change_only_when_it_changes() -> None:
    d = device()
    x = d.variables[d.machine.nodes["Axes/X/Position"]]
    now = datetime(2026, 5, 6, 7, 8, 9, 123456, tzinfo=UTC)
    first = x.change(Sample(1.0, now))
    assert (
        first.properties["Quality"].value == 192 and first.timestamp == millis(now) and first.alias == x.alias
    )
    assert x.change(Sample(2.0, now)).properties == {}
    bad = x.change(Sample(2.0, now, "BadNodeIdUnknown", "gone"))
    assert bad.value == 2.0 and bad.properties["Quality"].value == 0  # the last value, Bad
    assert x.change(Sample(2.0, now, "UncertainLastUsableValue")).properties["Quality"].value == 500


def test_times_and_values() -> None:
    assert millis(datetime(1970, 1, 1, 0, 0, 1, 999, tzinfo=UTC)) == 1000
    assert millis(datetime(1970, 1, 1, 0, 0, 1)) == 1000  # naive: UTC
    assert (
        millis(datetime(1969, 12, 31, 23, 59, 59, 500000, tzinfo=UTC)) == 0
    )  # no Sparkplug time before 1970
    assert value_of(Sample(0.0, datetime.now(UTC) - timedelta(1), "BadWaitingForInitialData")) is None
    assert value_of(Sample(3.5, datetime.now(UTC), "BadNotConnected")) == 3.5


def test_which_variables_dcmd_may_write_follows_the_mappings_mqtt_settings() -> None:
    d = device()
    nodes = d.machine.nodes
    assert dcmd_writable(nodes["Feed/Override"], MAPPING)
    assert not dcmd_writable(nodes["Feed/Locked"], MAPPING)  # the variable says no
    assert not dcmd_writable(nodes["Axes/X/Position"], MAPPING)  # read-only
    assert not dcmd_writable(nodes["Status/State"], MAPPING)  # the gateway's own
    closed = MAPPING.model_copy(update={"mqtt": None})
    assert not dcmd_writable(nodes["Feed/Override"], closed)


def test_a_commands_arguments_from_the_value_written_to_execute() -> None:
    d = device()
    start, select, move = d.commands
    assert start.arguments(True) == []
    with pytest.raises(InvalidArgument, match="write true"):
        start.arguments(False)
    assert select.arguments("part.nc") == ["part.nc"]
    assert move.arguments('{"a0": 1.5, "a1": 2}') == [1.5, 2]
    with pytest.raises(TooManyArguments):
        move.arguments('{"a0": 1, "a1": 2, "a2": 3}')
    execute, result = start.metrics(5, birth=False)
    assert (execute.value, result.value, execute.properties, result.properties) == (False, "", {}, {})
