"""Edge node payloads: NBIRTH, DBIRTH, NDATA, DDATA, DDEATH and NDEATH bytes from plain values.

Sparkplug 3.0 rules these functions apply (chapters 4-6):
- NBIRTH: seq 0, a payload timestamp, the metric `bdSeq` (Int64, the value of the session's will)
  and `Node Control/Rebirth` (Boolean false, never an alias), then every node metric with its name,
  alias, datatype, timestamp and current value (or is_null);
- DBIRTH: the next seq, every device metric likewise;
- NDATA/DDATA: the next seq; each metric by alias only (by name when it has no alias), without
  datatype, with its timestamp and value; `is_historical` for stored values sent late;
- DDEATH: the next seq and a timestamp, no metrics;
- NDEATH (the MQTT will): the metric `bdSeq` only, and no seq.

A message's seq is taken from the counter only once its payload is built, so a refused call
never leaves a gap that a host would answer with a rebirth request.

Choices where the specification is silent or leaves room:
- metrics are written in timestamp order (stable), since live values "MUST" be chronological
  and a batch gathers them from many variables; in DATA, two values of one metric with the same
  timestamp keep only the later one (the specification allows repeats only at different times);
- bdSeq and Node Control/Rebirth carry no alias (they never appear in DATA messages);
- the properties a sink most needs are named like Ignition's tag properties (`engUnit`, `engLow`,
  `engHigh`, `documentation`, `readOnly`); the specification defines only `Quality` (Int32: 0 BAD,
  192 GOOD, 500 STALE), which OPC UA status names map onto by severity (Uncertain is STALE).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

from gateway.codecs.sparkplug.datatypes import SparkplugType, set_metric_value, set_scalar, sparkplug_type
from gateway.codecs.sparkplug.errors import BadBirth, Unencodable
from gateway.codecs.sparkplug.sequence import Seq
from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload
from gateway.codecs.sparkplug.wire import serialize
from gateway.model.types import DataType, TypeSpec

BDSEQ = "bdSeq"
REBIRTH = "Node Control/Rebirth"
_RESERVED_NAMES = frozenset({BDSEQ, REBIRTH})
_UINT64 = 1 << 64

PROP_QUALITY = "Quality"
PROP_UNIT = "engUnit"
PROP_LOW = "engLow"
PROP_HIGH = "engHigh"
PROP_DESCRIPTION = "documentation"
PROP_READ_ONLY = "readOnly"


class Quality(IntEnum):
    """The values of the `Quality` property (Sparkplug 3.0, 6.4.8)."""

    BAD = 0
    GOOD = 192
    STALE = 500


def quality_of_status(status: str) -> Quality:
    """The Sparkplug quality of an OPC UA status name (Good…, Uncertain…, Bad…)."""
    if status.startswith("Good"):
        return Quality.GOOD
    if status.startswith("Uncertain"):
        return Quality.STALE
    return Quality.BAD


@dataclass(frozen=True, slots=True)
class Property:
    """One entry of a metric's PropertySet: a Sparkplug basic type and its value (None: is_null)."""

    type: SparkplugType
    value: object


def metric_properties(
    *,
    unit: str | None = None,
    low: float | None = None,
    high: float | None = None,
    quality: Quality | None = None,
    description: str | None = None,
    read_only: bool | None = None,
) -> dict[str, Property]:
    """The usual properties of a variable's metric; the ones given as None are left out."""
    props: dict[str, Property] = {}
    if unit is not None:
        props[PROP_UNIT] = Property(SparkplugType.String, unit)
    if low is not None:
        props[PROP_LOW] = Property(SparkplugType.Double, float(low))
    if high is not None:
        props[PROP_HIGH] = Property(SparkplugType.Double, float(high))
    if description is not None:
        props[PROP_DESCRIPTION] = Property(SparkplugType.String, description)
    if read_only is not None:
        props[PROP_READ_ONLY] = Property(SparkplugType.Boolean, read_only)
    if quality is not None:
        props[PROP_QUALITY] = Property(SparkplugType.Int32, int(quality))
    return props


@dataclass(frozen=True, slots=True)
class Metric:
    """A metric as the sink knows it: `value` in the gateway's canonical Python form for `spec`
    (None is a null), `timestamp` in ms since 1970 UTC (the source timestamp)."""

    name: str
    spec: TypeSpec
    value: object
    timestamp: int
    alias: int | None = None
    properties: Mapping[str, Property] = field(default_factory=dict)
    historical: bool = False
    transient: bool = False

    @property
    def datatype(self) -> SparkplugType:
        return sparkplug_type(self.spec)


# --- births -------------------------------------------------------------------------------------


def encode_nbirth(metrics: Sequence[Metric], *, bdseq: int, seq: Seq, timestamp: int) -> bytes:
    """An NBIRTH: the node's own metrics, bdSeq and Node Control/Rebirth beside them; seq restarts at 0."""
    _check_bdseq(bdseq)
    for metric in metrics:
        if metric.name in _RESERVED_NAMES:
            raise BadBirth("the codec writes this metric of the NBIRTH itself", metric=metric.name)
    own = [
        Metric(BDSEQ, TypeSpec(DataType.INT64), bdseq, timestamp),
        Metric(REBIRTH, TypeSpec(DataType.BOOLEAN), False, timestamp),
    ]
    payload = _birth(own + list(metrics), timestamp)
    payload.seq = seq.birth()
    return serialize(payload)


