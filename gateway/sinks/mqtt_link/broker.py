"""The broker connection in the gateway file: the keys the `mqtt:` section and `sparkplug.broker` share.

Both sections name a broker the same way (host, port, client id, credentials, protocol, timings, TLS,
backoff), so the keys are written once here; each section adds its own (`mqtt:` its topics and
limits, `sparkplug.broker` nothing more). The field order is the sections' order in the JSON schema.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Protocol

from pydantic import BeforeValidator, Field, SecretStr, field_validator, model_validator

from gateway.settings.base import Backoff, Strict

MIB = 1024 * 1024
MAX_PACKET_SIZE = 268_435_455  # the largest packet MQTT can encode (a 4-byte remaining length)
CLIENT_ID_FORBIDDEN = "+#\x00"  # the MQTT wildcards and NUL: no client id of ours has them

ProtocolVersion = Literal["3.1.1", "5"]


def _protocol(value: Any) -> Any:
    """YAML reads `protocol: 5` as a number; accept it, and 3.1.1 written as text."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return value


class MqttTls(Strict):
    """TLS towards the broker. The broker's certificate and host name are verified unless `verify: false`."""

    ca: str | None = Field(
        default=None, description="CA certificate file (PEM); default: the system's trusted CAs"
    )
    cert: str | None = Field(
        default=None, description="Client certificate file (PEM), for brokers that require one"
    )
    key: str | None = Field(default=None, description="Client private key file (PEM); default: inside `cert`")
    key_password: SecretStr | None = None
    verify: bool = Field(
        default=True, description="Verify the broker's certificate and host name (keep this on)"
    )

    @model_validator(mode="after")
    def _key_needs_cert(self) -> MqttTls:
        if self.key is not None and self.cert is None:
            raise ValueError("tls.key needs tls.cert")
        return self


class MqttReconnect(Backoff):
    """Exponential backoff between connection attempts to the broker, in seconds."""

    initial: float = Field(default=1.0, gt=0)
    max: float = Field(default=30.0, gt=0)


class BrokerConnection(Strict):
    """Where the broker is and how to log in (the keys both sections start with)."""

    host: str = Field(default="127.0.0.1", min_length=1)
    port: int = Field(default=1883, ge=1, le=65535, description="1883, or usually 8883 with TLS")
    client_id: str = Field(
        default="",
        max_length=128,
        description="Default: cnc-gateway-<host name>; keep it stable for broker ACLs",
    )
    username: str | None = None
    password: SecretStr | None = Field(
        default=None, description="Use ${NAME} to take it from the environment"
    )
    protocol: Annotated[ProtocolVersion, BeforeValidator(_protocol)] = Field(
        default="3.1.1", description="MQTT protocol version: 3.1.1 or 5"
    )
    keepalive: int = Field(default=30, ge=5, le=65535, description="Seconds")
    connect_timeout: float = Field(default=5.0, gt=0, le=120, description="Seconds for TCP, TLS and CONNACK")
    tls: MqttTls | None = None

    @field_validator("client_id")
    @classmethod
    def _client_id(cls, value: str) -> str:
        if any(ch in CLIENT_ID_FORBIDDEN for ch in value) or any(ch.isspace() for ch in value):
            raise ValueError(f"client_id {value!r} must not contain spaces, '+', '#' or NUL")
        return value


class SharedBroker(Protocol):
    """A section whose broker another sink may share: the connection and its backoff (`mqtt:` is one)."""

    host: str
    port: int
    client_id: str
    username: str | None
    password: SecretStr | None
    protocol: ProtocolVersion
    keepalive: int
    connect_timeout: float
    tls: MqttTls | None
    reconnect: MqttReconnect
