"""The FOCAS delivery transport's settings (`jobs.controller: {type: focas, host, ...}`).

The driver's own settings (`driver: {type: focas}`) are in its folder, gateway/sources/focas/config.py.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.settings.base import Strict
from gateway.sources.focas.config import DEFAULT_FOCAS_PORT, DEFAULT_FOLDER


class ControllerFocas(Strict):
    """A Fanuc that takes programs over FOCAS2 (`jobs.controller: {type: focas, host}`): its CNC memory or
    data server folder, 30i-series file names."""

    type: Literal["focas"] = Field(description="focas: program transfer over FOCAS2 Ethernet")
    host: str = Field(min_length=1, description="The control's address")
    port: int = Field(default=DEFAULT_FOCAS_PORT, ge=1, le=65535)
    timeout: float = Field(default=10.0, gt=0, description="Seconds per connect and per answer")
    folder: str = Field(
        default=DEFAULT_FOLDER,
        pattern=r"^//[A-Za-z0-9_]+/[A-Za-z0-9_/]*/$",
        description="Where programs go: //CNC_MEM/USER/PATH1/ (memory) or the data server's folder",
    )

    @property
    def address(self) -> str:
        return f"focas://{self.host}:{self.port}{self.folder}"
