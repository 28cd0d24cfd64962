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
"""

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
from gateway.codecs.sparkplug.wire import MAX_PAYLOAD, parse_payload

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
