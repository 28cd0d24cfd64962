"""Sparkplug B settings (gateway file, `sparkplug:`): who the gateway is as an edge node, and its broker.

Without the section nothing Sparkplug runs. With it, the gateway is one Sparkplug edge node
(`group_id`, `edge_node_id`) and every machine one of its devices.

The broker: by default the `mqtt:` section's (host, port, credentials, TLS, protocol, timings),
reached over a connection of its own, because Sparkplug needs what one MQTT connection cannot
share with the JSON topics: its own will (the NDEATH, not retained, with a number that changes
every connect) and a clean session. Its client id is the `mqtt:` one with `-sparkplug` appended
(two connections with one id would throw each other off the broker). `broker:` names another
broker instead, for plants whose SCADA broker is not the one the JSON topics go to; a gateway
without `mqtt:` needs it.
"""

from __future__ import annotations

from pydantic import Field, field_validator

from gateway.codecs.sparkplug.errors import SparkplugError
from gateway.codecs.sparkplug.limits import MAX_PAYLOAD
from gateway.codecs.sparkplug.topics import check_id
from gateway.settings.base import Strict
from gateway.shards.identity import shard_index
from gateway.sinks.mqtt_link.broker import MAX_PACKET_SIZE, MIB, BrokerConnection, MqttReconnect, SharedBroker

SUFFIX = "-sparkplug"  # appended to the mqtt: section's client id


class SparkplugBroker(BrokerConnection):
    """The MQTT broker the edge node connects to, when it is not the `mqtt:` section's."""

    client_id: str = Field(
        default="",
        max_length=128 + len(SUFFIX),  # the mqtt: section's, with the suffix
        description="Default: cnc-gateway-<host name>-sparkplug; keep it stable for broker ACLs",
    )
    reconnect: MqttReconnect = MqttReconnect()

    @classmethod
    def of_mqtt(cls, mqtt: SharedBroker) -> SparkplugBroker:
        """The `mqtt:` section's broker, for a connection of the edge node's own."""
        return cls(
            host=mqtt.host,
            port=mqtt.port,
            client_id=f"{mqtt.client_id}{SUFFIX}" if mqtt.client_id else "",
            username=mqtt.username,
            password=mqtt.password,
            protocol=mqtt.protocol,
            keepalive=mqtt.keepalive,
            connect_timeout=mqtt.connect_timeout,
            tls=mqtt.tls,
            reconnect=mqtt.reconnect,
        )


class SparkplugBuffer(Strict):
    """Store-and-forward while the broker or the primary host is away."""

    limit: int = Field(
        default=10_000,
        ge=1,
        le=10_000_000,
        description="DDATA messages kept (each holds one machine's changes of one publishing cycle); beyond "
        "it the oldest are dropped and counted",
    )
    persist: bool = Field(
        default=False,
        description="Also keep them in <state_dir>/sparkplug-backlog.sqlite3: they survive a restart",
    )


def _sparkplug_id(what: str, value: str) -> str:
    try:
        return check_id(what, value)
    except SparkplugError as exc:
        raise ValueError(exc.message) from None


class SparkplugConfig(Strict):
    """The gateway as a Sparkplug B edge node (gateway file). Absent: no Sparkplug."""

    group_id: str = Field(
        default="cnc", description="Sparkplug group id: spBv1.0/<group_id>/…; a plant, a hall, a line"
    )
    edge_node_id: str = Field(
        default_factory=lambda: "cnc-gateway" + (f"-shard-{k}" if (k := shard_index()) is not None else ""),
        description="This gateway's edge node id; unique in its group. Default: cnc-gateway, and for shard K"
        " of `cnc-gateway fleet` cnc-gateway-shard-K (each shard one edge node of the group)",
    )
    primary_host_id: str | None = Field(
        default=None,
        description="The primary host application (Ignition's MQTT Engine: its Primary Host ID): births and "
        "data wait until its STATE says online; meanwhile data is stored. Absent: publish at once",
    )
    broker: SparkplugBroker | None = Field(
        default=None, description="Another broker than the mqtt: section's (needed without an mqtt: section)"
    )
    buffer: SparkplugBuffer = SparkplugBuffer()
    max_pending_writes: int = Field(
        default=64, ge=1, le=100_000, description="DCMD writes (and commands) queued per machine"
    )
    max_packet_size: int = Field(
        default=2 * MIB,
        ge=MAX_PAYLOAD + 1024,
        le=MAX_PACKET_SIZE,
        description="Largest MQTT packet the edge node takes from its broker (NCMD, DCMD, STATE), in bytes; "
        f"above the {MAX_PAYLOAD} bytes of payload it decodes, so that a payload a little over is refused "
        "with its reason. As mqtt.max_packet_size: MQTT 5 tells the broker; MQTT 3.1.1 ends the connection",
    )

    @field_validator("group_id")
    @classmethod
    def _group(cls, value: str) -> str:
        _sparkplug_id("group_id", value)
        if value == "STATE":
            raise ValueError("group_id 'STATE' is where host applications publish their STATE")
        return value

    @field_validator("edge_node_id")
    @classmethod
    def _edge_node(cls, value: str) -> str:
        return _sparkplug_id("edge_node_id", value)

    @field_validator("primary_host_id")
    @classmethod
    def _host(cls, value: str | None) -> str | None:
        return None if value is None else _sparkplug_id("primary_host_id", value)

    def connection(self, mqtt: SharedBroker | None) -> SparkplugBroker:
        """The broker to connect to: `broker`, else the `mqtt:` section's (ValueError without either)."""
        if self.broker is not None:
            return self.broker
        if mqtt is None:
            raise ValueError("no broker: give sparkplug.broker, or an mqtt: section to share")
        return SparkplugBroker.of_mqtt(mqtt)
