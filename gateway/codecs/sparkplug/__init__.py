"""Sparkplug B (Eclipse Sparkplug 3.0): a pure, sans-I/O codec for an edge node.

Topics, payload bytes and events; no MQTT client, no asyncio. The Sparkplug sink builds on it:
the gateway is one edge node, every machine one of its devices.

    bd, seq, aliases = BdSeq(), Seq(), Aliases()                 # one of each per edge node
    will = encode_ndeath(bdseq=bd.connect())                     # the CONNECT's will, QoS 1
    nbirth = encode_nbirth(node_metrics, bdseq=bd.current, seq=seq, timestamp=now_ms)
    dbirth = encode_dbirth(machine_metrics, seq=seq, timestamp=now_ms)
    ddata = encode_ddata(changed, seq=seq, timestamp=now_ms)     # by alias; historical=True when stored
    kept = encode_stored(changed, timestamp=now_ms)              # offline: by name, historical, no seq
    release_stored(kept, {"Axes/X/Position": 7}, seq=seq).payload  # later: by alias, with the next seq
    topic = device_topic("plant", MessageType.DDATA, "cnc-gateway", "laser-sim")
    command = decode_dcmd(payload, MetricTable.from_metrics(machine_metrics))
    command.writes, command.refusals                             # Write(metric, value, timestamp), errors
    host.feed(parse_state(payload))                              # PrimaryHost: gate births and data

The payload schema is sparkplug_b.proto; sparkplug_b_pb2 is generated from it (protoc.py).

The names below are imported from their modules when first used (PEP 562): the configuration
checks Sparkplug ids with `check_id` (topics.py), and a gateway without `sparkplug:` loads
nothing else of the codec (nor protobuf).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from gateway.codecs.sparkplug.aliases import Aliases
    from gateway.codecs.sparkplug.commands import (
        Command,
        Definition,
        MetricTable,
        Write,
        decode_dcmd,
        decode_ncmd,
    )
    from gateway.codecs.sparkplug.datatypes import (
        Scalar,
        SparkplugType,
        Value,
        gateway_type,
        get_metric_value,
        pack_array,
        set_metric_value,
        sparkplug_type,
        unpack_array,
    )
    from gateway.codecs.sparkplug.errors import (
        BadBirth,
        BadCommand,
        BadId,
        BadState,
        BadTopic,
        BadValue,
        MalformedPayload,
        SparkplugError,
        Unencodable,
        UnknownAlias,
        UnknownMetric,
        WrongDatatype,
    )
    from gateway.codecs.sparkplug.limits import MAX_PAYLOAD
    from gateway.codecs.sparkplug.payloads import (
        BDSEQ,
        PROP_DESCRIPTION,
        PROP_HIGH,
        PROP_LOW,
        PROP_QUALITY,
        PROP_READ_ONLY,
        PROP_UNIT,
        REBIRTH,
        Metric,
        Property,
        Quality,
        Released,
        encode_command,
        encode_dbirth,
        encode_ddata,
        encode_ddeath,
        encode_nbirth,
        encode_ndata,
        encode_ndeath,
        encode_stored,
        metric_properties,
        quality_of_status,
        release_stored,
    )
    from gateway.codecs.sparkplug.sequence import BdSeq, Seq
    from gateway.codecs.sparkplug.state import HostState, PrimaryHost, parse_state
    from gateway.codecs.sparkplug.topics import (
        NAMESPACE,
        STATE_QOS,
        STATE_RETAIN,
        MessageType,
        StateTopic,
        Topic,
        check_id,
        command_subscriptions,
        device_topic,
        node_topic,
        parse_topic,
        state_topic,
    )
    from gateway.codecs.sparkplug.wire import parse_payload

_HOMES = {
    "Aliases": "aliases",
    "BDSEQ": "payloads",
    "BadBirth": "errors",
    "BadCommand": "errors",
    "BadId": "errors",
    "BadState": "errors",
    "BadTopic": "errors",
    "BadValue": "errors",
    "BdSeq": "sequence",
    "Command": "commands",
    "Definition": "commands",
    "HostState": "state",
    "MAX_PAYLOAD": "limits",
    "MalformedPayload": "errors",
    "MessageType": "topics",
    "Metric": "payloads",
    "MetricTable": "commands",
    "NAMESPACE": "topics",
    "PROP_DESCRIPTION": "payloads",
    "PROP_HIGH": "payloads",
    "PROP_LOW": "payloads",
    "PROP_QUALITY": "payloads",
    "PROP_READ_ONLY": "payloads",
    "PROP_UNIT": "payloads",
    "PrimaryHost": "state",
    "Property": "payloads",
    "Quality": "payloads",
    "REBIRTH": "payloads",
    "Released": "payloads",
    "STATE_QOS": "topics",
    "STATE_RETAIN": "topics",
    "Scalar": "datatypes",
    "Seq": "sequence",
    "SparkplugError": "errors",
    "SparkplugType": "datatypes",
    "StateTopic": "topics",
    "Topic": "topics",
    "Unencodable": "errors",
    "UnknownAlias": "errors",
    "UnknownMetric": "errors",
    "Value": "datatypes",
    "Write": "commands",
    "WrongDatatype": "errors",
    "check_id": "topics",
    "command_subscriptions": "topics",
    "decode_dcmd": "commands",
    "decode_ncmd": "commands",
    "device_topic": "topics",
    "encode_command": "payloads",
    "encode_dbirth": "payloads",
    "encode_ddata": "payloads",
    "encode_ddeath": "payloads",
    "encode_nbirth": "payloads",
    "encode_ndata": "payloads",
    "encode_ndeath": "payloads",
    "encode_stored": "payloads",
    "gateway_type": "datatypes",
    "get_metric_value": "datatypes",
    "metric_properties": "payloads",
    "node_topic": "topics",
    "pack_array": "datatypes",
    "parse_payload": "wire",
    "parse_state": "state",
    "parse_topic": "topics",
    "quality_of_status": "payloads",
    "release_stored": "payloads",
    "set_metric_value": "datatypes",
    "sparkplug_type": "datatypes",
    "state_topic": "topics",
    "unpack_array": "datatypes",
}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value


__all__ = [
    "BDSEQ",
    "MAX_PAYLOAD",
    "NAMESPACE",
    "PROP_DESCRIPTION",
    "PROP_HIGH",
    "PROP_LOW",
    "PROP_QUALITY",
    "PROP_READ_ONLY",
    "PROP_UNIT",
    "REBIRTH",
    "STATE_QOS",
    "STATE_RETAIN",
    "Aliases",
    "BadBirth",
    "BadCommand",
    "BadId",
    "BadState",
    "BadTopic",
    "BadValue",
    "BdSeq",
    "Command",
    "Definition",
    "HostState",
    "MalformedPayload",
    "MessageType",
    "Metric",
    "MetricTable",
    "PrimaryHost",
    "Property",
    "Quality",
    "Released",
    "Scalar",
    "Seq",
    "SparkplugError",
    "SparkplugType",
    "StateTopic",
    "Topic",
    "Unencodable",
    "UnknownAlias",
    "UnknownMetric",
    "Value",
    "Write",
    "WrongDatatype",
    "check_id",
    "command_subscriptions",
    "decode_dcmd",
    "decode_ncmd",
    "device_topic",
    "encode_command",
    "encode_dbirth",
    "encode_ddata",
    "encode_ddeath",
    "encode_nbirth",
    "encode_ndata",
    "encode_ndeath",
    "encode_stored",
    "gateway_type",
    "get_metric_value",
    "metric_properties",
    "node_topic",
    "pack_array",
    "parse_payload",
    "parse_state",
    "parse_topic",
    "quality_of_status",
    "release_stored",
    "set_metric_value",
    "sparkplug_type",
    "state_topic",
    "unpack_array",
]
