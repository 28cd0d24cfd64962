"""MQTT settings: the broker connection (gateway file), and how machines and variables appear there.

The gateway file's `mqtt:` section says which broker to reach and how (the keys it shares with
`sparkplug.broker`: gateway/sinks/mqtt_link/broker.py); without it the gateway does not use MQTT
at all. Mapping files may refine, per machine and per variable, the QoS, the retain flag, the payload
form, the topic and whether writes over MQTT are allowed (they are off unless a mapping says so).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Annotated, Literal, Protocol

from pydantic import AfterValidator, Field, field_validator, model_validator

from gateway.settings.access import check_role_name
from gateway.settings.base import Strict
from gateway.sinks.mqtt_link.broker import MAX_PACKET_SIZE, MIB, BrokerConnection, MqttReconnect

QoS = Literal[0, 1, 2]
PayloadMode = Literal["json", "raw"]

_TOPIC_FORBIDDEN = re.compile(r"[+#\x00]")


def check_topic_part(text: str, what: str) -> str:
    """A topic or topic prefix we publish under: no wildcards, no empty levels, no NUL."""
    if not text:
        raise ValueError(f"{what} must not be empty")
    if _TOPIC_FORBIDDEN.search(text):
        raise ValueError(f"{what} {text!r} must not contain the MQTT wildcards '+' or '#' or a NUL character")
    if text.startswith("/") or text.endswith("/") or "//" in text:
        raise ValueError(f"{what} {text!r} must be levels joined by '/', without empty levels")
    if text.startswith("$"):
        raise ValueError(f"{what} {text!r} must not start with '$' (brokers reserve such topics)")
    if len(text.encode("utf-8")) > 32_000:
        raise ValueError(f"{what} is too long")
    return text


def check_topic_filter(text: str, what: str) -> str:
    """A topic filter: levels joined by '/', `+` a whole level, `#` the whole last level; no NUL."""
    if not text:
        raise ValueError(f"{what} must not be empty")
    if "\x00" in text or len(text.encode("utf-8")) > 32_000:
        raise ValueError(f"{what} {text!r} must be shorter than 32,000 bytes, without NUL characters")
    levels = text.split("/")
    for index, level in enumerate(levels):
        if ("+" in level and level != "+") or ("#" in level and (level != "#" or index != len(levels) - 1)):
            raise ValueError(
                f"{what} {text!r}: '+' must be a whole level and '#' the whole last level (MQTT topic filter)"
            )
    if text.startswith("$"):
        raise ValueError(f"{what} {text!r} must not start with '$' (brokers reserve such topics)")
    return text


TopicFilter = Annotated[str, AfterValidator(lambda text: check_topic_filter(text, "topic filter"))]


class MqttBuffer(Strict):
    """Store-and-forward while the broker is unreachable (or slower than the machines)."""

    limit: int = Field(
        default=100_000,
        ge=1,
        le=10_000_000,
        description="QoS 1/2 messages kept, in order, while they cannot be sent; beyond it the oldest are "
        "dropped "
        "and counted. Retained state keeps its latest value per topic on top of this.",
    )
    persist: bool = Field(
        default=False,
        description="Also keep the backlog in <state_dir>/mqtt-backlog.sqlite3: it survives a restart",
    )


class MqttConfig(BrokerConnection):
    """The MQTT broker the gateway publishes to (gateway file). Absent: MQTT is off."""

    prefix: str = Field(default="cnc", description="First topic level(s): <prefix>/<machine>/<path>")
    qos: QoS = Field(default=1, description="Default QoS of value topics")
    retain: bool = Field(
        default=True, description="Retain value topics by default (dashboards see the value at once)"
    )
    payload: PayloadMode = Field(
        default="json", description="json: value, ts, quality, unit; raw: the value as text"
    )
    max_inflight: int = Field(
        default=4000,
        ge=1,
        le=65000,
        description="QoS 1/2 messages awaiting the broker's ack (MQTT 5: at most its Receive Maximum)",
    )  # large: the window refills once per turn of the loop, and a busy OPC UA face makes turns long
    max_set_payload: int = Field(default=65536, ge=16, description="Largest accepted /set payload, in bytes")
    max_packet_size: int = Field(
        default=MIB,
        ge=1024,
        le=MAX_PACKET_SIZE,
        description="Largest MQTT packet the gateway takes from the broker, in bytes. MQTT 5: sent as the "
        "CONNECT's Maximum Packet Size, so the broker drops a larger message for the gateway instead of "
        "sending it. MQTT 3.1.1 has no such field: a larger packet ends the connection as soon as its header "
        "arrives (set the broker's own limit: mosquitto's message_size_limit / max_packet_size)",
    )
    response_topics: list[TopicFilter] = Field(
        default_factory=list,
        description="MQTT 5 response topics (topic filters, + and # allowed) that /set and command "
        "requests may have their answers published to, besides the gateway's own result topics under "
        "`prefix`. A request asking for any other is refused (BadRequestNotAllowed), answered on its own "
        "result topic, and nothing is published where it asked",
    )
    max_pending_writes: int = Field(
        default=64, ge=1, le=100_000, description="Queued /set writes per machine"
    )
    reconnect: MqttReconnect = MqttReconnect()
    buffer: MqttBuffer = MqttBuffer()

    @field_validator("prefix")
    @classmethod
    def _prefix(cls, prefix: str) -> str:
        return check_topic_part(prefix, "prefix")

    @model_validator(mode="after")
    def _room_for_requests(self) -> MqttConfig:
        """A request the payload check would answer (too large) must fit in a packet the gateway takes."""
        if self.max_packet_size < self.max_set_payload + 1024:
            raise ValueError(
                f"max_packet_size ({self.max_packet_size}) must leave room for max_set_payload "
                f"({self.max_set_payload}) and a topic: at least {self.max_set_payload + 1024}"
            )
        return self


class MachineMqtt(Strict):
    """Per machine (mapping file): defaults for this machine's topics."""

    qos: QoS | None = Field(default=None, description="Default: the gateway file's mqtt.qos")
    retain: bool | None = Field(default=None, description="Default: the gateway file's mqtt.retain")
    payload: PayloadMode | None = Field(default=None, description="Default: the gateway file's mqtt.payload")
    writable: bool = Field(
        default=False,
        description="Accept <topic>/set writes for this machine's `access: readwrite` variables",
    )
    commands: bool = Field(
        default=False,
        description="Accept command requests on <prefix>/<machine>/commands/<name> (the mapping's commands)",
    )
    writer_role: str | None = Field(
        default=None,
        description="The role MQTT /set and command requests act with while access control is on; "
        "default: the gateway file's access.mqtt_writer_role (none: refused)",
    )

    @field_validator("writer_role")
    @classmethod
    def _writer_role(cls, value: str | None) -> str | None:
        return None if value is None else check_role_name(value)


