"""The OPC UA driver's settings (`driver:` in a mapping file; `type: opcua`, the default when absent)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, SecretStr, field_validator

from gateway.settings.base import Backoff, Strict
from gateway.settings.urls import check_endpoint


class OpcUaDriver(Strict):
    """A controller with an OPC UA server (B&R, Siemens, Beckhoff, Fanuc with the option, the simulator)."""

    type: Literal["opcua"] = "opcua"
    endpoint: str
    username: str | None = None
    password: SecretStr | None = None
    security: str = Field(
        default="None",
        description="asyncua security string, e.g. Basic256Sha256,SignAndEncrypt,cert.pem,key.pem",
    )
    timeout: float = Field(default=5.0, gt=0, description="Seconds per request")
    publishing_interval: float = Field(default=100.0, gt=0, description="Milliseconds")
    watchdog_interval: float = Field(default=1.0, gt=0, description="Seconds between liveness probes")
    publish_requests: int = Field(
        default=1,
        ge=1,
        le=8,
        description="Publish requests kept at the controller. 1: the next only once an answer is in the "
        "tree, so a gateway that falls behind is handed just the newest value of each variable; more "
        "keep the controller answering while the gateway works (more changes per second from a busy "
        "controller, or over a slow link)",
    )
    reconnect: Backoff = Backoff()

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, url: str) -> str:
        return check_endpoint(url)
