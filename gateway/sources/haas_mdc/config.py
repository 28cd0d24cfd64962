"""The Haas NGC machine data collection driver (`driver: {type: haas-mdc, host, port: 5051}`).

A variable's `source` is an MDC address (gateway/codecs/haas_mdc/protocol.py: `Q104`, `Q500.parts`,
`#5021`, `Q600:10500`), checked at load time; Q600 variables with `access: readwrite` are written
with ?E through the checked write path.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.settings.base import Backoff, Strict

DEFAULT_MDC_PORT = 5051


class HaasMdcDriver(Strict):
    """A Haas NGC control's MDC port (Setting 143: its number, nonzero)."""

    type: Literal["haas-mdc"]
    host: str = Field(description="The control's address")
    port: int = Field(default=DEFAULT_MDC_PORT, ge=1, le=65535, description="Setting 143")
    timeout: float = Field(default=3.0, gt=0, description="Seconds to connect, and to wait for each answer")
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"mdc://{self.host}:{self.port}"
