"""The two MTConnect drivers' settings (`driver:` in a mapping file). Both are read-only.

`driver: {type: mtconnect, url: http://agent:5000, device: haas-1}` (another agent) or
`driver: {type: shdr, host: 10.0.0.7, port: 7878}` (an adapter).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from gateway.settings.base import Backoff, Strict
from gateway.settings.urls import check_url

DEFAULT_SHDR_PORT = 7878


class MTConnectDriver(Strict):
    """Another MTConnect agent: /probe, then /sample?interval=… as a stream. Read-only."""

    type: Literal["mtconnect"]
    url: str = Field(description="The agent's base address, e.g. http://10.0.0.9:5000")
    device: str | None = Field(
        default=None, description="The device's name or uuid at the agent (needed when it has several)"
    )
    interval: int = Field(default=100, ge=0, le=60_000, description="ms between stream chunks")
    heartbeat: int = Field(default=2000, ge=100, le=600_000, description="ms of silence before a heartbeat")
    count: int = Field(default=10_000, ge=1, le=1_000_000, description="Observations per chunk at most")
    timeout: float = Field(default=5.0, gt=0, description="Seconds to wait for a response")
    reconnect: Backoff = Backoff()

    @field_validator("url")
    @classmethod
    def _url(cls, url: str) -> str:
        return check_url(url)

    @property
    def endpoint(self) -> str:
        return self.url if self.device is None else f"{self.url}/{self.device}"


class ShdrDriver(Strict):
    """An MTConnect adapter, straight over TCP (SHDR). Read-only."""

    type: Literal["shdr"]
    host: str
    port: int = Field(default=DEFAULT_SHDR_PORT, ge=1, le=65535)
    timeout: float = Field(default=5.0, gt=0, description="Seconds to connect")
    legacy_timeout: float = Field(
        default=600.0, gt=0, description="Seconds of silence from an adapter that does not answer PING"
    )
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"shdr://{self.host}:{self.port}"
