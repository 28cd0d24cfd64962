"""The base every config model derives from, and the shapes several sections share (backoff, type names).

Kept apart from the section modules so that they can embed one another (the
mapping embeds jobs, jobs embeds validation rules) without an import cycle.
"""

from __future__ import annotations

from typing import Annotated, Any, Self

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    WithJsonSchema,
    model_validator,
)

from gateway.model.types import TYPE_NAMES, TypeSpec


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


def _parse_type(value: Any) -> TypeSpec:
    if isinstance(value, TypeSpec):
        return value
    if not isinstance(value, str):
        raise ValueError(f"expected a type name such as Double, UInt16 or String[], got {value!r}")
    return TypeSpec.parse(value)


# A data type written by name (variables' type and source_type, command arguments): OPC UA built-in
# type names, a trailing [] for an array; the JSON Schema lists every name for editors.
TypeField = Annotated[
    TypeSpec,
    BeforeValidator(_parse_type),
    PlainSerializer(str, return_type=str),
    WithJsonSchema({"type": "string", "enum": TYPE_NAMES, "description": "OPC UA built-in type name"}),
]
