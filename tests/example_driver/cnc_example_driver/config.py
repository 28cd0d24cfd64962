"""The example driver's settings: `driver: {type: example, period: 0.05}`."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.settings.base import Strict


class ExampleDriver(Strict):
    """A counter and a memory, no controller (the example of a driver plugin)."""

    type: Literal["example"]
    period: float = Field(default=0.05, gt=0, le=60, description="Seconds between counts")

    @property
    def endpoint(self) -> str:
        return f"example://counter?period={self.period:g}"
