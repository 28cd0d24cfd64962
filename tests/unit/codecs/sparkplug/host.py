"""A Sparkplug host application's side of the wire, for the tests: reads what the edge node
publishes and writes the commands it receives.

Written from the Sparkplug 3.0 specification (6.4.16-17) on the generated message classes alone:
it shares no code with gateway.codecs.sparkplug's encoder or decoder (only the schema), so a
mistake in the codec cannot cancel out in a round trip. Datatypes are the specification's numbers.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from gateway.codecs.sparkplug.sparkplug_b_pb2 import Payload

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

# Datatype numbers from the specification's table.
INT8, INT16, INT32, INT64, UINT8, UINT16, UINT32, UINT64 = 1, 2, 3, 4, 5, 6, 7, 8
FLOAT, DOUBLE, BOOLEAN, STRING, DATETIME, TEXT = 9, 10, 11, 12, 13, 14
INT8_ARRAY, BOOLEAN_ARRAY, STRING_ARRAY, DATETIME_ARRAY = 22, 32, 33, 34

_SIGNED = {INT8: 8, INT16: 16, INT32: 32}  # 32-bit two's complement in int_value
_ARRAYS = {22: "b", 23: "h", 24: "i", 25: "q", 26: "B", 27: "H", 28: "I", 29: "Q", 30: "f", 31: "d"}


@dataclass
class HostMetric:
    name: str | None
    alias: int | None
    datatype: int | None
    timestamp: int | None
    value: Any
    is_null: bool
    is_historical: bool
    is_transient: bool
    properties: dict[str, tuple[int, Any]] = field(default_factory=dict)


@dataclass
class HostPayload:
    timestamp: int | None
    seq: int | None
    metrics: list[HostMetric]


def read(data: bytes, datatypes: Mapping[Any, int] | None = None) -> HostPayload:
    """Decode a payload as a host would: births carry datatypes; DATA metrics are looked up in
    `datatypes` (by alias, else name), which a host fills from the births."""
    payload = Payload.FromString(data)
    known: Mapping[Any, int] = datatypes if datatypes is not None else {}
    metrics = []
    for m in payload.metrics:
        name = m.name if m.HasField("name") else None
        alias = m.alias if m.HasField("alias") else None
        if m.HasField("datatype"):
            datatype: int | None = m.datatype
        else:
            datatype = known.get(alias) if alias is not None else known.get(name or "")
        value = None if m.is_null or m.WhichOneof("value") is None else value_of(m, datatype)
        props = {}
        for key, pv in zip(m.properties.keys, m.properties.values, strict=True):
            props[key] = (pv.type, None if pv.is_null else scalar_of(pv, pv.type))
        metrics.append(
            HostMetric(
                name,
                alias,
                datatype,
                m.timestamp if m.HasField("timestamp") else None,
                value,
                m.is_null,
                m.is_historical,
                m.is_transient,
                props,
            )
        )
    return HostPayload(
        payload.timestamp if payload.HasField("timestamp") else None,
        payload.seq if payload.HasField("seq") else None,
        metrics,
    )


def value_of(m: Payload.Metric, datatype: int | None) -> Any:
    assert datatype is not None, "a host needs the datatype from the birth"
    if datatype >= 22:
        return array_of(datatype, m.bytes_value)
    return scalar_of(m, datatype)


def scalar_of(m: Payload.Metric | Payload.PropertyValue, datatype: int) -> Any:
    if datatype in _SIGNED:
        raw = m.int_value
        return raw - (1 << 32) if raw >= 1 << 31 else raw
    if datatype in (UINT8, UINT16, UINT32):
        return m.int_value
    if datatype == INT64:
        raw = m.long_value
        return raw - (1 << 64) if raw >= 1 << 63 else raw
    if datatype == UINT64:
        return m.long_value
    if datatype == DATETIME:
        raw = m.long_value
        return EPOCH + timedelta(milliseconds=raw - (1 << 64) if raw >= 1 << 63 else raw)
    if datatype == FLOAT:
        return m.float_value
    if datatype == DOUBLE:
        return m.double_value
    if datatype == BOOLEAN:
        return m.boolean_value
    if datatype in (STRING, TEXT):
        return m.string_value
    raise AssertionError(f"no scalar datatype {datatype}")


def array_of(datatype: int, data: bytes) -> list[Any]:
    if datatype == BOOLEAN_ARRAY:
        (count,) = struct.unpack("<I", data[:4])
        assert len(data) == 4 + (count + 7) // 8
        return [bool(data[4 + i // 8] >> (7 - i % 8) & 1) for i in range(count)]
    if datatype == STRING_ARRAY:
        assert data == b"" or data.endswith(b"\x00")
        return [part.decode("utf-8") for part in data.split(b"\x00")[:-1]]
    if datatype == DATETIME_ARRAY:
        return [EPOCH + timedelta(milliseconds=ms) for (ms,) in struct.iter_unpack("<q", data)]
    letter = _ARRAYS[datatype]
    return [v for (v,) in struct.iter_unpack("<" + letter, data)]


# --- commands -----------------------------------------------------------------------------------


def command(*metrics: Payload.Metric, timestamp: int | None = 1_700_000_000_000) -> bytes:
    """An NCMD/DCMD payload with the given metrics."""
    payload = Payload()
    if timestamp is not None:
        payload.timestamp = timestamp
    payload.metrics.extend(metrics)
    return payload.SerializeToString()


def write(
    value: Any,
    datatype: int,
    *,
    alias: int | None = None,
    name: str | None = None,
    send_datatype: bool = False,
) -> Payload.Metric:
    """A command metric writing `value` of Sparkplug datatype `datatype`, as a host encodes it."""
    m = Payload.Metric()
    if alias is not None:
        m.alias = alias
    if name is not None:
        m.name = name
    if send_datatype:
        m.datatype = datatype
    if datatype >= 22:
        m.bytes_value = array_bytes(datatype, value)
    elif datatype in _SIGNED or datatype in (UINT8, UINT16, UINT32):
        m.int_value = value & 0xFFFFFFFF
    elif datatype in (INT64, UINT64):
        m.long_value = value & 0xFFFFFFFFFFFFFFFF
    elif datatype == DATETIME:
        m.long_value = ((value - EPOCH) // timedelta(milliseconds=1)) & 0xFFFFFFFFFFFFFFFF
    elif datatype == FLOAT:
        m.float_value = value
    elif datatype == DOUBLE:
        m.double_value = value
    elif datatype == BOOLEAN:
        m.boolean_value = value
    elif datatype in (STRING, TEXT):
        m.string_value = value
    else:
        raise AssertionError(f"no datatype {datatype}")
    return m


def array_bytes(datatype: int, values: list[Any]) -> bytes:
    if datatype == BOOLEAN_ARRAY:
        bits = bytearray((len(values) + 7) // 8)
        for i, v in enumerate(values):
            if v:
                bits[i // 8] |= 1 << (7 - i % 8)
        return struct.pack("<I", len(values)) + bytes(bits)
    if datatype == STRING_ARRAY:
        return b"".join(v.encode("utf-8") + b"\x00" for v in values)
    if datatype == DATETIME_ARRAY:
        return b"".join(struct.pack("<q", (v - EPOCH) // timedelta(milliseconds=1)) for v in values)
    return b"".join(struct.pack("<" + _ARRAYS[datatype], v) for v in values)
