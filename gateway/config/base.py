"""The base every config model derives from, and the backoff shape several sections share.

Kept apart from the section modules so that they can embed one another (the
mapping embeds jobs, jobs embeds validation rules) without an import cycle.
"""

from __future__ import annotations

from typing import Self

from pydantic import BaseModel, ConfigDict, Field, model_validator


class Strict(BaseModel):
    """Every config model rejects unknown keys and is immutable once loaded."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class Backoff(Strict):
    """Exponential backoff between attempts, in seconds."""

    # Sections subclass this for their own defaults (jobs.retry, mqtt.reconnect).

    initial: float = Field(default=0.5, gt=0)
    max: float = Field(default=10.0, gt=0)
    factor: float = Field(default=2.0, ge=1)

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if self.max < self.initial:
            raise ValueError(f"max ({self.max:g}) must not be below initial ({self.initial:g})")
        return self

    def delay(self, attempt: int) -> float:
        """Seconds to wait after failed attempt number `attempt` (1-based), before jitter."""
        return min(self.max, self.initial * self.factor ** max(0, attempt - 1))