class VariableMqtt(Strict):
    """Per variable (mapping file): overrides of the machine's MQTT settings."""

    topic: str | None = Field(
        default=None, description="Topic below <prefix>/<machine>/, instead of the lower-cased path"
    )
    qos: QoS | None = None
    retain: bool | None = None
    payload: PayloadMode | None = None
    writable: bool | None = Field(
        default=None,
        description="Accept <topic>/set writes (needs access: readwrite); default: the machine's setting",
    )
    publish: bool = Field(default=True, description="false: keep this variable out of MQTT altogether")

    @field_validator("topic")
    @classmethod
    def _topic(cls, topic: str | None) -> str | None:
        if topic is None:
            return None
        check_topic_part(topic, "topic")
        levels = topic.split("/")
        if topic == "status" or levels[-1] == "set" or levels[-2:] == ["set", "result"]:
            raise ValueError(f"topic {topic!r} would clash with the gateway's own set/result/status topics")
        if levels[0] in ("commands", "alarms"):
            raise ValueError(f"topic {topic!r} would clash with the gateway's own {levels[0]}/… topics")
        return topic


class MqttVariableEntry(Protocol):
    """What the MQTT and Sparkplug sinks read of a variable's mapping entry."""

    @property
    def path(self) -> str: ...

    @property
    def mqtt(self) -> VariableMqtt | None: ...


class MqttMachineEntry(Protocol):
    """What the MQTT and Sparkplug sinks read of a machine's mapping file (gateway/config/mapping.py
    `MachineMapping` fits it; mypy checks that where gateway/app.py hands the mappings over)."""

    @property
    def mqtt(self) -> MachineMqtt | None: ...

    @property
    def variables(self) -> Sequence[MqttVariableEntry]: ...
