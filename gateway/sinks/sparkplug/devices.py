"""Each machine as a Sparkplug device: its metrics, their aliases, and a change as a metric value.

A device's metrics, in its DBIRTH:
- every variable of the machine (mapped ones, and the gateway's own `Status/*` and `Jobs/*`), named
  by its tree path, with the datatype mapped from its type (arrays included), its alias, its value
  and source timestamp, and the properties `engUnit`, `engLow`/`engHigh` (the range),
  `documentation`, `readOnly` and `Quality`;
- every mapped command as two metrics: `Commands/<name>/Execute`, which a host writes to run it
  (Boolean for a command without arguments, the argument's type for one with one, a JSON object
  as a String for more), and `Commands/<name>/Result`, what the last run ended with.

Choices where the specification is silent, after what Ignition's MQTT Engine does with them:
- a variable that never had a value (BadWaitingForInitialData) is a null with Quality BAD;
- a Bad or Uncertain value while the controller is reachable keeps its last value, and its
  Quality goes with it as the property, in DDATA only when it changes;
- the Execute/Result pair, not one metric: Ignition makes a folder of `a/b` and cannot also make
  `a` a tag, and a Result beside each command is the only answer a Sparkplug host can read.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any, Protocol

from gateway.codecs.sparkplug import (
    PROP_QUALITY,
    Aliases,
    Definition,
    MessageType,
    Metric,
    MetricTable,
    Property,
    Quality,
    SparkplugType,
    device_topic,
    metric_properties,
    quality_of_status,
)
from gateway.errors import InvalidArgument
from gateway.model.methods import Method
from gateway.model.sample import Sample
from gateway.model.tree import Machine, VariableNode
from gateway.model.types import DataType, TypeSpec
from gateway.sinks.mqtt_link.requests import arguments, read_body

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
MS = timedelta(milliseconds=1)
WAITING = "BadWaitingForInitialData"
COMMANDS = "Commands"  # the machine methods that are commands (gateway/commands/runner.py)
BOOLEAN = TypeSpec(DataType.BOOLEAN)
STRING = TypeSpec(DataType.STRING)

QUALITY_PROPERTY: dict[Quality, dict[str, Property]] = {
    q: {PROP_QUALITY: Property(SparkplugType.Int32, int(q))} for q in Quality
}
_QUALITY_OF: dict[str, Quality] = {}


def quality(status: str) -> Quality:
    """The Sparkplug quality of an OPC UA status name (cached: a handful of names recur)."""
    q = _QUALITY_OF.get(status)
    if q is None:
        q = _QUALITY_OF[status] = quality_of_status(status)
    return q


def millis(ts: datetime) -> int:
    """A timestamp as milliseconds since 1970 UTC (a naive one is UTC; one before 1970, which a Sparkplug
    timestamp cannot carry and no controller means, is 0)."""
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=UTC)
    return max(0, (ts - EPOCH) // MS)


def now_ms() -> int:
    return millis(datetime.now(UTC))


def value_of(sample: Sample) -> Any:
    """The metric value of a sample: None (a null) before the controller ever gave one."""
    return None if sample.status == WAITING else sample.value


class VariableOpening(Protocol):
    @property
    def writable(self) -> bool | None: ...


class MachineOpening(Protocol):
    @property
    def writable(self) -> bool: ...

    @property
    def commands(self) -> bool: ...


class MappedVariable(Protocol):
    @property
    def path(self) -> str: ...

    @property
    def mqtt(self) -> VariableOpening | None: ...


class DeviceMapping(Protocol):
    """What DCMD reads of a machine's mapping file: its `mqtt:` openings, per machine and per variable
    (gateway/config/mapping.py `MachineMapping` fits it): both doors are MQTT, through one broker."""

    @property
    def mqtt(self) -> MachineOpening | None: ...

    @property
    def variables(self) -> Sequence[MappedVariable]: ...


def dcmd_writable(node: VariableNode, mapping: DeviceMapping | None) -> bool:
    """Whether the mapping opens `node` to writes over MQTT (mqtt.writable of the machine or variable),
    which DCMD writes follow: Sparkplug reaches the machine through the same broker."""
    spec = node.definition
    if node.internal or not spec.writable or mapping is None:
        return False
    for var in mapping.variables:
        if var.path == node.path and var.mqtt is not None and var.mqtt.writable is not None:
            return var.mqtt.writable
    return mapping.mqtt is not None and mapping.mqtt.writable


@dataclass(eq=False, slots=True)
class VariableMetric:
    """One variable of the tree as a device metric."""

    device: Device
    node: VariableNode
    alias: int
    writable: bool  # DCMD may write it (the mapping opens it to MQTT writes)
    static: dict[str, Property]
    quality: Quality | None = None  # the last one published or stored

    @property
    def name(self) -> str:
        return self.node.path

    @property
    def spec(self) -> TypeSpec:
        return self.node.definition.type

    def change(self, sample: Sample, *, birth: bool = False) -> Metric:
        """The metric of one change (in a birth: with every property)."""
        q = quality(sample.status)
        if birth:
            props: Mapping[str, Property] = {**self.static, **QUALITY_PROPERTY[q]}
        elif q is not self.quality:
            props = QUALITY_PROPERTY[q]
        else:
            props = {}
        self.quality = q
        return Metric(
            self.node.path,
            self.node.definition.type,
            value_of(sample),
            millis(sample.source_ts),
            self.alias,
            props,
        )


@dataclass(eq=False, slots=True)
class CommandMetric:
    """A mapped command as `Commands/<name>/Execute` (written to run it) and `…/Result`."""

    method: Method
    execute_alias: int
    result_alias: int
    enabled: bool  # the mapping's mqtt.commands
    result: str = ""
    result_ts: int = field(default_factory=now_ms)

    @property
    def execute(self) -> str:
        return f"{COMMANDS}/{self.method.name}/Execute"

    @property
    def result_name(self) -> str:
        return f"{COMMANDS}/{self.method.name}/Result"

    @property
    def spec(self) -> TypeSpec:
        inputs = self.method.inputs
        if not inputs:
            return BOOLEAN
        return inputs[0].type if len(inputs) == 1 else STRING

    def idle(self) -> Any:
        """Execute's value while no run is asked for: false, or the argument type's neutral value."""
        return self.spec.default()

    def arguments(self, value: Any) -> list[Any]:
        """The call's arguments from the value a host wrote to Execute (types are the call's to check)."""
        inputs = self.method.inputs
        if not inputs:
            if value is not True:
                raise InvalidArgument(f"write true to {self.execute} to run {self.method.name}")
            return []
        if len(inputs) == 1:
            return [value]
        body = read_body(str(value).encode("utf-8"))
        return arguments(self.method, body)

    def metrics(self, ts: int, *, birth: bool) -> list[Metric]:
        """Execute back at rest and Result with the last outcome (in a birth: with their properties)."""
        execute_props = metric_properties(
            read_only=not self.enabled, description=self.method.description or None
        )
        result_props = metric_properties(read_only=True, description=f"How the last {self.method.name} ended")
        return [
            Metric(
                self.execute, self.spec, self.idle(), ts, self.execute_alias, execute_props if birth else {}
            ),
            Metric(
                self.result_name,
                STRING,
                self.result,
                self.result_ts,
                self.result_alias,
                result_props if birth else {},
            ),
        ]


Target = VariableMetric | CommandMetric


class Device:
    """One machine: its topics, its metrics in birth order, and where it is in the session."""

    def __init__(
        self,
        machine: Machine,
        group_id: str,
        edge_node_id: str,
        aliases: Aliases,
        mapping: DeviceMapping | None,
    ) -> None:
        self.machine = machine
        self.name = machine.name
        self.mapping = mapping
        self.ddata = device_topic(group_id, MessageType.DDATA, edge_node_id, machine.name)
        self.dbirth = device_topic(group_id, MessageType.DBIRTH, edge_node_id, machine.name)
        self.ddeath = device_topic(group_id, MessageType.DDEATH, edge_node_id, machine.name)
        self.connected_node = machine.status.connected_node
        self._aliases = aliases
        self.variables: dict[VariableNode, VariableMetric] = {}
        self.commands: list[CommandMetric] = []
        self.targets: dict[str, Target] = {}  # by metric name: what a DCMD may name
        self.by_name: dict[str, int] = {}  # metric name → alias, for stored messages
        for node in machine.nodes.values():
            self.add(node)
        enabled = mapping is not None and mapping.mqtt is not None and mapping.mqtt.commands
        for (obj, _), method in machine.methods.items():
            if obj == COMMANDS:
                self._add_command(method, enabled)
        self.table = self._table()
        # Where the device is, as the sink's stream of changes says (not the tree now, which may be ahead).
        self.online = bool(machine.status.is_connected)
        self.alive = False  # born in this session, and online
        self.birth_due = False  # came online while the session is born: a DBIRTH at the end of the cycle
        self.pending: list[tuple[VariableMetric, Sample]] = []

    def add(self, node: VariableNode) -> VariableMetric:
        """A variable as a metric (also one that appears after start-up: the table is made again)."""
        spec = node.definition
        writable = dcmd_writable(node, self.mapping)
        rng = spec.range
        static = metric_properties(
            unit=spec.unit or None,
            low=rng.min if rng is not None else None,
            high=rng.max if rng is not None else None,
            description=spec.description or None,
            read_only=not writable,
        )
        metric = VariableMetric(self, node, self._aliases.alias(self.name, node.path), writable, static)
        self.variables[node] = metric
        self.targets[node.path] = metric
        self.by_name[node.path] = metric.alias
        if hasattr(self, "table"):
            self.table = self._table()
        return metric

    def _add_command(self, method: Method, enabled: bool) -> None:
        execute = f"{COMMANDS}/{method.name}/Execute"
        result = f"{COMMANDS}/{method.name}/Result"
        command = CommandMetric(
            method, self._aliases.alias(self.name, execute), self._aliases.alias(self.name, result), enabled
        )
        self.commands.append(command)
        self.targets[execute] = command
        self.targets[result] = command
        self.by_name[execute] = command.execute_alias
        self.by_name[result] = command.result_alias

    def _table(self) -> MetricTable:
        definitions = [Definition(m.node.path, m.spec, m.alias) for m in self.variables.values()]
        for c in self.commands:
            definitions += [
                Definition(c.execute, c.spec, c.execute_alias),
                Definition(c.result_name, STRING, c.result_alias),
            ]
        return MetricTable(definitions)

    def birth_metrics(self) -> list[Metric]:
        """Every metric with its current value, as the tree holds it now."""
        out = [metric.change(metric.node.sample, birth=True) for metric in self.variables.values()]
        ts = now_ms()
        for command in self.commands:
            out += command.metrics(ts, birth=True)
        return out
