"""The gateway file: settings shared by every machine, and the list of mapping files."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from gateway.config.jobs import InboxConfig
from gateway.config.base import Strict
from gateway.config.mapping import check_endpoint
from gateway.config.mqtt import MqttConfig

SecurityMode = Literal["None"]


class OpcUaServerConfig(Strict):
    """The OPC UA server that SCADA clients connect to."""

    endpoint: str = "opc.tcp://0.0.0.0:4840/cnc-gateway"
    name: str = "cnc-gateway"
    namespace: str = Field(default="urn:cnc-gateway", description="Namespace URI of the gateway's nodes")
    security: list[SecurityMode] = Field(
        default_factory=lambda: ["None"],
        min_length=1,
        description="Endpoint security modes offered; signed and encrypted modes arrive with the security work",
    )

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, url: str) -> str:
        return check_endpoint(url)


class GatewayConfig(Strict):
    """Gateway-wide settings. A mapping file run on its own gets these defaults."""

    opcua: OpcUaServerConfig = OpcUaServerConfig()
    state_dir: str = Field(default="state", description="Where the gateway keeps its state; relative to this file")
    machines: list[str] = Field(default_factory=list, description="Mapping files, relative to this file")
    log_level: Literal["debug", "info", "warning", "error"] = "info"
    inbox: InboxConfig = Field(
        default_factory=InboxConfig, description="The FTP inbox that nesting software drops programs into"
    )
    mqtt: MqttConfig | None = Field(default=None, description="The MQTT broker to publish to; absent: no MQTT")
