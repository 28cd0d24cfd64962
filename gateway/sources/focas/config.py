"""The FOCAS2 Ethernet driver's settings (`driver: {type: focas, host, port: 8193, ...}`).

A variable's `source` is a FOCAS address (gateway/codecs/focas/address.py: `status.run`,
`position.absolute[X]`, `#500`, `pmc:R100.3`, ...), checked at load time; its `sampling_interval`
(ms, default `defaults.sampling_interval`) puts it in the poll group of that interval.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.settings.base import Backoff, Strict

DEFAULT_FOCAS_PORT = 8193
DEFAULT_FOLDER = "//CNC_MEM/USER/PATH1/"


class FocasDriver(Strict):
    """A Fanuc control over FOCAS2 Ethernet (0i-D/F, 30i/31i/32i-A/B, and older where reachable)."""

    type: Literal["focas"]
    host: str = Field(description="The control's address (its embedded Ethernet port)")
    port: int = Field(
        default=DEFAULT_FOCAS_PORT, ge=1, le=65535, description="The FOCAS2 port (parameter 14)"
    )
    timeout: float = Field(default=5.0, gt=0, description="Seconds to connect, and to wait for each answer")
    sessions: int = Field(
        default=2,
        ge=1,
        le=16,
        description="FOCAS sessions the gateway opens at most (a Fanuc takes few: leave some for others)",
    )
    max_commands: int = Field(
        default=32, ge=1, le=255, description="Commands per multi-command request (batched reads)"
    )
    max_alarms: int = Field(default=32, ge=1, le=200, description="Active alarms read per poll at most")
    folder: str = Field(
        default=DEFAULT_FOLDER,
        pattern=r"^//[A-Za-z0-9_]+/[A-Za-z0-9_/]*/$",
        description="Program folder for program.select by name, and for program transfer (30i-series paths)",
    )
    reconnect: Backoff = Backoff()

    @property
    def endpoint(self) -> str:
        return f"focas://{self.host}:{self.port}"
