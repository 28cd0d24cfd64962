"""NCMD and DCMD payloads read against the metrics the births announced: writes, rebirth, refusals.

A command that is not a Sparkplug B payload at all raises MalformedPayload. Otherwise each of
its metrics is taken on its own: a metric the edge node can act on becomes a `Write` (or, in an
NCMD, the rebirth request), and one it cannot becomes a refusal with its reason, so that a host
that sends one bad metric among good ones still gets the good ones done, and the sink counts and
logs the rest. Refusals:
- UnknownAlias / UnknownMetric: an alias or name the birth did not announce, or neither given;
- WrongDatatype: a datatype other than the birth's, or the value in another field than the
  type's (datatypes.py says which fields are read);
- BadValue: a null, no value, a number outside the type's range, bytes that are no array of the
  type, text that is not UTF-8; or a name that contradicts the alias;
- BadCommand: no metrics at all, a value marked historical, `Node Control/Rebirth` not true.

Sparkplug 3.0 says commands name metrics by alias when the birth gave one (and an edge node
"should be resilient" to names); both are read here. The rebirth request is by name only: its
NBIRTH metric has no alias, by rule. What the codec does not judge: whether the metric is
writable, the caller's role, the mapping's range. Those are the tree's write path's.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from gateway.codecs.sparkplug.datatypes import SparkplugType, Value, get_metric_value, sparkplug_type
from gateway.codecs.sparkplug.errors import (
    BadBirth,
    BadCommand,
    BadValue,
    SparkplugError,
    UnknownAlias,
    UnknownMetric,
    WrongDatatype,
)
from gateway.codecs.sparkplug.payloads import REBIRTH, Metric
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.codecs.sparkplug.wire import MAX_PAYLOAD, parse_payload
from gateway.model.types import TypeSpec


@dataclass(frozen=True, slots=True)
class Definition:
    """A metric as its birth announced it."""

    name: str
    spec: TypeSpec
    alias: int | None = None

    @property
    def datatype(self) -> SparkplugType:
        return sparkplug_type(self.spec)


class MetricTable:
    """The metrics of one NBIRTH or DBIRTH, by alias and by name, to read commands against."""

    __slots__ = ("_by_alias", "_by_name")

    def __init__(self, definitions: Iterable[Definition]) -> None:
        self._by_name: dict[str, Definition] = {}
        self._by_alias: dict[int, Definition] = {}
        for definition in definitions:
            if definition.name in self._by_name:
                raise BadBirth("the name appears twice", metric=definition.name)
            self._by_name[definition.name] = definition
            if definition.alias is not None:
                if definition.alias in self._by_alias:
                    other = self._by_alias[definition.alias].name
                    raise BadBirth(f"alias {definition.alias} is also {other!r}", metric=definition.name)
                self._by_alias[definition.alias] = definition

    @classmethod
    def from_metrics(cls, metrics: Iterable[Metric]) -> MetricTable:
        """The table of the metrics a birth was encoded from."""
        return cls(Definition(m.name, m.spec, m.alias) for m in metrics)

    def by_alias(self, alias: int) -> Definition | None:
        return self._by_alias.get(alias)

    def by_name(self, name: str) -> Definition | None:
        return self._by_name.get(name)

    def __iter__(self) -> Iterator[Definition]:
        return iter(self._by_name.values())

    def __len__(self) -> int:
        return len(self._by_name)


@dataclass(frozen=True, slots=True)
class Write:
    """A request to write `value` (the gateway's canonical Python form) to `metric`."""

    metric: Definition
    value: Value
    timestamp: int | None = None


@dataclass(frozen=True, slots=True)
class Command:
    """What one NCMD or DCMD asks for."""

    timestamp: int | None
    writes: tuple[Write, ...] = ()
    refusals: tuple[SparkplugError, ...] = ()
    rebirth: bool = False


def decode_ncmd(data: bytes, table: MetricTable, *, limit: int = MAX_PAYLOAD) -> Command:
    """Read an NCMD against the node's NBIRTH metrics; `Node Control/Rebirth` true asks for a rebirth."""
    return _decode(data, table, node=True, limit=limit)


def decode_dcmd(data: bytes, table: MetricTable, *, limit: int = MAX_PAYLOAD) -> Command:
    """Read a DCMD against the device's DBIRTH metrics."""
    return _decode(data, table, node=False, limit=limit)


def _decode(data: bytes, table: MetricTable, *, node: bool, limit: int) -> Command:
    payload = parse_payload(data, limit=limit)
    timestamp = payload.timestamp if payload.HasField("timestamp") else None
    writes: list[Write] = []
    refusals: list[SparkplugError] = []
    rebirth = False
    if not payload.metrics:
        refusals.append(BadCommand("the command has no metrics"))
    for metric in payload.metrics:
        try:
            if node and _is_rebirth(metric):
                _check_rebirth(metric)
                rebirth = True
            else:
                writes.append(_write(metric, table))
        except SparkplugError as exc:
            if exc.metric is None:
                exc.metric = _label(metric)
            refusals.append(exc)
    return Command(timestamp, tuple(writes), tuple(refusals), rebirth)


def _is_rebirth(metric: Payload.Metric) -> bool:
    return not metric.HasField("alias") and metric.HasField("name") and metric.name == REBIRTH


def _check_rebirth(metric: Payload.Metric) -> None:
    if metric.HasField("datatype") and metric.datatype != SparkplugType.Boolean:
        raise WrongDatatype(f"the birth says Boolean, the command says {_type_name(metric.datatype)}")
    if metric.WhichOneof("value") != "boolean_value":
        raise WrongDatatype(
            f"a rebirth request is a Boolean true, got {metric.WhichOneof('value') or 'no value'}"
        )
    if not metric.boolean_value:
        raise BadCommand("a rebirth request is a Boolean true; false asks for nothing")


def _write(metric: Payload.Metric, table: MetricTable) -> Write:
    definition = _identify(metric, table)
    if metric.HasField("datatype") and metric.datatype != definition.datatype:
        raise WrongDatatype(
            f"the birth says {definition.datatype.name}, the command says {_type_name(metric.datatype)}",
            metric=definition.name,
        )
    if metric.is_historical:
        raise BadCommand("a value marked historical cannot be written", metric=definition.name)
    if metric.is_null:
        raise BadValue("a null cannot be written", metric=definition.name)
    try:
        value = get_metric_value(metric, definition.spec)
    except SparkplugError as exc:
        exc.metric = definition.name
        raise
    timestamp = metric.timestamp if metric.HasField("timestamp") else None
    return Write(definition, value, timestamp)


def _identify(metric: Payload.Metric, table: MetricTable) -> Definition:
    name = _name(metric)
    if metric.HasField("alias"):
        definition = table.by_alias(metric.alias)
        if definition is None:
            raise UnknownAlias("the birth bound no metric to this alias", metric=f"alias {metric.alias}")
        if name is not None and name != definition.name:
            raise BadValue(f"alias {metric.alias} is {definition.name!r}, the name says {name!r}")
        return definition
    if name is None:
        raise UnknownMetric("the metric has neither an alias nor a name", metric="a metric")
    by_name = table.by_name(name)
    if by_name is None:
        raise UnknownMetric("the birth announced no metric of this name", metric=name[:80])
    return by_name


def _name(metric: Payload.Metric) -> str | None:
    if not metric.HasField("name"):
        return None
    name: object = metric.name
    if not isinstance(name, str):  # protobuf hands back bytes when a proto2 string is not UTF-8
        raise BadValue("the metric name is not UTF-8 text", metric="a metric")
    return name


def _label(metric: Payload.Metric) -> str:
    if metric.HasField("alias"):
        return f"alias {metric.alias}"
    name: object = metric.name if metric.HasField("name") else None
    return name[:80] if isinstance(name, str) else "a metric"


def _type_name(number: int) -> str:
    try:
        return SparkplugType(number).name
    except ValueError:
        return f"datatype {number} (not a Sparkplug type)"
