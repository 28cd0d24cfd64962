"""What the tree is told about a machine and its variables: small frozen definitions.

The model owns these types; the configuration builds them from a mapping file
(gateway/config/mapping.py: `VariableSpec.definition()`, `MachineMapping.definition()`),
and the gateway builds its own variables (Status/…, Jobs/…) from the same type.
Nothing here knows YAML, pydantic or a driver: a variable's controller address is
an opaque string that only its source reads.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.model.types import TypeSpec


@dataclass(frozen=True, slots=True)
class Range:
    """Engineering range: shown to clients (OPC UA EURange) and enforced on writes."""

    min: float
    max: float

    def __post_init__(self) -> None:
        if not self.min < self.max:
            raise ValueError(f"range min ({self.min}) must be below max ({self.max})")


@dataclass(frozen=True, slots=True)
class VariableDefinition:
    """One variable: its place in the tree, its type, how raw values scale, who may write it.

    `source` is the driver's address of the variable ("ns=2;s=…" for OPC UA), empty
    for gateway-owned variables. `source_type` is the controller's own type when
    scaling changes it. `deadband` is absolute, in engineering units (0: every change).
    """

    path: str
    type: TypeSpec
    source: str = ""
    source_type: TypeSpec | None = None
    unit: str = ""
    description: str = ""
    writable: bool = False
    role: str | None = None  # lowest role that may write it; None: the machine's, else the gateway's default
    gain: float = 1.0
    offset: float = 0.0
    deadband: float = 0.0
    range: Range | None = None

    def __post_init__(self) -> None:
        if self.gain == 0:
            raise ValueError(f"{self.path}: a gain of zero cannot be undone for writes")
        if self.deadband < 0:
            raise ValueError(f"{self.path}: the deadband must not be negative")

    @property
    def raw_type(self) -> TypeSpec:
        """The type the controller holds (the variable's own type unless scaling changes it)."""
        return self.source_type or self.type

    @property
    def scaled(self) -> bool:
        return self.gain != 1.0 or self.offset != 0.0


@dataclass(frozen=True, slots=True)
class MachineDefinition:
    """One machine: its name, its variables, and what the tree itself needs to know of it.

    `write_role` is the lowest role that may write a variable whose definition
    names none (None: the gateway's default). `endpoint` is the controller's
    address as users know it, shown as `Status/Endpoint`. `acknowledge_role` is the
    lowest role that may acknowledge and confirm its alarms (None: it has no alarms).
    """

    name: str
    variables: tuple[VariableDefinition, ...]
    description: str = ""
    write_role: str | None = None
    endpoint: str = ""
    acknowledge_role: str | None = None