def encode_dbirth(metrics: Sequence[Metric], *, seq: Seq, timestamp: int) -> bytes:
    """A DBIRTH with every metric of the device, by name and alias, with datatype and value."""
    payload = _birth(metrics, timestamp)
    payload.seq = seq.next()
    return serialize(payload)


def _birth(metrics: Sequence[Metric], timestamp: int) -> Payload:
    names: set[str] = set()
    aliases: dict[int, str] = {}
    for metric in metrics:
        if not metric.name:
            raise BadBirth("a metric in a birth needs a name")
        if metric.name in names:
            raise BadBirth("the name appears twice in the birth", metric=metric.name)
        names.add(metric.name)
        if metric.alias is not None:
            if metric.alias in aliases:
                raise BadBirth(f"alias {metric.alias} is also {aliases[metric.alias]!r}", metric=metric.name)
            aliases[metric.alias] = metric.name
        if metric.historical:
            raise BadBirth("a birth carries current values, not historical ones", metric=metric.name)
    payload = _payload(timestamp)
    for metric in _chronological(metrics):
        _write_metric(payload.metrics.add(), metric, birth=True)
    return payload


# --- data ---------------------------------------------------------------------------------------


def encode_ndata(metrics: Sequence[Metric], *, seq: Seq, timestamp: int) -> bytes:
    """An NDATA with the node metrics that changed."""
    return _data(metrics, seq, timestamp)


def encode_ddata(metrics: Sequence[Metric], *, seq: Seq, timestamp: int) -> bytes:
    """A DDATA with the device metrics that changed (or, marked historical, were stored)."""
    return _data(metrics, seq, timestamp)


def _data(metrics: Sequence[Metric], seq: Seq, timestamp: int) -> bytes:
    if not metrics:
        raise Unencodable("a DATA message needs at least one metric")
    latest: dict[tuple[object, int], Metric] = {}
    for metric in metrics:
        key = (metric.name if metric.alias is None else metric.alias, metric.timestamp)
        latest.pop(key, None)  # the later value of one instant wins, and goes where it came
        latest[key] = metric
    payload = _payload(timestamp)
    for metric in _chronological(latest.values()):
        _write_metric(payload.metrics.add(), metric, birth=False)
    payload.seq = seq.next()
    return serialize(payload)


# --- deaths -------------------------------------------------------------------------------------


def encode_ddeath(*, seq: Seq, timestamp: int) -> bytes:
    """A DDEATH: the device is offline as of `timestamp` (hosts use it as the time it went)."""
    payload = _payload(timestamp)
    payload.seq = seq.next()
    return serialize(payload)


def encode_ndeath(*, bdseq: int, timestamp: int | None = None) -> bytes:
    """The NDEATH for the will of a CONNECT: only the bdSeq metric, and no seq.

    `timestamp` (the CONNECT's time) is optional: the broker publishes the will later, so hosts
    take their own time of receipt.
    """
    _check_bdseq(bdseq)
    payload = Payload()
    metric = payload.metrics.add()
    metric.name = BDSEQ
    metric.datatype = SparkplugType.Int64
    set_metric_value(metric, TypeSpec(DataType.INT64), bdseq)
    if timestamp is not None:
        payload.timestamp = _check_timestamp(timestamp)
        metric.timestamp = payload.timestamp
    return serialize(payload)


# --- pieces -------------------------------------------------------------------------------------


def _payload(timestamp: int) -> Payload:
    payload = Payload()
    payload.timestamp = _check_timestamp(timestamp)
    return payload


def _chronological(metrics: Iterable[Metric]) -> list[Metric]:
    return sorted(metrics, key=lambda m: m.timestamp)


def _write_metric(out: Payload.Metric, metric: Metric, *, birth: bool) -> None:
    try:
        if birth or metric.alias is None:
            out.name = _text("a metric name", metric.name)
        if metric.alias is not None:
            if not 0 <= metric.alias < _UINT64:
                raise Unencodable(f"alias {metric.alias} is not a uint64")
            out.alias = metric.alias
        if birth:
            out.datatype = metric.datatype
        out.timestamp = _check_timestamp(metric.timestamp)
        if metric.historical:
            out.is_historical = True
        if metric.transient:
            out.is_transient = True
        set_metric_value(out, metric.spec, metric.value)
        if metric.properties:
            _write_properties(out.properties, metric.properties)
    except Unencodable as exc:
        if exc.metric is None:
            exc.metric = metric.name
        raise


def _write_properties(out: Payload.PropertySet, properties: Mapping[str, Property]) -> None:
    for key, prop in properties.items():
        out.keys.append(_text("a property key", key))
        value = out.values.add()
        value.type = prop.type
        if prop.value is None:
            value.is_null = True
        else:
            try:
                set_scalar(value, prop.type, prop.value)
            except Unencodable as exc:
                raise Unencodable(f"property {key!r}: {exc.message}") from None


def _text(what: str, value: str) -> str:
    if not isinstance(value, str):
        raise Unencodable(f"{what} is text, got {type(value).__name__}")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise Unencodable(f"{what} with a lone surrogate at {exc.start} cannot be UTF-8") from None
    return value


def _check_timestamp(timestamp: int) -> int:
    if isinstance(timestamp, bool) or not isinstance(timestamp, int) or not 0 <= timestamp < _UINT64:
        raise Unencodable(f"a timestamp is ms since 1970 as a uint64, got {timestamp!r}")
    return timestamp


def _check_bdseq(bdseq: int) -> None:
    if isinstance(bdseq, bool) or not isinstance(bdseq, int) or not 0 <= bdseq <= 255:
        raise Unencodable(f"bdSeq is 0..255, got {bdseq!r}")
