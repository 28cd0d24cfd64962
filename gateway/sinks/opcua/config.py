"""The gateway file's `opcua:` section: the OPC UA server that SCADA clients connect to."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import Field, field_validator, model_validator

import gateway.sinks.opcua.extensions as extensions
from gateway.settings.sections import Sectioned, with_sections
from gateway.settings.urls import check_endpoint
from gateway.sinks.opcua.endpoints import Profile, SecurityName, check_security, endpoints_for

SecurityMode = SecurityName


class OpcUaServerConfig(Sectioned):
    """The OPC UA server that SCADA clients connect to."""

    endpoint: str = "opc.tcp://0.0.0.0:4840/cnc-gateway"
    name: str = "cnc-gateway"
    namespace: str = Field(default="urn:cnc-gateway", description="Namespace URI of the gateway's nodes")
    security: list[SecurityMode] | None = Field(
        default=None,
        min_length=1,
        description="Endpoints offered, e.g. [Basic256Sha256_SignAndEncrypt, None]; default: the profile's",
    )
    profile: Profile | None = Field(
        default=None,
        description="standard (default): None plus every signed and encrypted endpoint; "
        "secure: without None; open: None only",
    )
    redundant_servers: list[str] = Field(
        default_factory=list,
        description="With shard: lease, the application URIs of every server of the fleet, for their"
        " ServerUriArray (each shard's is urn:<host>:cnc-gateway:shard-K); empty: the shards of this host"
        " under cnc-gateway fleet",
    )

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, url: str) -> str:
        return check_endpoint(url)

    @model_validator(mode="after")
    def _security(self) -> OpcUaServerConfig:
        check_security(self.security, self.profile)
        return self

    @property
    def endpoints(self) -> tuple[str, ...]:
        """The security endpoints to offer (names from gateway.sinks.opcua.endpoints)."""
        return endpoints_for(self.security, self.profile)


if not TYPE_CHECKING:  # with the keys the extensions add under opcua: (none but those of other packages)
    OpcUaServerConfig = with_sections(OpcUaServerConfig, extensions.server_sections())
